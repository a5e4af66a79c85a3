"""The readings the fits take: the last ``window`` (set-points, reading, step) triples, and their
arrays as the fits want them.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .params import TrackerParams


def fit_window(p: TrackerParams, noisy: bool) -> int:
    """Readings per fit: ``window``, or on a noisy detector the longer ``noisy_window``."""
    return max(p.window, p.noisy_window) if noisy else p.window


class Window:
    """The last ``length`` readings, each (set-points (N,) cycles, reading (S + 1,), step), and
    their arrays, stacked once per change (every fit of a reading takes them)."""

    def __init__(self, length: int):
        self.length = length
        self.history: deque = deque(maxlen=length)
        self._stacked = None  # (u, raw y, age) of the history, or None when it changed

    def __len__(self) -> int:
        return len(self.history)

    def append(self, reading) -> None:
        self.history.append(reading)
        self._stacked = None

    def lengthen(self, length: int) -> None:
        """Take ``length`` readings per fit from the next reading on."""
        self.length = length
        self.history = deque(self.history, maxlen=length)
        self._stacked = None

    def refill(self, readings) -> None:
        """The window made of ``readings`` (the last ``length`` of them)."""
        self.history = deque(readings, maxlen=self.length)
        self._stacked = None

    def clear(self) -> None:
        self.history.clear()
        self._stacked = None

    def rescale(self, ratio: float) -> None:
        """The set-points in new cycles, ``ratio`` of them per old one."""
        self.history = deque(((h[0] * ratio, h[1], h[2]) for h in self.history), maxlen=self.length)
        self._stacked = None

    @property
    def latest(self):
        return self.history[-1]

    def steps(self) -> np.ndarray:
        """The step of each reading (K,)."""
        return np.array([h[2] for h in self.history], dtype=np.int64)

    def arrays(self, calibration, readings=None, raw: bool = False):
        """(set-points (K, N) cycles, readings (K, S + 1), age (K,) steps before the latest) of
        ``readings`` (default: the window); the detected energies corrected by the calibration's
        detector gain and offset unless ``raw``. The window's own arrays are shared between
        calls: the caller does not change them."""
        if readings is None:
            if self._stacked is None:
                self._stacked = _stack(self.history)
            u, y, age = self._stacked
        else:
            u, y, age = _stack(readings)
        return u, (y if raw else calibration.correct(y)), age


def _stack(readings):
    u = np.stack([h[0] for h in readings])
    y = np.stack([h[1] for h in readings])
    steps = np.array([h[2] for h in readings], dtype=np.float64)
    return u, y, steps[-1] - steps  # age: steps before the latest
