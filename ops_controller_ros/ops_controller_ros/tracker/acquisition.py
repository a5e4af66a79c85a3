"""Acquisition: the global search for the delay errors when the tracker has no estimate, and the
local re-lock (recovery) after its fits stopped explaining the readings.

The search scores ``candidates`` random delay vectors over one period per stage against the
window, refines the ``refine`` best by Levenberg-Marquardt (each stage's drift too where a static
fit does not explain the window, and the detector's gain and offset where the model still does
not) and accepts the estimate only when its residual is within the tolerance. It is a generator
(one unit of work per ``yield``), so its work can be spread over readings (``search_units``,
``step_budget_ms``).
"""

from __future__ import annotations

import time
from collections import deque

import numpy as np

from .fit import wrap

SEARCH_CHUNK = 128  # candidates scored per unit of the global search


class Acquisition:
    """The global search and the local re-lock of :class:`~.core.PhaseTracker` (a mixin: it
    works on the tracker's state)."""

    def _search_step(self) -> None:
        """Advance the global search by this reading's share: ``search_units`` units of work
        (0: all of it), fewer if ``step_budget_ms`` (a real-time cap, 0: none) is spent first;
        the commands keep dithering meanwhile."""
        if self._search is None:
            self._search = self._acquire()
        units = self.params.search_units
        budget = self.params.step_budget_ms
        deadline = time.perf_counter() + budget / 1e3 if budget > 0 else float("inf")
        done = 0
        try:
            while True:
                next(self._search)
                done += 1
                if done == units or time.perf_counter() >= deadline:
                    return
        except StopIteration:
            self._search = None

    def _acquire(self):
        """The global search on the window as it is now, a generator (one unit per yield); an
        estimate found readings later is carried forward by its drift."""
        p = self.params
        u, y, age = self._window()
        started = self._step
        drift = np.zeros(self.stage)
        cand = self._rng.uniform(-0.5, 0.5, size=(p.candidates, self.stage))
        scores = []
        for i in range(0, p.candidates, SEARCH_CHUNK):
            scores.append(self._cost(cand[i : i + SEARCH_CHUNK], u, y, age, drift))
            yield
        cost = np.concatenate(scores)
        best = cand[np.argsort(cost)[: p.refine]]
        x, cost = yield from self._refine(best, u, y, age, drift, p.iterations)
        i = int(np.argmin(cost))
        fitted_drift = np.zeros(self.stage)
        if cost[i] > self._tolerance() and p.acquire_drift:
            # Drift within the window (strong drift): fit it too, from the best starts.
            z = np.concatenate([x, np.zeros_like(x)], axis=1)
            z, cost = yield from self._refine(z, u, y, age, None, p.iterations)
            i = int(np.argmin(cost))
            x, fitted_drift = z[:, : self.stage], z[i, self.stage :]
        if cost[i] > self._tolerance() and p.calibrate:
            x, fitted_drift, cost, i = yield from self._refine_detector(
                x, fitted_drift, cost, i, u, age
            )
        self.residual = float(cost[i])
        if self.residual <= self._tolerance():
            self._start_tracking(x[i] + (self._step - started) * fitted_drift)
            self.drift = self._bounded(fitted_drift)
            self.acquisitions += 1

    def _refine_detector(self, x, fitted_drift, cost, i, u, age):
        """A detector off its calibration: fit its gain and offset to the best estimate's
        predictions, then refine again on the corrected readings (a generator, as
        :meth:`_acquire`); returns (x, fitted_drift, cost, i)."""
        p = self.params
        if self._fit_detector_to(x[i], fitted_drift, u, age, provisional=True):
            y = self.calibration.correct(self._window(raw=True)[1][-len(u) :])
            z = np.concatenate([x, np.tile(fitted_drift, (len(x), 1))], axis=1)
            z, cost = yield from self._refine(z, u, y, age, None, p.iterations)
            i = int(np.argmin(cost))
            x, fitted_drift = z[:, : self.stage], z[i, self.stage :]
        return x, fitted_drift, cost, i

    def _fit_detector_to(
        self, x, drift, u, age, last=None, provisional=False, min_power=0.0
    ) -> bool:
        """Fit the detector's gain and offset to the window's readings as the errors ``x`` (N,)
        and ``drift`` predict them (an acquisition, or a fresh lock, that does not fit), or to
        its ``last`` readings only, of those the ones whose power reads ``min_power`` or more;
        True if the fit was taken (none without such a reading). ``provisional``: an
        acquisition's (see :meth:`_detector_settled`)."""
        pred = self._predict(x[None], u, age, drift)[0]
        raw = self._window(raw=True)[1][-len(u) :]
        if last is not None:
            pred, raw = pred[-last:], raw[-last:]
        near = raw[:, -1] >= min_power
        if not near.any():
            return False
        return self.calibration.fit_detector(pred[near], raw[near], provisional)

    def _start_tracking(self, x: np.ndarray) -> None:
        """Track from the acquired estimate x (cycles)."""
        self.estimate = wrap(x)
        self.drift = np.zeros(self.stage)
        self._lock_tick = self._tick

    def _recover(self) -> None:
        """A local re-fit of the errors and the drift to the readings since the fit failed,
        from the prediction with the present drift, no drift, and each stage's drift reversed;
        after a full window without success, a global acquisition."""
        p = self.params
        n = self.stage
        self.estimate = self.estimate + self._gap * self.drift  # this reading's prediction
        readings = self._recovering
        if len(readings) < p.recover_readings:
            return
        u, y, age = self._window(readings)
        drifts = [self.drift, np.zeros(n)]
        for j in range(n):
            d = self.drift.copy()
            d[j] = -d[j]
            drifts.append(d)
        starts = np.tile(self.estimate, (len(drifts), 1))
        fits = self._fit_paths(starts, np.array(drifts), u, y, age, p.iterations)
        i = int(np.argmin(fits.data_cost))
        x, drift, cost = fits.x[i], fits.drift[i], float(fits.data_cost[i])
        self._path, self._objective, self._ratio = fits.path[i], fits.objective[i], 0.0
        self.residual = cost
        if self.residual <= self._tolerance():
            self._bad_fits = 0
            self.estimate, self.drift = x, self._bounded(drift)
            self._history = deque(readings, maxlen=self._window_len)
            self._recovering = None
        elif len(readings) >= self._window_len:
            self._recovering = None
            self.estimate = None
            self._history = deque(readings[-self._window_len :], maxlen=self._window_len)
            self._search_step()
