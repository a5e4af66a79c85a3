"""The model's period while tracking: whole-cycle moves (hops) that measure the wavelength, the
period correction they give, and whole-cycle moves off a set-point near its line's limit.

Every ``hop_every`` tracking readings one stage's set-point moves by ``hop_cycles`` periods of the
model (the landscape repeats, so the lock stays where the model is right); a model period off by
a fraction r moves that stage's phase by ``hop_cycles * r``, which the path fits of the next
readings measure (r is fitted with the path), and the wavelength is corrected by ``hop_gain`` of
it per fit. The tracker re-expresses its state in the new cycles
(:meth:`~.core.PhaseTracker._adopt_optics`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..setpoint_range import MARGIN_CYCLES, inward_periods, periods_per_reading
from .params import TrackerParams

MAX_HOP_RATIO = 0.05  # largest period error one fit may report (relative)
HOP_POWER = 0.98  # a whole-cycle move waits for a reading at least this good
HOP_MAX_DRIFT = 0.005  # ... and for a stage drifting slower than this (cycles per step)
HOP_GAIN_MOVES = 20.0  # the period correction's gain halves after this many moves ...
HOP_GAIN_FLOOR = 0.05  # ... and falls no lower than this share of hop_gain
# a set-point this near its line's limit moves whole cycles inwards (one rule for every controller)
RANGE_MARGIN_CYCLES = MARGIN_CYCLES


@dataclass
class Period:
    """The moves' state: hops of one run (from a reset), range moves of the tracker's life."""

    hops: int = 0  # whole-cycle moves made to measure the wavelength
    next_hop: int = 0  # the reading the next may come at
    hop_tick: int | None = None  # the reading after the last one
    range_moves: int = 0  # whole-cycle moves off a line's limit

    def restart(self) -> None:
        self.hops, self.next_hop, self.hop_tick = 0, 0, None

    def moved(self, tick: int) -> None:
        """The reading at ``tick`` is the first after a hop."""
        self.hop_tick = tick

    def in_window(self, tick: int, readings: int) -> bool:
        """Whether a window of ``readings`` up to ``tick`` holds a hop and the reading before
        it: it measures the period."""
        return self.hop_tick is not None and tick - self.hop_tick <= readings - 2

    def plan_hop(self, p: TrackerParams, noisy: bool, clean_lock: bool, drift, base, tick: int):
        """A whole-cycle move of one stage's set-point now, if one is due: (stage, cycles), to
        add to the set-points ``base``. ``noisy``: told a noisy detector or source (a move's
        period fit leans on the stacked slot, which that noise moves: ``noisy_hop_every``);
        ``clean_lock``: no bad fit, no knot test and no knot within a window, a good reading.
        None where a stage's drift is fast: its knots would cost more than a hop measures."""
        every = p.noisy_hop_every if noisy else p.hop_every
        if not every or not clean_lock or tick < self.next_hop:
            return None
        j = self.hops % drift.size
        if abs(drift[j]) >= HOP_MAX_DRIFT:
            return None
        k = -p.hop_cycles if base[j] > 0 else p.hop_cycles  # towards the middle
        self.hops += 1
        self.next_hop = tick + every
        return j, k

    def range_move(self, rig, base):
        """Whole cycles off a set-point (``base``, cycles) near its line's limit: the drift
        carries a lock towards it, and a rig refuses a command beyond it. Of the stages within
        ``RANGE_MARGIN_CYCLES`` of a limit, the one nearest its limit moves inwards, towards the
        middle of its range, by at most as many whole cycles as its line makes in one reading
        (at least one): the rule every controller keeps its range by
        (:func:`~ops_controller_ros.setpoint_range.inward_periods`). Returns (stage, cycles) or
        None. Not a hop: the cycles are the model's, and the lock stays where the model is
        right."""
        lo, hi = rig.range_fs
        period = rig.period_fs
        x = base * period
        margin = float(RANGE_MARGIN_CYCLES) * period
        if not ((x - lo < margin) | (hi - x < margin)).any():
            return None  # (as inward_periods finds: none near a limit)
        most = periods_per_reading(rig.reach_fs, period)
        periods = inward_periods(x, lo, hi, period, RANGE_MARGIN_CYCLES, most)
        if not periods.any():
            return None
        room = np.minimum(base - lo / period, hi / period - base)
        j = int(np.argmin(np.where(periods != 0, room, np.inf)))
        self.range_moves += 1
        return j, int(periods[j])

    def move(self, p: TrackerParams, rig, base, tick: int, noisy: bool, clean: bool, drift):
        """Whole cycles added to the set-points ``base`` (cycles, in place) now: off a line's
        limit if one is near (:meth:`range_move`), else a hop if one is due (:meth:`plan_hop`);
        the hop (stage, cycles), or None."""
        move = self.range_move(rig, base)
        hop = None
        if move is None:
            move = hop = self.plan_hop(p, noisy, clean, drift, base, tick)
        if move is not None:
            base[move[0]] += move[1]
        return hop

    def correct(self, p: TrackerParams, calibration, r: float) -> None:
        """A window fit with a hop found the model's period off by r (model over true, minus 1):
        move the calibration's wavelength by a share of ``hop_gain`` of it that falls with the
        moves made (an average of the measurements, not the last few: with a constant gain the
        estimate random-walks with their noise)."""
        r = float(np.clip(r, -MAX_HOP_RATIO, MAX_HOP_RATIO))
        share = max(HOP_GAIN_MOVES / (HOP_GAIN_MOVES + self.hops), HOP_GAIN_FLOOR)
        calibration.wavelength_nm /= 1.0 + p.hop_gain * share * r
