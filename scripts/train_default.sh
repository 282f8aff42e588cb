#!/usr/bin/env bash
# Full training recipe for the shipped model and the README's Table I (2 CPU cores, CPU-only torch).
#
#   1. data: three training sets (dataset seeds 101, 103, 104; 6,500 scenes) and a held-out set with
#      another dataset seed (202), so no held-out sequence seed was ever used in training;
#   2. stage 1: racklay (single frame) alone on the machine (2 threads) for STAGE1 of its TOTAL minutes;
#      stage 2a, side by side with one thread each: racklay continues its schedule to TOTAL minutes, and
#      mvracklay-disc-4 starts from racklay's stage-1 weights (the ConvLSTM enters as a zero-initialised
#      correction; its memory follows the camera motion read from the images, and its training windows
#      take every s-th frame, s in 1..3, both by default) for the remaining TOTAL - STAGE1 minutes:
#      every model <= TOTAL minutes in all;
#      stage 2b: mvracklay-4 likewise, on one core while the others are evaluated; 2c: mvracklay-disc-8;
#   3. Table I of every model on the held-out set, raw and with box decision offsets chosen on a
#      tuning set (seed 303; `mvracklay calibrate`) (windowed, as in the paper; streaming too for the
#      default), the depth-projection baseline, reconstruction accuracy from predicted vs ground-truth layouts;
#   4. learning curves PNG, inference benchmark, fp16 weights for mvracklay/models/.
#
# "Minutes" are wall-clock minutes spent in optimiser steps (data loading and validation not counted).
# Every step resumes: re-running skips finished sequences and continues runs from RUN/last.pt.
# Override the folders with DATA=... RUNS=...; for a smoke check of the whole recipe, shrink it, e.g.
#   DATA=/tmp/d RUNS=/tmp/r TRAIN_SEQUENCES="20 10 10" HELDOUT_SEQUENCES=2 TUNE_SEQUENCES=2 HELDOUT_FRAMES=12 TOTAL=1 STAGE1=0.6 \
#   WEIGHTS=/tmp/r/w.pt CURVES=/tmp/r/curves.png scripts/train_default.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
DATA=${DATA:-data}
RUNS=${RUNS:-runs}
TOTAL=${TOTAL:-120}   # training minutes per model in all
STAGE1=${STAGE1:-80}  # racklay's minutes before the sequence models branch off it
WORKERS=${WORKERS:-2}
TRAIN_SEQUENCES=${TRAIN_SEQUENCES:-1000 2500 3000}
HELDOUT_SEQUENCES=${HELDOUT_SEQUENCES:-24}
HELDOUT_FRAMES=${HELDOUT_FRAMES:-50}
TUNE_SEQUENCES=${TUNE_SEQUENCES:-8}
WEIGHTS=${WEIGHTS:-mvracklay/models/mvracklay-disc-4.pt}
CURVES=${CURVES:-docs/network_curves.png}
COMMON=(--epochs 1000 --steps-per-epoch 250 --val-sequences 20 --val-frames 12 --seed 0 --quiet)

# 1. Data: 6,500 scenes x 12 frames (90/5/5 train/val/test split by the generator), 128x128 images,
#    layouts R=3, D=128; the model reads 128x128 canonical images and predicts D=64. (At 128x128 the
#    generator writes ~200 frames/s on the 2 cores, so the three sets take ~7 minutes.)
read -r N1 N2 N3 <<< "$TRAIN_SEQUENCES"
TRAIN=()
for PAIR in "train128:$N1:101" "train128b:$N2:103" "train128c:$N3:104"; do
    IFS=: read -r NAME N SEED <<< "$PAIR"
    $PY -m mvracklay generate "$DATA/$NAME" --sequences "$N" --frames 12 --size 128 --seed "$SEED" --workers "$WORKERS"
    TRAIN+=("$DATA/$NAME")
done
#    Held-out: 24 sequences x 50 frames (>= 20 sequences), dataset seed 202.
HELDOUT="$DATA/heldout128"
$PY -m mvracklay generate "$HELDOUT" --sequences "$HELDOUT_SEQUENCES" --frames "$HELDOUT_FRAMES" --size 128 --seed 202 --workers "$WORKERS"
#    Tuning: 8 sequences x 50 frames, dataset seed 303: the box decision offsets (and the stitching's
#    clean-up for predicted layouts) are chosen here, never on the held-out set.
TUNE="$DATA/tune128"
$PY -m mvracklay generate "$TUNE" --sequences "$TUNE_SEQUENCES" --frames "$HELDOUT_FRAMES" --size 128 --seed 303 --workers "$WORKERS"

#    No held-out sequence seed may appear in a training set.
$PY - "$HELDOUT/manifest.json" "$TUNE/manifest.json" "${TRAIN[@]/%//manifest.json}" <<'PYEOF'
import json, sys
held, tune, *train = [{e["seed"] for e in json.load(open(p))["sequences"]} for p in sys.argv[1:]]
used = set().union(*train)
assert not held & (used | tune), "held-out sequence seeds overlap a training or the tuning set"
print(f"held-out: {len(held)} sequence seeds, none used in training ({len(used)}) or tuning ({len(tune)})")
PYEOF

# 2. Stage 1: racklay alone, both cores, its cosine schedule spanning TOTAL minutes, paused at STAGE1.
mkdir -p "$RUNS"
$PY -m mvracklay train --data "${TRAIN[@]}" --out "$RUNS/racklay" --variant racklay --resume --threads 2 \
    --minutes "$TOTAL" --stop-at "$STAGE1" "${COMMON[@]}" >> "$RUNS/racklay.log" 2>&1
