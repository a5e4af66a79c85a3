"""The detector's full scale, raised while the rig runs when its traces show it low.

A stacker can show no more light than its perfect stack: the pulse energies of the output slots
add up to the input energy when both polarizations reach the detector, and to less when a
polarizer sends part of it elsewhere. In the units of the normalized trace (the perfect stack
reads 1 in its slot) the slot energies therefore sum to at most 1 at any delays, and to nearly 1
at a lock. The calibration's full scale comes out low on a drifting stacker (its peaking-up step
sees the stack at its best reading during the drift; docs/rig.md), and then the summed slot
energies of a locked stacker read above 1. :class:`FullScaleFollower` watches that sum over a
window of readings and raises the full scale to the window's median when that is more. The
median keeps one noisy reading from raising it; the full scale is never lowered (a sum below 1
is what every unlocked reading shows). The rig computes ``ops/power`` with it; the trace it
publishes stays in the calibration's units (:meth:`~.rig.Rig.reading`).

A dark slot does not read zero on average where the digitizer clips the detector's noise at its
lowest code (a scope whose baseline sits at the bottom of the screen): an 8-bit trace over 1.25
full scales with noise 0.002 reads each of the 30 dark slots of N = 5 about 5e-4 high, 1.5 % of
the sum, which the plain sum took for light and the power then read 3 % low. The follower
therefore subtracts a dark floor from every slot but the brightest: the median over the slots of
each slot's mean over the window (:func:`dark_floor`), which at a lock is a dark slot's.
"""

from __future__ import annotations

import numpy as np

#: Fewer slots than this: no dark floor (with one or two slots the median slot may be lit).
MIN_SLOTS_FOR_FLOOR = 3


def dark_floor(readings: np.ndarray) -> float:
    """The mean reading of a dark slot over a window of readings (R, S): the median over the
    slots of each slot's mean. At a lock most slots are dark, so the median slot is one of
    them; unlocked, it may be lit, and the floor is then too high, which only keeps the
    follower from raising the full scale. 0 where there are fewer than
    :data:`MIN_SLOTS_FOR_FLOOR` slots."""
    readings = np.asarray(readings, dtype=np.float64)
    if readings.shape[-1] < MIN_SLOTS_FOR_FLOOR:
        return 0.0
    return float(np.median(readings.mean(axis=0)))


class FullScaleFollower:
    """Median of the summed slot energies (less the dark floor of all slots but the brightest)
    over the last ``window`` readings; ``gain`` is the full scale over the calibration's: the
    largest such median so far, and at least 1. ``subtract_dark_floor`` False: the plain sum
    (for comparisons)."""

    def __init__(self, window: int, subtract_dark_floor: bool = True):
        if int(window) < 1:
            raise ValueError(f"window must be at least 1 reading, got {window}")
        self.window = int(window)
        self.subtract_dark_floor = bool(subtract_dark_floor)
        self._readings: np.ndarray | None = None  # (window, S) ring of slot energies
        self._count = 0
        self.gain = 1.0
        self.floor = 0.0  # the last window's dark floor, in the calibration's units

    def observe(self, slot_energies) -> bool:
        """Take one reading's slot energies (S,), in the calibration's units; True when the
        full scale grew. A reading that is not finite, or of another slot count than the
        first, is ignored."""
        energies = np.asarray(slot_energies, dtype=np.float64).ravel()
        if energies.size == 0 or not np.all(np.isfinite(energies)):
            return False
        if self._readings is None:
            self._readings = np.zeros((self.window, energies.size))
        elif energies.size != self._readings.shape[1]:
            return False
        self._readings[self._count % self.window] = energies
        self._count += 1
        if self._count < self.window:
            return False
        sums = self._readings.sum(axis=1)
        if self.subtract_dark_floor:
            self.floor = dark_floor(self._readings)
            sums = sums - (self._readings.shape[1] - 1) * self.floor
        median = float(np.median(sums))
        if median <= self.gain:
            return False
        self.gain = median
        return True
