#!/usr/bin/env bash
# The recipe of scripts/train_default.sh at 256x256 input (2 CPU cores; bf16 autocast where the CPU has it), in steps that
# each fit a working session and resume:
#
#   1. data: the same 6,500 training scenes, held-out and tuning scenes, rendered at 256x256 (same
#      dataset seeds 101/103/104, 202, 303; ~16 minutes on the 2 cores);
#   2. stage 1: racklay alone on both cores, a 120-minute schedule paused at 80 (102 minutes of wall
#      clock), exported with its discriminators as a fp16 warm start to $STAGE1_WEIGHTS. When that
#      file exists (weights/racklay256-stage1.pt is shipped) the stage is skipped;
#   3. stage 2, side by side, one thread each, both from the stage-1 weights at 3e-4 for the last
#      40 minutes: mvracklay-disc-4 and racklay (the baseline gets the same second stage, so the two
#      differ only in the sequence model's slot memory);
#   4. Table I on the held-out set (windowed; streaming for the sequence model), raw and with box
#      decision offsets chosen on the tuning set.
#
# The shipped mvracklay/models/mvracklay-disc-4-256.pt is step 3's mvracklay-disc-4, calibrated in step 4, exported with
# `mvracklay train --export runs/mvracklay-disc-4-256/calibrated.pt --out mvracklay/models/mvracklay-disc-4-256.pt`.
#
# Re-running skips finished data and continues runs from RUN/last.pt. Override the folders with
# DATA=... RUNS=...; STAGE=1 stops after stage 1, STAGE=2 after stage 2. A smoke check of the whole
# script: DATA=/tmp/d RUNS=/tmp/r STAGE1_WEIGHTS=/tmp/r/w.pt TRAIN_SEQUENCES="20 10 10" HELDOUT_SEQUENCES=2
#   TUNE_SEQUENCES=2 HELDOUT_FRAMES=12 TOTAL=1 STAGE1=0.6 scripts/train_256.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
DATA=${DATA:-data}
RUNS=${RUNS:-runs}
TOTAL=${TOTAL:-120}
STAGE1=${STAGE1:-80}
STAGE=${STAGE:-4}
WORKERS=${WORKERS:-2}
STAGE1_WEIGHTS=${STAGE1_WEIGHTS:-weights/racklay256-stage1.pt}
# bf16 autocast where the CPU computes it natively (AVX512-BF16 / AMX), else fp32 (emulated bf16 is 18-24x slower)
DEFAULT_PRECISION=$($PY -c "from network.precision import cpu_has_native_bf16 as f; print('bf16' if f() else 'fp32')")
PRECISION=${PRECISION:-$DEFAULT_PRECISION}
SIZE=(--input-size 256 256 --precision "$PRECISION")
COMMON=(--epochs 1000 --steps-per-epoch 250 --val-sequences 20 --val-frames 12 --seed 0 --quiet)

# 1. Data at 256x256.
read -r N1 N2 N3 <<< "${TRAIN_SEQUENCES:-1000 2500 3000}"
HN=${HELDOUT_SEQUENCES:-24}
TN=${TUNE_SEQUENCES:-8}
HF=${HELDOUT_FRAMES:-50}
TRAIN=()
for SPEC in "train256:$N1:12:101" "train256b:$N2:12:103" "train256c:$N3:12:104" "heldout256:$HN:$HF:202" \
    "tune256:$TN:$HF:303"; do
    IFS=: read -r NAME N FRAMES SEED <<< "$SPEC"
    $PY -m mvracklay generate "$DATA/$NAME" --sequences "$N" --frames "$FRAMES" --size 256 --seed "$SEED" \
        --workers "$WORKERS"
    if [[ $NAME == train* ]]; then TRAIN+=("$DATA/$NAME"); fi
done
HELDOUT="$DATA/heldout256"
TUNE="$DATA/tune256"
mkdir -p "$RUNS"

# 2. Stage 1: racklay on both cores, paused at STAGE1 of its TOTAL minutes; its weights (and discriminators)
#    become the warm start of both stage-2 runs.
if [ ! -f "$STAGE1_WEIGHTS" ]; then
    $PY -m mvracklay train --data "${TRAIN[@]}" --out "$RUNS/racklay256" --variant racklay --resume --threads 2 \
        --minutes "$TOTAL" --stop-at "$STAGE1" "${SIZE[@]}" "${COMMON[@]}" >> "$RUNS/racklay256.log" 2>&1
    $PY -m mvracklay train --export "$RUNS/racklay256/last.pt" --out "$STAGE1_WEIGHTS" --with-discriminators \
        --note "scripts/train_256.sh stage 1: racklay, $STAGE1 of a $TOTAL-minute schedule on 2 threads, $PRECISION, 256x256 input, data seeds 101/103/104; the warm start of stage 2"
fi
[ "$STAGE" -le 1 ] && exit 0

# 3. Stage 2: one thread each, side by side, from the stage-1 weights.
WARM=$($PY -c "print(max(0.1, $TOTAL - $STAGE1))")
stage2() {  # variant, run name
    $PY -m mvracklay train --data "${TRAIN[@]}" --out "$RUNS/$2" --variant "$1" --resume --threads 1 \
        --init-from "$STAGE1_WEIGHTS" --lr 3e-4 --minutes "$WARM" "${SIZE[@]}" "${COMMON[@]}" >> "$RUNS/$2.log" 2>&1
}
stage2 mvracklay-disc-4 mvracklay-disc-4-256 &
stage2 racklay racklay256-stage2 &
wait
[ "$STAGE" -le 2 ] && exit 0

# 4. Table I on the held-out set, raw and calibrated on the tuning set, two evaluations side by side.
EVAL=(--data "$HELDOUT" --split all --threads 1 --quiet)
table1() {  # run, checkpoint name, output name, extra flags
    $PY -m mvracklay evaluate --checkpoint "$RUNS/$1/$2.pt" "${EVAL[@]}" --json "$RUNS/$1/$3.json" "${@:4}" \
        > "$RUNS/$1/$3.txt"
}
calibrated() {  # run, extra flags for the calibrated table
    $PY -m mvracklay calibrate --checkpoint "$RUNS/$1/best.pt" --data "$TUNE" --out "$RUNS/$1/calibrated.pt" \
        --threads 1 --quiet --json "$RUNS/$1/calibration.json" > "$RUNS/$1/calibration.txt"
    table1 "$1" calibrated table1_calibrated "${@:2}"
}
(table1 mvracklay-disc-4-256 best table1_window && calibrated mvracklay-disc-4-256 &&
    table1 mvracklay-disc-4-256 calibrated table1_calibrated_stream --mode stream) &
(table1 racklay256-stage2 best table1_window && calibrated racklay256-stage2) &
wait
for R in mvracklay-disc-4-256 racklay256-stage2; do
    echo "== $R"
    for T in table1_window table1_calibrated table1_calibrated_stream; do
        [ -f "$RUNS/$R/$T.txt" ] && { echo "-- $T"; sed -n 2,6p "$RUNS/$R/$T.txt"; }
    done
done
