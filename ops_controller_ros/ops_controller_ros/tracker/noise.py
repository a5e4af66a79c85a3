"""What the tracker knows of its detector's noise, and what it sizes by it.

Three sources: the noise it was told (``detector_noise``, the rig's digitizer and source), the
noise measured from the first reading taken twice at the same set-points, and the noise the
tracking fits find in their residuals. From them: whether the detector counts as noisy (longer
windows, stiffer drift, larger excursions, the knot test's noisy settings), the fits' tolerance
and the std of a reading the path fits weigh by.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .params import TrackerParams

FIT_VAR_FITS = 25  # tracking fits whose residuals give the readings' std (their median)
FIT_VAR_MIN = 5  # ... once this many are in
NOISE_TRIES = 4  # repeats of the first reading to measure the noise, a step apart


def _fits() -> deque:
    return deque(maxlen=FIT_VAR_FITS)


def median(values) -> float:
    """The median of a few floats, as ``np.median`` gives it (the middle one, or the mean of the
    middle two: their sum halved), without its overhead; NaN if one is NaN."""
    ordered = sorted(values)
    n = len(ordered)
    if n == 0 or any(v != v for v in ordered):
        return float("nan")
    if n % 2:
        return float(ordered[n // 2])
    return float((ordered[n // 2 - 1] + ordered[n // 2]) / 2.0)


@dataclass
class Noise:
    """The noise state of one run (from a reset)."""

    told_noisy: bool  # told a noisy detector or source (:attr:`.model.RigModel.told_noisy`)
    var: float | None = None  # variance measured from the repeated first reading
    tries: int = 0  # repeated readings that came steps apart (no measure of noise)
    first: float | None = None  # a first measure that would count, to be confirmed by a second
    fit_vars: deque = field(default_factory=_fits)  # mean squared residuals of tracking fits
    # noise variances of the tracking fits' residuals, read from their changes from one reading
    # to the next (:meth:`note_fit`), and whether they found the detector noisy (kept)
    white_vars: deque = field(default_factory=_fits)
    fits_noisy: bool = False
    # the medians of the two, kept until the next figure comes (a fit asks for them each time)
    _medians: list = field(default_factory=lambda: [None, None], repr=False)

    # ------------------------------------------------------------------ what it implies
    def noisy(self, p: TrackerParams) -> bool:
        """Told noisy, a noise measured of at least ``noisy_threshold``, or found noisy by the
        tracking fits (:meth:`note_fit`)."""
        measured = self.var or 0.0
        return self.told_noisy or measured >= p.noisy_threshold**2 or self.fits_noisy

    def white_var(self) -> float:
        """The median of the tracking fits' last noise variances (:meth:`note_fit`)."""
        if self._medians[1] is None:
            self._medians[1] = median(self.white_vars)
        return self._medians[1]

    def fit_var(self) -> float:
        """The median of the tracking fits' last mean squared residuals."""
        if self._medians[0] is None:
            self._medians[0] = median(self.fit_vars)
        return self._medians[0]

    def var_assumed(self, p: TrackerParams) -> float:
        """The noise variance the excursion and the tolerance are sized for: the assumed one
        (``detector_noise``), the measured one, and once the fits found the detector noisy
        (``fit_noisy_threshold``) the one they found, whichever is largest."""
        var = max(p.detector_noise**2, self.var or 0.0)
        if self.fits_noisy:
            var = max(var, self.white_var())
        return var

    def tolerance(self, p: TrackerParams, base: float | None = None) -> float:
        """Mean squared residual that still counts as a fit: the base tolerance
        (``residual_tolerance`` by default) plus three times the noise variance assumed."""
        return (p.residual_tolerance if base is None else base) + 3.0 * self.var_assumed(p)

    def reading_sd(self, p: TrackerParams) -> float:
        """The std of a reading about the model that the path fits assume: ``fit_noise_floor``
        plus the largest of the detector noise assumed, the measured noise where it makes the
        detector noisy, and the median mean squared residual of the last tracking fits (the
        model's misfit as the fits find it; before ``FIT_VAR_MIN`` of them, the lock tolerance
        plus the measured noise). The fits' own misfit, not the repeated reading's noise, sets
        how far the random walk may absorb a knot of the drift; on a noisy detector the fits'
        residuals alone are too small (the path follows part of the noise), and the measured
        noise is kept."""
        measured = self.var or 0.0
        if len(self.fit_vars) >= FIT_VAR_MIN:
            var = self.fit_var()
        else:
            var = p.residual_tolerance + measured
        if self.noisy(p):
            var = max(var, measured)
        return (p.fit_noise_floor**2 + max(var, p.detector_noise**2)) ** 0.5

    @property
    def measured(self) -> float | None:
        """The noise std measured from the repeated first reading (None before)."""
        return None if self.var is None else self.var**0.5

    @property
    def fitted(self) -> float | None:
        """The noise std as the tracking fits find it (:meth:`note_fit`), None before
        ``FIT_VAR_MIN`` figures are in."""
        if len(self.white_vars) < FIT_VAR_MIN:
            return None
        return self.white_var() ** 0.5

    # ------------------------------------------------------------------ measuring it
    def measuring(self, readings: int) -> bool:
        """Whether the noise is still to be measured: the first reading is repeated until two
        readings at the same set-points come a step apart, at most ``NOISE_TRIES`` times (then
        it stays unmeasured: taken as clean unless told)."""
        return self.var is None and readings > 0 and self.tries < NOISE_TRIES

    def measure(self, p: TrackerParams, last, u_now, y, steps: int) -> bool:
        """The noise from this reading (set-points ``u_now``, reading ``y``) and the one before
        (``last``: its set-points and reading), if they were taken at the same set-points a step
        apart and differ. A noise that would count (noisy, or at least a third of
        ``residual_tolerance`` in variance: it widens the fits' tolerance) is measured once more
        and the smaller taken: a delay line still moving or a drift between the two inflates
        it, never deflates it. True when the detector now counts as noisy by it (the longer
        window is due)."""
        last_u, last_y = last
        diff = y[:-1] - last_y[:-1]
        # Two identical readings are one record read twice (an instrument that gives its last
        # record again when no new trigger came), not a detector without noise; readings steps
        # apart hold the drift between them, which is no detector noise.
        if steps == 1 and np.array_equal(last_u, u_now) and np.any(diff):
            var = float(np.mean(diff * diff)) / 2.0
            counts = var >= min(p.noisy_threshold**2, p.residual_tolerance / 3.0)
            if self.first is not None or not counts or self.told_noisy:
                return self._set(p, var if self.first is None else min(var, self.first))
            self.first = var  # to be confirmed by the next pair
        self.tries += 1
        if self.tries >= NOISE_TRIES and self.first is not None:
            return self._set(p, self.first)
        return False

    def _set(self, p: TrackerParams, var: float) -> bool:
        self.var = var
        return var >= p.noisy_threshold**2

    def note_fit(self, p: TrackerParams, cost: float, residuals) -> bool:
        """A tracking fit taken: its mean squared residual ``cost`` and, where the noise is
        still read from the fits, the slot energies' residuals at its path (K, S; None where the
        window holds no path). The figure read from them is half the mean squared change of the
        residuals from one reading to the next: a detector's noise is new in every reading,
        while a misfit of the model changes slowly (the residuals' own level would not tell them
        apart). True when the median of the last ``FIT_VAR_FITS`` figures reaches
        ``fit_noisy_threshold`` (squared): the detector counts as noisy from then on, with the
        longer window. Fewer than that many figures decide nothing: the median of a few is
        moved by a knot's wake."""
        self.fit_vars.append(cost)
        self._medians[0] = None
        if residuals is None:
            return False
        change = np.diff(residuals, axis=0)
        self.white_vars.append(float(np.mean(change * change)) / 2.0)
        self._medians[1] = None
        if len(self.white_vars) < FIT_VAR_FITS:
            return False
        if self.white_var() >= p.fit_noisy_threshold**2:
            self.fits_noisy = True
            return True
        return False

    def reads_fits(self, p: TrackerParams) -> bool:
        """Whether the tracking fits' residuals are still read for noise: not once the detector
        counts as noisy (told or measured so keeps its sizing), nor with the threshold 0."""
        return bool(p.fit_noisy_threshold) and not self.noisy(p)
