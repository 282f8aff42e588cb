"""The shipped weights' layouts on a fixed generated sequence, byte for byte: a restructuring of the code
must not change what a user gets. The digests in `data/layout_digests.json` were made with the same
commands; the network runs in a subprocess on one thread with the CPU kernels pinned to one instruction
set (AVX2 and MKL's compatible path) in torch's graphs (``MVRACKLAY_RUNTIME=torch``: ONNX Runtime, the default
where installed, picks its kernels by the CPU and cannot be pinned; `tests/test_ortgraph.py` holds it to
torch's outputs), so the figures do not depend on the machine's CPU features."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DIGESTS = Path(__file__).with_name("data") / "layout_digests.json"
#: pinned kernels: the same arithmetic on any x86-64 CPU with AVX2 (every one of the last decade)
PINNED = {"ONEDNN_MAX_CPU_ISA": "AVX2", "ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "COMPATIBLE",
          "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MVRACKLAY_RUNTIME": "torch"}  # fmt: skip


def layout_digest(folder: Path) -> str:
    """sha256 over every frame's top, front and visible arrays (not the .npz bytes, which hold zip times)."""
    h = hashlib.sha256()
    files = sorted(folder.glob("[0-9]*.npz"))
    assert files, f"no layouts in {folder}"
    for f in files:
        with np.load(f, allow_pickle=False) as z:
            for key in sorted(z.files):
                a = np.ascontiguousarray(z[key])
                h.update(f"{f.name}:{key}:{a.dtype}:{a.shape}".encode())
                h.update(a.tobytes())
    return h.hexdigest()


#: the three commands in one pinned interpreter (torch and the models imported once): generate a sequence, `run`
#: with the default model and `predict` with the 256x256 one
COMMANDS = r"""
import sys
from pathlib import Path
from mvracklay.cli import main
tmp = Path(sys.argv[1])
data = tmp / "data"
assert main(["generate", str(data), "--sequences", "1", "--frames", "6", "--size", "256", "--seed", "11"]) == 0
seq = next(p for p in sorted(data.iterdir()) if p.is_dir() and (p / "meta.json").is_file())
assert main(["run", str(seq), "--out", str(tmp / "run"), "--no-rrd", "--threads", "1", "--quiet"]) == 0
assert main(["predict", str(seq), "--checkpoint", "mvracklay-disc-4-256", "--out", str(tmp / "pred256"),
             "--threads", "1", "--quiet"]) == 0
"""


def compute(tmp: Path) -> dict[str, str]:
    """The digests: `run` with the default model and `predict` with the 256x256 one, 6 frames, seed 11."""
    env = {**os.environ, **PINNED}
    subprocess.run([sys.executable, "-c", COMMANDS, str(tmp)], cwd=ROOT, env=env, check=True, capture_output=True,
                   text=True)  # fmt: skip
    return {"run_default": layout_digest(tmp / "run" / "layouts"), "predict_256": layout_digest(tmp / "pred256")}


@pytest.mark.skipif(not DIGESTS.is_file(), reason="no stored digests")
def test_the_shipped_models_layouts_are_unchanged(tmp_path):
    assert compute(tmp_path) == json.loads(DIGESTS.read_text())


if __name__ == "__main__":  # python tests/test_shipped_layouts_digest.py: store the digests anew
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        DIGESTS.write_text(json.dumps(compute(Path(d)), indent=2) + "\n")
    print(DIGESTS.read_text())
