#!/usr/bin/env bash
# Full training recipe for the shipped model and the README's Table I (2 CPU cores, CPU-only torch).
#
#   1. data: a training set (dataset seed 101) and a held-out set with another dataset seed (202),
#      so no held-out sequence seed was ever used in training;
#   2. train mvracklay-disc-4 and the racklay baseline for 120 minutes each on the same data;
#   3. Table I of both on the held-out set (windowed mode, as in the paper, and streaming);
#   4. learning curves PNG, inference benchmark, fp16 weights for weights/.
#
# Every step resumes: re-running skips finished sequences and continues runs from RUN/last.pt.
# Override the folders with DATA=... RUNS=...; for a smoke check of the whole recipe, shrink it, e.g.
#   DATA=/tmp/d RUNS=/tmp/r TRAIN_SEQUENCES=20 HELDOUT_SEQUENCES=2 HELDOUT_FRAMES=12 MINUTES=0.5 \
#   WEIGHTS=/tmp/r/w.pt CURVES=/tmp/r/curves.png scripts/train_default.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
DATA=${DATA:-data}
RUNS=${RUNS:-runs}
MINUTES=${MINUTES:-120}
WORKERS=${WORKERS:-2}
TRAIN_SEQUENCES=${TRAIN_SEQUENCES:-2000}
HELDOUT_SEQUENCES=${HELDOUT_SEQUENCES:-24}
HELDOUT_FRAMES=${HELDOUT_FRAMES:-50}
WEIGHTS=${WEIGHTS:-weights/mvracklay-disc-4.pt}
CURVES=${CURVES:-docs/network_curves.png}

# 1. Data. 2,000 scenes x 12 frames = 24,000 training frames (90/5/5 train/val/test split by the
#    generator), 256x256 images, layouts R=3, D=128; the model reads them at 128x128 and predicts D=64.
$PY -m mvracklay generate "$DATA/train" --sequences "$TRAIN_SEQUENCES" --frames 12 --size 256 --seed 101 --workers "$WORKERS"
#    Held-out: 24 sequences x 50 frames (>= 20 sequences), dataset seed 202.
$PY -m mvracklay generate "$DATA/heldout" --sequences "$HELDOUT_SEQUENCES" --frames "$HELDOUT_FRAMES" --size 256 --seed 202 --workers "$WORKERS"

#    No held-out sequence seed may appear in the training set.
$PY - "$DATA/train/manifest.json" "$DATA/heldout/manifest.json" <<'PYEOF'
import json, sys
seeds = [{e["seed"] for e in json.load(open(p))["sequences"]} for p in sys.argv[1:]]
assert not seeds[0] & seeds[1], "held-out sequence seeds overlap the training set"
print(f"held-out: {len(seeds[1])} sequence seeds, none used in training ({len(seeds[0])})")
PYEOF

# 2. Train (same data, same frames per step, same budget). Validation every 250 steps on 20 val sequences.
for V in mvracklay-disc-4 racklay; do
    $PY -m mvracklay train --data "$DATA/train" --out "$RUNS/$V" --variant "$V" --resume \
        --minutes "$MINUTES" --epochs 1000 --steps-per-epoch 250 --val-sequences 20 --val-frames 12 --seed 0
done

# 3. Table I on every held-out sequence (all 24 x 50 frames).
for V in mvracklay-disc-4 racklay; do
    $PY -m mvracklay evaluate --checkpoint "$RUNS/$V/best.pt" --data "$DATA/heldout" --split all \
        --json "$RUNS/$V/table1_window.json" | tee "$RUNS/$V/table1_window.txt"
done
$PY -m mvracklay evaluate --checkpoint "$RUNS/mvracklay-disc-4/best.pt" --data "$DATA/heldout" --split all \
    --mode stream --json "$RUNS/mvracklay-disc-4/table1_stream.json" | tee "$RUNS/mvracklay-disc-4/table1_stream.txt"

# 4. Curves, speed, shipped weights.
$PY -m network.curves "$CURVES" "mvracklay-disc-4=$RUNS/mvracklay-disc-4" "racklay=$RUNS/racklay"
$PY benchmarks/bench_infer.py --checkpoint "$RUNS/mvracklay-disc-4/best.pt" --threads 2 --sizes 128 256
$PY -m mvracklay train --export "$RUNS/mvracklay-disc-4/best.pt" --out "$WEIGHTS"
