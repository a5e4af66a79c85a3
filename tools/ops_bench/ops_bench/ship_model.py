"""Ship a trained run as a ready-to-run model folder (issue 11): the best evaluated model of
``train --eval-freq`` (RUN/best: model.zip + metadata.json, no replay buffer), its learning curve
(the periodic test evaluations against training time, from RUN/logs/progress*.csv: every
resumed part) and a fresh
evaluation on held-out seeds by `ros2 run ops_gym_bridge evaluate`.

Usage (after `source setup.bash`):
  ops-bench ship-model runs/issue11/n5_hard models/n5_hard [--seeds 100 101 102 103 104]
Writes models/NAME/{model.zip, metadata.json, learning.csv, eval/...}; the folder is what
`ros2 run ops_controller_ros policy --ros-args -p model:=models/NAME` and `evaluate` accept.

  ops-bench ship-model runs/issue11/n5_easy docs/results/issue11/n5_easy_k0 --curve-only
keeps only what a figure needs of a run that is not shipped (an ablation): metadata.json and
learning.csv (kilobytes), no model; with --eval also the held-out evaluation of the run's best
model (DEST/eval), e.g. for a run with the other detector that is not shipped but is reported.
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

from ops_gym_bridge.experiments.progress_log import read_progress

from ops_bench.reference_actions import rig_arguments

# evaluation seeds: not the seeds the training evaluations used (0 ...), so the shipped figure
# is not the one the best model was selected on
HELD_OUT_SEEDS = ["100", "101", "102", "103", "104"]


def learning_curve(logs: Path, out: Path) -> int:
    """minutes, env steps, test P_N/P_max of every periodic evaluation (every part of a resumed
    run, minutes from its start); returns the count."""
    rows = [
        (
            float(row["minutes"]),
            int(float(row["time/total_timesteps"])),
            float(row["eval/final_power"]),
        )
        for row in read_progress(logs)
        if row.get("eval/final_power")
    ]
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["minutes", "env_steps", "test_final_power"])
        for minutes, steps, power in rows:
            w.writerow([f"{minutes:.2f}", steps, f"{power:.4f}"])
    return len(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("run", type=Path, help="a train --out directory with best/ and logs/")
    ap.add_argument("dest", type=Path, help="the model folder to write, e.g. models/n5_hard")
    ap.add_argument("--seeds", nargs="+", default=HELD_OUT_SEEDS)
    ap.add_argument("--episodes", default="5")
    ap.add_argument(
        "--curve-only",
        action="store_true",
        help="write only metadata.json (of the run) and learning.csv: an ablation for the figures",
    )
    ap.add_argument(
        "--final",
        action="store_true",
        help="ship the model at the end of training (RUN/model.zip) instead of RUN/best: a run "
        "without periodic evaluations (e.g. a fine-tune measured by its continuous runs)",
    )
    ap.add_argument(
        "--eval",
        action="store_true",
        help="with --curve-only: also evaluate RUN/best on the held-out seeds into DEST/eval",
    )
    args = ap.parse_args(argv)
    if args.curve_only:
        args.dest.mkdir(parents=True, exist_ok=True)
        shutil.copy2(args.run / "metadata.json", args.dest / "metadata.json")
        n = learning_curve(args.run / "logs", args.dest / "learning.csv")
        print(f"[ship] {args.dest}: metadata and learning curve ({n} evaluations)", flush=True)
        return evaluate(args.run / "best", args) if args.eval else 0
    best = args.run if args.final else args.run / "best"
    for name in ("model.zip", "metadata.json"):
        if not (best / name).is_file():
            hint = "" if args.final else " (train with --eval-freq, or ship --final)"
            print(f"error: {best / name} is missing{hint}", file=sys.stderr)
            return 2
    args.dest.mkdir(parents=True, exist_ok=True)
    for name in ("model.zip", "metadata.json"):
        shutil.copy2(best / name, args.dest / name)
    n = learning_curve(args.run / "logs", args.dest / "learning.csv")
    print(f"[ship] {args.dest}: model, metadata, learning curve ({n} evaluations)", flush=True)
    return evaluate(args.dest, args)


def evaluate(model: Path, args) -> int:
    """`evaluate` of the model folder ``model`` on the held-out seeds and the rig it was
    trained on, into DEST/eval."""
    metadata = json.loads((model / "metadata.json").read_text())
    cmd = ["ros2", "run", "ops_gym_bridge", "evaluate", str(model), "--seeds", *args.seeds]
    cmd += rig_arguments(metadata)  # a model trained on a rig is evaluated on it
    cmd += ["--episodes", args.episodes, "--out", str(args.dest / "eval"), "--torch-threads", "1"]
    print("[ship] " + " ".join(cmd), flush=True)
    return subprocess.run(cmd).returncode


if __name__ == "__main__":
    raise SystemExit(main())
