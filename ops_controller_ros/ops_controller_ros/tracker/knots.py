"""The knot test: a stage's drift changed slope within the window.

A tracking fit that does not explain its readings is tried again under one hypothesis per stage,
knot position and side (:func:`knot_hypotheses`), all fitted at once (:class:`~.fit.PathFitRun`
with ``knots``); a hypothesis wins only if it explains the readings clearly better
(:func:`choose`). With ``defer_knot_test`` the test waits until the command is out
(:meth:`~.core.PhaseTracker.think`); with a real-time budget on a noisy detector it may run on
over the next readings (:class:`KnotRun`), its winner then tried again on the window it ends at
(:func:`retry`). :class:`Knots` is the test's state; the functions here are its steps.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from . import fit
from .params import TrackerParams

#: A knot test spread over readings iterates its hypotheses in groups of this many, a group's
#: iteration at a time, so that each reading's budget holds: all of a noisy detector's
#: hypotheses at once take several times a 100 Hz rig's step per iteration.
KNOT_RUN_CHUNK = 8
#: ... and, unless ``knot_keep`` says otherwise, only this many of them iterate on after
#: ``knot_prune_after`` iterations, with the first (no knot): one group. A spread test is then
#: about a third of the units of work, and ends in a third of the readings.
KNOT_RUN_KEEP = 7
#: With a budget that cuts the knot test short on a noisy detector, one test in this many is run
#: again (is it still cut short?); the others are left out (:meth:`Knots.skipped`).
KNOT_RETRY = 20


class KnotRun(NamedTuple):
    """A knot test spread over readings (``slice_knot_test``): its hypotheses' fit, run within
    each reading's budget, and what its winner needs to be tried on a later window."""

    fits: fit.PathFitRun  # the hypotheses' fit (the first: no knot)
    knots: tuple  # (stage, first, change) (M,) as knot_hypotheses gives them
    steps: np.ndarray  # the step of each reading of its window
    drift: np.ndarray  # the drift the hypotheses started from


class KnotJob(NamedTuple):
    """A knot test left for ``think``: the plain fit it is to beat (predicted, x, drift, cost,
    u, y, age, ratio) and the lock's state before the answer (the drift, and the plain fit's
    path, objective and period error)."""

    fit: tuple  # (predicted, x, drift, cost, u, y, age, ratio)
    drift_before: np.ndarray
    path: np.ndarray
    objective: float
    ratio: float


@dataclass
class Knots:
    """The knot test's state of one run (from a reset)."""

    taken: int = 0  # knot hypotheses taken
    tests_cut: int = 0  # tests on a noisy detector its budget cut short or left out: no knot
    tests_spread: int = 0  # tests run over several readings (slice_knot_test)
    cut_short: bool = False  # the last test run was cut short
    skips: int = 0  # tests left out since then
    tick: int = -(10**9)  # the reading the last knot was taken at
    job: KnotJob | None = None  # the test think() is to run (defer_knot_test)
    run: KnotRun | None = None  # a test spread over readings, under way

    @property
    def testing(self) -> bool:
        """A knot test asked for or under way."""
        return self.job is not None or self.run is not None

    def won(self, tick: int) -> None:
        self.taken += 1
        self.tick = tick

    def skipped(self, deadline, noisy: bool) -> bool:
        """Whether to leave this knot test out: on a noisy detector whose last test its budget
        cut short (and so was inconclusive), the next ones would be cut too, and each blocks a
        real-time loop for its whole compute. One test in ``KNOT_RETRY`` runs anyway and tries
        again."""
        if deadline is None or not self.cut_short or not noisy:
            return False
        self.skips += 1
        if self.skips % KNOT_RETRY == 0:
            return False
        self.tests_cut += 1
        return True

    def ran(self, deadline, noisy: bool) -> bool:
        """A test has run until ``deadline``: whether it counts (False: cut short on a noisy
        detector, where hypotheses iterated once or twice win on the noise, so it is left
        inconclusive)."""
        if deadline is not None and time.perf_counter() >= deadline and noisy:
            self.tests_cut += 1
            self.cut_short = True
            return False
        self.cut_short = False
        return True


