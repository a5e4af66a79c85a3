"""A learned policy that decides every ``hold_steps`` readings and holds its command in between.

A policy trained on the ideal stacker takes every reading to show the effect of its last action.
Under a latency of L steps it does not (the last L commands have not acted yet), and the shipped
models fall from ~0.9 to ~0.2 at one step (docs/physics.md, "Learned policies under latency: held
decisions"). A lab's classic remedy is to wait: the policy decides on one reading in
``hold_steps``, and on the readings in between its command is held (increment 0: the same
set-points). With ``hold_steps`` = L + 1 every reading it decides on already shows its previous
command, so to the policy the rig looks latency-free, with ``hold_steps`` times the drift and
noise per decision.

The policy sees only the readings it decides on: its observation history
(``observation_spec.history``) is built from those, each pushed with the action decided on the
one before. Held readings never reach it (measured: fed every reading, held ones with a zero
action, the same hold leaves n5_hard at 0.06 under one step of latency, against 0.83).

One declaration, used by ``evaluate --hold-steps`` and the ``policy`` node's ``hold_steps``
parameter (both through :mod:`ops_controller_ros.runner_factory`, which puts the
:class:`HeldRunner` outside a switching model and a re-acquiring watchdog, so their readings
are the decisions' too): 1 (the default) decides on every reading, as before; k from 2 to
:data:`HOLD_STEPS_MAX` on one reading in k; 0 (``auto``) on one in ``latency_steps`` + 1 of the
rig the runner is told of (``--realism`` / ``--rig``, the node's ``realism`` /
``latency_steps``; a latency it is not told of, ``evaluate --env``, is not counted). Pure numpy:
no rclpy, no torch.

A model trained with held decisions (``train --hold-steps``: the environments' side of the same
hold, :mod:`ops_contract.held`, which declares the values) records its ``hold_steps`` in its
metadata (0 for auto; ``PolicyMeta.hold_steps``); ``evaluate`` and the policy node hold it so by
default (an explicit value overrides, and a model without the entry decides on every reading).
"""

from __future__ import annotations

import numpy as np
from ops_contract.held import (  # noqa: F401  (declared once, with the env side of the hold)
    HOLD_STEPS,
    HOLD_STEPS_AUTO,
    HOLD_STEPS_DEFAULT,
    HOLD_STEPS_MAX,
    check_hold_steps,
    resolve_hold_steps,
)

from .runner_wrapper import RunnerWrapper

#: The policy node's default: the model's own (its metadata's ``hold_steps``; 1 where absent).
HOLD_STEPS_MODEL = -1
HOLD_STEPS_HELP = (
    "readings per decision of the policy: it acts on one reading in k and holds its command "
    "(the same set-points) on the others, seeing only the readings it acts on; -1 (default): "
    "the model's (its metadata's hold_steps, written by train --hold-steps; 1 where it has "
    "none); 1: every reading; 0 (auto): the told latency_steps + 1; allowed: -1, 0 or "
    f"1-{HOLD_STEPS_MAX}"
)


class HeldRunner(RunnerWrapper):
    """A runner (``act``, ``restart``, ``took``, ``reset_state``, ``spec``, ``policy``: a
    :class:`~ops_controller_ros.policy_io.PolicyRunner`, a switching model or a watchdog) that
    decides on the first reading and then on one in ``hold_steps``; on the others :meth:`act`
    returns zeros (increment 0: the command held) and the wrapped runner is not called, so its
    observations are built from the decisions' readings alone (module docstring). All rigs of a
    batch (``num_envs``) decide on the same readings."""

    def __init__(self, runner, hold_steps: int, num_envs: int | None = None) -> None:
        hold = check_hold_steps(hold_steps)
        if hold == HOLD_STEPS_AUTO:
            raise ValueError(
                f"{HOLD_STEPS} 0 (auto) must be resolved against the told latency first "
                "(resolve_hold_steps)"
            )
        super().__init__(runner, num_envs)
        self.hold_steps = hold
        self.readings = 0  # readings since the (re)start
        self.decisions = 0  # of which the policy decided on

    def restart(self) -> None:
        """A new start: the next reading is a decision, with a new history."""
        self.runner.restart()
        self.readings = 0
        self.decisions = 0

    @property
    def decided(self) -> bool:
        """Whether the policy decided on the last reading (False: its command was held)."""
        return self.readings > 0 and (self.readings - 1) % self.hold_steps == 0

    def act(self, pulse_energies, power, setpoints_fs, applied_fs=None) -> np.ndarray:
        decide = self.readings % self.hold_steps == 0
        self.readings += 1
        if decide:
            self.decisions += 1
            return self.runner.act(pulse_energies, power, setpoints_fs, applied_fs)
        held = np.zeros((self._n, self.spec.stage), dtype=np.float32)
        return held[0] if self._single else held
