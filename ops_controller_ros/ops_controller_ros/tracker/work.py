"""Work counted in rows: the delay vectors the physics evaluates, each weighed by its stage's cost
(:attr:`.model.RigModel.work_scale`, 1 at N = 5), so that a budget holds on any machine.

The long searches (the global search, the latency check) are generators that yield the rows of
each unit of work they did. One whose whole work stays within ``search_work_budget`` runs as it
always did; a larger one (N = 7: hundreds of ms) is spread, ``spread_rows`` a reading, by
:func:`advance`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Generator

from .params import TrackerParams


def scaled(job: Generator, scale: float) -> Generator:
    """``job`` with each unit's rows (its yields; None counts 0) times ``scale``; its value."""
    while True:
        try:
            rows = next(job)
        except StopIteration as done:
            return done.value
        yield (rows or 0) * scale


def advance(job: Generator, rows=None, units: int = 0, budget_ms: float = 0.0):
    """Run ``job`` until it ends, (True, its value), or this reading's share is done, (False,
    None): ``rows`` of work (None: no cap; a unit is not begun when the last one's rows would
    overrun what is left, and at least one runs), ``units`` (0: no cap), and a real-time cap
    of ``budget_ms`` (0: none)."""
    deadline = time.perf_counter() + budget_ms / 1e3 if budget_ms > 0 else math.inf
    left = math.inf if rows is None else float(rows)
    done, last = 0, 0.0
    try:
        while True:
            last = float(next(job) or 0.0)
            done += 1
            left -= last
            if done == units or time.perf_counter() >= deadline or last > left:
                return False, None
    except StopIteration as finished:
        return True, finished.value


def spread_rows(p: TrackerParams, whole_rows: float):
    """A reading's share of a search whose whole work is ``whole_rows``: None (all of it at
    once) when it is within ``search_work_budget`` (or that is 0), else ``spread_rows``."""
    if not p.search_work_budget or whole_rows <= p.search_work_budget:
        return None
    return p.spread_rows


def refine_rows(starts: int, dim: int, readings: int, iterations: int) -> int:
    """The rows of a :func:`.fit.refine` of ``starts`` over ``dim`` variables: each iteration
    evaluates every start and its ``dim`` steps, then the trial."""
    return iterations * starts * (dim + 2) * readings


def search_rows(p: TrackerParams, n: int, readings: int) -> int:
    """The most work of one global search (:func:`.acquisition.acquire`) on ``readings``
    readings at N = ``n``, unweighed: scoring, the refinement, then (at most) with the drift
    and with the detector's line."""
    refine = refine_rows(p.refine, n, readings, p.iterations)
    with_drift = refine_rows(p.refine, 2 * n, readings, p.iterations)
    return p.candidates * readings + refine + 2 * with_drift
