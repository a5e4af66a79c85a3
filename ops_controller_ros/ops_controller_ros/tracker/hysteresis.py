"""The told hysteresis of an open-loop piezo, inverted on the way out.

A piezo driven open loop goes where its hysteresis takes it, not where it was sent: the tracker
would see that as drift that turns whenever a line turns. Told of the rig's hysteresis
(``actuator_hysteresis``) it drives each line so that the model's position is the set-point it
means, as a piezo controller's compensation does (the simulator's Prandtl-Ishlinskii model,
:func:`ops_sim_ros.rig.hysteresis`, inverted). The rest of the tracker then works in set-points
that the lines take as they are; only the commands on the wire differ.

The inverse runs in a compiled kernel (:func:`_drive_kernel`): the same in numpy's dozen small
calls per command cost the tracker 0.1-0.15 ms a reading, the kernel a few µs.
"""

from __future__ import annotations

import numba
import numpy as np

from .lm import _ENTRY

_F1, _F2 = numba.float64[:], numba.float64[:, :]


@numba.njit(_F1(_F1, _F2, _F1, numba.float64, numba.float64, numba.float64), **_ENTRY)
def _drive_kernel(meant, plays, radii, weight, half, step):  # pragma: no cover - compiled
    """The drives (N,) that put the hysteresis output at ``meant`` (N,) fs from the operators'
    states ``plays`` (K, N), which then follow the drive as the actuator takes it (clipped to
    +- ``half``, on the DAC's levels of ``step``; 0: none). Per line, the position is
    (x - w mean_k clip(x - p_k, -r_k, r_k)) / (1 - w): increasing and linear between break
    points, so a Newton step within a bracket ends in the piece that holds the target."""
    k, n = plays.shape
    out = np.empty(n)
    for j in range(n):
        target = meant[j] * (1.0 - weight)  # the drive minus w times the mean lag, wanted
        x, lo, hi = meant[j], -np.inf, np.inf
        for _ in range(200):
            lag, inside = 0.0, 0
            for i in range(k):
                d = x - plays[i, j]
                if d >= radii[i]:
                    lag += radii[i]
                elif d <= -radii[i]:
                    lag -= radii[i]
                else:
                    lag += d
                    inside += 1
            miss = target - (x - weight * lag / k)
            if abs(miss) <= 1e-12 * (1.0 + abs(target)):
                break
            if miss > 0.0:
                lo = x
            else:
                hi = x
            x_next = x + miss / (1.0 - weight * inside / k)
            if not (lo < x_next < hi) and np.isfinite(lo) and np.isfinite(hi):
                x_next = 0.5 * (lo + hi)  # (a step out of the bracket: halve it)
            x = x_next
        x = min(max(x, -half), half)
        out[j] = x
        applied = x
        if step > 0.0:
            applied = min(max(np.round((x + half) / step) * step - half, -half), half)
        for i in range(k):
            plays[i, j] = min(max(plays[i, j], applied - radii[i]), applied + radii[i])
    return out


class HysteresisCompensation:
    """Set-points meant (fs) in, drives to send (fs) out, for a model ``config`` (an OpsConfig)
    with ``actuator_hysteresis`` > 0. It follows the model's play operators from the drives it
    gives; the same set-points asked again (a command re-sent) give the same drive and leave
    the operators as they were."""

    def __init__(self, config):
        from ops_sim_ros.rig import hysteresis_radii, hysteresis_weight

        self.weight = hysteresis_weight(float(config.actuator_hysteresis))
        self.half_travel = float(config.actuator_range_fs)
        bits = self.dac_bits = int(getattr(config, "dac_bits", 0))
        self.dac_step = 2.0 * self.half_travel / (2**bits - 1) if bits > 0 else 0.0
        self.radii = hysteresis_radii(self.half_travel)
        self.plays = None  # (K, N) the operators' states
        self._last = (None, None)  # (set-points meant, drive given)

    @classmethod
    def told(cls, config, params) -> HysteresisCompensation | None:
        """The compensation for the model's hysteresis (None: none told, or
        ``compensate_hysteresis`` off)."""
        if not params.compensate_hysteresis:
            return None
        return cls(config) if float(getattr(config, "actuator_hysteresis", 0.0)) > 0.0 else None

    def reset(self, drive_fs) -> None:
        """The lines at rest on ``drive_fs`` (N,): where the simulator's actuator starts."""
        from ops_sim_ros.rig import HYSTERESIS_OPERATORS, quantize

        x = np.clip(
            np.asarray(drive_fs, dtype=np.float64).ravel(), -self.half_travel, self.half_travel
        )
        if self.dac_bits > 0:  # (the actuator rests on its DAC's levels)
            x = quantize(x, -self.half_travel, self.half_travel, self.dac_bits)
        self.plays = np.ascontiguousarray(np.tile(x, (HYSTERESIS_OPERATORS, 1)))
        self._last = (None, None)

    def drive(self, setpoints_fs: np.ndarray) -> np.ndarray:
        """The drive (N,) fs that puts the lines' hysteresis output at ``setpoints_fs``."""
        meant = np.asarray(setpoints_fs, dtype=np.float64).ravel()
        if self.plays is None:
            self.reset(meant)
        if self._last[0] is not None and np.array_equal(meant, self._last[0]):
            return self._last[1].copy()
        x = _drive_kernel(
            meant, self.plays, self.radii, self.weight, self.half_travel, self.dac_step
        )
        self._last = (meant.copy(), x)
        return x.copy()
