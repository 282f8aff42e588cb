"""Demo: generate a short WareSynth sequence, stitch its layouts into a 3D map, export .glb/.json.

    .venv/bin/python demos/reconstruct_sequence.py [OUT_DIR]

Uses the ground-truth layouts; with a trained network, point `LayoutFolder` at the folder that
`mvracklay predict` wrote instead.
"""

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts import LayoutSpec  # noqa: E402
from stitching.export_gltf import export_glb  # noqa: E402
from stitching.pipeline import Stitcher  # noqa: E402
from stitching.warehouse_map import origin_from_record  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402
from waresynth.generate import DatasetSettings, generate_dataset  # noqa: E402

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="mvracklay_demo_"))
root = generate_dataset(
    out / "data",
    DatasetSettings(num_sequences=1, frames=30, image_size=(96, 96), spec=LayoutSpec(), seed=5, progress=False),
)
seq = open_dataset(root).sequences()[0]

stitcher = Stitcher(seq.spec)  # detect -> lift -> shift -> merge, one frame at a time
for i in range(seq.num_frames):
    frame, step = stitcher.push(seq.layouts(i), i)
    print(f"frame {i:2d}: {len(frame.boxes):2d} boxes seen, camera at {step.offset:+.3f} m ({step.method})")

wmap = stitcher.map(origin_world=origin_from_record(seq.frame(0)))
wmap.save(out / "warehouse.json")
export_glb(wmap, out / "warehouse.glb")
for rack in wmap.racks:
    for shelf in rack.shelves:
        print(f"{shelf.id}: {len(shelf.boxes)} boxes, clear height {shelf.clear_height:.2f} m")
print(f"wrote {out / 'warehouse.json'} and {out / 'warehouse.glb'}")
