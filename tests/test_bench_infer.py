"""`benchmarks/bench_infer.py`: figures per size and mode, with the frozen graphs (float32 or a bf16
trunk, in torch or ONNX Runtime) or the modules."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from network.model.ortgraph import available

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_infer.py"


def test_bench_infer_times_streaming_with_and_without_the_graphs(tmp_path):
    base = [sys.executable, str(SCRIPT), "--sizes", "64", "--frames", "3", "--repeats", "1", "--modes", "stream"]
    # the default (fp32 graphs) runs in every other inference test: here the modules and the graphs in bf16 (in
    # torch; tests/test_ortgraph.py holds ONNX Runtime's graphs to torch's)
    cases = ((["--no-graphs"], False, "fp32"), (["--precision", "bf16"], True, "bf16"))
    seq = tmp_path / "seq"  # a sequence's frames (any size, resized) for the first case
    (seq / "rgb").mkdir(parents=True)
    from PIL import Image

    for i in range(2):
        Image.new("RGB", (40, 30), (60 * i, 90, 120)).save(seq / "rgb" / f"{i:05d}.png")
    for flags, graphs, precision in cases:
        out = tmp_path / f"{graphs}{precision}.json"
        given = ["--sequence", str(seq)] if graphs is False else []
        done = subprocess.run(
            [*base, *flags, *given, "--threads", "1", "--json", str(out)], capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr
        (row,) = json.loads(out.read_text())
        assert row["frames_from"] == (str(seq) if given else "random")
        assert (row["size"], row["mode"], row["graphs"]) == (64, "stream", graphs) and row["fps_best"] > 0
        assert row["precision"] == precision and ("the trunk in bf16" in done.stdout) is (precision == "bf16")
        assert (row["graphs_built"] > 0) is graphs  # the trunk's, the slot maps' and the box-depth head's, or none
        assert ("no frozen graphs" in done.stdout) is not graphs
        asked = "onnx" if "--runtime" in flags else "torch"  # the tests' environment names torch (conftest)
        assert f"runtime {asked}," in done.stdout
        assert row["runtime"] == ("onnx" if asked == "onnx" and available() else "torch")  # what ran the trunk
