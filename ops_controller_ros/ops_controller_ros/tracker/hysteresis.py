"""The told hysteresis of an open-loop piezo, inverted on the way out.

A piezo driven open loop goes where its hysteresis takes it, not where it was sent: the tracker
would see that as drift that turns whenever a line turns. Told of the rig's hysteresis
(``actuator_hysteresis``) it drives each line so that the model's position is the set-point it
means, as a piezo controller's compensation does (a Prandtl-Ishlinskii model inverted,
:func:`ops_sim_ros.rig.hysteresis_drive`). The rest of the tracker then works in set-points that
the lines take as they are; only the commands on the wire differ.
"""

from __future__ import annotations

import numpy as np


class HysteresisCompensation:
    """Set-points meant (fs) in, drives to send (fs) out, for a model ``config`` (an OpsConfig)
    with ``actuator_hysteresis`` > 0. It follows the model's play operators from the drives it
    gives; the same set-points asked again (a command re-sent) give the same drive and leave
    the operators as they were."""

    def __init__(self, config):
        from ops_sim_ros.rig import hysteresis_radii

        self.fraction = float(config.actuator_hysteresis)
        self.half_travel = float(config.actuator_range_fs)
        self.dac_bits = int(getattr(config, "dac_bits", 0))
        self.radii = hysteresis_radii(self.half_travel)
        self.plays = None
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
        from ops_sim_ros.rig import HYSTERESIS_OPERATORS

        x = self._applied(np.asarray(drive_fs, dtype=np.float64).reshape(1, -1))
        self.plays = np.repeat(x[None], HYSTERESIS_OPERATORS, axis=0)
        self._last = (None, None)

    def drive(self, setpoints_fs: np.ndarray) -> np.ndarray:
        """The drive (N,) fs that puts the lines' hysteresis output at ``setpoints_fs``."""
        from ops_sim_ros.rig import hysteresis_drive, play

        meant = np.asarray(setpoints_fs, dtype=np.float64).reshape(1, -1)
        if self.plays is None:
            self.reset(meant[0])
        if self._last[0] is not None and np.array_equal(meant, self._last[0]):
            return self._last[1].copy()
        x = hysteresis_drive(meant, self.plays, self.radii, self.fraction)
        x = np.clip(x, -self.half_travel, self.half_travel)
        self.plays = play(self._applied(x)[None], self.plays, self.radii[:, None, None])
        self._last = (meant, x[0])
        return x[0].copy()

    def _applied(self, x: np.ndarray) -> np.ndarray:
        """The drive as the actuator takes it: clipped to its travel, through its DAC."""
        from ops_sim_ros.rig import quantize

        x = np.clip(x, -self.half_travel, self.half_travel)
        if self.dac_bits > 0:
            return quantize(x, -self.half_travel, self.half_travel, self.dac_bits)
        return x
