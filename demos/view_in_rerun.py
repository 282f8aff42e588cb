"""Demo: log a stitched sequence to Rerun (RGB, layouts, per-frame cuboids, growing map, camera path).

    .venv/bin/python demos/view_in_rerun.py [OUT_DIR] [--spawn]

Writes OUT_DIR/warehouse.rrd (open it with `rerun OUT_DIR/warehouse.rrd`), or opens the viewer
with --spawn. Equivalent CLI: `mvracklay reconstruct SEQ_DIR --out OUT_DIR [--spawn]`.
"""

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts import LayoutSpec  # noqa: E402
from stitching import rerun_log  # noqa: E402
from stitching.pipeline import Stitcher  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402
from waresynth.generate import DatasetSettings, generate_dataset  # noqa: E402

args = [a for a in sys.argv[1:] if a != "--spawn"]
spawn = "--spawn" in sys.argv
out = Path(args[0]) if args else Path(tempfile.mkdtemp(prefix="mvracklay_demo_"))
root = generate_dataset(
    out / "data",
    DatasetSettings(num_sequences=1, frames=30, image_size=(128, 128), spec=LayoutSpec(), seed=3, progress=False),
)
seq = open_dataset(root).sequences()[0]

rec = rerun_log.start("mvracklay-demo", save=None if spawn else out / "warehouse.rrd", spawn=spawn)
stitcher = Stitcher(seq.spec)
path = []
for i in range(seq.num_frames):
    layouts = seq.layouts(i)
    frame, step = stitcher.push(layouts, i)
    path.append(rerun_log.camera_point(step.offset))
    rerun_log.log_frame(rec, i, layouts, frame, step.offset, rgb=seq.rgb(i), path=path)
    rerun_log.log_map(rec, stitcher.map(), i, seq.spec.num_slots)
rec.flush()
rec.disconnect()
if not spawn:
    print(f"wrote {out / 'warehouse.rrd'}: {sorted(rerun_log.read_entities(out / 'warehouse.rrd'))}")