[ -f "$RUNS/racklay-stage1.pt" ] || cp "$RUNS/racklay/last.pt" "$RUNS/racklay-stage1.pt"
#    Stage 2a, side by side with one thread each: racklay resumes its schedule to TOTAL; mvracklay-disc-4
#    starts from racklay's stage-1 weights at the learning rate racklay's schedule had there (3e-4) for
#    the minutes left. Stage 2b: mvracklay-4 the same way, on one core while the others are evaluated.
WARM=$($PY -c "print(max(0.1, $TOTAL - $STAGE1))")
warm_start() {  # variant
    $PY -m mvracklay train --data "${TRAIN[@]}" --out "$RUNS/$1" --variant "$1" --resume --threads 1 \
        --init-from "$RUNS/racklay-stage1.pt" --lr 3e-4 --minutes "$WARM" "${COMMON[@]}" >> "$RUNS/$1.log" 2>&1
}
$PY -m mvracklay train --data "${TRAIN[@]}" --out "$RUNS/racklay" --variant racklay --resume --threads 1 \
    --minutes "$TOTAL" "${COMMON[@]}" >> "$RUNS/racklay.log" 2>&1 &
warm_start mvracklay-disc-4 &
wait
warm_start mvracklay-4 &
MV4=$!

# 3. Table I on every held-out sequence (all 24 x 50 frames), one thread; reconstruction accuracy.
EVAL=(--data "$HELDOUT" --split all --threads 1 --quiet)
table1() {  # variant, name, extra flags (CKPT=calibrated scores the calibrated copy)
    $PY -m mvracklay evaluate --checkpoint "$RUNS/$1/${CKPT:-best}.pt" "${EVAL[@]}" --json "$RUNS/$1/$2.json" "${@:3}" \
        > "$RUNS/$1/$2.txt"
}
calibrate() {  # variant: box decision offsets chosen on the tuning set -> RUN/calibrated.pt, then its Table I
    $PY -m mvracklay calibrate --checkpoint "$RUNS/$1/best.pt" --data "$TUNE" --out "$RUNS/$1/calibrated.pt" \
        --threads 1 --quiet --json "$RUNS/$1/calibration.json" > "$RUNS/$1/calibration.txt"
    CKPT=calibrated table1 "$1" table1_calibrated
}
table1 mvracklay-disc-4 table1_window
table1 mvracklay-disc-4 table1_stream --mode stream
table1 mvracklay-disc-4 table1_true_anchors --true-anchors
table1 racklay table1_window
calibrate mvracklay-disc-4
CKPT=calibrated table1 mvracklay-disc-4 table1_calibrated_stream --mode stream
CKPT=calibrated table1 mvracklay-disc-4 table1_calibrated_flip --flip-average
CKPT=calibrated table1 mvracklay-disc-4 table1_calibrated_flip_stream --flip-average --mode stream
calibrate racklay
$PY -m mvracklay evaluate-baseline --data "$HELDOUT" --split all --quiet --json "$RUNS/baseline_depth.json" \
    > "$RUNS/baseline_depth.txt"
$PY -m mvracklay eval-reconstruction "$HELDOUT" --quiet --json > "$RUNS/reconstruction_gt.json"
for V in mvracklay-disc-4 racklay; do
    for C in best:_raw calibrated:; do  # checkpoint:file suffix
        $PY -m mvracklay eval-reconstruction "$HELDOUT" --checkpoint "$RUNS/$V/${C%%:*}.pt" --noisy --threads 1 \
            --quiet --json > "$RUNS/reconstruction_$V${C#*:}.json"
    done
done
wait $MV4
table1 mvracklay-4 table1_window
calibrate mvracklay-4
#    Stage 2c: mvracklay-disc-8 the same way (one thread; its window of 8 frames), then its Table I.
warm_start mvracklay-disc-8
table1 mvracklay-disc-8 table1_window
calibrate mvracklay-disc-8
#    The README's two tables come from the JSON files above: `research/results_tables.py "$RUNS"` (a research
#    tool, outside the recipe).

# 4. Curves, speed, shipped weights.
CURVE_RUNS=("racklay=$RUNS/racklay" "mvracklay-4=$RUNS/mvracklay-4" "mvracklay-disc-4=$RUNS/mvracklay-disc-4"
    "mvracklay-disc-8=$RUNS/mvracklay-disc-8")
[ -d "$RUNS/_unaligned-disc-4" ] && CURVE_RUNS+=("mvracklay-disc-4(unaligned)=$RUNS/_unaligned-disc-4")
$PY -m network.training.curves "$CURVES" "${CURVE_RUNS[@]}"
#    the second stage zoomed: stage 1 ran on 2 threads, so it ends near 2 x STAGE1 CPU-minutes
FROM=$($PY -c "print(max(0.0, 2 * $STAGE1 - 10))")
$PY -m network.training.curves --from "$FROM" "${CURVES%.png}_stage2.png" "${CURVE_RUNS[@]}"
$PY benchmarks/bench_infer.py --checkpoint "$RUNS/mvracklay-disc-4/best.pt" --threads 2 --sizes 128 256 \
    | tee "$RUNS/bench_infer.txt"
$PY -m mvracklay train --export "$RUNS/mvracklay-disc-4/calibrated.pt" --out "$WEIGHTS" \
    --note "scripts/train_default.sh (TOTAL=$TOTAL, STAGE1=$STAGE1): racklay $STAGE1 min on 2 threads, then mvracklay-disc-4 from its weights for $WARM min beside racklay's last $WARM min, one thread each; box decision offsets calibrated on $TUNE"
