"""A privileged teacher: the action that cancels the simulator's true delay error.

The simulator knows what no stacker can: each delay line's hidden offset (initial error, random
walk and drift, :mod:`ops_sim_ros.noise`) and the drift's slope. The stacked power is periodic in
each stage's applied delay by one optical period (the envelope, a thousand times wider, hardly
moves) and unchanged when every applied delay changes sign (the complex conjugate of the optical
fields gives the same intensities). :func:`oracle_increments` moves each line's set-point toward
the nearest optimum (applied delay a whole number of periods) where the line will be when the
command acts (after the rig's ``latency_steps``, the drift's slope carried that far), clipped to
the actuator's step: the increment action of :class:`~ops_sim_ros.env.OpsEnv` in [-1, 1].

:func:`teacher_labels` is what a student that sees only the rig's observation is taught: the
first ``probe_steps`` steps of every episode a fixed probe (:func:`probe_pattern`; a student
cannot tell the true error from its sign-flipped twin before it has moved: the conjugate
symmetry makes both give the same readings, and the mean of the two cancelling actions is
zero), then the oracle.
"""

from __future__ import annotations

import numpy as np


def wrap_fs(x: np.ndarray, period_fs: float) -> np.ndarray:
    """``x`` (fs) minus the nearest whole number of periods: in [-period / 2, period / 2]."""
    return x - period_fs * np.round(x / period_fs)


def true_error_fs(sim) -> np.ndarray:
    """(B, N) fs: where each delay line's commanded set-point puts it now relative to the
    nearest optimum (the latest command, the hidden offset; wrapped to a period)."""
    return wrap_fs(sim.setpoints_fs + sim.noise.offset, sim.config.optical_period_fs)


def oracle_increments(sim) -> np.ndarray:
    """(B, N) increment actions in [-1, 1] for a :class:`~ops_sim_ros.simulation.
    BatchedSimulation`: each line's step toward its nearest optimum as it will be when the
    command acts (latency_steps + 1 steps of drift ahead), clipped to the actuator's max step."""
    cfg = sim.config
    lead = int(cfg.latency_steps) + 1
    ahead = sim.setpoints_fs + sim.noise.offset
    if sim.noise.drift_enabled:
        ahead = ahead + lead * sim.noise.slope
    step = -wrap_fs(ahead, cfg.optical_period_fs) / cfg.max_step_fs
    return np.clip(step, -1.0, 1.0)


def probe_pattern(steps: int, stage: int) -> np.ndarray:
    """(steps, N) the fixed probe of an episode's first steps, one max step per stage and step:
    the signs of rows 1, 2, ... of a Sylvester-Hadamard matrix (its columns 1..N), so that the
    readings see every stage move with a sign pattern of its own."""
    size = 1
    while size < max(steps + 1, stage + 1):
        size *= 2
    h = np.ones((1, 1))
    while h.shape[0] < size:
        h = np.block([[h, h], [h, -h]])
    return h[1 : steps + 1, 1 : stage + 1].copy()


def teacher_labels(sim, probe_steps: int = 1, age=None) -> np.ndarray:
    """(B, N) the teacher's actions for a student on the rig's view: the probe where fewer than
    ``probe_steps`` steps of the run have been taken, the oracle elsewhere. ``age``: (B,) steps
    since each env's run started afresh (default: the episode's step count; a run that carries
    on over episodes is probed at its start only)."""
    labels = oracle_increments(sim)
    if probe_steps > 0:
        age = sim.step_count if age is None else np.asarray(age)
        early = age < probe_steps
        if early.any():
            labels[early] = probe_pattern(probe_steps, sim.stage)[age[early]]
    return labels


def privileged_features(sim) -> np.ndarray:
    """What only the simulator knows, as a critic (:mod:`.asymmetric`) or a student's auxiliary
    targets (``distill --aux-weight``) take it: (B, 3 N) float32, the cos and sin of each line's
    true error (2 pi / optical period), then the drift's slope per step in units of the
    actuator's largest step (0 without drift)."""
    cfg = sim.config
    phase = 2.0 * np.pi * true_error_fs(sim) / cfg.optical_period_fs
    slope = sim.noise.slope / cfg.max_step_fs if sim.noise.drift_enabled else 0.0 * phase
    return np.concatenate([np.cos(phase), np.sin(phase), slope], axis=1).astype(np.float32)


def privileged_dim(stage: int) -> int:
    """The number of :func:`privileged_features` of a stacker of ``stage`` lines."""
    return 3 * int(stage)
