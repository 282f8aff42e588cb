#!/usr/bin/env bash
# mvracklay-disc-4 at 256x256 input with its depth heads, everything inside one 120-minute training budget
# on the 2 CPU cores (scripts/train_256.sh trains the network for the whole budget and fits the heads after
# it). The heads change the top view more than the network's last minutes do, so this recipe gives the
# network's second stage fewer minutes and fits the heads in the rest:
#
#   1. data: the second 256x256 training set of scripts/train_256.sh (2,500 scenes, seed 103; the stage-1
#      warm start was trained on it among others), the held-out and the tuning scenes (seeds 202, 303), and
#      BOX_EXTRA more scenes of 6 frames for the box-depth head (default 5,000, seed 104, data/train256box;
#      BOX_CONFIG=FILE makes them with that generator config, in data/train256box-<FILE's name>, e.g.
#      scripts/configs/no_sparse.json: no scene with the sparse shelf preset);
#   2. stage 1: weights/racklay256-stage1.pt (80 of racklay's 120-minute schedule on 2 threads, shipped);
#   3. stage 2: mvracklay-disc-4 from those weights at 3e-4 on both threads for STAGE2 minutes (default
#      18.5, 7 where PRECISION is bf16: 7 minutes lose little of the network and give the box-depth head 1.4
#      times the scenes, runs/budget256m against runs/budget256n and runs/budget256p; 3.5 minutes lose,
#      runs/budget256o; 10 minutes, runs/budget256q, level held out, lower on the tuning set, +1 on the front
#      view; STAGE2=14 for runs/budget256g-m; scripts/train_256.sh: 40 minutes on one thread beside
#      racklay's second stage);
#   4. box decision offsets chosen on the tuning set (as in scripts/train_256.sh, not counted: no weight moves);
#   5. the heads, the network frozen: first the back-edge and the upright heads side by side, one thread each,
#      each on HEAD_SEQUENCES training sequences (default 700); then the box-depth head with parallax on both
#      threads, its streamed pass split over two processes, over the scenes of both training folders in turn
#      (at most BOX_SEQUENCES, default all 7,500): it streams the first BOX_FRAMES frames of each (6) and keeps
#      the slots from frame BOX_FROM (3) on (the head is short of scenes rather than of frames, and frames 0-2
#      lack the parallax against 3 frames back; `--cold-start`: frames 0-2 skip the network, entering only the
#      motion estimate and the parallax history, so the pass holds 1.3-1.6 times the scenes; BOX_COLD=0 streams
#      them through it, runs/budget256i-l), and its pass stops at the minutes the budget has left, less
#      BOX_MARGIN (1.5) and the fit's share (`--pass-minutes`: the fit takes BOX_FIT_RATIO minutes per minute
#      of pass, measured 0.90 with bf16 and the cold start, default 0.95 (0.55 and 0.6 without it); in float32
#      default 1.3 (0.95 without it, measured 0.88-0.92)), so a faster machine fits the head on more scenes and
#      a slower one on fewer. Every step's wall minutes are
#      counted whole, model loading and caching included. BOX_SEQUENCES=0 leaves the box-depth head out (the
#      earlier recipe, with STAGE2=28). The heads' passes run the trunk in PRECISION (stage 2's: bf16 on CPUs
#      with native bf16), and so does the box-depth head's fit (`--precision`). The head also reads each box's
#      front (`--front`: its setback behind the rack front; +0.4 to +0.7 top box on the same backs, about +0.4
#      net, no slower); BOX_FRONT=0 fits the head without it (runs/budget256i-l); BOX_WIDTH=64 fits a head of
#      64 channels instead of 32 (`--head-width`; its fit takes 2.6 times the share, measured 2.24 minutes per
#      pass-minute with bf16 and the cold start; +0.45 top box held out and on the tuning set on a machine whose
#      pass streams every scene made with the default width, runs/budget256s/w64, but the whole script with it,
#      runs/budget256t, only -0.1 to +0.3 online against two default runs, so the default stays 32);
#      once the rack heads are joined, the offset that centres the rack depth they read on the tuning set's
#      true depths (`calibrate --target rack-depth`; not counted either: no weight moves);
#   6. the budget added up (the runs' step minutes, the heads' wall minutes; refused over TOTAL), then Table I
#      on the held-out set: the network alone, with the rack heads, with all heads, and all heads over the
#      whole sequence, flip-averaged, with neighbouring frames fused.
#
# Re-running skips finished data, fits and tables and continues the run from its last.pt. Override the
# folders with DATA=... RUNS=...; "minutes" of a run are wall-clock minutes spent in optimiser steps (loading
# and validation not counted), as in the other recipes. A smoke check of the whole script:
#   DATA=/tmp/bd RUNS=/tmp/br TRAIN_SEQUENCES=12 HELDOUT_SEQUENCES=2 TUNE_SEQUENCES=2 HELDOUT_FRAMES=12
#   STAGE2=0.3 HEAD_SEQUENCES=4 HEAD_EPOCHS=1 BOX_EXTRA=4 TOTAL=100 scripts/train_256_budget.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
DATA=${DATA:-data}
RUNS=${RUNS:-runs/budget256}
TOTAL=${TOTAL:-120}
DEFAULT_PRECISION=$($PY -c "from network.precision import cpu_has_native_bf16 as f; print('bf16' if f() else 'fp32')")
PRECISION=${PRECISION:-$DEFAULT_PRECISION}
BOX_COLD=${BOX_COLD:-1}
if [ "$BOX_COLD" = 1 ]; then RATIOS=(0.95 1.3); else RATIOS=(0.6 0.95); fi  # the fit's share: bf16, float32
BOX_WIDTH=${BOX_WIDTH:-32}
case "$BOX_WIDTH" in
    32) ;;
    64) read -r -a RATIOS <<< "$(awk -v a="${RATIOS[0]}" -v b="${RATIOS[1]}" 'BEGIN { printf "%.2f %.2f", 2.6 * a, 2.6 * b }')" ;;
    *) echo "train_256_budget.sh: BOX_WIDTH must be 32 or 64 (the fit's share is measured for those), got $BOX_WIDTH" >&2; exit 2 ;;
