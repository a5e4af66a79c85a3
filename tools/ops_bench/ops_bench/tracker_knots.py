"""A tracker run in process with what each reading cost (``ops-bench tracker-compute``'s loop).

``tracker_run`` runs the tracker (its defaults, or the parameters given) for ``steps`` readings on
one seed (N = 5, testing split, polarizer detector) and returns every reading, the steps since the
drift's last knot (a stage's slope redrawn), the estimate's error, the knots, and the compute per
reading (``observe`` + ``command`` + ``think`` and the revised command, as
``controllers.next_command`` runs them: a node at 100 Hz has 10 ms).
"""

from __future__ import annotations

import time

import numpy as np
from ops_contract.config import make_config
from ops_controller_ros.controllers import make_controller
from ops_sim_ros.env import OpsEnv


def make_env(mode: str, steps: int, seed: int, realism: str = "ideal") -> tuple[OpsEnv, dict]:
    """The testing environment of one run, reset with ``seed`` * 1000."""
    config = make_config(stage=5, mode=mode, split="test", realism=realism)
    env = OpsEnv.from_config(config, max_episode_steps=steps + 1)
    _, info = env.reset(seed=seed * 1000)
    return env, info


def tracker_run(mode: str, steps: int, seed: int, params: dict, realism: str = "ideal") -> dict:
    """One run's readings, knots and compute per reading (the module docstring), on the
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
