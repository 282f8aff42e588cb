#!/usr/bin/env bash
# mvracklay-disc-4 at 256x256 input with its depth heads, everything inside one 120-minute training budget
# on the 2 CPU cores (scripts/train_256.sh trains the network for the whole budget and fits the heads after
# it). The heads change the top view more than the network's last minutes do, so this recipe gives the
# network's second stage fewer minutes and fits the heads in the rest:
#
#   1. data: the second 256x256 training set of scripts/train_256.sh (2,500 scenes, seed 103; the stage-1
#      warm start was trained on it among others), the held-out and the tuning scenes (seeds 202, 303);
#   2. stage 1: weights/racklay256-stage1.pt (80 of racklay's 120-minute schedule on 2 threads, shipped);
#   3. stage 2: mvracklay-disc-4 from those weights at 3e-4 on both threads for STAGE2 minutes (default
#      18.5, 14 where PRECISION is bf16; scripts/train_256.sh: 40 minutes on one thread beside racklay's second
#      stage);
#   4. box decision offsets chosen on the tuning set (as in scripts/train_256.sh, not counted: no weight moves);
#   5. the heads, the network frozen, on both threads at once: on one the back-edge head, then the upright
#      head, each on HEAD_SEQUENCES training sequences (default 700); on the other the box-depth head with
#      parallax on BOX_SEQUENCES scenes (default 1150, 2500 where PRECISION is bf16: the bf16 trunk and fit
#      make room for them, and the stage's last minutes buy nothing), of which it streams the first BOX_FRAMES frames (6)
#      and keeps the slots from frame BOX_FROM (3) on: the head is short of scenes rather than of frames,
#      and frames 0-2 lack the parallax against 3 frames back. Their wall minutes are counted whole, caching
#      included. BOX_SEQUENCES=0 leaves the box-depth head out and fits the two rack heads side by side, one
#      thread each (the earlier recipe, with STAGE2=28). The heads' passes run the trunk in PRECISION (stage 2's:
#      bf16 on CPUs with native bf16), and so does the box-depth head's fit (`--precision`);
#   6. the budget added up (the runs' step minutes, the fits' wall minutes; refused over TOTAL), then Table I
#      on the held-out set: the network alone, with the rack heads, with all heads, and all heads over the
#      whole sequence, flip-averaged, with neighbouring frames fused.
#
# Re-running skips finished data, fits and tables and continues the run from its last.pt. Override the
# folders with DATA=... RUNS=...; "minutes" of a run are wall-clock minutes spent in optimiser steps (loading
# and validation not counted), as in the other recipes. A smoke check of the whole script:
#   DATA=/tmp/bd RUNS=/tmp/br TRAIN_SEQUENCES=12 HELDOUT_SEQUENCES=2 TUNE_SEQUENCES=2 HELDOUT_FRAMES=12
#   STAGE2=0.3 HEAD_SEQUENCES=4 HEAD_EPOCHS=1 BOX_SEQUENCES=4 TOTAL=100 scripts/train_256_budget.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
DATA=${DATA:-data}
RUNS=${RUNS:-runs/budget256}
TOTAL=${TOTAL:-120}
DEFAULT_PRECISION=$($PY -c "from network.precision import cpu_has_native_bf16 as f; print('bf16' if f() else 'fp32')")
PRECISION=${PRECISION:-$DEFAULT_PRECISION}
if [ "$PRECISION" = bf16 ]; then STAGE2=${STAGE2:-14} BOX_SEQUENCES=${BOX_SEQUENCES:-2500}; fi
STAGE2=${STAGE2:-18.5}
HEAD_SEQUENCES=${HEAD_SEQUENCES:-700}
HEAD_EPOCHS=${HEAD_EPOCHS:-}
BOX_SEQUENCES=${BOX_SEQUENCES:-1150}
BOX_FRAMES=${BOX_FRAMES:-6}
BOX_FROM=${BOX_FROM:-3}
WORKERS=${WORKERS:-2}
STAGE1_WEIGHTS=${STAGE1_WEIGHTS:-weights/racklay256-stage1.pt}
[ -f "$STAGE1_WEIGHTS" ] || { echo "train_256_budget.sh: $STAGE1_WEIGHTS is missing (scripts/train_256.sh STAGE=1 makes it)" >&2; exit 2; }

# 1. Data at 256x256.
TRAIN="$DATA/train256b"
HELDOUT="$DATA/heldout256"
TUNE="$DATA/tune256"
for SPEC in "$TRAIN:${TRAIN_SEQUENCES:-2500}:12:103" "$HELDOUT:${HELDOUT_SEQUENCES:-24}:${HELDOUT_FRAMES:-50}:202" \
    "$TUNE:${TUNE_SEQUENCES:-8}:${HELDOUT_FRAMES:-50}:303"; do
    IFS=: read -r DIR N FRAMES SEED <<< "$SPEC"
    $PY -m mvracklay generate "$DIR" --sequences "$N" --frames "$FRAMES" --size 256 --seed "$SEED" --workers "$WORKERS"
done
mkdir -p "$RUNS"
RUN="$RUNS/mvracklay-disc-4"

