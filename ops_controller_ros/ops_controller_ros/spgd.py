"""SPGD-PID: stochastic parallel gradient descent on the measured power, with a PID stage.

The classic controller of coherent beam combining (the paper's introduction). One iteration:

1. draw a random sign vector s in {-1, +1}^N and perturb all delays at once, two-sided:
   measure J+ = P(u + a s) and J- = P(u - a s);
2. estimate the gradient g = (J+ - J-) / (2 a) * s  (power per fs);
3. the error e_k = gain * g (fs) drives a PID stage, Δ = kp e_k + ki Σe + kd (e_k - e_{k-1}),
   optionally smoothed by momentum (v = m v + Δ), clipped to ``max_update_fs``; u += v.

The class is a two-phase state machine with no notion of time or transport: ``command()`` gives
the set-points to apply next, ``observe(power)`` the reading they produced. The ROS node and the
in-process evaluation both drive it the same way.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class SpgdParams:
    gain: float = 0.05  # fs^2 per unit of normalized power: e = gain * dP/ddelay
    perturbation_fs: float = 0.03  # dither amplitude a per stage (about 1 % of a 1030 nm cycle)
    kp: float = 1.0
    ki: float = 0.0
    kd: float = 0.0
    momentum: float = 0.0  # 0 <= m < 1
    max_update_fs: float = 0.5  # largest set-point change per iteration
    integral_limit_fs: float = 5.0  # anti-windup bound of the integral term

    def __post_init__(self):
        checks = (
            ("gain", self.gain > 0, "> 0"),
            ("perturbation_fs", self.perturbation_fs > 0, "> 0"),
            ("momentum", 0.0 <= self.momentum < 1.0, "in [0, 1)"),
            ("max_update_fs", self.max_update_fs > 0, "> 0"),
            ("integral_limit_fs", self.integral_limit_fs >= 0, ">= 0"),
        )
        for name, ok, allowed in checks:
            if not ok:
                raise ValueError(f"{name} must be {allowed} (got {getattr(self, name)!r})")
        for name in ("kp", "ki", "kd"):
            if not np.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite (got {getattr(self, name)!r})")

    def to_dict(self) -> dict:
        return asdict(self)


class SpgdPid:
    """Two-sided SPGD with a PID stage on the update (see module docstring)."""

    def __init__(self, stage: int, params: SpgdParams | None = None, setpoints_fs=None, seed=None):
        self.stage = int(stage)
        self.params = params or SpgdParams()
        self._rng = np.random.default_rng(seed)
        self.reset(np.zeros(self.stage) if setpoints_fs is None else setpoints_fs)

    def reset(self, setpoints_fs) -> None:
        """Start again from ``setpoints_fs`` (e.g. after the simulator restarted)."""
        u = np.asarray(setpoints_fs, dtype=np.float64).reshape(self.stage)
        self.setpoints_fs = u.copy()
        self._velocity = np.zeros(self.stage)
        self._integral = np.zeros(self.stage)
        self._last_error = np.zeros(self.stage)
        self._signs = self._rng.choice((-1.0, 1.0), size=self.stage)
        self._phase = 0  # 0: waiting for J+, 1: waiting for J-
        self._j_plus = 0.0
        self.iterations = 0
        self.last_power = float("nan")

    def command(self) -> np.ndarray:
        """Set-points (fs) to apply now: u + a s, then u - a s."""
        sign = 1.0 if self._phase == 0 else -1.0
        return self.setpoints_fs + sign * self.params.perturbation_fs * self._signs

    def observe(self, power: float, pulse_energies=None) -> None:
        """The power measured with the last ``command()``; every second reading updates u.

        SPGD uses the power only; ``pulse_energies`` is accepted for the common interface of
        :mod:`ops_controller_ros.controllers`."""
        if self._phase == 0:
            self._j_plus = float(power)
            self._phase = 1
            return
        p = self.params
        j_minus = float(power)
        self.last_power = 0.5 * (self._j_plus + j_minus)
        gradient = (self._j_plus - j_minus) / (2.0 * p.perturbation_fs) * self._signs
        error = p.gain * gradient
        self._integral = np.clip(self._integral + error, -p.integral_limit_fs, p.integral_limit_fs)
        update = p.kp * error + p.ki * self._integral + p.kd * (error - self._last_error)
        self._last_error = error
        self._velocity = p.momentum * self._velocity + update
        self._velocity = np.clip(self._velocity, -p.max_update_fs, p.max_update_fs)
        self.setpoints_fs = self.setpoints_fs + self._velocity
        self._signs = self._rng.choice((-1.0, 1.0), size=self.stage)
        self._phase = 0
        self.iterations += 1
