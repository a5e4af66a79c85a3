"""The landscape's side peaks: gradient ascent on P_N / P_max from random delays, per stage count
and detector, and the highest local maximum short of the stack (SPGD's ``restart_below`` sits
above it: docs/results/spgd/index.md, "Restarts only below every side peak").

Each start is uniform over one optical cycle per stage; the ascent takes normalized gradient
steps (as SPGD does, the gradient of log P, here by central differences) until it has settled. A
start ends on the stack when it reaches 0.99.

Usage (after `source setup.bash`):
  ops-bench side-peaks [--stages 2 3 4 5 6] [--starts 1500] [--detectors polarizer total]
"""

from __future__ import annotations

import argparse

import numpy as np
from ops_sim_ros.physics import PulseStacker

STEP = 0.02  # fs per unit of the normalized gradient
DELTA_FS = 1e-3  # central-difference step


def ascend(stacker: PulseStacker, starts: np.ndarray, iterations: int) -> np.ndarray:
    """P_N / P_max where normalized gradient ascent from ``starts`` (B, N) fs settles."""
    x = starts.copy()
    n = x.shape[1]
    for _ in range(iterations):
        _, power = stacker.energies_and_power(x)
        gradient = np.empty_like(x)
        for j in range(n):
            d = np.zeros(n)
            d[j] = DELTA_FS
            _, up = stacker.energies_and_power(x + d)
            _, down = stacker.energies_and_power(x - d)
            gradient[:, j] = (up - down) / (2 * DELTA_FS)
        x = x + STEP * gradient / np.maximum(power, 0.02)[:, None]
    return stacker.energies_and_power(x)[1]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--stages", type=int, nargs="+", default=[2, 3, 4, 5, 6])
    p.add_argument("--starts", type=int, default=1500)
    p.add_argument("--iterations", type=int, default=300)
    p.add_argument("--detectors", nargs="+", default=["polarizer", "total"])
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    print("| detector | N | starts ending on the stack | highest side peak |")
    print("|---|---|---|---|")
    for detector in args.detectors:
        for n in args.stages:
            stacker = PulseStacker(stage=n, dtype=np.float64, detector=detector)
            rng = np.random.default_rng(args.seed)
            period = stacker.optical_period_fs
            starts = rng.uniform(-0.5, 0.5, (args.starts, n)) * period
            power = ascend(stacker, starts, args.iterations)
            stacked = power >= 0.99
            side = power[~stacked]
            highest = f"{side.max():.3f}" if side.size else "none"
            print(f"| {detector} | {n} | {stacked.mean():.1%} | {highest} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
