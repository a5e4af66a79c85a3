"""The model's period and calibration while tracking: whole-cycle moves (hops) that measure the
wavelength, the period correction they give, and the online calibration of the detector (and,
optionally, the optics) with the state re-expressed in the new cycles.

Every ``hop_every`` tracking readings one stage's set-point moves by ``hop_cycles`` periods of the
model (the landscape repeats, so the lock stays where the model is right); a model period off by
a fraction r moves that stage's phase by ``hop_cycles * r``, which the path fits of the next
readings measure (r is fitted with the path), and the wavelength is corrected by ``hop_gain`` of
it per fit.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from ..setpoint_range import MARGIN_CYCLES, inward_periods, periods_per_reading

MAX_HOP_RATIO = 0.05  # largest period error one fit may report (relative)
HOP_POWER = 0.98  # a whole-cycle move waits for a reading at least this good
HOP_MAX_DRIFT = 0.005  # ... and for a stage drifting slower than this (cycles per step)
HOP_GAIN_MOVES = 20.0  # the period correction's gain halves after this many moves ...
HOP_GAIN_FLOOR = 0.05  # ... and falls no lower than this share of hop_gain
# a set-point this near its line's limit moves whole cycles inwards (one rule for every controller)
RANGE_MARGIN_CYCLES = MARGIN_CYCLES


class PeriodCalibration:
    """Hops, the period correction and the calibration of :class:`~.core.PhaseTracker` (a
    mixin: it works on the tracker's state)."""

    def _plan_hop(self):
        """A whole-cycle move of one stage's set-point now, if one is due: (stage, cycles)."""
        p = self.params
        # A told source noise (.weights) counts as noisy here: a move's period fit leans on the
        # stacked slot, which that noise moves (hard, 1 % pulse noise: a move ended an episode
        # at 0.02; realism sweep, 100 episodes)
        noisy = self._told_noisy() or self._weights is not None
        every = p.noisy_hop_every if noisy else p.hop_every
        testing = self._knot_job is not None or self._knot_run is not None  # a knot test
        if not every or self._bad_fits or testing or self._tick < self._hop_next:
            return None
        # only on a clean lock: not right after a knot of the drift, not on a low reading
        if self._tick - self._knot_tick < self._window_len or not self.last_power >= HOP_POWER:
            return None
        j = self.hops % self.stage
        if abs(self.drift[j]) >= HOP_MAX_DRIFT:  # a fast drift: its knots cost more than a hop
            return None
        k = -p.hop_cycles if self._base[j] > 0 else p.hop_cycles  # towards the middle
        self._base[j] += k
        self.hops += 1
        self._hop_next = self._tick + every
        return j, k

    def _range_move(self):
        """Whole cycles off a set-point near its line's limit: the drift carries a lock towards
        it, and a rig refuses a command beyond it (simulated lab, hard, 25 Hz: a stage at its
        0 V limit after ~4 minutes, and every later command refused). Of the stages within
        ``RANGE_MARGIN_CYCLES`` of a limit, the one nearest its limit moves inwards, towards the
        middle of its range, by at most as many whole cycles as its line makes in one reading
        (at least one): the rule every controller keeps its range by
        (:func:`~ops_controller_ros.setpoint_range.inward_periods`). Returns (stage, cycles) or
        None. Not a hop: the cycles are the model's, and the lock stays where the model is
        right."""
        lo, hi = self.range_fs
        most = periods_per_reading(self.reach_fs, self.period_fs)
        periods = inward_periods(
            self._base * self.period_fs, lo, hi, self.period_fs, RANGE_MARGIN_CYCLES, most
        )
        if not periods.any():
            return None
        room = np.minimum(self._base - lo / self.period_fs, hi / self.period_fs - self._base)
        j = int(np.argmin(np.where(periods != 0, room, np.inf)))
        k = int(periods[j])
        self._base[j] += k
        self.range_moves += 1
        return j, k

    def _correct_period(self, r: float) -> None:
        """A window fit with a whole-cycle move found the model's period off by r (model over
        true, minus 1): move the wavelength by hop_gain of it."""
        r = float(np.clip(r, -MAX_HOP_RATIO, MAX_HOP_RATIO))
        # A gain that falls with the moves made (an average of the measurements, not the last
        # few): with a constant gain the estimate random-walked with its measurements' noise
        # (docs/tracker.md, "Over DDS"; `ops-bench tracker-wavelength` at commit 51e857d
        # measured it).
        share = max(HOP_GAIN_MOVES / (HOP_GAIN_MOVES + self.hops), HOP_GAIN_FLOOR)
        self.calibration.wavelength_nm /= 1.0 + self.params.hop_gain * share * r
        self._adopt_optics()

    def _adopt_optics(self) -> None:
        """Take the calibration's wavelength and width into the model and re-express the
        state (estimate, drift, set-points, the window's commands) in the new cycles."""
        old_period = self.period_fs
        self.stacker = self.calibration.stacker()
        self.period_fs = self.calibration.period_fs
        ratio = old_period / self.period_fs  # the same fs are this many new cycles per old one
        latest = self._history[-1][0]
        self.estimate = self.estimate + latest - latest * ratio  # same phase
        self.drift = self.drift * ratio
        self._base = self._base * ratio
        self._last_command = self._last_command * ratio
        self._acting = self._acting * ratio
        self._position = self._position * ratio
        for entry in self._in_flight:
            entry[1] = entry[1] * ratio
        self._history = deque(
            ((h[0] * ratio, h[1], h[2]) for h in self._history), maxlen=self._window_len
        )

    def _calibrate(self, u: np.ndarray, path: np.ndarray) -> None:
        """Feed the window's fit to the calibration; every ``calibration_every`` readings, move
        the model's wavelength and pulse width and re-express the state in the new cycles."""
        raw = self._window(raw=True)[1]
        optics = self.params.calibrate_optics
        self.calibration.observe(self.stacker, u, path, raw, self.period_fs, optics, self._weights)
        if not optics or self._tick % self.params.calibration_every:
            return
        if self.calibration.update_optics():
            self._adopt_optics()
