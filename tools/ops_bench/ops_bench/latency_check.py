"""The tracker's latency check (issue 30): a tracker told the wrong latency, in process; the
reading at which it takes the rig's latency, and its final P_N / P_max.

Usage (after `source setup.bash`):
  OPENBLAS_NUM_THREADS=1 ops-bench latency-check [--seeds 12] [--first-seed 501]
Prints one line per case (rig latency, told latency, mode): the readings at which the latency
was taken, sorted (- : never within --steps), and the mean and worst of the last 20 readings.
"""

from __future__ import annotations

import argparse

import numpy as np
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker
from ops_sim_ros.simulation import BatchedSimulation

CASES = [(1, 0, "medium"), (1, 0, "hard"), (2, 1, "medium"), (2, 1, "hard"), (0, 1, "medium"),
         (0, 1, "hard"), (4, 2, "medium"), (4, 2, "hard")]  # fmt: skip


def run(rig: int, told: int, mode: str, seed: int, steps: int = 150, params=None):
    """A rig of latency ``rig`` and a tracker told ``told`` (``params``: TrackerParams or the
    defaults): (tracker, reading at which it took a latency or None, every reading's P_N/P_max).
    ``ops_controller_ros/test/test_latency_check.py`` runs it too."""
    sim = BatchedSimulation(make_config(5, mode, "test", latency_steps=rig), 1, seed=seed)
    tracker = PhaseTracker(make_config(5, mode, "test", latency_steps=told), params, seed=seed)
    sim.reset(seed=seed)
    taken_at, powers = None, []
    for k in range(steps):
        res = sim.step_setpoints(next_command(tracker)[None])
        tracker.observe(float(res.power[0]), res.pulse_energies[0])
        powers.append(float(res.power[0]))
        if tracker.latency_changes and taken_at is None:
            taken_at = k + 1
    return tracker, taken_at, np.array(powers)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--first-seed", type=int, default=501)
    ap.add_argument("--steps", type=int, default=150)
    args = ap.parse_args(argv)
    print("| rig | told | mode | taken at reading (sorted) | within 50 | final mean | worst |")
    print("|---|---|---|---|---|---|---|")
    for rig, told, mode in CASES:
        taken, finals = [], []
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            tracker, at, powers = run(rig, told, mode, seed, args.steps)
            final = float(np.mean(powers[-20:]))
            taken.append(at if at is not None and tracker.latency == rig else None)
            finals.append(final)
        shown = ", ".join(str(t) if t else "-" for t in sorted(taken, key=lambda t: t or 10**9))
        within = sum(1 for t in taken if t is not None and t <= 50)
        print(f"| {rig} | {told} | {mode} | {shown} | {within}/{len(taken)} | "
              f"{np.mean(finals):.3f} | {np.min(finals):.3f} |", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
