"""The knot test: a stage's drift changed slope within the window.

A tracking fit that does not explain its readings is tried again under one hypothesis per
stage, knot position and side (:func:`knot_hypotheses`), all fitted at once
(:func:`~.fit.fit_paths` with ``knots``); a hypothesis wins only if it explains the readings
clearly better (:meth:`KnotTest._knot_fit`). With ``defer_knot_test`` the test waits until the
command is out (:meth:`KnotTest.think`).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from . import fit


class KnotRun(NamedTuple):
    """A knot test spread over readings (``slice_knot_test``): its hypotheses' fit, run within
    each reading's budget, and what its winner needs to be tried on a later window."""

    fits: fit.PathFitRun  # the hypotheses' fit (the first: no knot)
    knots: tuple  # (stage, first, change) (M,) as knot_hypotheses gives them
    steps: np.ndarray  # the step of each reading of its window
    drift: np.ndarray  # the drift the hypotheses started from


class KnotJob(NamedTuple):
    """A knot test left for :meth:`KnotTest.think`: the arguments of ``_knot_fit`` and the
    tracker's state before the answer (the plain fit's path, objective and period error)."""

    fit: tuple  # (predicted, x, drift, cost, u, y, age, ratio)
    drift_before: np.ndarray
    path: np.ndarray
    objective: float
    ratio: float


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
    by the change throughout: bent starts explained the phase step of a move on a model off in
    wavelength as a knot before the period fit could (medium, wavelength -2 %, seeds 0 and 3:
    readings of 0.07 after the lock; extreme unchanged: seeds 1000/1001 x 3000 steps
    97.90/97.63 % straight, 97.90/97.66 % bent)."""
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


#: A knot test spread over readings iterates its hypotheses in groups of this many, a group's
#: iteration at a time (~2 ms here), so that each reading's budget holds: all 51 of a noisy
#: detector's hypotheses at once take ~10 ms an iteration, and the start ~20 ms, which made a
#: 100 Hz loop late for the test's readings (over DDS, lab, hard: the readings before a loss).
KNOT_RUN_CHUNK = 8
#: ... and, unless ``knot_keep`` says otherwise, only this many of them iterate on after
#: ``knot_prune_after`` iterations, with the first (no knot): one group. A spread test is then
#: 31 units of work instead of 91, and ends in a third of the readings.
KNOT_RUN_KEEP = 7

#: With a budget that cuts the knot test short on a noisy detector, one test in this many is run
#: again (is it still cut short?); the others are left out (:meth:`KnotTest._knot_test_skipped`).
KNOT_RETRY = 20


class KnotTest:
    """The knot test of :class:`~.core.PhaseTracker` (a mixin: it works on the tracker's
    state)."""

    def think(self, spread: bool = True) -> bool:
        """Work that may wait until the command is out: the knot test the last reading asked
        for, with ``defer_knot_test`` (a node calls this after publishing the command, in the
        time before the next step; :meth:`observe` calls it first if nobody did), and the next
        part of a knot test spread over readings (``slice_knot_test``). True when their outcome
        changed the command already given: :meth:`command` then gives the revised one (a node
        sends it at once; if the step ran on the first one, its reading is not paired with the
        revised command and is not used). ``spread`` False: the deferred test only (``observe``
        runs it first: a spread test moves on in the time after a command, not twice a reading)."""
        deadline = None
        aimed = (self.estimate, self.drift)  # what the command given aims by
        if self._knot_job is not None:
            job, self._knot_job = self._knot_job, None
            # the state the test starts from: as it was before the answer
            self.drift, self._path = job.drift_before, job.path
            self._objective, self._ratio = job.objective, job.ratio
            deadline = self._knot_deadline()
            predicted, x, drift, cost, u, y, age, ratio = job.fit
            if self._spreads_knot_test(deadline):
                if self._knot_run is None:  # (one under way: this reading goes untested)
                    run = self._start_knot_run(predicted, u, y, age, ratio, spread=True)
                    if run.fits.run(deadline):  # done within the budget: as if not spread
                        x, drift, cost = self._knot_choice(run.fits.result(), x, drift, cost)
                    else:  # on over the next readings; this one takes the plain fit
                        self._knot_run = run
                        self.knot_tests_spread += 1
            else:
                x, drift, cost = self._knot_fit(*job.fit, deadline=deadline)
            self._finish_track(predicted, x, drift, cost, u, y, age, ratio, deadline)
        if spread and self._knot_run is not None:
            self._advance_knot_run(deadline or self._knot_deadline())
        changed = not all(map(np.array_equal, aimed, (self.estimate, self.drift)))
        self._revise = self._awaiting and changed
        return self._revise

    def _spreads_knot_test(self, deadline) -> bool:
        """Whether a knot test the budget cuts short runs on over the next readings: on a noisy
        detector. A clean one takes the test as far as it got (extreme, no detector noise, 15 %
        of the commands late, the node's 4 ms: 87.1 / 90.8 % of readings >= 0.95 with 55 / 41
        losses, spread 83.7 / 81.8 % with 124 each; ``ops-bench tracker-late --mode extreme
        --realism ideal --seeds 1002 1003`` at commit 321ffa4): its knots matter a reading
        sooner."""
        return deadline is not None and self.params.slice_knot_test and self._noisy()

    def _start_knot_run(self, predicted, u, y, age, ratio=False, spread=False) -> KnotRun:
        """The hypotheses of :meth:`_knot_fit` on this window (u, y, age), started from the
        prediction, not yet fitted. ``spread``: to run over readings, in groups of
        ``KNOT_RUN_CHUNK`` and pruned to ``KNOT_RUN_KEEP`` unless ``knot_keep`` is set (see
        :class:`.fit.PathFitRun`)."""
        p = self.params
        keep = p.knot_keep or (KNOT_RUN_KEEP if spread else 0)
        knots = knot_hypotheses(
            self.stage, len(u), self._knot_setting("knot_readings"), p.knot_start_cycles
        )
        path0 = knot_starts(predicted, self.drift, age, knots, ratio)
        m = knots[0].size
        fits = self._path_fit_run(
            path0[:, -1],
            np.tile(self.drift, (m, 1)),
            u,
            y,
            age,
            self._knot_setting("knot_iterations"),
            ratio=ratio,
            knots=knots,
            prune=(p.knot_prune_after, keep) if keep else None,
            path0=path0,
            chunk=KNOT_RUN_CHUNK if spread else None,
        )
        steps = np.array([h[2] for h in self._history], dtype=np.int64)[-len(u) :]
        return KnotRun(fits, knots, steps, self.drift.copy())

    def _advance_knot_run(self, deadline) -> None:
        """The knot test under way, on until ``deadline`` (one iteration at least); at its end
        its winner, if a hypothesis won, is tried on the window now (:meth:`_retry_knot`)."""
        run = self._knot_run
        if self.estimate is None or self._recovering is not None:
            self._knot_run = None  # the lock it was to refine is gone
            return
        if not run.fits.run(deadline):
            return
        self._knot_run = None
        fits = run.fits.result()
        penalty = self._knot_setting("knot_penalty")
        best = int(np.argmin(fits.objective[1:])) + 1
        if fits.objective[best] + penalty < fits.objective[0]:
            self._retry_knot(run, best, fits)

    def _retry_knot(self, run: KnotRun, best: int, fits) -> None:
        """A knot the spread test found in its (older) window, fitted again on the window now
        against no knot (each from the estimate now; the knot at the same step, or before the
        window if it left it, with the change found), and taken if it still wins by the
        penalty."""
        stage = int(run.knots[0][best])
        knot_step = run.steps[int(run.knots[1][best])]
        u, y, age = self._window()
        k = len(u)
        steps = np.array([h[2] for h in self._history], dtype=np.int64)
        first = min(max(int(np.searchsorted(steps, knot_step)), 1), k - 1)
        change = float(fits.drift[best, stage] - run.drift[stage])
        knots = (np.array([0, stage]), np.array([k, first]), np.array([0.0, change]))
        ratio = self._hop_tick is not None and self._tick - self._hop_tick <= k - 2
        path0 = knot_starts(self.estimate, self.drift, age, knots, ratio)
        path0[1, :, stage] -= path0[1, -1, stage] - self.estimate[stage]  # bent back from now
        retry = self._fit_paths(
            path0[:, -1],
            np.tile(self.drift, (2, 1)),
            u,
            y,
            age,
            self._knot_setting("knot_iterations"),
            ratio=ratio,
            knots=knots,
            path0=path0,
        )
        if retry.objective[1] + self._knot_setting("knot_penalty") >= retry.objective[0]:
            return
        self._path, self._objective, self._ratio = retry.path[1], retry.objective[1], retry.ratio[1]
        self.estimate, self.drift = retry.x[1], self._bounded(retry.drift[1])
        self.calibration.take_fitted_line(float(retry.gain[1]), float(retry.level[1]))
        self.knots += 1
        self._knot_tick = self._tick

    def _knot_test_skipped(self, deadline) -> bool:
        """Whether to leave this knot test out: on a noisy detector whose last test its budget
        cut short (and so was inconclusive), the next ones would be cut too, and each blocks a
        real-time loop for its whole compute (~50 ms on a 2-core machine: five readings of a
        100 Hz rig). One test in ``KNOT_RETRY`` runs anyway and tries again."""
        if deadline is None or not self._knot_cut_short or not self._noisy():
            return False
        self._knot_skips += 1
        if self._knot_skips % KNOT_RETRY == 0:
            return False
        self.knot_tests_cut += 1
        return True

    def _knot_setting(self, name: str):
        """The knot test's setting ``name`` for this detector: ``noisy_<name>`` on a noisy one
        (``knot_readings``, ``knot_walk_sigmas``, ``knot_iterations``, ``knot_penalty``)."""
        return getattr(self.params, f"noisy_{name}" if self._noisy() else name)

    def _knot_deadline(self):
        """When the knot test and the fits after it must stop (``knot_budget_ms``), or None."""
        budget = self.params.knot_budget_ms
        return time.perf_counter() + budget / 1e3 if budget else None

    def _knot_fit(self, predicted, x, drift, cost, u, y, age, ratio=False, deadline=None):
        """The best of the present fit (x, drift, cost) and the knot hypotheses, all fitted at
        once: each stage's slope changed from each of the last ``knot_readings`` readings of the
        window on (``noisy_knot_readings`` on a noisy detector), started either way (one reading
        is even in the change); the steps before the knot keep the present drift. Taken in turn,
        a hypothesis wins only if its whole cost plus ``knot_penalty`` (``noisy_knot_penalty``
        on a noisy detector) is below the best so far (the path and period error of the winner
        are kept).

        The first start is no knot (its knot after the window): the present fit iterated as
        long as the hypotheses, so that a knot must beat the best fit without one, not a fit of
        fewer iterations (seen: a model 2 % off in wavelength, whose moves a well-started
        knot fit explained better than a three-iteration path fit: knots at the moves)."""
        if self._knot_test_skipped(deadline):
            return x, drift, cost
        run = self._start_knot_run(predicted, u, y, age, ratio)
        run.fits.run(deadline)
        if deadline is not None and time.perf_counter() >= deadline and self._noisy():
            # Cut short on a noisy detector: hypotheses iterated once or twice win on the noise
            # (lab, hard, the node's 4 ms against a ~50 ms test: 92.6-97.4 % of readings >= 0.95
            # with late commands, 98.7-99.3 % with the cut test left inconclusive; docs/tracker.md)
            self.knot_tests_cut += 1
            self._knot_cut_short = True
            return x, drift, cost
        self._knot_cut_short = False
        return self._knot_choice(run.fits.result(), x, drift, cost)

    def _knot_choice(self, fits, x, drift, cost):
        """The best of the present fit (x, drift, cost) and the knot test's ``fits`` (the first:
        no knot), a hypothesis only by ``knot_penalty``; its path and period error kept."""
        best, best_path, best_obj = (x, drift, cost), self._path, self._objective
        best_ratio, best_line, won = self._ratio, (self._gain_step, self._level_step), False
        penalty = self._knot_setting("knot_penalty")
        for i in range(fits.objective.size):
            if fits.objective[i] + (penalty if i else 0.0) < best_obj:
                best = (fits.x[i], fits.drift[i], float(fits.data_cost[i]))
                best_path, best_obj, won = fits.path[i], fits.objective[i], i > 0
                best_ratio, best_line = fits.ratio[i], (float(fits.gain[i]), float(fits.level[i]))
        self._path, self._objective, self._ratio = best_path, best_obj, best_ratio
        self._gain_step, self._level_step = best_line
        self.knots += won
        if won:
            self._knot_tick = self._tick
        return best

    def _walk_jump(self) -> float:
        """The largest move of the fitted path over its last step, away from the drift, in
        units of the walk's std (a knot shows here before the readings' residual grows)."""
        if self._path.shape[0] < 2:
            return 0.0
        step = self._path[-1] - self._path[-2] - self._gap * self.drift
        return float(np.max(np.abs(step))) / (self._walk_sigma() * self._gap**0.5)