def test_rows(n: int, k: int, readings: int, iterations: int) -> int:
    """The rows the physics evaluates in a whole knot test of :func:`knot_hypotheses` on a
    window of ``k`` readings (at most: each hypothesis's start and every iteration's trial and
    Jacobian), to weigh against the work budget before it starts."""
    hypotheses = 1 + 2 * n * min(readings, k - 1)
    return (iterations + 1) * hypotheses * k * (n + 2)


def budget_rows(p: TrackerParams, scale: float):
    """The rows a reading may evaluate for a knot test (``work_budget`` over the stage's
    ``scale``, :attr:`.model.RigModel.work_scale`), or None (no budget)."""
    return p.work_budget / scale if p.work_budget else None


def over_budget(p: TrackerParams, n: int, k: int, noisy: bool, scale: float) -> bool:
    """Whether a knot test on a window of ``k`` readings would take more than a reading's work
    budget: it is then spread over readings (:func:`spreads`)."""
    readings, iterations = (setting(p, s, noisy) for s in ("knot_readings", "knot_iterations"))
    rows = budget_rows(p, scale)
    return rows is not None and test_rows(n, k, readings, iterations) > rows


def setting(p: TrackerParams, name: str, noisy: bool):
    """The knot test's setting ``name`` for this detector: ``noisy_<name>`` on a noisy one
    (``knot_readings``, ``knot_walk_sigmas``, ``knot_iterations``, ``knot_penalty``)."""
    return getattr(p, f"noisy_{name}" if noisy else name)


def deadline(p: TrackerParams):
    """When the knot test and the fits after it must stop (``knot_budget_ms``), or None."""
    budget = p.knot_budget_ms
    return time.perf_counter() + budget / 1e3 if budget else None


def spreads(p: TrackerParams, deadline, noisy: bool, over: bool) -> bool:
    """Whether a knot test runs on over the next readings: one ``over`` the work budget
    (:func:`over_budget`), and on a noisy detector one a real-time ``deadline`` would cut short.
    A clean detector takes a test the deadline cuts as far as it got: its knots matter a
    reading sooner."""
    return over or (deadline is not None and p.slice_knot_test and noisy)


def knot_hypotheses(n: int, k: int, knot_readings: int, start_cycles: float):
    """(stage, first, change) (M,) each: no knot first (its knot after the window), then each
    stage's slope changed from each of the last ``knot_readings`` readings on, either way."""
    firsts = np.arange(k - 1, max(k - 1 - knot_readings, 0), -1)
    stage, first, sign = (
        np.concatenate([[value], a.ravel()])
        for value, a in zip(
            (0, k, 0.0),
            np.meshgrid(np.arange(n), firsts, [1.0, -1.0], indexing="ij"),
            strict=True,
        )
    )
    return stage, first, sign * start_cycles


def knot_starts(predicted, drift, age, knots, ratio: bool) -> np.ndarray:
    """The starts' paths (M, K, N): the path of the prediction (back from it by the drift), bent
    at the knot: the knotted stage moved on by the change for every step since the reading
    before the knot (a straight path through the bent end needed twice the iterations for the
    same fits). In a window with a whole-cycle move (``ratio``) the path starts straight, moved
    by the change throughout: bent starts explain the phase step of a move on a model off in
    wavelength as a knot before the period fit can."""
    stage, first, change = knots
    m, k = stage.size, age.size
    line = predicted[None] - age[:, None] * drift[None]  # (K, N)
    path0 = np.tile(line, (m, 1, 1))
    if ratio:
        since = np.broadcast_to(age[first - 1][:, None], (m, k))
    else:
        since = np.clip(age[first - 1][:, None] - age[None, :], 0.0, None)  # (M, K)
    path0[np.arange(m)[:, None], np.arange(k)[None], stage[:, None]] += change[:, None] * since
    return path0


