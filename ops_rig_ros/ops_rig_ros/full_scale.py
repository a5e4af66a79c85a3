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

The power a lab publishes is then a measure of the stack: with a full scale 13 % low the rig's
``ops/power`` read 1.0 (clipped) on a stack the simulated lab's truth put at 0.87.
"""

from __future__ import annotations

from collections import deque

import numpy as np


class FullScaleFollower:
    """Median of the summed slot energies over the last ``window`` readings; ``gain`` is the
    full scale over the calibration's: the largest such median so far, and at least 1."""

    def __init__(self, window: int):
        if int(window) < 1:
            raise ValueError(f"window must be at least 1 reading, got {window}")
        self.window = int(window)
        self._sums: deque[float] = deque(maxlen=self.window)
        self.gain = 1.0

    def observe(self, slot_energy_sum: float) -> bool:
        """Take one reading's summed slot energies, in the calibration's units; True when the
        full scale grew."""
        if not np.isfinite(slot_energy_sum):
            return False
        self._sums.append(float(slot_energy_sum))
        if len(self._sums) < self.window:
            return False
        median = float(np.median(self._sums))
        if median <= self.gain:
            return False
        self.gain = median
        return True
