"""Ship a trained run as a ready-to-run model folder: the best evaluated model of
``train --eval-freq`` (RUN/best: model.zip + metadata.json, no replay buffer), its learning curve
(the periodic test evaluations against training time, from RUN/logs/progress*.csv: every
resumed part) and a fresh
evaluation on held-out seeds by `ros2 run ops_gym_bridge evaluate`.

Usage (after `source setup.bash`):
  ops-bench ship-model runs/learned/n5_hard models/n5_hard [--seeds 100 101 102 103 104]
Writes models/NAME/{model.zip, metadata.json, learning.csv, eval/...}; the folder is what
`ros2 run ops_controller_ros policy --ros-args -p model:=models/NAME` and `evaluate` accept.

  ops-bench ship-model runs/learned/n5_easy DEST --curve-only
keeps only what a figure needs of a run that is not shipped (an ablation): metadata.json and
learning.csv (kilobytes), no model; with --eval also the held-out evaluation of the run's best
model (DEST/eval), e.g. for a run with the other detector that is not shipped but is reported.

  ops-bench ship-model runs/ft DEST --checkpoint 4583280 --after models/n5_hard_lab/learning.csv
ships a checkpoint (RUN/checkpoints/model_<STEPS>_steps.zip, its metadata with its own step
count) instead of RUN/best; --after puts the learning curve of the model a fine-tune started
from (`train --init-from`) before the run's own: its evaluations up to the run's first step,
and the run's minutes counted on from there.
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

from ops_controller_ros.policy_io import CHECKPOINT_NAME, read_metadata, save_metadata
from ops_experiments.progress_log import read_progress

from ops_bench.reference_actions import rig_arguments

# evaluation seeds: not the seeds the training evaluations used (0 ...), so the shipped figure
# is not the one the best model was selected on
HELD_OUT_SEEDS = ["100", "101", "102", "103", "104"]


def learning_curve(logs: Path, out: Path, after: Path | None = None) -> int:
    """minutes, env steps, test P_N/P_max of every periodic evaluation (every part of a resumed
    run, minutes from its start); with ``after`` (an earlier learning.csv: the curve of the model
    the run started from), that curve's rows before the run's first step, then the run's rows
    with their minutes counted on from the last of those. Returns the count."""
    rows = [
        (
            float(row["minutes"]),
            int(float(row["time/total_timesteps"])),
            float(row["eval/final_power"]),
        )
        for row in read_progress(logs)
        if row.get("eval/final_power")
    ]
    if after is not None:
        rows = _joined(_read_curve(after), rows)
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["minutes", "env_steps", "test_final_power"])
        for minutes, steps, power in rows:
            w.writerow([f"{minutes:.2f}", steps, f"{power:.4f}"])
    return len(rows)


def _read_curve(path: Path) -> list[tuple[float, int, float]]:
    with open(path, newline="") as f:
        return [
            (float(r["minutes"]), int(r["env_steps"]), float(r["test_final_power"]))
            for r in csv.DictReader(f)
        ]


def _joined(earlier: list, rows: list) -> list:
    """``earlier``'s rows before the first step of ``rows``, then ``rows`` shifted in time."""
    if not rows:
        return list(earlier)
    start = min(steps for _, steps, _ in rows)
    kept = [row for row in earlier if row[1] < start]
    offset = kept[-1][0] if kept else 0.0
    return kept + [(minutes + offset, steps, power) for minutes, steps, power in rows]


def _checkpoint_source(run: Path, steps: int, dest: Path) -> Path | None:
    """Write RUN's checkpoint at ``steps`` into ``dest`` as a model folder (model.zip and the
    checkpoints' metadata with that step count); None when there is none."""
    zipped = run / "checkpoints" / f"model_{steps}_steps.zip"
    if not zipped.is_file():
        return None
    metadata = read_metadata(zipped)  # the checkpoint's own step count
    metadata.pop("checkpoint", None)
    metadata.pop("format_version", None)
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copy2(zipped, dest / "model.zip")
    save_metadata(dest, metadata)
    return dest


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
    ap.add_argument(
        "--checkpoint",
        type=int,
        metavar="STEPS",
        help="ship the checkpoint RUN/checkpoints/model_<STEPS>_steps.zip instead of RUN/best",
    )
    ap.add_argument(
        "--after",
        type=Path,
        metavar="LEARNING_CSV",
        help="the learning.csv of the model the run started from (train --init-from): its "
        "evaluations before the run's first step come first in DEST/learning.csv",
    )
    args = ap.parse_args(argv)
    if args.checkpoint is not None and (args.final or args.curve_only):
        ap.error("--checkpoint ships a checkpoint: not with --final or --curve-only")
    if args.after is not None and not args.after.is_file():
        ap.error(f"--after: {args.after} is not a file (give a model's learning.csv)")
    if args.curve_only:
        args.dest.mkdir(parents=True, exist_ok=True)
        shutil.copy2(args.run / "metadata.json", args.dest / "metadata.json")
        n = learning_curve(args.run / "logs", args.dest / "learning.csv", args.after)
        print(f"[ship] {args.dest}: metadata and learning curve ({n} evaluations)", flush=True)
        return evaluate(args.run / "best", args) if args.eval else 0
    if args.checkpoint is not None:
        if _checkpoint_source(args.run, args.checkpoint, args.dest) is None:
            kept = sorted(
                int(m.group(1))
                for p in (args.run / "checkpoints").glob("model_*_steps.zip")
                if (m := CHECKPOINT_NAME.match(p.name))
            )
            print(
                f"error: --checkpoint {args.checkpoint}: no "
                f"{args.run / 'checkpoints'}/model_{args.checkpoint}_steps.zip "
                f"(the run has checkpoints at {kept or 'no step'})",
                file=sys.stderr,
            )
            return 2
    else:
        best = args.run if args.final else args.run / "best"
        for name in ("model.zip", "metadata.json"):
            if not (best / name).is_file():
                hint = "" if args.final else " (train with --eval-freq, or ship --final)"
                print(f"error: {best / name} is missing{hint}", file=sys.stderr)
                return 2
        args.dest.mkdir(parents=True, exist_ok=True)
        for name in ("model.zip", "metadata.json"):
            shutil.copy2(best / name, args.dest / name)
    n = learning_curve(args.run / "logs", args.dest / "learning.csv", args.after)
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