def start_run(
    path_fit_run,
    p: TrackerParams,
    noisy: bool,
    predicted,
    drift,
    window_steps,
    u,
    y,
    age,
    ratio=False,
    spread=False,
) -> KnotRun:
    """The hypotheses of a knot test on the window (u, y, age; ``window_steps`` the step of each
    of its readings), started from the prediction and ``drift``, not yet fitted
    (``path_fit_run``: the tracker's :class:`~.fit.PathFitRun` of its arguments). ``spread``:
    to run over readings, in groups of ``KNOT_RUN_CHUNK`` and pruned to ``KNOT_RUN_KEEP``
    unless ``knot_keep`` is set."""
    keep = p.knot_keep or (KNOT_RUN_KEEP if spread else 0)
    n = drift.size
    knots = knot_hypotheses(n, len(u), setting(p, "knot_readings", noisy), p.knot_start_cycles)
    path0 = knot_starts(predicted, drift, age, knots, ratio)
    m = knots[0].size
    fits = path_fit_run(
        path0[:, -1],
        np.tile(drift, (m, 1)),
        u,
        y,
        age,
        setting(p, "knot_iterations", noisy),
        ratio=ratio,
        knots=knots,
        prune=(p.knot_prune_after, keep) if keep else None,
        path0=path0,
        chunk=KNOT_RUN_CHUNK if spread else None,
    )
    return KnotRun(fits, knots, window_steps[-len(u) :], drift.copy())


class Choice(NamedTuple):
    """The outcome of a knot test: the fit taken (x, drift, cost), its path, whole cost, period
    error and detector line (gain, level steps), and whether a knot won."""

    best: tuple
    path: np.ndarray
    objective: float
    ratio: float
    line: tuple
    won: bool


def choose(fits, current: tuple, current_fit: tuple, penalty: float) -> Choice:
    """The best of the present fit (``current``: x, drift, cost; ``current_fit``: its path,
    objective, ratio and line, as :meth:`.tracking.Lock.fit_state` gives them) and the knot
    test's ``fits`` (the first: no knot, iterated as long as the hypotheses, so that a knot must
    beat the best fit without one), taken in turn: a hypothesis only by ``penalty``."""
    best = current
    best_path, best_obj, best_ratio, best_line = current_fit
    won = False
    for i in range(fits.objective.size):
        if fits.objective[i] + (penalty if i else 0.0) < best_obj:
            best = (fits.x[i], fits.drift[i], float(fits.data_cost[i]))
            best_path, best_obj, won = fits.path[i], fits.objective[i], i > 0
            best_ratio, best_line = fits.ratio[i], (float(fits.gain[i]), float(fits.level[i]))
    return Choice(best, best_path, best_obj, best_ratio, best_line, won)


def spread_winner(run: KnotRun, penalty: float):
    """The hypothesis (index) a finished spread test found, if one beat no knot by ``penalty``;
    else None."""
    fits = run.fits.result()
    best = int(np.argmin(fits.objective[1:])) + 1
    if fits.objective[best] + penalty < fits.objective[0]:
        return best, fits
    return None


def retry(fit_paths, run: KnotRun, best: int, fits, now: tuple, iterations: int, penalty: float):
    """The winner ``best`` of a spread test (its ``fits``) tried on the window now (``now``:
    the step of each reading, the estimate, the drift, u, y, age, ratio) against no knot, each
    from the estimate now: the knot at the same step, or before the window if it left it, with
    the change found. The fits (``fit_paths``: the tracker's, run to their end; ``iterations``
    each) if the knot still wins by ``penalty`` (the knot's is the second); else None."""
    window_steps, estimate, drift, u, y, age, ratio = now
    stage = int(run.knots[0][best])
    knot_step = run.steps[int(run.knots[1][best])]
    k = len(age)
    first = min(max(int(np.searchsorted(window_steps, knot_step)), 1), k - 1)
    change = float(fits.drift[best, stage] - run.drift[stage])
    knots = (np.array([0, stage]), np.array([k, first]), np.array([0.0, change]))
    path0 = knot_starts(estimate, drift, age, knots, ratio)
    path0[1, :, stage] -= path0[1, -1, stage] - estimate[stage]  # bent back from now
    out = fit_paths(
        path0[:, -1],
        np.tile(drift, (2, 1)),
        u,
        y,
        age,
        iterations,
        ratio=ratio,
        knots=knots,
        path0=path0,
    )
    return None if out.objective[1] + penalty >= out.objective[0] else out
