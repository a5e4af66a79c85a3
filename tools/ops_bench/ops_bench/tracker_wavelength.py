"""The tracker's wavelength estimate on rigs off the model's 1030 nm (issue 20).

For each mode and true wavelength, runs of ``--steps`` steps per seed in process (N = 5, testing
split, polarizer detector; the tracker is told the nominal 1030 nm): the estimate after 100, 300,
1000 steps and at the end, its largest error over the seeds from step 300 on, and the readings
>= 0.95 after the first lock with the whole-cycle moves (the default) and without them
(``hop_every=0``), so the cost of the moves in lock is measured beside what they estimate.

Usage (after `source setup.bash`):
  ops-bench tracker-wavelength [--modes hard extreme] [--steps 3000]
      [--seeds 2001 2002] [--wavelengths 1030] [--write docs/tracker.md]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_experiments.continuous import lock_figures
from ops_sim_ros.env import OpsEnv

from ops_bench.docs import write_section

SECTION = "## Tracker: wavelength estimated online (issue 20)"
WAVELENGTHS = (1009.4, 1019.7, 1030.0, 1040.3, 1050.6)  # -2 %, -1 %, 0, +1 %, +2 %
CHECKPOINTS = (100, 300, 1000)


def run(mode: str, true_nm: float, steps: int, seed: int, params: TrackerParams):
    """(P_N/P_max per step, the wavelength estimate per step) of one run."""
    nominal = make_config(stage=5, mode=mode, split="test")
    env = OpsEnv.from_config(nominal.replace(wavelength_nm=true_nm), max_episode_steps=steps + 1)
    _, info = env.reset(seed=seed)
    ctl = PhaseTracker(nominal, params, info["setpoints_fs"], seed=seed)
    power, estimate = np.empty(steps), np.empty(steps)
    for t in range(steps):
        r = env.step_setpoints(next_command(ctl))
        ctl.observe(float(r.power[0]), r.pulse_energies[0])
        power[t] = r.power[0]
        estimate[t] = ctl.calibration.wavelength_nm
    return power, estimate


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--modes", nargs="+", default=["hard", "extreme"])
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--seeds", type=int, nargs="+", default=[2001, 2002])
    ap.add_argument(
        "--wavelengths", type=float, nargs="+", default=list(WAVELENGTHS), help="true, nm"
    )
    ap.add_argument("--write", help="replace this section of a markdown file with the table")
    args = ap.parse_args(argv)
    cmd = "ops-bench tracker-wavelength " + " ".join(sys.argv[1:])
    lines = [
        SECTION,
        "",
        f"Command: `{cmd}` (N = 5, split=test, polarizer detector, seeds {args.seeds}, "
        f"{args.steps} steps each; the simulator runs the true wavelength, the tracker starts from "
        "1030 nm). Estimates: mean over the seeds; error: the largest over the seeds and steps "
        "from 300 on; locked: readings >= 0.95 after the first lock, with the whole-cycle moves "
        "(the default) and without (`hop_every=0`).",
        "",
        "| mode | true nm | estimate at 100 / 300 / 1000 / end | range from step 300 "
        "| largest error from step 300 | locked, moves | locked, no moves |",
        "|---|---|---|---|---|---|---|",
    ]
    t0 = time.monotonic()
    for mode in args.modes:
        for true_nm in args.wavelengths:
            est, locked, plain = [], [], []
            for seed in args.seeds:
                power, estimate = run(mode, true_nm, args.steps, seed, TrackerParams())
                est.append(estimate)
                locked.append(lock_figures(power)["locked_fraction"])
                power, _ = run(mode, true_nm, args.steps, seed, TrackerParams(hop_every=0))
                plain.append(lock_figures(power)["locked_fraction"])
            est = np.array(est)
            points = [est[:, min(c, args.steps) - 1].mean() for c in CHECKPOINTS]
            points.append(est[:, -1].mean())
            error = 100 * np.abs(est[:, 299:] / true_nm - 1).max()
            lines.append(
                f"| {mode} | {true_nm} | {' / '.join(f'{v:.1f}' for v in points)} | "
                f"{est[:, 299:].min():.1f}–{est[:, 299:].max():.1f} | {error:.2f} % | "
                f"{100 * np.mean(locked):.2f} % | {100 * np.mean(plain):.2f} % |"
            )
            print(lines[-1], f"[{time.monotonic() - t0:.0f} s]", flush=True)
    if args.write:
        write_section(SECTION, "\n".join(lines) + "\n", pathlib.Path(args.write))
        print(f"wrote the section {SECTION!r} of {args.write}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