esac
if [ "$PRECISION" = bf16 ]; then STAGE2=${STAGE2:-7} BOX_FIT_RATIO=${BOX_FIT_RATIO:-${RATIOS[0]}}; fi
STAGE2=${STAGE2:-18.5}
BOX_FIT_RATIO=${BOX_FIT_RATIO:-${RATIOS[1]}}
BOX_MARGIN=${BOX_MARGIN:-1.5}
HEAD_SEQUENCES=${HEAD_SEQUENCES:-700}
HEAD_EPOCHS=${HEAD_EPOCHS:-}
TRAIN_SEQUENCES=${TRAIN_SEQUENCES:-2500}
BOX_EXTRA=${BOX_EXTRA:-5000}
BOX_SEQUENCES=${BOX_SEQUENCES:-$((TRAIN_SEQUENCES + BOX_EXTRA))}
BOX_FRAMES=${BOX_FRAMES:-6}
BOX_FROM=${BOX_FROM:-3}
BOX_FRONT=${BOX_FRONT:-1}
WORKERS=${WORKERS:-2}
STAGE1_WEIGHTS=${STAGE1_WEIGHTS:-weights/racklay256-stage1.pt}
[ -f "$STAGE1_WEIGHTS" ] || { echo "train_256_budget.sh: $STAGE1_WEIGHTS is missing (scripts/train_256.sh STAGE=1 makes it)" >&2; exit 2; }

# 1. Data at 256x256.
TRAIN="$DATA/train256b"
# BOX_CONFIG: a generator config (JSON) for the box-depth head's extra scenes, made in a folder of their own
BOX_CONFIG=${BOX_CONFIG:-}
TRAIN2="$DATA/train256box"
BOX_GENERATE=()  # generate's extra arguments for that folder
if [ -n "$BOX_CONFIG" ]; then
    [ -f "$BOX_CONFIG" ] || { echo "train_256_budget.sh: BOX_CONFIG $BOX_CONFIG is missing" >&2; exit 2; }
    TRAIN2="$DATA/train256box-$(basename "$BOX_CONFIG" .json)"
    BOX_GENERATE=(--config "$BOX_CONFIG")
fi
HELDOUT="$DATA/heldout256"
TUNE="$DATA/tune256"
SPECS=("$TRAIN:$TRAIN_SEQUENCES:12:103" "$HELDOUT:${HELDOUT_SEQUENCES:-24}:${HELDOUT_FRAMES:-50}:202"
    "$TUNE:${TUNE_SEQUENCES:-8}:${HELDOUT_FRAMES:-50}:303")
[ "$BOX_SEQUENCES" -gt 0 ] && [ "$BOX_EXTRA" -gt 0 ] && SPECS+=("$TRAIN2:$BOX_EXTRA:$BOX_FRAMES:104")
for SPEC in "${SPECS[@]}"; do
    IFS=: read -r DIR N FRAMES SEED <<< "$SPEC"
    CONFIG=()
    [ "$DIR" = "$TRAIN2" ] && CONFIG=("${BOX_GENERATE[@]}")
    $PY -m mvracklay generate "$DIR" --sequences "$N" --frames "$FRAMES" --size 256 --seed "$SEED" --workers "$WORKERS" \
        "${CONFIG[@]}"
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


