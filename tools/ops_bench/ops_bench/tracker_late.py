"""The tracker in process with late commands, as a free-running rig over DDS takes them.

N = 5, testing split, ``--realism`` (default ``lab``), ``--steps`` readings per seed. Each step
the tracker's command (``controllers.next_command``: ``command``, then ``think`` and the revised
command) goes to an ``OpsEnv``; with probability ``--p-late`` (a random stream of its own, from
the seed) it comes a step late: the environment first steps once more on the previous
set-points, and the reading after the command is given to the tracker with ``steps=2`` (the
steps since its previous reading, as the node tells it; ``command_age`` 0). Per seed: the share
of readings >= 0.95 from the first reading >= 0.95 on, and the losses (entries into < 0.8 after
it), as ``evaluate --continuous`` counts them (``continuous.lock_figures``).

The node caps its knot test at ``knot_budget_ms`` 4 of the wall clock, the tracker in process at
none (0): ``--param knot_budget_ms=4.0`` gives the node's setting, and with it figures that
depend on the machine and its load (docs/tracker.md, "A knot test cut short on a noisy
detector takes no knot").

Usage (after `source setup.bash`):
  ops-bench tracker-late [--p-late 0.15] [--seeds 1002 1003 1004 1005] [--steps 3000]
      [--mode hard] [--realism lab] [--param knot_budget_ms=4.0] [--out late.json]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from ops_contract.config import MODES, REALISMS, make_config
from ops_contract.threads import limit_blas_threads
from ops_controller_ros.controllers import make_controller, next_command
from ops_controller_ros.tracker import TrackerParams
from ops_experiments.cli_args import positive_int
from ops_experiments.continuous import lock_figures
from ops_sim_ros.env import OpsEnv

from ops_bench import study

STAGE = 5
#: The late-command stream's seed is the run's seed + this (the scratch harness's offset).
LATE_SEED_OFFSET = 77


def p_late_type(text: str) -> float:
    """An argparse ``type``: a probability in [0, 1)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number in [0, 1) (got {text!r})") from None
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"must be in [0, 1) (got {text})")
    return value


def run(
    seed: int,
    steps: int = 3000,
    p_late: float = 0.15,
    mode: str = "hard",
    realism: str = "lab",
    params: dict | None = None,
) -> np.ndarray:
    """Every reading's P_N/P_max of one run (see the module docstring)."""
    cfg = make_config(stage=STAGE, mode=mode, split="test", realism=realism)
    env = OpsEnv.from_config(cfg, max_episode_steps=steps * 2 + 10)  # late steps count too
    _, info = env.reset(seed=seed)
    ctl = make_controller(
        "tracker", cfg, params or {}, setpoints_fs=info["setpoints_fs"], seed=seed
    )
    rng = np.random.default_rng(seed + LATE_SEED_OFFSET)
    previous = np.asarray(info["setpoints_fs"], dtype=float)
    power = np.empty(steps)
    try:
        for t in range(steps):
            command = np.asarray(next_command(ctl), dtype=float)
            gap = 1
            if rng.random() < p_late:  # the rig steps once more on the old set-points
                env.step_setpoints(previous)
                gap = 2
            r = env.step_setpoints(command)
            power[t] = float(r.power[0])
            ctl.observe(float(power[t]), r.pulse_energies[0], steps=gap, command_age=0)
            previous = command
    finally:
        env.close()
    return power


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument(
        "--p-late", type=p_late_type, default=0.15, help="share of late commands, in [0, 1)"
    )
    ap.add_argument("--seeds", type=int, nargs="+", default=[1002, 1003, 1004, 1005])
    ap.add_argument("--steps", type=positive_int, default=3000, help="readings per seed")
    ap.add_argument("--mode", choices=MODES, default="hard")
    ap.add_argument("--realism", choices=REALISMS, default="lab")
    study.add_options(ap, "tracker (the node's: knot_budget_ms=4.0)")
    args = ap.parse_args(argv)
    study.check_params(ap, args, TrackerParams)
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    limit_blas_threads()  # as the node and evaluate (unless OPENBLAS_NUM_THREADS etc. is set)
    setting = f"{args.mode}, {args.realism}, p_late {args.p_late:g}, {args.steps} steps"
    setting += f", tracker {' '.join(args.param)}" if args.param else ""
    print(f"[tracker-late] {setting}", flush=True)
    per_seed = []
    for seed in args.seeds:
        t0 = time.monotonic()
        f = lock_figures(run(seed, args.steps, args.p_late, args.mode, args.realism, args.params))
        f = {"seed": seed, "percent_locked": 100 * f["locked_fraction"], **f}
        per_seed.append(f)
        print(
            f"seed {seed} p_late {args.p_late}: {f['percent_locked']:.2f} % locked, "
            f"{f['losses']} losses ({time.monotonic() - t0:.0f} s)",
            flush=True,
        )
    percents = [f["percent_locked"] for f in per_seed]
    losses = [f["losses"] for f in per_seed]
    summary = {
        "mean_percent_locked": float(np.mean(percents)),
        "worst_percent_locked": float(np.min(percents)),
        "total_losses": int(sum(losses)),
        "most_losses": int(max(losses)),
    }
    print(
        f"{len(per_seed)} seeds: mean {summary['mean_percent_locked']:.2f} % locked, worst "
        f"{summary['worst_percent_locked']:.2f} %; losses {summary['total_losses']} in all, "
        f"at most {summary['most_losses']} in a run",
        flush=True,
    )
    if args.out:
        out = {
            "settings": {
                "stage": STAGE,
                "mode": args.mode,
                "split": "test",
                "realism": args.realism,
                "p_late": args.p_late,
                "steps": args.steps,
                "seeds": args.seeds,
                "late_seed_offset": LATE_SEED_OFFSET,
                "tracker_params": args.params,
            },
            "summary": summary,
            "per_seed": per_seed,
            "load_average_end": [round(v, 2) for v in os.getloadavg()],
        }
        study.write_figures(args.out, "tracker-late", argv, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