# 3. Stage 2 on both threads.
$PY -m mvracklay train --data "$TRAIN" --out "$RUN" --variant mvracklay-disc-4 --resume --threads 2 \
    --init-from "$STAGE1_WEIGHTS" --lr 3e-4 --minutes "$STAGE2" --input-size 256 256 --precision "$PRECISION" \
    --epochs 1000 --steps-per-epoch 250 --val-sequences 20 --val-frames 12 --seed 0 --quiet >> "$RUNS/train.log" 2>&1

# 4. Box decision offsets on the tuning set.
[ -f "$RUN/calibrated.pt" ] || $PY -m mvracklay calibrate --checkpoint "$RUN/best.pt" --data "$TUNE" \
    --out "$RUN/calibrated.pt" --threads 2 --quiet --json "$RUN/calibration.json" > "$RUN/calibration.txt"


# 5. The heads on both threads (the network frozen); then one file with the rack heads, one with all of them.
EPOCHS=()
[ -n "$HEAD_EPOCHS" ] && EPOCHS=(--epochs "$HEAD_EPOCHS")
fit() {  # command, output name
    [ -f "$RUN/$2.pt" ] || $PY -m mvracklay "$1" --checkpoint "$RUN/calibrated.pt" --data "$TRAIN" \
        --sequences "$HEAD_SEQUENCES" --val "$TUNE" --threads 1 --quiet "${EPOCHS[@]}" --precision "$PRECISION" --out "$RUN/$2.pt" \
        --json "$RUN/$2.fit.json" > "$RUN/$2.log" 2>&1
}
fit_box() {  # its whole wall time, model loading included, in box.wall_seconds
    [ -f "$RUN/box.pt" ] && return
    local t0
    t0=$(date +%s)
    $PY -m mvracklay fit-box-depth --checkpoint "$RUN/calibrated.pt" --data "$TRAIN" --sequences "$BOX_SEQUENCES" \
        --frames "$BOX_FRAMES" --from-frame "$BOX_FROM" --parallax --threads 1 --cache-dir "$RUNS" --quiet --precision "$PRECISION" \
        "${EPOCHS[@]}" --out "$RUN/box.pt" --json "$RUN/box.fit.json" > "$RUN/box.log" 2>&1
    echo $(( $(date +%s) - t0 )) > "$RUN/box.wall_seconds"
}
if [ "$BOX_SEQUENCES" -gt 0 ]; then
    { fit fit-back-edges back_edges && fit fit-uprights uprights; } &
    fit_box &
else
    fit fit-back-edges back_edges &
    fit fit-uprights uprights &
fi
wait
[ -f "$RUN/heads.pt" ] || $PY benchmarks/graft_heads.py "$RUN/uprights.pt" "$RUN/back_edges.pt" "$RUN/heads.pt" \
    --only uprights
if [ "$BOX_SEQUENCES" -gt 0 ] && [ ! -f "$RUN/heads_box.pt" ]; then
    $PY benchmarks/graft_heads.py "$RUN/box.pt" "$RUN/heads.pt" "$RUN/heads_box.pt" --only box_depth
fi

# 6. The budget, then Table I.
BOX_WALL=""
[ "$BOX_SEQUENCES" -gt 0 ] && BOX_WALL="$RUN/box.wall_seconds"
$PY - "$STAGE1_WEIGHTS" "$RUN/best.pt" "$RUN/back_edges.fit.json" "$RUN/uprights.fit.json" "$TOTAL" "$BOX_WALL" <<'EOF' |
import json, sys
from pathlib import Path
stage1, best, back, up, total, box = sys.argv[1:7]
s1 = json.loads(Path(stage1).with_suffix(".json").read_text())["train_wall_minutes"]
last = json.loads(Path(best).with_name("last.json").read_text())["train_wall_minutes"]  # this run's own steps
fits = [json.loads(Path(p).read_text())["wall_minutes"] for p in (back, up)]
out = {"stage1": s1, "stage2": last, "back_edges": fits[0], "uprights": fits[1]}
if box:  # one thread: the two rack heads one after the other; the other: the box-depth head
    out["box_depth"] = int(Path(box).read_text()) / 60
    spent = s1 + last + max(sum(fits), out["box_depth"])
else:  # the two rack heads side by side
    spent = s1 + last + max(fits)
out["total"] = spent
print(json.dumps(out))
if spent > float(total):
    sys.exit(f"train_256_budget.sh: {spent:.1f} minutes spent, over the budget of {total}")
EOF
    tee "$RUN/budget.json"
EVAL=(--data "$HELDOUT" --split all --threads 2 --quiet)
table1() {  # checkpoint, output name, extra flags
    [ -f "$RUN/$2.json" ] || $PY -m mvracklay evaluate --checkpoint "$RUN/$1" "${EVAL[@]}" --json "$RUN/$2.json" \
        "${@:3}" > "$RUN/$2.txt"
}
table1 calibrated.pt table1_network --no-depth-read
table1 heads.pt table1_heads
TABLES=(table1_network table1_heads)
FULL=heads.pt
if [ "$BOX_SEQUENCES" -gt 0 ]; then
    table1 heads_box.pt table1_heads_box
    TABLES+=(table1_heads_box)
    FULL=heads_box.pt
fi
table1 "$FULL" table1_offline --whole-sequence --flip-average --fuse-frames
for T in "${TABLES[@]}" table1_offline; do echo "-- $T"; sed -n 2,6p "$RUN/$T.txt"; done
