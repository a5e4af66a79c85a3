"""A controller driven in process against the simulator, its commands kept inside a range the
way the loop node keeps them (shared by the range tests of the tracker, SPGD and the policy)."""

from __future__ import annotations

import numpy as np
from ops_controller_ros.controllers import next_command
from ops_controller_ros.setpoint_range import RangeKeeper
from ops_sim_ros.simulation import BatchedSimulation

#: The simulator's default optical period (1030 nm), fs.
PERIOD_FS = 1030.0 / 299.792458


def centred_range(stage: int, periods: float) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of +- ``periods`` optical periods around 0 for every stage: a range that
    just allows the moves (a range of 5.2 periods keeps a set-point within 0.6 of the middle)."""
    return np.full(stage, -periods * PERIOD_FS), np.full(stage, periods * PERIOD_FS)


def drive(ctl, config, seed: int, steps: int, keeper: RangeKeeper | None = None, first=False):
    """Run ``ctl`` for ``steps`` readings of a simulator of ``config`` (reset with ``seed``),
    each command through ``keeper.keep`` when given (the node's path); ``first``: the controller
    observes the reset's reading first (a learned policy acts on a reading). Returns the
    commands sent (steps, N) and the powers read (steps,)."""
    sim = BatchedSimulation(config, 1, seed=seed)
    res = sim.reset(seed=seed)
    if first:
        ctl.observe(float(res.power[0]), res.pulse_energies[0])
    commands, powers = [], []
    for _ in range(steps):
        command = next_command(ctl)
        if keeper is not None:
            command = keeper.keep(ctl, command)
        commands.append(command)
        res = sim.step_setpoints(np.asarray(command)[None])
        ctl.observe(float(res.power[0]), res.pulse_energies[0])
        powers.append(float(res.power[0]))
    return np.array(commands), np.array(powers)


def inside(commands, low, high) -> bool:
    """Whether every command is within [low, high] (per stage)."""
    return bool(np.all(commands >= low - 1e-9) and np.all(commands <= high + 1e-9))
