"""The README's pictures: a rendered view of a run's ``warehouse.glb`` and a preview sheet.

    .venv/bin/python scripts/readme_figures.py                    # the demo's seeded sequence, run here
    .venv/bin/python scripts/readme_figures.py --run out/demo/run --sequence out/demo/data/seq_00000
    .venv/bin/python scripts/readme_figures.py --building MAP      # a building map's building.glb

Without ``--run`` it generates the demo's sequence (`mvracklay.demo_job`: seed 2026, 50 frames,
256x256) and runs the shipped model on it in a work folder. The ``.glb`` is loaded with trimesh
and ray-cast headlessly with Open3D's ``RaycastingScene`` (no display or GL needed), shaded with
a fixed light and outlined where one object meets another; the preview sheet is
`waresynth.preview.write_sheet` of the sequence's middle frame. Both PNGs are palette-quantised
so they stay a few tens of KB, and the same inputs give the same bytes.
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import zlib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from layouts.errors import InputError  # noqa: E402
from layouts.fileio import atomic_write_bytes  # noqa: E402

OUT = ROOT / "docs" / "images"
SUPERSAMPLE = 2
BACKGROUND = np.array([246, 247, 249], np.float32)
FLOOR = np.array([214, 217, 222], np.float32)
LIGHT = np.array([-0.35, 0.85, 0.55])  # glTF frame: Y up, +Z toward the camera's side of the row


def load_glb(path: Path) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    """(name, vertices (V, 3), triangles (T, 3), RGB) per mesh of a ``.glb``, in world coordinates."""
    import trimesh

    if not path.is_file():
        raise InputError(f"{path}: file not found")
    scene = trimesh.load(path, force="scene")
    meshes = []
    for node in sorted(scene.graph.nodes_geometry):
        transform, name = scene.graph[node]
        mesh = scene.geometry[name]
        v = trimesh.transform_points(np.asarray(mesh.vertices, np.float64), transform)
        factor = getattr(mesh.visual.material, "baseColorFactor", None)
        colour = np.full(3, 180.0) if factor is None else _linear_to_srgb(np.asarray(factor)[:3] / 255.0)
        meshes.append((str(node), v, np.asarray(mesh.faces, np.int64), colour.astype(np.float32)))
    if not meshes:
        raise InputError(f"{path}: no meshes to render")
    return meshes


def _linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """glTF's linear base colour factors (0-1) -> sRGB 0-255, as a viewer shows them."""
    c = np.clip(c, 0.0, 1.0)
    return 255.0 * np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def _shade_colour(name: str, base: np.ndarray) -> np.ndarray:
    """A box's colour varied a little by its stable id, so neighbouring boxes read apart."""
    if "/box_" not in name:
        return base
    jitter = (zlib.crc32(name.encode()) % 1000) / 1000.0 - 0.5
    return np.clip(base * (1.0 + 0.22 * jitter), 0, 255)


def _camera(
    lo: np.ndarray, hi: np.ndarray, width: int, height: int, rise: float = 0.34
) -> tuple[np.ndarray, np.ndarray]:
    """Ray origins and unit directions of an oblique view (in front of the row, above it by ``rise`` times its
    length, from the left), its window fitted to the row's bounding box with a small margin."""
    centre = (lo + hi) / 2
    span = float(hi[0] - lo[0])
    eye = centre + np.array([-0.3 * span, rise * span + 1.2, 0.66 * span + 2.5])
    fwd = centre - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) - eye
    u = corners @ right / (corners @ fwd)
    v = corners @ up / (corners @ fwd)
    (u0, u1), (v0, v1) = (u.min(), u.max()), (v.min(), v.max())
    margin = 0.04 * (u1 - u0)
    u0, u1, v0, v1 = u0 - margin, u1 + margin, v0 - margin, v1 + margin
    # Widen the shorter side of the window to the picture's aspect ratio, keeping its centre.
    aspect = width / height
    if (u1 - u0) / (v1 - v0) < aspect:
        grow = (aspect * (v1 - v0) - (u1 - u0)) / 2
        u0, u1 = u0 - grow, u1 + grow
    else:
        grow = ((u1 - u0) / aspect - (v1 - v0)) / 2
        v0, v1 = v0 - grow, v1 + grow
    us = u0 + (np.arange(width) + 0.5) / width * (u1 - u0)
    vs = v1 - (np.arange(height) + 0.5) / height * (v1 - v0)
    d = fwd + us[None, :, None] * right + vs[:, None, None] * up
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(eye, d.shape).copy(), d


