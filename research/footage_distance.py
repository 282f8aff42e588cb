"""Held-out sequences as footage without metadata: the distance read, and the maps against the recorded camera.

    python research/footage_distance.py data/heldout256 --sequences 10 --work /tmp/footage

For each of the first N sequences: its RGB frames as a phone folder (``IMG_0001.jpg`` ..., JPEG 90) and as a
10 fps H.264 ``.mp4``; ``mvracklay run`` on both (no camera file, no distance) and on the sequence itself with
``--distance`` set -10 / +5 / +10 / +20 % off its recorded one and at the recorded one, and on the folder with
``--camera-height`` (the true one, as a robot's mount knows it); each map scored with
``mvracklay eval-reconstruction SEQ --map OUT/warehouse.json --scale-corrected --json``. Prints the reading
errors (median, 90th percentile) and the maps' figures as they are and with the scale corrected.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

PY = sys.executable
FACTORS = (0.9, 1.05, 1.1, 1.2)


def mvracklay(*args: str) -> str:
    r = subprocess.run([PY, "-m", "mvracklay", *args], capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"mvracklay {' '.join(args)} failed: {r.stderr.strip()[-400:]}")
    return r.stdout


def to_footage(seq: Path, work: Path) -> tuple[Path, Path]:
    """The sequence's frames as a JPEG phone folder and an mp4 (no metadata)."""
    import av

    folder, video = work / "phone" / seq.name, work / "video" / f"{seq.name}.mp4"
    frames = [np.asarray(Image.open(p).convert("RGB")) for p in sorted((seq / "rgb").glob("*.png"))]
    if not folder.is_dir():
        folder.mkdir(parents=True)
        for i, rgb in enumerate(frames):
            Image.fromarray(rgb).save(folder / f"IMG_{i + 1:04d}.jpg", quality=90)
    if not video.is_file():
        video.parent.mkdir(parents=True, exist_ok=True)
        with av.open(str(video), "w") as c:
            st = c.add_stream("libx264", rate=10)
            st.width, st.height, st.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv420p"
            for rgb in frames:
                c.mux(st.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
            c.mux(st.encode())
    return folder, video


def run_and_score(inp: Path, seq: Path, out: Path, *extra: str) -> dict:
    if not (out / "warehouse.json").is_file():
        mvracklay("run", str(inp), "--out", str(out), "--threads", "2", "--quiet", "--no-rrd", *extra)
    res = json.loads(mvracklay("eval-reconstruction", str(seq), "--map", str(out / "warehouse.json"),
                               "--scale-corrected", "--noisy", "--json", "--quiet"))  # fmt: skip
    meta = json.loads((out / "warehouse.json").read_text())["meta"]
    (corr,) = res["scale_corrected"].values()
    return {"distance": meta["distance"], "source": meta["distance_source"], "as_is": res["summary"], "corrected": corr}


def pooled(rows: list[dict], key: str) -> dict:
    """Precision / recall over the summed TP / FP / FN, and the share of shelves with the exact box count."""
    tp, fp, fn = (sum(r[key][k] for r in rows) for k in ("tp", "fp", "fn"))
    shelves = sum(r[key]["shelves"] for r in rows)
    exact = sum(r[key].get("count_exact", round(r[key]["count_accuracy"] * r[key]["shelves"])) for r in rows)
    return {"precision": tp / max(1, tp + fp), "recall": tp / max(1, tp + fn), "exact": exact / max(1, shelves)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("data", type=Path)
    ap.add_argument("--sequences", type=int, default=10)
    ap.add_argument("--work", type=Path, default=Path("/tmp/footage"))
    a = ap.parse_args()
    seqs = sorted(p for p in a.data.iterdir() if (p / "meta.json").is_file())[: a.sequences]
    table: dict[str, list[dict]] = {}
    errors: dict[str, list[float]] = {"folder": [], "video": [], "height": []}
    for seq in seqs:
        meta = json.loads((seq / "meta.json").read_text())
        true_d = float(np.median([f["distance"] for f in meta["frames"]]))
        height = -float(meta["frames"][0]["camera_position"][1])
        folder, video = to_footage(seq, a.work)
        runs = {
            "recorded": run_and_score(seq, seq, a.work / "out" / seq.name / "recorded"),
            "folder": run_and_score(folder, seq, a.work / "out" / seq.name / "folder"),
            "video": run_and_score(video, seq, a.work / "out" / seq.name / "video"),
            # the folder again with the camera's true height above the floor, as a robot's mount gives it
            "height": run_and_score(
                folder, seq, a.work / "out" / seq.name / "height", "--camera-height", f"{height:.3f}"
            ),
        }
        for f in FACTORS:
            runs[f"x{f:g}"] = run_and_score(
                seq, seq, a.work / "out" / seq.name / f"x{f:g}", "--distance", f"{true_d * f:.4f}"
            )
        for k in ("folder", "video", "height"):
            if k != "height" or runs[k]["source"] == "camera height":
                errors[k].append(100 * (runs[k]["distance"] / true_d - 1))
        for k, v in runs.items():
            table.setdefault(k, []).append(v)
        print(seq.name, f"true {true_d:.3f}", {k: round(v["distance"], 3) for k, v in runs.items()}, flush=True)
    print("\ndistance read, error % (signed): median |e|, 90th percentile |e|, mean e")
    for k, e in errors.items():
        if not e:
            continue
        e = np.array(e)
        print(
            f"  {k:<8} n {len(e):2d} {np.median(np.abs(e)):5.2f} {np.percentile(np.abs(e), 90):5.2f} {e.mean():+5.2f}"
        )
    print("\nmaps (pooled): precision / recall / shelves with the exact count, as they are | scale corrected")
    for k, rows in table.items():
        s, c = pooled(rows, "as_is"), pooled(rows, "corrected")
        print(
            f"  {k:<9} {s['precision']:.3f} / {s['recall']:.3f} / {s['exact']:.1%} | "
            f"{c['precision']:.3f} / {c['recall']:.3f} / {c['exact']:.1%}"
        )


if __name__ == "__main__":
    main()
