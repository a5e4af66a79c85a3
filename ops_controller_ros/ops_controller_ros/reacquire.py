"""A watchdog that re-acquires a lost stack: a learned policy that lost the stack is kicked to a
fresh point of the landscape and searches again.

Measured (models/README.md, "No catastrophic episode"): a learned policy that loses the stack in
a 200-step episode rarely finds it again within the episode (it sits on a side peak or a flat
stretch, its actions near zero), and those episodes end near zero. The watchdog wraps any runner
(a plain :class:`~ops_controller_ros.policy_io.PolicyRunner` or a
:class:`~ops_controller_ros.policy_switch.SwitchingRunner`) with the same interface and acts on
the readings alone (P_N / P_max, no model of the rig):

* it counts the readings in a row below ``good_power``; a reading at or above it resets the
  count, so a stack at or above ``good_power`` is never kicked;
* after ``patience`` such readings it *kicks*: for ``kick_steps`` readings the applied action
  is the largest step (+-1, the actuator's ``max_step_fs``) in a random direction drawn once
  per kick (a random sign per stage), which carries every delay ``kick_steps x max_step``
  away, to a point the policy has not searched from;
* then the policy acts again; its memory holds the kick's actions (:meth:`took`), as the
  switching model's policies hold each other's. The count starts again after the kick.

The figures (:class:`~ops_contract.policy_layers.WatchdogParams`) are declared with the
metadata's schema; a model directory turns the watchdog on with a ``reacquire`` entry in its
``metadata.json`` (absent: off; an empty object: the defaults), e.g.::

    "reacquire": {"good_power": 0.8, "patience": 50, "kick_steps": 5, "seed": 0}

:mod:`ops_controller_ros.runner_factory` wraps the model's runner in one, so the ``policy`` node
and ``evaluate`` run the same watchdog. A kick also starts the policy's recurrent state afresh,
if it has one (the stack is lost: a new search). Pure numpy: no rclpy, no torch.
"""

from __future__ import annotations

import numpy as np
from ops_contract.policy_layers import REACQUIRE_KEY, WatchdogParams  # noqa: F401

from .runner_wrapper import RunnerWrapper


class ReacquireWatchdog(RunnerWrapper):
    """A runner wrapped in the re-acquiring watchdog (module docstring); the interface of
    :class:`~ops_controller_ros.policy_io.PolicyRunner` (``act``, ``restart``, ``took``,
    ``spec``, ``policy``). ``kicking``: per rig, whether the last action was a kick's;
    ``kicks``: kicks begun so far, all rigs together."""

    def __init__(self, runner, params: WatchdogParams | None = None, num_envs: int | None = None):
        super().__init__(runner, num_envs)
        self.params = params or WatchdogParams()
        self.kicks = 0
        self.restart()

    def restart(self) -> None:
        """A new start (the simulator reset): counts cleared, no kick under way, the kicks'
        directions drawn anew from the seed."""
        self.runner.restart()
        self._rng = np.random.default_rng(self.params.seed)
        self._low = np.zeros(self._n, dtype=int)
        self._kick_left = np.zeros(self._n, dtype=int)
        self._direction = np.zeros((self._n, self.spec.stage), dtype=np.float32)

    @property
    def kicking(self):
        k = self._kick_left > 0
        return bool(k[0]) if self._single else k.copy()

    def act(self, pulse_energies, power, setpoints_fs, applied_fs=None) -> np.ndarray:
        p = self.params
        power_now = np.asarray(power, dtype=np.float64).reshape(self._n)
        policy_action = self.runner.act(pulse_energies, power, setpoints_fs, applied_fs)
        action = np.asarray(policy_action, dtype=np.float32).reshape(self._n, -1).copy()
        # A kick under way carries on to its end, whatever the readings.
        was_kicking = self._kick_left > 0
        self._low = np.where(was_kicking, 0, np.where(power_now < p.good_power, self._low + 1, 0))
        start = (~was_kicking) & (self._low >= p.patience)
        if start.any():
            signs = self._rng.choice(np.array([-1.0, 1.0], dtype=np.float32), size=action.shape)
            self._direction[start] = signs[start]
            self._kick_left[start] = p.kick_steps
            self._low[start] = 0
            self.kicks += int(np.count_nonzero(start))
            self.runner.reset_state(start)
        kicking = self._kick_left > 0
        action[kicking] = self._direction[kicking]
        self._kick_left = np.where(kicking, self._kick_left - 1, 0)
        out = action.reshape(-1) if self._single else action
        if kicking.any():
            self.runner.took(out)
        return out