def render_glb(path: Path, width: int = 720, height: int = 300, rise: float = 0.34) -> np.ndarray:
    """An (H, W, 3) uint8 picture of the ``.glb`` from an oblique view above the row's front (``rise``: how high,
    as a share of the row's length)."""
    import open3d as o3d

    meshes = load_glb(path)
    lo = np.min([v.min(axis=0) for _, v, _, _ in meshes], axis=0)
    hi = np.max([v.max(axis=0) for _, v, _, _ in meshes], axis=0)
    rs = o3d.t.geometry.RaycastingScene(nthreads=1)
    colours = []
    for name, v, f, rgb in meshes:
        rs.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
        colours.append(_shade_colour(name, rgb))
    # The floor: a large quad at the lowest point, so the row stands on something.
    pad = 10 * (hi[0] - lo[0]) + 50.0
    floor_y = lo[1] - 0.002
    fv = np.array(
        [[lo[0] - pad, floor_y, lo[2] - pad], [hi[0] + pad, floor_y, lo[2] - pad],
         [hi[0] + pad, floor_y, hi[2] + pad], [lo[0] - pad, floor_y, hi[2] + pad]],
        np.float32,
    )  # fmt: skip
    rs.add_triangles(o3d.core.Tensor(fv), o3d.core.Tensor(np.array([[0, 2, 1], [0, 3, 2]], np.uint32)))
    colours.append(FLOOR)
    table = np.stack(colours + [BACKGROUND])

    w, h = width * SUPERSAMPLE, height * SUPERSAMPLE
    origin, dirs = _camera(lo, hi, w, h, rise)
    rays = o3d.core.Tensor(np.concatenate([origin, dirs], axis=-1).astype(np.float32))
    hit = rs.cast_rays(rays)
    gid = hit["geometry_ids"].numpy().astype(np.int64)
    miss = gid == o3d.t.geometry.RaycastingScene.INVALID_ID
    gid[miss] = len(table) - 1
    t = hit["t_hit"].numpy()
    normal = hit["primitive_normals"].numpy()
    normal *= np.where(np.einsum("hwc,hwc->hw", normal, dirs) > 0, -1.0, 1.0)[..., None]  # face the viewer

    light = LIGHT / np.linalg.norm(LIGHT)
    lambert = np.clip(normal @ light, 0.0, 1.0)
    shade = 0.58 + 0.42 * lambert
    # Shadows of the objects on the floor and on the boards below them, one ray toward the light.
    points = origin + dirs * np.where(miss, 0.0, t)[..., None]
    shadow_rays = np.concatenate([points + normal * 1e-3, np.broadcast_to(light, points.shape)], axis=-1)
    shadowed = np.isfinite(rs.cast_rays(o3d.core.Tensor(shadow_rays.astype(np.float32)))["t_hit"].numpy())
    shade = np.where(shadowed & ~miss, shade * 0.78, shade)
    img = table[gid] * np.where(miss, 1.0, shade)[..., None]

    # Outlines where one object meets another, or a face turns.
    edge = np.zeros(gid.shape, bool)
    for axis in (0, 1):
        dg = np.diff(gid, axis=axis) != 0
        dn = np.linalg.norm(np.diff(normal, axis=axis), axis=-1) > 0.3
        e = (dg | dn) & ~np.delete(miss, 0, axis=axis)
        if axis == 0:
            edge[1:] |= e
        else:
            edge[:, 1:] |= e
    floor_id = len(table) - 2
    edge &= ~((gid == floor_id) & np.roll(gid == floor_id, 1, axis=0) & np.roll(gid == floor_id, 1, axis=1))
    img[edge] = img[edge] * 0.35
    img = img.reshape(height, SUPERSAMPLE, width, SUPERSAMPLE, 3).mean(axis=(1, 3))
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def png_bytes(img, colours: int = 96) -> bytes:
    """A palette PNG (median-cut, no dithering) of an RGB array or PIL image: small, and the same bytes each time."""
    from PIL import Image

    im = img if isinstance(img, Image.Image) else Image.fromarray(img)
    q = im.convert("RGB").quantize(colors=colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    buf = io.BytesIO()
    q.save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def preview_png(sequence: Path, scale: float = 0.62) -> bytes:
    """The generator's preview sheet of the sequence's middle frame, shrunk and palette-quantised."""
    from PIL import Image

    from waresynth.dataset import open_dataset
    from waresynth.preview import write_sheet

    found = [s for s in open_dataset(sequence.parent).sequences() if s.root.resolve() == sequence.resolve()]
    if not found:
        raise InputError(f"--sequence {sequence}: not a sequence of the dataset in {sequence.parent}")
    seq = found[0]
    with tempfile.TemporaryDirectory() as tmp:
        sheet = Path(tmp) / "sheet.png"
        write_sheet(seq, seq.num_frames // 2, sheet, "demo")
        im = Image.open(sheet).convert("RGB")
        im.load()
    size = (round(im.width * scale), round(im.height * scale))
    return png_bytes(im.resize(size, Image.Resampling.LANCZOS), colours=128)


def demo_run(work: Path) -> tuple[Path, Path]:
    """The demo's seeded sequence, run with the shipped model: (run folder, sequence folder)."""
    from mvracklay.demo_job import main as demo_main

    rc = demo_main(["--out", str(work), "--quiet"])
    if rc != 0:
        raise InputError(f"the demo job failed (exit status {rc})")
    return work / "run", work / "data" / "seq_00000"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, help="an existing run folder with warehouse.glb (default: run the demo)")
    p.add_argument("--sequence", type=Path, help="a generated sequence folder for the preview sheet")
    p.add_argument("--work", type=Path, default=ROOT / "out" / "readme_figures", help="work folder of the demo run")
    p.add_argument("--out", type=Path, default=OUT, help="where the PNGs go")
    p.add_argument(
        "--building", type=Path, help="a building map folder (`mvracklay map`): render only its building.glb"
    )
    args = p.parse_args(argv)
    try:
        if args.building is not None:
            png = args.out / "building_glb.png"
            atomic_write_bytes(png, png_bytes(render_glb(args.building / "building.glb", 760, 420, rise=0.9)))
            print(f"wrote {png} ({png.stat().st_size // 1024} KB)")
            return 0
        run, sequence = (args.run, args.sequence) if args.run else demo_run(args.work)
        args.out.mkdir(parents=True, exist_ok=True)
        glb = args.out / "warehouse_glb.png"
        atomic_write_bytes(glb, png_bytes(render_glb(run / "warehouse.glb")))
        print(f"wrote {glb} ({glb.stat().st_size // 1024} KB)")
        if sequence is not None:
            sheet = args.out / "preview_sheet.png"
            atomic_write_bytes(sheet, preview_png(sequence))
            print(f"wrote {sheet} ({sheet.stat().st_size // 1024} KB)")
    except InputError as e:
        print(f"readme_figures: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
