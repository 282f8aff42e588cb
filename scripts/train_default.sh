#!/usr/bin/env bash
# Full training recipe for the shipped model and the README's Table I (2 CPU cores, CPU-only torch).
#
#   1. data: three training sets (dataset seeds 101, 103, 104; 6,500 scenes) and a held-out set with
#      another dataset seed (202), so no held-out sequence seed was ever used in training;
#   2. train mvracklay-disc-4, mvracklay-4 and the racklay baseline on the same data with the same
#      budget, side by side (one torch thread each, so the three share the 2 cores alike); then, within
#      120 minutes per model in all, a second stage side by side: racklay continued to 120 minutes, and
#      mvracklay-disc-4 warm-started from the racklay run's best checkpoint for the remaining minutes;
#   3. Table I of all three on the held-out set (windowed mode, as in the paper, and streaming for the
#      default), and reconstruction accuracy from predicted vs ground-truth layouts;
#   4. learning curves PNG, inference benchmark, fp16 weights for weights/.
#
# Every step resumes: re-running skips finished sequences and continues runs from RUN/last.pt.
# Override the folders with DATA=... RUNS=...; for a smoke check of the whole recipe, shrink it, e.g.
#   DATA=/tmp/d RUNS=/tmp/r TRAIN_SEQUENCES="20 10 10" HELDOUT_SEQUENCES=2 HELDOUT_FRAMES=12 MINUTES=0.5 \
#   WEIGHTS=/tmp/r/w.pt CURVES=/tmp/r/curves.png scripts/train_default.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
DATA=${DATA:-data}
RUNS=${RUNS:-runs}
MINUTES=${MINUTES:-85}  # minutes of training steps per run (data loading and validation not counted)
TOTAL=${TOTAL:-120}     # stage 2: racklay continued to TOTAL; the warm start gets TOTAL minus its source's minutes
WORKERS=${WORKERS:-2}
TRAIN_SEQUENCES=${TRAIN_SEQUENCES:-1000 2500 3000}
HELDOUT_SEQUENCES=${HELDOUT_SEQUENCES:-24}
HELDOUT_FRAMES=${HELDOUT_FRAMES:-50}
WEIGHTS=${WEIGHTS:-weights/mvracklay-disc-4.pt}
CURVES=${CURVES:-docs/network_curves.png}
VARIANTS="mvracklay-disc-4 mvracklay-4 racklay"

# 1. Data: 6,500 scenes x 12 frames (90/5/5 train/val/test split by the generator), 128x128 images,
#    layouts R=3, D=128; the model reads 128x128 and predicts D=64. (At 128x128 the generator writes
#    ~200 frames/s on the 2 cores, so the three sets take ~7 minutes.)
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

#    No held-out sequence seed may appear in a training set.
$PY - "$HELDOUT/manifest.json" "${TRAIN[@]/%//manifest.json}" <<'PYEOF'
import json, sys
held, *train = [{e["seed"] for e in json.load(open(p))["sequences"]} for p in sys.argv[1:]]
used = set().union(*train)
assert not held & used, "held-out sequence seeds overlap a training set"
print(f"held-out: {len(held)} sequence seeds, none used in training ({len(used)})")
PYEOF

# 2. Train the three variants side by side (same data, same frames per step, same budget).
#    Validation every 250 steps on 20 val sequences x 12 frames (not counted in the budget). The
#    sequence variants of this stage use the plain ConvLSTM (in place of the single-frame block), the
#    model the README's from-scratch rows measured.
for V in $VARIANTS; do
    PLAIN=(); [ "$V" = racklay ] || PLAIN=(--no-temporal-residual)
    $PY -m mvracklay train --data "${TRAIN[@]}" --out "$RUNS/$V" --variant "$V" --resume --threads 1 --quiet \
        --minutes "$MINUTES" --epochs 1000 --steps-per-epoch 250 --val-sequences 20 --val-frames 12 --seed 0 \
        "${PLAIN[@]}" > "$RUNS/$V.log" 2>&1 &
done
wait

#    Stage 2: the single-frame model continues to TOTAL minutes; the sequence model starts from it
#    (residual ConvLSTM: a zero-initialised correction, so it starts equal to racklay) with a lower
#    learning rate, for the minutes the source leaves of TOTAL.
[ -d "$RUNS/racklay-$TOTAL" ] || cp -r "$RUNS/racklay" "$RUNS/racklay-$TOTAL"
WARM_MIN=$($PY -c "import json,sys; print(max(0.1, $TOTAL - json.load(open(sys.argv[1]))['train_wall_minutes']))" \
    "$RUNS/racklay/best.json")
$PY -m mvracklay train --data "${TRAIN[@]}" --out "$RUNS/racklay-$TOTAL" --variant racklay --resume --threads 1 --quiet \
    --minutes "$TOTAL" --epochs 1000 --steps-per-epoch 250 --val-sequences 20 --val-frames 12 --seed 0 \
    > "$RUNS/racklay-$TOTAL.log" 2>&1 &
$PY -m mvracklay train --data "${TRAIN[@]}" --out "$RUNS/mvracklay-disc-4-warm" --variant mvracklay-disc-4 --resume \
    --init-from "$RUNS/racklay/best.pt" --lr 3e-4 --threads 1 --quiet --minutes "$WARM_MIN" --epochs 1000 \
    --steps-per-epoch 250 --val-sequences 20 --val-frames 12 --seed 0 > "$RUNS/mvracklay-disc-4-warm.log" 2>&1 &
wait
VARIANTS="$VARIANTS racklay-$TOTAL mvracklay-disc-4-warm"

# 3. Table I on every held-out sequence (all 24 x 50 frames); reconstruction accuracy.
for V in $VARIANTS; do
    $PY -m mvracklay evaluate --checkpoint "$RUNS/$V/best.pt" --data "$HELDOUT" --split all \
        --json "$RUNS/$V/table1_window.json" | tee "$RUNS/$V/table1_window.txt"
done
$PY -m mvracklay evaluate --checkpoint "$RUNS/mvracklay-disc-4/best.pt" --data "$HELDOUT" --split all \
    --mode stream --json "$RUNS/mvracklay-disc-4/table1_stream.json" | tee "$RUNS/mvracklay-disc-4/table1_stream.txt"
$PY -m mvracklay eval-reconstruction "$HELDOUT" | tee "$RUNS/reconstruction_gt.txt"
$PY -m mvracklay eval-reconstruction "$HELDOUT" --checkpoint "$RUNS/mvracklay-disc-4/best.pt" --noisy \
    | tee "$RUNS/reconstruction_pred.txt"

# 4. Curves, speed, shipped weights.
$PY -m network.curves "$CURVES" "mvracklay-disc-4=$RUNS/mvracklay-disc-4" "mvracklay-4=$RUNS/mvracklay-4" \
    "racklay=$RUNS/racklay"
$PY benchmarks/bench_infer.py --checkpoint "$RUNS/mvracklay-disc-4/best.pt" --threads 2 --sizes 128 256
$PY -m mvracklay train --export "$RUNS/mvracklay-disc-4/best.pt" --out "$WEIGHTS" \
    --note "scripts/train_default.sh (MINUTES=$MINUTES): mvracklay-disc-4 beside mvracklay-4 and racklay, one thread each on 2 cores"
