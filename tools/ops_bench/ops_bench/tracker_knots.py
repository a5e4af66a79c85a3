"""Where the tracker loses readings in extreme mode, against what any controller could do.

Two in-process runs of ``--steps`` steps per seed (N = 5, testing split, polarizer detector):

* **bound**: a controller that knows the delay errors and the drift of every step up to its last
  reading exactly and learns of a knot (a stage's slope redrawn) only from the reading after it:
  it commands -(error + last step's drift). Its readings >= 0.95 are the most a controller that
  learns the drift from its readings can hold.
* **tracker**: the tracker (its defaults, or ``--param KEY=VALUE``), with the readings below 0.95
  counted by the steps since the last knot, the knots that caused one, the estimate's error and
  the compute per reading (``observe`` + ``command`` + ``think`` and the revised command, as
  ``controllers.next_command`` runs them: a node at 100 Hz has 10 ms).

Usage (after `source setup.bash`):
  ops-bench tracker-knots --mode extreme --steps 3000 --seeds 1000 [--param window=10]
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np
from ops_contract.config import make_config
from ops_controller_ros.controllers import make_controller
from ops_experiments.cli_args import parse_key_values
from ops_experiments.continuous import lock_figures
from ops_sim_ros.env import OpsEnv


def make_env(mode: str, steps: int, seed: int, realism: str = "ideal") -> tuple[OpsEnv, dict]:
    config = make_config(stage=5, mode=mode, split="test", realism=realism)
    env = OpsEnv.from_config(config, max_episode_steps=steps + 1)
    _, info = env.reset(seed=seed * 1000)
    return env, info


def bound_run(mode: str, steps: int, seed: int) -> np.ndarray:
    """P_N/P_max of the informed controller (see the module docstring)."""
    env, _ = make_env(mode, steps, seed)
    noise = env.sim.noise
    previous = noise.mu.copy()
    power = np.empty(steps)
    for t in range(steps):
        last_drift = noise.mu - previous  # what the last reading revealed of the drift
        previous = noise.mu.copy()
        power[t] = env.step_setpoints(-(noise.walk + noise.mu + last_drift)[0]).power[0]
    return power


def tracker_run(mode: str, steps: int, seed: int, params: dict, realism: str = "ideal") -> dict:
    """One run's readings, knots and compute per reading (see the module docstring), on the
    ``realism`` rig, which the tracker is told."""
    env, info = make_env(mode, steps, seed, realism)
    nominal = make_config(stage=5, mode=mode, realism=realism)
    ctl = make_controller("tracker", nominal, params, setpoints_fs=info["setpoints_fs"], seed=seed)
    noise, period = env.sim.noise, env.optical_period_fs
    slope = noise.slope.copy()
    last_knot = -(10**9)
    power, since = np.empty(steps), np.empty(steps, dtype=int)
    # per reading: observe + the command after it (a node's answer), and think() + the
    # revised command (the work after the answer; 0 unless defer_knot_test)
    answer_ms, think_ms = np.zeros(steps + 1), np.zeros(steps + 1)
    error = np.full(steps, np.nan)
    knots = []  # (step from which the new slope acts, its change in cycles per step)
    for t in range(steps):
        t0 = time.perf_counter()
        command = ctl.command()
        t1 = time.perf_counter()
        if ctl.think():
            command = ctl.command()
        t2 = time.perf_counter()
        answer_ms[t] += (t1 - t0) * 1e3
        think_ms[t] += (t2 - t1) * 1e3
        r = env.step_setpoints(command)
        power[t] = r.power[0]
        t3 = time.perf_counter()
        ctl.observe(float(r.power[0]), r.pulse_energies[0])
        answer_ms[t + 1] += (time.perf_counter() - t3) * 1e3
        since[t] = t - last_knot
        change = np.abs(noise.slope[0] - slope[0]).max() / period
        if change > 1e-12:  # redrawn at the end of this step: acts from the next
            last_knot = t + 1
            knots.append((t + 1, change))
        slope = noise.slope.copy()
        if ctl.estimate is not None:
            truth = (noise.walk + noise.mu)[0] / period
            error[t] = np.abs((ctl.estimate - truth + 0.5) % 1.0 - 0.5).max()
    return {
        "power": power,
        "since": since,
        "error": error,
        "knots": knots,
        "ctl": ctl,
        "compute_ms": (answer_ms + think_ms)[1:],  # the reading's observe, then command/think
        "answer_ms": answer_ms[1:],
        "think_ms": think_ms[1:],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--mode", default="extreme")
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1000])
    ap.add_argument("--param", nargs="*", default=[], help="tracker parameters KEY=VALUE")
    args = ap.parse_args(argv)
    params = parse_key_values(args.param, "--param")
    for seed in args.seeds:
        t0 = time.monotonic()
        b = lock_figures(bound_run(args.mode, args.steps, seed))
        print(
            f"seed {seed} bound:   locked {b['locked_fraction']:.4f}, losses {b['losses']}, "
            f"worst after lock {b['worst_after_lock']:.4f}"
        )
        run = tracker_run(args.mode, args.steps, seed, params)
        f = lock_figures(run["power"])
        first = f["first_lock_step"] or 0
        bad = np.flatnonzero(run["power"][first:] < 0.95) + first
        print(
            f"seed {seed} tracker: locked {f['locked_fraction']:.4f}, losses {f['losses']}, "
            f"worst after lock {f['worst_after_lock']:.4f}, readings < 0.95: {bad.size}, "
            f"knots taken {run['ctl'].knots} ({time.monotonic() - t0:.0f} s)"
        )
        by_age = Counter(np.minimum(run["since"][bad], 12).tolist())
        print(
            "  readings < 0.95 by steps since the last knot (12: 12 or more):",
            sorted(by_age.items()),
        )
        starts = {k for k, _ in run["knots"]}
        bad_set = set(bad.tolist())
        hit = [c for k, c in run["knots"] if any(k + j in bad_set for j in range(4))]
        sizes = np.array([c for _, c in run["knots"]])
        print(
            f"  knots: {len(starts)}, followed within 4 readings by one < 0.95: {len(hit)}; slope "
            f"change (cycles/step) median {np.median(sizes):.4f}, of those {np.median(hit):.4f}"
            if hit
            else f"  knots: {len(starts)}, none followed by a reading < 0.95"
        )
        ms = run["compute_ms"][first:]
        print(
            "  compute per reading after the first lock, ms: median/p99/max "
            + "/".join(f"{v:.1f}" for v in (np.median(ms), np.percentile(ms, 99), ms.max()))
            + f"; readings over 10 ms: {100 * np.mean(ms > 10):.1f} %"
        )
        err = run["error"][first:]
        print(
            "  estimate error (largest stage, cycles) p50/p90/p99: "
            + "/".join(f"{v:.4f}" for v in np.nanpercentile(err, [50, 90, 99]))
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
