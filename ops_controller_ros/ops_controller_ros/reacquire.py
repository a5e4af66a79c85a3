"""A watchdog that re-acquires a lost stack: a learned policy that lost the stack is kicked to a
fresh point of the landscape and searches again.

Measured (issue 32): a learned policy that loses the stack in a 200-step episode rarely finds
it again within the episode (it sits on a side peak or a flat stretch, its actions near zero),
and those episodes end near zero. The watchdog wraps any runner (a plain
:class:`~ops_controller_ros.policy_io.PolicyRunner` or a
:class:`~ops_controller_ros.policy_switch.SwitchingRunner`) with the same interface and acts
on the readings alone (P_N / P_max, no model of the rig):

* it counts the readings in a row below ``good_power``; a reading at or above it resets the
  count, so a stack at or above ``good_power`` is never kicked;
* after ``patience`` such readings it *kicks*: for ``kick_steps`` readings the applied action
  is the largest step (+-1, the actuator's ``max_step_fs``) in a random direction drawn once
  per kick (a random sign per stage), which carries every delay ``kick_steps x max_step``
  away, to a point the policy has not searched from;
* then the policy acts again; its memory holds the kick's actions (:meth:`took`), as the
  switching model's policies hold each other's. The count starts again after the kick.

The figures (``WatchdogParams``) are declared once here; a model directory turns the watchdog
on with a ``reacquire`` entry in its ``metadata.json`` (absent: off; an empty object: these
defaults), e.g.::

    "reacquire": {"good_power": 0.8, "patience": 50, "kick_steps": 5, "seed": 0}

:func:`~ops_controller_ros.policy_switch.make_runner` wraps the model's runner in one, so the
``policy`` node and ``evaluate`` run the same watchdog. Pure numpy: no rclpy, no torch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from .runner_wrapper import RunnerWrapper

REACQUIRE_KEY = "reacquire"


@dataclass(frozen=True)
class WatchdogParams:
    """When the watchdog kicks and how far (readings of P_N / P_max; steps of the actuator)."""

    # A reading at or above this is "the stack found": it resets the count (never kicked).
    good_power: float = 0.8
    # Readings in a row below good_power before a kick (from the start, the last good reading
    # or the end of the last kick). patience and kick_steps were chosen on tuning seeds
    # (7001-7020, models/README.md "No catastrophic episode"): longer kicks (15-40 steps)
    # made the rig-observation models worse, since they read absolute set-points.
    patience: int = 50
    # Readings during which a kick applies the largest step in its random direction.
    kick_steps: int = 5
    # Seed of the kicks' directions (one generator per runner: reproducible evaluations).
    seed: int = 0

    def __post_init__(self) -> None:
        checks = (
            ("good_power", 0.0 < self.good_power <= 1.0, "in (0, 1]"),
            ("patience", self.patience >= 1, ">= 1"),
            ("kick_steps", self.kick_steps >= 1, ">= 1"),
            ("seed", self.seed >= 0, ">= 0"),
        )
        for name, ok, allowed in checks:
            value = getattr(self, name)
            if isinstance(value, bool) or not ok or not math.isfinite(value):
                raise ValueError(f"reacquire {name} must be {allowed} (got {value!r})")
        for name in ("patience", "kick_steps", "seed"):
            if int(getattr(self, name)) != getattr(self, name):
                raise ValueError(
                    f"reacquire {name} must be an integer (got {getattr(self, name)!r})"
                )

    @classmethod
    def from_dict(cls, data: dict) -> WatchdogParams:
        """From a metadata entry; unknown keys (a note, say) are ignored."""
        if not isinstance(data, dict):
            raise ValueError(f"the '{REACQUIRE_KEY}' entry must be an object (got {data!r})")
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})


class ReacquireWatchdog(RunnerWrapper):
    """A runner wrapped in the re-acquiring watchdog (module docstring); the interface of
    :class:`~ops_controller_ros.policy_io.PolicyRunner` (``act``, ``restart``, ``took``,
    ``spec``, ``policy``). ``kicking``: per rig, whether the last action was a kick's;
    ``kicks``: kicks begun so far, all rigs together."""

    def __init__(self, runner, params: WatchdogParams | None = None, num_envs: int | None = None):
        super().__init__(runner, num_envs)
        self.params = params or WatchdogParams()
        self._rng = np.random.default_rng(self.params.seed)
        self.kicks = 0
        self.restart()

    def restart(self) -> None:
        """A new start (the simulator reset): counts cleared, no kick under way."""
        self.runner.restart()
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
        kicking = self._kick_left > 0
        action[kicking] = self._direction[kicking]
        self._kick_left = np.where(kicking, self._kick_left - 1, 0)
        out = action.reshape(-1) if self._single else action
        if kicking.any():
            self.runner.took(out)
        return out


def watchdog_params_of(metadata: dict) -> WatchdogParams | None:
    """The watchdog a model's metadata asks for (None: no ``reacquire`` entry, off).
    ValueError for a malformed entry."""
    if REACQUIRE_KEY not in metadata:
        return None
    return WatchdogParams.from_dict(metadata[REACQUIRE_KEY])
