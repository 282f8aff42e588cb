"""Demo: how much room is left on each shelf, and where does a 40 x 30 x 30 cm carton fit?

.venv/bin/python demos/free_space_query.py [OUT_DIR]
"""

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts import LayoutSpec  # noqa: E402
from stitching.free_space import fits, format_table, free_space  # noqa: E402
from stitching.pipeline import folder_frames, reconstruct  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402
from waresynth.generate import DatasetSettings, generate_dataset  # noqa: E402

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="mvracklay_demo_"))
root = generate_dataset(
    out / "data",
    DatasetSettings(num_sequences=1, frames=30, image_size=(96, 96), spec=LayoutSpec(), seed=9, progress=False),
)
seq = open_dataset(root).sequences()[0]
wmap = reconstruct(folder_frames(seq.layout_folder), seq.spec, indexed=True).map

print(format_table(free_space(wmap)))
print()
for fit in fits(wmap, 0.40, 0.30, 0.30, margin=0.02):
    where = ", ".join(f"{a:.2f}..{b:.2f} m" for a, b in fit.centres)
    print(f"a 40x30x30 cm carton fits on {fit.shelf}{' (turned)' if fit.rotated else ''}: centre at X {where}")
