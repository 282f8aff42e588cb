"""One sequence of a WareSynth dataset rendered to disk: its frames (RGB, depth, semantic, instance), layouts,
scene.json and meta.json, written under a temporary name and renamed when complete (`waresynth.generate` writes
many)."""

from __future__ import annotations

import os
import resource
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from layouts.camera import Intrinsics
from layouts.camera_record import CAMERA_ANGLE_KEYS
from layouts.codecs import FrameLayouts, LayoutFolder
from layouts.fileio import atomic_write_json
from layouts.spec import LayoutSpec
from waresynth.config import draw_hfov
from waresynth.groundtruth import frame_layouts, frame_slots
from waresynth.imageio import write_png
from waresynth.look import lens_of
from waresynth.render import Renderer
from waresynth.row_plan import CameraPlan, RowPlan
from waresynth.scene import Scene
from waresynth.scene_builder import build_scene


def _frame_record(
    scene: Scene, i: int, pos: np.ndarray, slots: list[dict[str, Any]], lay: FrameLayouts
) -> dict[str, Any]:
    """Frame ``i``'s record in meta.json: camera position, distance, the slots' boards and origins, view share."""
    return {
        "index": i,
        "camera_position": [float(v) for v in pos],
        "distance": float(scene.camera.distance),
        "rack_mid_z": float(scene.rack_mid_z),
        "slots": [{**sl, "origin": [float(pos[0]), sl["board_top_y"], float(scene.rack_mid_z)]} for sl in slots],
        "visible_fraction": float(lay.visible.mean()),
    }


def _sequence_meta(
    entry: dict[str, Any], scene: Scene, intr: Intrinsics, hfov: float, records: list[dict[str, Any]]
) -> dict[str, Any]:
    """The sequence's meta.json: its entry, intrinsics, camera, scene facts and the frame records."""
    name, seed, frames, distance = entry["name"], int(entry["seed"]), int(entry["frames"]), scene.camera.distance
    return {
        "name": name,
        "split": entry["split"],
        "seed": seed,
        "num_frames": frames,
        "image_size": [intr.width, intr.height],
        # a lens's coefficients beside fx..cy, as `layouts.camera_record.lens_from_record` reads them
        "intrinsics": {**intr.to_dict(), **(lens.to_dict() if (lens := lens_of(scene.look)) else {})},
        "step": float(scene.camera.step),
        "camera": {
            "height": scene.camera.height,
            "distance": distance,
            "hfov_deg": hfov,
            **dict(zip(CAMERA_ANGLE_KEYS, scene.camera.angles)),
            "motion_blur": float(scene.sensor["motion_blur"]),
        },
        "rack_mid_z": float(scene.rack_mid_z),
        "visible_levels": scene.visible_levels,
        "background": scene.background,
        "density": scene.density,
        "frames": records,
    }


def write_sequence(
    root: Path,
    entry: dict[str, Any],
    spec: LayoutSpec,
    cfg: dict[str, Any],
    image_size: tuple[int, int],
    nthreads: int = 1,
    on_frame: Callable[[], None] | None = None,
    planned: tuple[RowPlan, CameraPlan] | None = None,
) -> dict[str, Any]:
    """Render one sequence into ``root/.NAME.tmp`` and rename it to ``root/NAME`` when complete.

    ``planned``: its row and camera path as planned (a pass of `waresynth.building.plan`), else sampled.
    Returns what it cost in the process that wrote it: name, frames, cpu_seconds, max_rss_mib.
    """
    cpu0 = time.process_time()
    name, seed, frames = entry["name"], int(entry["seed"]), int(entry["frames"])
    final, tmp = root / name, root / f".{name}.tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    hfov = draw_hfov(cfg, seed)
    intr = Intrinsics.from_fov(image_size[0], image_size[1], hfov)
    scene_rng = np.random.default_rng(np.random.SeedSequence([seed, 0]))
    noise_rng = np.random.default_rng(np.random.SeedSequence([seed, 1]))
    scene = build_scene(scene_rng, cfg, intr, frames, planned, spec.x_extent)
    renderer = Renderer(
        scene,
        intr,
        nthreads=nthreads,
        noise_seed=int(noise_rng.integers(2**63)),
        supersample=cfg["sensor"]["supersample"],
    )
    for sub in ("rgb", "depth", "semantic", "instance"):
        (tmp / sub).mkdir(parents=True)
    folder = LayoutFolder.create(tmp / "layouts", spec)
    sampled = planned is None  # a building's planned pass keeps the levels its route names
    slots = frame_slots(scene, spec, sampled)
    # the camera's travel while the shutter is open (centred on the frame's position)
    exposure = np.array([scene.sensor["motion_blur"] * scene.camera.step, 0.0, 0.0])
    records = []
    for i, pos in enumerate(scene.camera.positions):
        fr = renderer.render(pos, noise_rng, motion=exposure)
        fname = f"{i:06d}.png"
        write_png(tmp / "rgb" / fname, fr.rgb)
        write_png(tmp / "depth" / fname, fr.depth_mm)
        write_png(tmp / "semantic" / fname, fr.semantic)
        write_png(tmp / "instance" / fname, fr.instance)
        lay = frame_layouts(scene, spec, float(pos[0]), sampled)
        folder.write(i, lay)
        records.append(_frame_record(scene, i, pos, slots, lay))
        if on_frame:
            on_frame()
    atomic_write_json(tmp / "scene.json", scene.to_dict())
    meta = _sequence_meta(entry, scene, intr, hfov, records)
    atomic_write_json(tmp / "meta.json", meta)
    os.replace(tmp, final)
    return {
        "name": name,
        "frames": frames,
        "cpu_seconds": time.process_time() - cpu0,
        "max_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
