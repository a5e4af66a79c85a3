"""The tracker with a rig node's power: the sum of the squared slot energies of the trace, clipped
at 1, with the slot energies read ``gain`` times high (a full scale calibrated low), in process.

Prints, per full-scale error and ``power_weight``, the share of readings >= 0.95 (the true
P_N / P_max) after the first ``--settle`` readings, mean and worst over the seeds (docs/rig.md,
"The tracker reads it too").
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np


def held_share(mode, gain, power_weight, seed, steps, settle, realism, exact_power=False):
    """Share of readings ``settle``..``steps`` whose true P_N/P_max is >= 0.95."""
    from ops_contract.config import make_config
    from ops_controller_ros.controllers import next_command
    from ops_controller_ros.tracker import PhaseTracker, TrackerParams
    from ops_sim_ros.simulation import BatchedSimulation

    config = make_config(5, mode, "test", realism=realism)
    sim = BatchedSimulation(config, 1, seed=seed)
    sim.reset(seed=seed)
    tracker = PhaseTracker(config, replace(TrackerParams(), power_weight=power_weight), seed=seed)
    held = []
    for step in range(steps):
        res = sim.step_setpoints(next_command(tracker)[None])
        energies = gain * res.pulse_energies[0]
        power = float(res.power[0])
        if not exact_power:  # as the rig node estimates it (ops_rig_ros/trace.py)
            power = float(np.clip(np.sum(np.maximum(energies, 0.0) ** 2), 0.0, 1.0))
        tracker.observe(power, energies)
        if step >= settle:
            held.append(float(res.power[0]) >= 0.95)
    return float(np.mean(held))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="ops-bench rig-power", description=__doc__)
    ap.add_argument("--mode", default="hard")
    ap.add_argument("--gains", type=float, nargs="+", default=[1.0, 1.02, 1.04, 1.08, 1.15, 0.97])
    ap.add_argument("--weights", type=float, nargs="+", default=[1.0, 0.0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[8401, 8402, 8403, 8404])
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--settle", type=int, default=100)
    ap.add_argument("--realism", default="ideal", choices=("ideal", "lab"))
    ap.add_argument("--exact-power", action="store_true", help="the simulator's own power")
    args = ap.parse_args(argv)
    print("| slot energies read | power_weight | share >= 0.95 (mean) | worst seed |")
    print("|---|---|---|---|")
    for gain in args.gains:
        for weight in args.weights:
            shares = [
                held_share(
                    args.mode,
                    gain,
                    weight,
                    s,
                    args.steps,
                    args.settle,
                    args.realism,
                    args.exact_power,
                )
                for s in args.seeds
            ]
            print(
                f"| x{gain:g} | {weight:g} | {np.mean(shares):.3f} | {min(shares):.3f} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
