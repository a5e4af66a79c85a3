#!/usr/bin/env bash
# Table 1 with both observation sets: the quick profile with the authors' detector,
# agents on the authors' observation with the authors' code's hyper-parameters
# (docs/results/n5_quick_authors_hp: the paper's Table 1 as the authors' code made it), then with
# the paper's tables' hyper-parameters on the authors' observation (docs/results/n5_quick_authors)
# and on the rig's (docs/results/n5_quick_rig), one run at a time, niced. TD3 then SAC at N = 5, seed 0, mode by
# mode with both sets (authors, then rig), then the rest of each profile. Every command resumes: run this
# script again to continue (stored runs are skipped, interrupted ones continue from their save).
# It runs a frozen copy of the commit it starts from (runs/frozen-<commit>, first on PYTHONPATH),
# so that edits of the working tree cannot reach a run in progress.
cd "$(dirname "$0")/.."
source setup.bash >/dev/null
set -euo pipefail
commit=$(git rev-parse --short HEAD)
frozen="$PWD/runs/frozen-$commit"
if [ ! -d "$frozen" ]; then
    mkdir -p "$frozen.tmp" && git archive HEAD | tar -x -C "$frozen.tmp" && mv "$frozen.tmp" "$frozen"
fi
export PYTHONPATH="$frozen/ops_sim_ros:$frozen/ops_controller_ros:$frozen/ops_gym_bridge:$PYTHONPATH"
bench() { nice -n 15 python -m ops_gym_bridge.benchmark --profile quick --detector total \
    --jobs 1 --status-every 600 "$@"; }
authors_hp=(--observation authors --hyperparams-set authors --out docs/results/n5_quick_authors_hp)
authors=(--observation authors --out docs/results/n5_quick_authors)
rig=(--observation rig --out docs/results/n5_quick_rig)
bench "${authors_hp[@]}" --algos td3 sac --seeds 0 --extra-stages
for algo in td3 sac; do  # seed 0, mode by mode, both sets: a side-by-side cell at a time
    for mode in easy medium hard; do
        for set in authors rig; do
            [ "$set" = authors ] && out=("${authors[@]}") || out=("${rig[@]}")
            bench "${out[@]}" --algos "$algo" --modes "$mode" --seeds 0 --extra-stages --controllers
        done
    done
done
bench "${authors_hp[@]}"
bench "${authors[@]}"
bench "${rig[@]}"
