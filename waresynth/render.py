"""Ray-cast renderer on Open3D's ``RaycastingScene`` (CPU): RGB, depth, semantic and instance ids.

The scene is a set of cuboids (12 triangles each); per-triangle lookup tables map a primitive id
to the semantic id, instance id, material and face plane. Racks, boxes and clutter go into the
ray-casting scene; the floor and the back wall are planes intersected analytically by the rays
that miss everything else (they lie below / behind all other things), which keeps rays cheap.

Speed (2x2 block fill): rays are cast for the even pixels (the corners of 2x2 pixel blocks);
a block whose four corner rays hit the same planar face gets its three other pixels by
intersecting their rays with that face's plane (exact depth, same ids), and only blocks on
silhouettes or face edges cast their remaining rays. A thing smaller than two pixels that lies
wholly inside one block can be missed; ``exact=True`` casts every ray.

Shading: Lambert from one point light plus ambient, a Blinn-Phong highlight scaled by the
material's reflectance, shadows from shadow rays toward the light (cast from block corners and
averaged over the corners on the same face, which softens shadow edges by a pixel), procedural
textures computed from the hit point (`waresynth.textures`), exposure gain and Gaussian sensor
noise; a config's look (`waresynth.look`: light level, extra lights, white balance, vignetting, shot and
read noise, tone curve, a lens's rays, compression) when it has one. All vectorised numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from layouts.camera import Intrinsics
from waresynth import semantics as sem
from waresynth.look import SensorLook, amplification, lens_of
from waresynth.scene import Scene
from waresynth.textures import SurfaceTables, albedo

# Corner signs of a unit cube and its 12 triangles (two per face, consecutive).
_CORNERS = np.array(
    [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], np.float64
)
_TRIS = np.array(
    [
        [0, 1, 2], [0, 2, 3],  # -Z face
        [4, 6, 5], [4, 7, 6],  # +Z face
        [0, 4, 5], [0, 5, 1],  # -Y face
        [3, 2, 6], [3, 6, 7],  # +Y face
        [0, 3, 7], [0, 7, 4],  # -X face
        [1, 5, 6], [1, 6, 2],  # +X face
    ],
    np.uint32,
)  # fmt: skip

_MISS_COLOUR = (0.08, 0.08, 0.1)
_INVALID = np.uint32(0xFFFFFFFF)


@dataclass
class Frame:
    rgb: np.ndarray  #: uint8 (H, W, 3)
    depth_mm: np.ndarray  #: uint16 (H, W), Z depth in millimetres, 0 = no hit
    semantic: np.ndarray  #: uint8 (H, W)
    instance: np.ndarray  #: uint16 (H, W), 0 = none


def cuboid_mesh(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (8P, 3) float32, triangles (12P, 3) uint32 and triangle -> part index (12P,)."""
    n = len(scene.parts)
    centers = np.array([p.center for p in scene.parts], np.float64).reshape(n, 3)
    sizes = np.array([p.size for p in scene.parts], np.float64).reshape(n, 3)
    yaws = np.array([p.yaw for p in scene.parts], np.float64)
    local = _CORNERS[None] * sizes[:, None, :] / 2  # (P, 8, 3)
    c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    # Width axis (local x) -> (cos, 0, sin) in world (x, z); depth axis (local z) -> (-sin, 0, cos).
    wx = c * local[..., 0] - s * local[..., 2]
    wz = s * local[..., 0] + c * local[..., 2]
    verts = np.stack([wx, local[..., 1], wz], axis=-1) + centers[:, None, :]
    tris = _TRIS[None] + (np.arange(n, dtype=np.uint32) * 8)[:, None, None]
    tri_part = np.repeat(np.arange(n, dtype=np.int64), 12)
    return verts.reshape(-1, 3).astype(np.float32), tris.reshape(-1, 3), tri_part


#: Whether this process has built a renderer (and so may run Open3D/TBB threads): forking it is
#: then unsafe, and the dataset writer starts its workers from a clean forkserver instead.
RENDERER_USED = False
#: the most views a motion-blurred frame averages (`Renderer.motion_samples`)
MAX_MOTION_SAMPLES = 16


