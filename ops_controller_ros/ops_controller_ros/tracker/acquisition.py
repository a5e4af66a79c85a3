"""Acquisition: the global search for the delay errors when the tracker has no estimate, and the
fit of the detector's line to an estimate that does not otherwise explain its readings.

The search scores ``candidates`` random delay vectors over one period per stage against the
window, refines the ``refine`` best by Levenberg-Marquardt (each stage's drift too where a static
fit does not explain the window, and the detector's gain and offset where the model still does
not) and gives the estimate with its residual; the tracker accepts it only when that is within
the tolerance. It is a generator (one unit of work per ``yield``), so its work can be spread over
readings (``search_units``, ``step_budget_ms``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .params import TrackerParams

SEARCH_CHUNK = 128  # candidates scored per unit of the global search


class Acquired(NamedTuple):
    """A search's outcome: the errors (N,) and drift (N,) at the step it started at, and the
    mean squared residual of the window it fitted."""

    x: np.ndarray
    drift: np.ndarray
    residual: float
    started: int  # the step it started at: the estimate is carried on from there by the drift


@dataclass
class Search:
    """The global search's state of one run (from a reset)."""

    job: Generator | None = None  # the search under way (:func:`acquire`), if any
    acquisitions: int = 0  # estimates accepted

    def step(self, p: TrackerParams, start: Callable[[], Generator]) -> Acquired | None:
        """Advance the search (``start()`` begins one) by this reading's share:
        ``search_units`` units of work (0: all of it), fewer if ``step_budget_ms`` (a real-time
        cap, 0: none) is spent first; its outcome once it ends. (A search spread over readings
        fits a window readings old and carries its estimate on by the drift it fitted, which
        loses locks: by default it runs whole.)"""
        if self.job is None:
            self.job = start()
        units = p.search_units
        budget = p.step_budget_ms
        deadline = time.perf_counter() + budget / 1e3 if budget > 0 else float("inf")
        done = 0
        try:
            while True:
                next(self.job)
                done += 1
                if done == units or time.perf_counter() >= deadline:
                    return None
        except StopIteration as finished:
            self.job = None
            return finished.value


def acquire(rig, p: TrackerParams, rng, window, calibration, tolerance, started: int):
    """The global search on the window as it is when it starts, a generator (one unit per
    yield) that returns its :class:`Acquired`. ``rig``: the :class:`~.model.RigModel`;
    ``tolerance()``: the residual that counts as a fit, asked as the search goes on; ``started``:
    the step now."""
    n = rig.stage
    u, y, age = window.arrays(calibration)
    drift = np.zeros(n)
    cand = rng.uniform(-0.5, 0.5, size=(p.candidates, n))
    scores = []
    for i in range(0, p.candidates, SEARCH_CHUNK):
        scores.append(rig.cost(cand[i : i + SEARCH_CHUNK], u, y, age, drift))
        yield
    cost = np.concatenate(scores)
    best = cand[np.argsort(cost)[: p.refine]]
    x, cost = yield from rig.refine(best, u, y, age, drift, p.iterations)
    i = int(np.argmin(cost))
    fitted_drift = np.zeros(n)
    if cost[i] > tolerance() and p.acquire_drift:
        # Drift within the window (strong drift): fit it too, from the best starts.
        z = np.concatenate([x, np.zeros_like(x)], axis=1)
        z, cost = yield from rig.refine(z, u, y, age, None, p.iterations)
        i = int(np.argmin(cost))
        x, fitted_drift = z[:, :n], z[i, n:]
    if cost[i] > tolerance() and p.calibrate:
        x, fitted_drift, cost, i = yield from _refine_detector(
            rig, p, window, calibration, x, fitted_drift, cost, i, u, age
        )
    return Acquired(x[i], fitted_drift, float(cost[i]), started)


def _refine_detector(rig, p, window, calibration, x, fitted_drift, cost, i, u, age):
    """A detector off its calibration: fit its gain and offset to the best estimate's
    predictions, then refine again on the corrected readings (a generator, as :func:`acquire`);
    returns (x, fitted_drift, cost, i)."""
    if fit_detector_to(rig, calibration, window, x[i], fitted_drift, u, age, provisional=True):
        y = calibration.correct(window.arrays(calibration, raw=True)[1][-len(u) :])
        z = np.concatenate([x, np.tile(fitted_drift, (len(x), 1))], axis=1)
        z, cost = yield from rig.refine(z, u, y, age, None, p.iterations)
        i = int(np.argmin(cost))
        x, fitted_drift = z[:, : rig.stage], z[i, rig.stage :]
    return x, fitted_drift, cost, i


def fit_detector_to(
    rig, calibration, window, x, drift, u, age, last=None, provisional=False, min_power=0.0
) -> bool:
    """Fit the detector's gain and offset to the window's readings as the errors ``x`` (N,) and
    ``drift`` predict them (an acquisition, or a fresh lock, that does not fit), or to its
    ``last`` readings only, of those the ones whose power reads ``min_power`` or more; True if
    the fit was taken (none without such a reading). ``provisional``: an acquisition's (see
    :func:`.tracking.detector_settled`)."""
    pred = rig.predict(x[None], u, age, drift)[0]
    raw = window.arrays(calibration, raw=True)[1][-len(u) :]
    if last is not None:
        pred, raw = pred[-last:], raw[-last:]
    near = raw[:, -1] >= min_power
    if not near.any():
        return False
    return calibration.fit_detector(pred[near], raw[near], provisional)


def relock_drifts(drift: np.ndarray) -> np.ndarray:
    """The drifts a local re-lock starts from: the present one, none, and each stage's
    reversed."""
    drifts = [drift, np.zeros(drift.size)]
    for j in range(drift.size):
        d = drift.copy()
        d[j] = -d[j]
        drifts.append(d)
    return np.array(drifts)