# 5. The heads (the network frozen): the rack heads side by side, then the box-depth head on both threads.
EPOCHS=()
[ -n "$HEAD_EPOCHS" ] && EPOCHS=(--epochs "$HEAD_EPOCHS")
fit() {  # command, output name
    [ -f "$RUN/$2.pt" ] || $PY -m mvracklay "$1" --checkpoint "$RUN/calibrated.pt" --data "$TRAIN" \
        --sequences "$HEAD_SEQUENCES" --val "$TUNE" --threads 1 --quiet "${EPOCHS[@]}" --precision "$PRECISION" --out "$RUN/$2.pt" \
        --json "$RUN/$2.fit.json" > "$RUN/$2.log" 2>&1
}
timed() {  # name, command...: run it once; its whole wall time in $RUN/name.wall_seconds (a re-run skips it)
    [ -f "$RUN/$1.wall_seconds" ] && return
    local t0
    t0=$(date +%s)
    "${@:2}"
    echo $(( $(date +%s) - t0 )) > "$RUN/$1.wall_seconds"
}
rack_heads() {
    local a b
    fit fit-back-edges back_edges & a=$!
    fit fit-uprights uprights & b=$!
    wait "$a" && wait "$b"
}
budget() {  # mode ("pass": the box-depth head's pass minutes; "total": the budget's record)
    $PY - "$1" "$STAGE1_WEIGHTS" "$RUN" "$TOTAL" "$BOX_MARGIN" "$BOX_FIT_RATIO" <<'EOF'
import json, sys
from pathlib import Path
mode, stage1, run, (total, margin, ratio) = sys.argv[1], sys.argv[2], Path(sys.argv[3]), map(float, sys.argv[4:7])
s1 = json.loads(Path(stage1).with_suffix(".json").read_text())["train_wall_minutes"]
s2 = json.loads((run / "last.json").read_text())["train_wall_minutes"]  # this run's own steps
wall = {p.name.split(".")[0]: int(p.read_text()) / 60 for p in run.glob("*.wall_seconds")}
spent = s1 + s2 + sum(wall.values())
if mode == "pass":  # the minutes left, less the margin, shared between the pass and the fit after it
    left = total - spent - margin
    if left <= 0:
        sys.exit(f"train_256_budget.sh: {spent:.1f} of {total:g} minutes spent, none left for the box-depth head")
    print(f"{left / (1 + ratio):.2f}")
    sys.exit()
fits = [json.loads((run / f"{k}.fit.json").read_text())["wall_minutes"] for k in ("back_edges", "uprights")]
out = {"stage1": s1, "stage2": s2, "back_edges": fits[0], "uprights": fits[1], **wall, "total": spent}
print(json.dumps(out))
if spent > total:
    sys.exit(f"train_256_budget.sh: {spent:.1f} minutes spent, over the budget of {total:g}")
EOF
}
timed rack_heads rack_heads
if [ "$BOX_SEQUENCES" -gt 0 ] && [ ! -f "$RUN/box.pt" ]; then
    PASS=$(budget pass)
    BOX_DATA=("$TRAIN")
    [ "$BOX_EXTRA" -gt 0 ] && BOX_DATA+=("$TRAIN2")
    BOX_FLAGS=()
    [ "$BOX_FRONT" = 1 ] && BOX_FLAGS=(--front)
    [ "$BOX_COLD" = 1 ] && [ "$BOX_FROM" -gt 0 ] && BOX_FLAGS+=(--cold-start)
    timed box_depth $PY -m mvracklay fit-box-depth --checkpoint "$RUN/calibrated.pt" --data "${BOX_DATA[@]}" \
        --sequences "$BOX_SEQUENCES" --frames "$BOX_FRAMES" --from-frame "$BOX_FROM" --parallax --pass-minutes "$PASS" \
        --cache-workers 2 --threads 2 --cache-dir "$RUNS" --quiet --precision "$PRECISION" --head-width "$BOX_WIDTH" \
        "${EPOCHS[@]}" "${BOX_FLAGS[@]}" \
        --out "$RUN/box.pt" --json "$RUN/box.fit.json" > "$RUN/box.log" 2>&1
fi
[ -f "$RUN/heads.pt" ] || { rm -f "$RUN/rack_depth_offset.json"
    $PY benchmarks/graft_heads.py "$RUN/uprights.pt" "$RUN/back_edges.pt" "$RUN/heads.pt" --only uprights; }
# the rack depth the heads read, centred on the tuning set's (not counted, as the box offsets: no weight moves)
[ -f "$RUN/rack_depth_offset.json" ] || { rm -f "$RUN/heads_box.pt"  # grafted from the heads before it
    $PY -m mvracklay calibrate --target rack-depth --checkpoint "$RUN/heads.pt" --data "$TUNE" --threads 2 --quiet \
        --json "$RUN/rack_depth_offset.json" > "$RUN/rack_depth_offset.txt"; }
if [ "$BOX_SEQUENCES" -gt 0 ] && [ ! -f "$RUN/heads_box.pt" ]; then
    $PY benchmarks/graft_heads.py "$RUN/box.pt" "$RUN/heads.pt" "$RUN/heads_box.pt" --only box_depth
fi

# 6. The budget, then Table I.
budget total | tee "$RUN/budget.json"
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