class Renderer:
    """Renders one scene from any camera position, the camera rotated as ``scene.camera`` says."""

    def __init__(
        self,
        scene: Scene,
        intrinsics: Intrinsics,
        nthreads: int = 1,
        exact: bool = False,
        noise_seed: int | None = 0,
        supersample: int = 1,
    ):
        global RENDERER_USED
        RENDERER_USED = True
        if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or not 1 <= supersample <= 4:
            raise ValueError(f"supersample must be an integer in [1, 4], got {supersample!r}")
        self.scene = scene
        self.intr = intrinsics
        self.nthreads = int(nthreads)
        w, h = intrinsics.width, intrinsics.height
        self.supersample = int(supersample)
        #: the renderer of the s x s sub-pixel grid whose means make the colours (None: one ray per pixel)
        self._fine: Renderer | None = None
        if self.supersample > 1:
            s = self.supersample
            self._fine = Renderer(scene, intrinsics.scaled(w * s, h * s), nthreads, exact, noise_seed=None)
        self.block = not exact and w % 2 == 0 and h % 2 == 0
        verts, tris, tri_part = cuboid_mesh(scene)
        self.n_tris = len(tris)
        self._init_casting(verts, tris, tri_part)
        self._init_tables(verts, tris, tri_part)
        self._init_rays()
        self.light = np.array(scene.light["position"], np.float32)
        # Sensor noise: each frame adds a random window of one Gaussian buffer per renderer.
        # (a sub-pixel renderer, noise_seed None, adds none: its means get the pixel's noise)
        if noise_seed is not None:
            n_noise = 3 * w * h + 65536
            sigma = np.float32(scene.sensor["noise_sigma"])
            self._noise_buf = np.random.default_rng(noise_seed).standard_normal(n_noise, dtype=np.float32) * sigma
        #: the sequence's look on the pixel colours (None: neutral, or a sub-pixel renderer)
        self.look: SensorLook | None = None
        if noise_seed is not None and scene.look:
            self.look = SensorLook(scene.look, intrinsics, scene.sensor["gain"], noise_seed)

    def _init_casting(self, verts: np.ndarray, tris: np.ndarray, tri_part: np.ndarray) -> None:
        """The ray-casting scene of the casters, and the floor and wall planes cast analytically."""
        # The floor (Y = 0, below everything) and the back wall (behind everything) are planes
        # intersected analytically where a ray misses the rest; the ray-casting scene holds only
        # racks, boxes and clutter, which keeps its rays cheap. The same scene answers shadow
        # rays: they run toward a light above and in front of the row, never into floor or wall.
        self._planes: list[tuple[str, int, float, tuple[float, ...]]] = []
        caster = np.ones(len(self.scene.parts), bool)
        for i, p in enumerate(self.scene.parts):
            if p.semantic in (sem.FLOOR, sem.WALL) and p.yaw == 0.0:
                (cx, cy, cz), (sx, sy, sz) = p.center, p.size
                if p.semantic == sem.FLOOR:  # its upper (-Y) face: triangles 4, 5
                    self._planes.append(
                        ("floor", i * 12 + 4, cy - sy / 2, (cx - sx / 2, cx + sx / 2, cz - sz / 2, cz + sz / 2))
                    )
                else:  # its front (-Z) face: triangles 0, 1
                    self._planes.append(
                        ("wall", i * 12, cz - sz / 2, (cx - sx / 2, cx + sx / 2, cy - sy / 2, cy + sy / 2))
                    )
                caster[i] = False
        keep = caster[tri_part]
        self.rs = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        if keep.any():
            self.rs.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(np.ascontiguousarray(tris[keep])))
        self.shadow_rs = self.rs
        self._tri_map = np.append(np.flatnonzero(keep), self.n_tris).astype(np.uint32)

    def _init_tables(self, verts: np.ndarray, tris: np.ndarray, tri_part: np.ndarray) -> None:
        """Per-triangle look-ups of the hits: ids, colours, reflectance, face normals and planes, textures."""
        # Per-triangle tables with one extra row (index n_tris) standing for "no hit".
        scene = self.scene
        parts, mats = scene.parts, scene.materials
        tp = np.append(tri_part, 0)

        def table(values, dtype, miss=0):
            arr = np.asarray(values, dtype)[tp]
            arr[-1] = miss
            return arr

        self.t_sem = table([p.semantic for p in parts], np.uint8)
        self.t_inst = table([p.instance for p in parts], np.uint16)
        m_idx = [p.material for p in parts]
        colour = np.array([mats[i].colour for i in m_idx], np.float32)
        ambient = max(float(scene.light["ambient"]), 1e-3)
        t_col = [table(colour[:, k], np.float32, _MISS_COLOUR[k] / ambient) for k in range(3)]
        t_pattern = table([mats[i].pattern for i in m_idx], np.int8)
        self.t_refl = table([mats[i].reflectance for i in m_idx], np.float32)
        # Outward face normals and planes (n . x = d) per triangle.
        v = verts.astype(np.float64)[tris.astype(np.int64)]
        nrm = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        centre = np.array([p.center for p in parts], np.float64)[tri_part]
        out = ((v.mean(1) - centre) * nrm).sum(1) < 0
        nrm[out] *= -1
        self.t_n = [np.append(nrm[:, k], 0.0).astype(np.float32) for k in range(3)]
        self.t_d = np.append((nrm * v[:, 0]).sum(1), 0.0)  # float64 for exact plane fills

        self.surface = SurfaceTables(
            pattern=t_pattern,
            part=tp,
            colour=t_col,
            normal_z=self.t_n[2],
            center=np.array([p.center for p in parts], np.float32),
            size=np.array([p.size for p in parts], np.float32),
            scale=np.array([mats[i].scale for i in m_idx], np.float32),
            cos=np.cos([p.yaw for p in parts]).astype(np.float32),
            sin=np.sin([p.yaw for p in parts]).astype(np.float32),
        )

    def _init_rays(self) -> None:
        """The world ray direction of every pixel (and of the 2x2 block corners), and its depth per unit length."""
        intrinsics = self.intr
        w, h = intrinsics.width, intrinsics.height
        cx, cy, fx, fy = intrinsics.cx, intrinsics.cy, intrinsics.fx, intrinsics.fy

        # Rays are cast in the world: a camera ray d is the world ray R d (R = I for a level camera,
        # which leaves every ray exactly as it was).
        rot = self.scene.camera.rotation
        # A lens (`waresynth.look`): pixel (u, v) of its image sees the pinhole ray of the undistorted point.
        lens = lens_of(self.scene.look)

        def directions(us: np.ndarray, vs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            u, vv = np.meshgrid(us + 0.5, vs + 0.5)
            x, y = (u - cx) / fx, (vv - cy) / fy
            if lens is not None:
                x, y = lens.undistort(x, y)
            d = np.stack([x, y, np.ones_like(u)], -1)
            d = d / np.linalg.norm(d, axis=-1, keepdims=True)
            return (d @ rot.T).astype(np.float32), d[..., 2].astype(np.float32)

        self.dirs, forward = directions(np.arange(w), np.arange(h))  # (H, W, 3) world, (H, W) along the axis
        self.dflat = [np.ascontiguousarray(self.dirs[..., k]).reshape(-1) for k in range(3)]
        #: per pixel, the Z depth (along the optical axis) of a unit of ray length
        self.depth_per_t = np.ascontiguousarray(forward).reshape(-1)
        if self.block:
            self.cdirs = directions(np.arange(0, w + 1, 2), np.arange(0, h + 1, 2))[0]  # (H/2+1, W/2+1, 3)

    # ------------------------------------------------------------------ ray casting
    def _cast(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(t, prim) for rays from ``origin`` along unit ``dirs`` (..., 3); misses give inf / n_tris."""
        shape = dirs.shape[:-1]
        rays = np.empty((int(np.prod(shape)), 6), np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = dirs.reshape(-1, 3)
        res = self.rs.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=self.nthreads)
        t = res["t_hit"].numpy().reshape(-1).copy()
        prim = res["primitive_ids"].numpy().reshape(-1)
        prim = self._tri_map[np.minimum(prim, np.uint32(len(self._tri_map) - 1))]
        miss = np.flatnonzero(prim == self.n_tris)
        if len(miss) and self._planes:
            d = rays[miss, 3:]
            best = np.full(len(miss), np.inf, np.float32)
            best_prim = np.full(len(miss), self.n_tris, np.uint32)
            for kind, tri, level, (a0, a1, b0, b1) in self._planes:
                axis, u_axis, v_axis = (1, 0, 2) if kind == "floor" else (2, 0, 1)
                dn = d[:, axis]
                with np.errstate(divide="ignore", invalid="ignore"):
                    tt = (np.float32(level) - origin[axis]) / dn
                    u = origin[u_axis] + tt * d[:, u_axis]
                    v = origin[v_axis] + tt * d[:, v_axis]
                ok = (dn > 0) & (tt > 0) & (tt < best) & (u >= a0) & (u <= a1) & (v >= b0) & (v <= b1)
                best = np.where(ok, tt, best)
                best_prim = np.where(ok, np.uint32(tri), best_prim)
            t[miss] = best
            prim[miss] = best_prim
        return t.reshape(shape), prim.reshape(shape)

    def _occluded(self, px, py, pz, sel: np.ndarray) -> np.ndarray:
        """Shadow test toward the light for the points ``sel`` of flat arrays px, py, pz (+ normal offset)."""
        if not len(sel):
            return np.zeros(0, bool)
        prim = self._prim_flat[sel]
        rays = np.empty((len(sel), 6), np.float32)
        for k, (p, n) in enumerate(zip((px, py, pz), self.t_n)):
            q = p[sel] + n[prim] * np.float32(2e-3)
            rays[:, k] = q
            rays[:, 3 + k] = self.light[k] - q
        occ = self.shadow_rs.test_occlusions(
            o3d.core.Tensor.from_numpy(rays), tnear=0.0, tfar=0.999, nthreads=self.nthreads
        )
        return occ.numpy().astype(bool)

    def _trace(self, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Full-resolution t (H*W,; 0 where nothing is hit) and prim (H*W,), plus the filled-block mask
        (H/2, W/2) or None."""
        t, prim, agree = self._trace_rays(origin)
        t[prim == self.n_tris] = 0.0
        return t, prim, agree

    def _trace_rays(self, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        h, w = self.intr.height, self.intr.width
        if not self.block:
            t, prim = self._cast(origin, self.dirs)
            return t.reshape(-1), prim.reshape(-1), None
        tc, pc = self._cast(origin, self.cdirs)  # corner grid (H/2+1, W/2+1)
        fc = pc >> 1  # face id (both triangles of a face share it)
        f00 = fc[:-1, :-1]
        agree = (f00 == fc[:-1, 1:]) & (f00 == fc[1:, :-1]) & (f00 == fc[1:, 1:])
        p00 = np.ascontiguousarray(pc[:-1, :-1])
        hit = agree & (p00 != self.n_tris)
        t = np.empty((h // 2, 2, w // 2, 2), np.float32)
        prim = np.empty((h // 2, 2, w // 2, 2), np.uint32)
        t[:, 0, :, 0] = tc[:-1, :-1]
        prim[:, 0, :, 0] = p00
        nx, ny, nz = (n[p00] for n in self.t_n)
        num = (self.t_d[p00] - (nx * origin[0] + ny * origin[1] + nz * origin[2])).astype(np.float32)
        d4 = self.dirs.reshape(h // 2, 2, w // 2, 2, 3)
        for sy, sx in ((0, 1), (1, 0), (1, 1)):
            dd = d4[:, sy, :, sx]
            den = nx * dd[..., 0] + ny * dd[..., 1] + nz * dd[..., 2]
            den[~hit] = 1.0
            t[:, sy, :, sx] = np.where(hit, num / den, np.float32(np.inf))
            prim[:, sy, :, sx] = p00
        need = np.zeros((h // 2, 2, w // 2, 2), bool)
        need[:] = ~agree[:, None, :, None]
        need[:, 0, :, 0] = False
        sel = np.flatnonzero(need)
        t = t.reshape(-1)
        prim = prim.reshape(-1)
        if len(sel):
            tt, pp = self._cast(origin, self.dirs.reshape(-1, 3)[sel])
            t[sel] = tt
            prim[sel] = pp
        return t, prim, agree

    # ------------------------------------------------------------------ shading
    def render(self, position: np.ndarray, rng: np.random.Generator, motion: np.ndarray | None = None) -> Frame:
        """Render the view from world ``position`` (x, y, z); ``rng`` draws the sensor noise.

        Depth, semantics and instances are sampled at the pixel centres; with ``supersample`` s > 1
        each pixel's colour is the mean of an s x s grid of rays spread over its area, as a sensor
        integrates light (sub-pixel edges instead of staircases), and the noise is added after.
        ``motion`` (world metres, (3,)): the camera's travel while the shutter is open, centred on
        ``position``; the colours are then the mean over views along it (`motion_samples`), the
        labels stay ``position``'s.
        """
        w, h = self.intr.width, self.intr.height
        origin = np.asarray(position, np.float32)
        t, prim, agree = self._trace(origin)
        # Cameras stay >= 0.2 m above the floor, so every hit is deeper than 0.5 mm (never 0).
        z_mm = t * self.depth_per_t
        z_mm *= np.float32(1000.0)
        np.rint(z_mm, out=z_mm)
        np.clip(z_mm, 0, 65535, out=z_mm)
        depth_mm = z_mm.astype(np.uint16)
        semantic = np.take(self.t_sem, prim)
        instance = np.take(self.t_inst, prim)
        k = self.motion_samples(motion)
        if k == 1:
            cols = self._colours(origin, (t, prim, agree))
        else:
            travel = np.asarray(motion, np.float32)
            cols = self._colours(origin + travel * np.float32(0.5 / k - 0.5))
            for j in range(1, k):
                for c, more in zip(cols, self._colours(origin + travel * np.float32((j + 0.5) / k - 0.5))):
                    c += more
            for c in cols:
                c *= np.float32(1.0 / k)
        if self.look is not None:
            self.look.linear(cols, rng)
        noise = self._noise(rng)
        rgb = np.empty((h * w, 3), np.uint8)
        n_px = h * w
        for k in range(3):
            c = cols[k]
            c += noise[k * n_px : (k + 1) * n_px]
            np.clip(c, 0, 255, out=c)
            rgb[:, k] = c
        rgb = rgb.reshape(h, w, 3)
        if self.look is not None:
            rgb = self.look.compress(rgb, rng)
        return Frame(rgb, depth_mm.reshape(h, w), semantic.reshape(h, w), instance.reshape(h, w))

    def motion_samples(self, motion: np.ndarray | None) -> int:
        """Views averaged for a camera travel ``motion`` during the exposure: enough that the rack front moves
        at most a pixel between two (1 when the camera stands still), at most MAX_MOTION_SAMPLES."""
        if motion is None:
            return 1
        travel = float(np.linalg.norm(np.asarray(motion, np.float64)))
        if not np.isfinite(travel):
            raise ValueError(f"motion must be a finite (3,) vector in metres, got {motion!r}")
        pixels = travel * self.intr.fx / max(self.scene.camera.distance, 1e-6)
        return 1 if travel == 0.0 else int(min(MAX_MOTION_SAMPLES, max(2, math.ceil(pixels) + 1)))

    def _colours(self, origin: np.ndarray, traced: tuple | None = None) -> list[np.ndarray]:
        """`_radiance` from ``origin`` (``traced``: its `_trace`, when known), over the sub-pixel grid when
        supersampled."""
        if self._fine is None:
            return self._radiance(origin, *(traced if traced is not None else self._trace(origin)))
        w, h, s = self.intr.width, self.intr.height, self.supersample
        sub = self._fine._radiance(origin, *self._fine._trace(origin))
        return [c.reshape(h, s, w, s).mean((1, 3), dtype=np.float32).reshape(-1) for c in sub]

    def _radiance(self, origin: np.ndarray, t: np.ndarray, prim: np.ndarray, agree) -> list[np.ndarray]:
        """Colour channels (3 x (H*W,) float32, 8-bit levels + 0.5 for rounding, before noise) of the hits
        ``t``, ``prim`` and block mask ``agree`` of `_trace`."""
        self._face = prim >> 1  # uint32 face ids (both triangles of a face share one)
        prim = prim.astype(np.intp)  # one conversion for the many table look-ups below
        self._prim_flat = prim
        miss = prim == self.n_tris
        dx, dy, dz = self.dflat
        px, py, pz = origin[0] + t * dx, origin[1] + t * dy, origin[2] + t * dz
        nx, ny, nz = (np.take(n, prim) for n in self.t_n)
        cols = albedo(self.surface, prim, px, py, pz)

        # Misses have t = 0 and a zero normal: no diffuse, no highlight, and the miss row of the
        # colour table is pre-divided by the ambient term, so they come out in the miss colour.
        light = self.scene.light
        lx, ly, lz = self.light[0] - px, self.light[1] - py, self.light[2] - pz
        dist2 = lx * lx + ly * ly + lz * lz
        inv = np.float32(1.0) / np.sqrt(dist2)
        lx *= inv
        ly *= inv
        lz *= inv
        ndl = np.maximum(nx * lx + ny * ly + nz * lz, np.float32(0.0))
        vis = self._visibility(px, py, pz, ndl, agree, miss)
        look = self.scene.look
        gain = 255.0 * self.scene.sensor["gain"]
        if look:
            gain *= math.prod(amplification(look))
        gain = np.float32(gain)
        falloff = np.float32(look.get("falloff", 0.015))
        diffuse = (np.float32(light["intensity"]) * gain) * ndl * vis / (np.float32(1.0) + falloff * dist2)
        hx, hy, hz = lx - dx, ly - dy, lz - dz
        ndh = np.maximum(nx * hx + ny * hy + nz * hz, np.float32(0.0))
        ndh /= np.sqrt(hx * hx + hy * hy + hz * hz + np.float32(1e-12))
        ndh *= ndh
        ndh8 = ndh * ndh
        ndh8 *= ndh8
        spec = (np.take(self.t_refl, prim) * gain) * ndh8 * ndh8 * ndh8 * vis  # (n.h)^24
        spec[ndl <= 0] = 0.0
        spec += np.float32(0.5)  # rounds on the cast to uint8
        shade = np.float32(light["ambient"]) * gain + diffuse
        for extra in look.get("extra_lights", ()):
            shade += self._extra_light(extra, px, py, pz, nx, ny, nz, gain, falloff)
        out = []
        for k in range(3):
            c = cols[k] * shade
            c += spec
            out.append(c)
        return out

    @staticmethod
    def _extra_light(extra: dict, px, py, pz, nx, ny, nz, gain: np.float32, falloff: np.float32) -> np.ndarray:
        """Lambert shading (8-bit levels) from one of the look's extra lights along the aisle: distance falloff,
        no shadow ray and no highlight (they cost a cast each)."""
        lx, ly, lz = (np.float32(q) - p for q, p in zip(extra["position"], (px, py, pz)))
        dist2 = lx * lx + ly * ly + lz * lz
        ndl = np.maximum(nx * lx + ny * ly + nz * lz, np.float32(0.0)) / np.sqrt(dist2)
        return (np.float32(extra["intensity"]) * gain) * ndl / (np.float32(1.0) + falloff * dist2)

    def _visibility(self, px, py, pz, ndl, agree, miss) -> np.ndarray:
        """Light visibility per pixel: 1 lit, 1 - shadow_strength in shadow.

        With block fill, shadow rays are cast from the block corners; another pixel averages
        the corners of its block that lie on its own face (which softens shadow edges by a
        pixel) and casts its own ray only when none does.
        """
        h, w = self.intr.height, self.intr.width
        dark = np.float32(1.0 - self.scene.light["shadow_strength"])
        one = np.float32(1.0)
        vis = np.ones(h * w, np.float32)
        lit = (ndl > 0) & ~miss
        if agree is None:
            sel = np.flatnonzero(lit)
            vis[sel] = np.where(self._occluded(px, py, pz, sel), dark, one)
            return vis
        hb, wb = h // 2, w // 2
        v4 = vis.reshape(hb, 2, wb, 2)
        lit4 = lit.reshape(hb, 2, wb, 2)
        face4 = self._face.reshape(hb, 2, wb, 2)
        cidx = np.arange(h * w).reshape(hb, 2, wb, 2)[:, 0, :, 0]
        csel = cidx[lit4[:, 0, :, 0]]
        vis[csel] = np.where(self._occluded(px, py, pz, csel), dark, one)
        # Corner grid with the far row/column (outside the image) marked as matching no face.
        cface = np.full((hb + 1, wb + 1), 0xFFFFFFFF, np.uint32)
        cface[:-1, :-1] = face4[:, 0, :, 0]
        cvis = np.zeros((hb + 1, wb + 1), np.float32)
        cvis[:-1, :-1] = v4[:, 0, :, 0]
        corners = [(cface[a : a + hb, b : b + wb], cvis[a : a + hb, b : b + wb]) for a in (0, 1) for b in (0, 1)]
        need = np.zeros((hb, 2, wb, 2), bool)
        for sy, sx in ((0, 1), (1, 0), (1, 1)):
            f = face4[:, sy, :, sx]
            total = np.zeros((hb, wb), np.float32)
            count = np.zeros((hb, wb), np.float32)
            for cf, cv in corners:
                m = cf == f
                np.add(total, cv, out=total, where=m)
                count += m
            v4[:, sy, :, sx] = np.where(count > 0, total / np.maximum(count, one), one)
            need[:, sy, :, sx] = (count == 0) & lit4[:, sy, :, sx]
        sel = np.flatnonzero(need)
        if len(sel):
            vis[sel] = np.where(self._occluded(px, py, pz, sel), dark, one)
        return vis

    def _noise(self, rng: np.random.Generator) -> np.ndarray:
        """Sensor noise for one frame: a window of the renderer's Gaussian buffer chosen by ``rng``."""
        n = 3 * self.intr.width * self.intr.height
        off = int(rng.integers(65536))
        return self._noise_buf[off : off + n]
