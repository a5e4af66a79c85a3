"""Acquisition: the global search for the delay errors when the tracker has no estimate, and the
fit of the detector's line to an estimate that does not otherwise explain its readings.

The search scores ``candidates`` random delay vectors over one period per stage against the
window, refines the ``refine`` best by Levenberg-Marquardt (each stage's drift too where a static
fit does not explain the window, and the detector's gain and offset where the model still does
not) and gives the estimate with its residual; the tracker accepts it only when that is within
the tolerance. It is a generator (one unit of work per ``yield``, its rows: :mod:`.work`), so
its work can be spread over readings: at N = 7 it is, ``spread_rows`` a reading, and what it
found on the window it started on is then refined on the window as it is when it ends.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .params import TrackerParams
from .work import advance, spread_rows

SEARCH_CHUNK = 128  # candidates scored per unit of the global search
SPREAD_CHUNK = 64  # ... of one spread over readings (a unit at N = 7: some 8 ms here)
POLISH_STARTS = 3  # a spread search's best starts refined again on the window as it is now
POLISH_ROUNDS = 3  # ... at most this many times (readings come while it refines)


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
    rows: float | None = None  # its share of a reading's work (None: all at once; .work)
    acquisitions: int = 0  # estimates accepted

    def readings(self, whole_rows: float) -> int:
        """The readings a search of ``whole_rows`` takes at the share now (0: run whole)."""
        return 0 if self.rows is None else int(np.ceil(whole_rows / self.rows))

    def step(self, p: TrackerParams, start: Callable[[], Generator], whole_rows: float):
        """Advance the search (``start(spread)`` begins one, whose whole work is ``whole_rows``) by
        this reading's share; its outcome once it ends. A search within ``search_work_budget``
        runs whole unless ``search_units`` or ``step_budget_ms`` spread it; a larger one runs
        ``spread_rows`` a reading and ends by bringing its estimate up to the window as it is
        then (:func:`_catch_up`)."""
        if self.job is None:
            self.rows = spread_rows(p, whole_rows)
            self.job = start(self.rows is not None)
        finished, value = advance(self.job, self.rows, p.search_units, p.step_budget_ms)
        if finished:
            self.job = None
        return value


def acquire(rig, p: TrackerParams, rng, window, calibration, tolerance, started: int, spread=False):
    """The global search on the window as it is when it starts, a generator (one unit per
    yield) that returns its :class:`Acquired`. ``rig``: the :class:`~.model.RigModel`;
    ``tolerance()``: the residual that counts as a fit, asked as the search goes on; ``started``:
    the step now; ``spread``: to run over readings (smaller units)."""
    n = rig.stage
    u, y, age = window.arrays(calibration)
    readings = list(window.history)  # as they are now: readings come while a spread search runs
    drift = np.zeros(n)
    cand = rng.uniform(-0.5, 0.5, size=(p.candidates, n))
    scores = []
    chunk = SPREAD_CHUNK if spread else SEARCH_CHUNK
    for i in range(0, p.candidates, chunk):
        scores.append(rig.cost(cand[i : i + chunk], u, y, age, drift))
        yield len(scores[-1]) * len(u) * rig.work_scale  # rows (.work)
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
            rig, p, (window, readings), calibration, x, fitted_drift, cost, i, u, age
        )
    found = Acquired(x[i], fitted_drift, float(cost[i]), started)
    return (yield from _catch_up(rig, p, window, calibration, found, x, cost))


def _catch_up(rig, p, window, calibration, found: Acquired, x, cost):
    """A search spread over readings found its estimate on the window as it was when it
    started; readings came meanwhile, and the delays walked on. Its best starts, carried on by
    the fitted drift, are refined (errors and drift) on the window as it is now, until a
    refinement ends on the window it began on; the estimate is then the present one. (A search
    that ran whole in one reading returns as it found.)"""
    n = rig.stage
    keep = np.argsort(cost)[: max(1, min(POLISH_STARTS, len(cost)))]
    z = np.concatenate([x[keep], np.tile(found.drift, (keep.size, 1))], axis=1)
    started, drift = found.started, found.drift
    for _ in range(POLISH_ROUNDS):
        now = int(window.latest[2])
        if now == started:
            break
        z[:, :n] += (now - started) * z[:, n:]
        u, y, age = window.arrays(calibration)
        z, cost = yield from rig.refine(z, u, y, age, None, p.polish_iterations)
        i = int(np.argmin(cost))
        started, drift = now, z[i, n:]
        found = Acquired(z[i, :n], drift, float(cost[i]), now)
    return found


def _refine_detector(rig, p, searched, calibration, x, fitted_drift, cost, i, u, age):
    """A detector off its calibration: fit its gain and offset to the best estimate's
    predictions, then refine again on the corrected readings (a generator, as :func:`acquire`;
    ``searched``: the window and the readings the search took from it); returns (x,
    fitted_drift, cost, i)."""
    window, readings = searched
    args = (rig, calibration, window, x[i], fitted_drift, u, age)
    if fit_detector_to(*args, provisional=True, readings=readings):
        raw = window.arrays(calibration, readings, raw=True)[1]
        y = calibration.correct(raw[-len(u) :])
        z = np.concatenate([x, np.tile(fitted_drift, (len(x), 1))], axis=1)
        z, cost = yield from rig.refine(z, u, y, age, None, p.iterations)
        i = int(np.argmin(cost))
        x, fitted_drift = z[:, : rig.stage], z[i, rig.stage :]
    return x, fitted_drift, cost, i


def fit_detector_to(
    rig,
    calibration,
    window,
    x,
    drift,
    u,
    age,
    last=None,
    provisional=False,
    min_power=0.0,
    readings=None,
) -> bool:
    """Fit the detector's gain and offset to the window's readings (or ``readings``) as the
    errors ``x`` (N,) and ``drift`` predict them (an acquisition, or a fresh lock, that does not
    fit), or to its ``last`` readings only, of those the ones whose power reads ``min_power`` or
    more; True if the fit was taken (none without such a reading). ``provisional``: an
    acquisition's (see :func:`.tracking.detector_settled`)."""
    pred = rig.predict(x[None], u, age, drift)[0]
    raw = window.arrays(calibration, readings, raw=True)[1][-len(u) :]
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
