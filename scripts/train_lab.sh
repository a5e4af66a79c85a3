#!/usr/bin/env bash
# Issue 32, item 4 ("Learning on the rig"): a model for N = 5, hard mode, trained on the `lab`
# rig with every episode's rig drawn anew (train --rig-randomize lab: latency 0-2 steps and the
# other imperfections over their ranges; docs/physics.md, "A rig drawn per episode").
#
#   scripts/train_lab.sh            # starts the run, or resumes it: run it again every session
#   MINUTES=50 TOTAL=9000000 OUT=runs/issue32/n5_hard_lab scripts/train_lab.sh
#
# Each call trains for MINUTES of wall time (default 50), saves, and exits 0; the next call
# resumes (replay buffer, step count and DIR/best carry over) until the model has TOTAL steps
# (default 9,000,000: the 3,000,000 of models/n5_hard it starts from + 6,000,000 on the rig).
# Every 50,000 steps it evaluates 20 test episodes on the fixed `lab` rig and keeps the best
# in OUT/best. Then (seconds: a learned model evaluates ~25 episodes a second):
#
#   ros2 run ops_gym_bridge evaluate OUT/best --realism lab --mode hard --splits test \
#       --seeds $(seq 8301 8320) --episodes 5      # 100 episodes, mean and worst; goal >= 0.95
#
# INIT=models/n5_hard (default) fine-tunes that model (SAC, fast set, --obs-history 4: at least
# the largest latency + 1); INIT= (empty) trains from scratch with the same options.
cd "$(dirname "$0")/.."
source setup.bash >/dev/null
set -euo pipefail
OUT=${OUT:-runs/issue32/n5_hard_lab}
MINUTES=${MINUTES:-50}
TOTAL=${TOTAL:-9000000}
INIT=${INIT-models/n5_hard}
train() { nice -n 15 ros2 run ops_gym_bridge train "$@" --eval-freq 50000 --eval-episodes 20 \
    --max-minutes "$MINUTES" --no-progress --torch-threads 1 --out "$OUT"; }
steps_now() { python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['timesteps'])" "$1"; }
if [ -f "$OUT/model.zip" ]; then
    left=$((TOTAL - $(steps_now "$OUT/metadata.json")))
    if [ "$left" -le 0 ]; then
        echo "[train_lab] $OUT has its $TOTAL steps; evaluate $OUT/best (see this script's head)"
        exit 0
    fi
    train --resume --timesteps "$left"
elif [ -n "$INIT" ]; then
    left=$((TOTAL - $(steps_now "$INIT/metadata.json")))
    train --init-from "$INIT" --mode hard --realism lab --rig-randomize lab \
        --hyperparams learning_rate=0.0003 --seed 0 --timesteps "$left"
else
    train --hyperparams-set fast --stage 5 --mode hard --obs-history 4 --reward nines \
        --realism lab --rig-randomize lab --seed 0 --timesteps "$TOTAL"
fi
