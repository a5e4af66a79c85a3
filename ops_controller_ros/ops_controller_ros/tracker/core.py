"""The tracker's state machine: :class:`PhaseTracker` (reset / command / observe / think).

The tracker is a thin stateful facade. Its state lives in a few objects, each owned and changed by
the module whose job it is: the commands and the count of readings (:class:`.commands.Loop`), the
window of readings (:class:`.window.Window`), the estimate and its last path fit
(:class:`.tracking.Lock`), the detector's noise (:class:`.noise.Noise`), the global search
(:class:`.acquisition.Search`), the knot test (:class:`.knots.Knots`), the period's moves
(:class:`.period.Period`), the latency check (:class:`.latency_check.LatencyWatch`) and the
false-lock rule (:class:`.tracking.Guard`), beside the model it fits with
(:class:`.model.RigModel`) and the calibration. The methods here run a reading through them:
acquiring (no estimate), tracking (each reading re-fits the window's path; a fit that does not
explain its readings asks for the knot test) and recovering (a local re-lock). The method:
the package docstring (:mod:`ops_controller_ros.tracker`).
"""

from __future__ import annotations

from functools import partial

import numpy as np

from ..calibration import ModelCalibration
from . import fit, knots, work
from .acquisition import Search, acquire, fit_detector_to, relock_drifts
from .commands import Loop, excursion, hold_dither
from .drift_memory import drift_memory
from .knots import KnotJob, Knots
from .latency_check import LatencyWatch
from .model import RigModel, told_noise
from .noise import Noise
from .params import TrackerParams
from .period import HOP_POWER, Period
from .tracking import (
    KNOT_MAX_GAP,
    Guard,
    Lock,
    bounded,
    detector_settled,
    drift_prior,
    gain_prior,
    largest_gap,
    level_prior,
    walk_jump,
)
from .vibration import under_vibration
from .window import Window, fit_window


def _shown(part: str, name: str, doc: str, settable: bool = False) -> property:
    """A public figure of the tracker that one of its state objects holds."""

    def get(self):
        return getattr(getattr(self, part), name)

    def put(self, value):
        setattr(getattr(self, part), name, value)

    return property(get, put if settable else None, doc=doc)


class PhaseTracker:
    """Model-based stacking controller (see the package docstring): reset / command / observe,
    and think for the work that may wait until the command is out."""

    estimate = _shown("lock", "estimate", "hidden delay errors now, cycles (None: none)", True)
    drift = _shown("lock", "drift", "the errors' drift per step, cycles", True)
    residual = _shown("lock", "residual", "mean squared residual of the last fit")
    acquisitions = _shown("search", "acquisitions", "estimates a global search found")
    knots = _shown("knot", "taken", "knot hypotheses taken while tracking")
    knot_tests_cut = _shown("knot", "tests_cut", "knot tests a budget cut short or left out")
    knot_tests_spread = _shown("knot", "tests_spread", "knot tests run over several readings")
    hops = _shown("period", "hops", "whole-cycle moves made to measure the wavelength")
    range_moves = _shown("period", "range_moves", "whole-cycle moves off a line's limit")
    false_locks = _shown("guard", "false_locks", "locks dropped for mostly low readings")
    calibration_resets = _shown("guard", "calibration_resets", "detector calibrations reset")
    latency = _shown("watch", "latency", "the latency in use, steps")
    latency_told = _shown("watch", "told", "the latency the model told, steps")
    latency_note = _shown("watch", "note", "why the latency in use is not the told one")
    latency_changes = _shown("watch", "changes", "latencies taken by the check")
    latency_checks = _shown("watch", "checks", "latency checks started")
    latency_costs = _shown("watch", "costs", "the last check's residual per latency")
    last_power = _shown("loop", "last_power", "P_N/P_max of the last reading")
    locked = _shown("lock", "locked", "whether the tracker has an estimate")
    window_length = _shown("window", "length", "readings per fit now (longer once noisy)")
    measured_noise = _shown("noise", "measured", "noise std of the repeated first reading")
    fit_noise = _shown("noise", "fitted", "noise std the tracking fits find (None: too few)")
    stacker = _shown("rig", "stacker", "the model's stacker now")
    period_fs = _shown("rig", "period_fs", "the model's optical period now, fs")

    def __init__(
        self,
        model,
        params: TrackerParams | None = None,
        setpoints_fs=None,
        seed=None,
        setpoint_range_fs=None,
        reach_fs=None,
    ):
        """``model``: the nominal OpsConfig; ``setpoint_range_fs``, ``reach_fs``: the lines'
        range and speed (:class:`.model.RigModel`)."""
        self.model = model
        self.stage = int(model.stage)
        self.params = under_vibration(told_noise(params or TrackerParams(), model), model)
        self.calibration = ModelCalibration(model, self.params.calibration_memory)
        self.rig = RigModel(model, self.params, setpoint_range_fs, reach_fs)
        self.watch = LatencyWatch(self.rig.latency, self.params)
        self.period = Period()
        self._rng = np.random.default_rng(seed)
        self._check_rng = self._rng.spawn(1)[0]  # (the latency check's: the commands' unmoved)
        self.reset(np.zeros(self.stage) if setpoints_fs is None else setpoints_fs)

    @property
    def setpoints_fs(self) -> np.ndarray:
        """The set-points the controller aims at (cycles -> fs), without the excursion."""
        return self.loop.base * self.rig.period_fs

    @property
    def noisy(self) -> bool:
        """Whether the tracker takes its detector as noisy (told, measured or fitted so)."""
        return self.noise.noisy(self.params)

    # ------------------------------------------------------------------ interface
    def reset(self, setpoints_fs) -> None:
        """Start again from ``setpoints_fs``: forget the estimate and the readings (the latency
        found, the range moves and the calibration are kept)."""
        p = self.params
        self.loop = Loop.start(self.rig.rest(setpoints_fs))
        self.noise = Noise(told_noisy=self.rig.told_noisy)
        self.window = Window(fit_window(p, self.rig.told_noisy))
        self.lock = Lock(self.stage, memory=drift_memory(p, self.model, self.rig.vibration))
        self.search = Search()
        self.knot = Knots()
        self.guard = Guard(p)
        self.period.restart()
        self.watch.restart(p)

    def command(self) -> np.ndarray:
        """Set-points (fs) to apply now. Asked again before the reading (a node re-sending a
        command whose reading did not come), the same set-points: a second call must not draw
        new excursions or undo a whole-cycle move that the first one made."""
        loop, lock, p = self.loop, self.lock, self.params
        if loop.awaiting and not loop.revise:
            return self.rig.wire(loop.last_command)
        loop.revise = False
        if lock.estimate is not None:
            # aim at the stacking point of the step the command acts at
            loop.aim(-(lock.estimate + (1 + self.watch.latency) * lock.drift))
        if lock.estimate is None or lock.recovering is not None:
            # acquiring, or recovering (excursions around the prediction)
            if lock.estimate is None and self.noise.measuring(len(self.window)):
                u = self.window.latest[0].copy()  # the first reading twice: the detector's noise
            else:
                signs = self._rng.choice((-1.0, 1.0), size=self.stage)
                u = loop.base + p.acquire_dither_cycles * signs
        else:
            loop.hop = self._whole_cycle_move()
            length = hold_dither(p, self.noise.var_assumed(p), lock.drift)
            u = loop.base + length * excursion(p, self.stage, loop.tick)
        u = self.rig.reachable(u, loop.position)
        self.watch.command(loop.step, u)
        loop.send(u, self.watch.latency)
        return self.rig.wire(u)

    def observe(
        self, power: float, pulse_energies=None, steps: int = 1, command_age: int | None = None
    ) -> None:
        """The reading produced by the last :meth:`command`; updates the estimate.

        ``steps``: the simulator (or rig) steps since the previous reading (1 in process and in
        lockstep; free-running, a late command costs a step on the old set-points and drift).

        ``command_age``: steps from the step that took the last command to this reading's (0:
        this step took it; the nodes read it from ``ops/delays``). With a latency, a command acts
        that many steps after the step that took it, not after the reading it answered: a late
        command told as such is not taken for a longer latency. None: taken by the step after the
        previous reading (in process, lockstep)."""
        y = self.rig.reading(power, pulse_energies)
        steps = int(steps)
        if steps < 1:
            raise ValueError(f"steps since the previous reading must be >= 1 (got {steps})")
        self.think(spread=False)  # a deferred knot test nobody ran: its outcome first
        loop, lock = self.loop, self.lock
        loop.reading(power, steps)
        if command_age is not None:
            taken, expected = loop.step - int(command_age), loop.step - steps + 1
            loop.command_taken(taken, expected)
            self.watch.command_taken(taken, expected)
        u_now, hop = loop.reading_setpoints(self.watch.latency, self.rig.lag_gain)
        noise = self.noise
        if noise.measuring(len(self.window)) and noise.measure(
            self.params, self.window.latest[:2], u_now, y, steps
        ):
            self._take_noisy_window()
        reading = (u_now.copy(), y, loop.step)
        self.window.append(reading)
        if lock.recovering is not None:
            lock.recovering.append(reading)
            self._recover()
        elif lock.estimate is not None and lock.skips_fit(self.params.fit_every, hop):
            lock.estimate = lock.predicted(loop.gap)  # (fit_every: the next fit takes it)
        elif lock.estimate is not None and self.params.answer_first:
            lock.defer(hop, loop.gap)  # the fit in think(), once the command is out
        elif lock.estimate is not None:
            self._track(hop)
        elif len(self.window) == self.window.length or self.search.job is not None:
            self._search_step()
        self._check_false_lock(float(power))
        self._watch_reading(y)
        self.guard.unlocked_too_long(self.params, self.locked, self.calibration)

    def think(self, spread: bool = True) -> bool:
        """Work that may wait until the command is out: the reading's tracking fit
        (``answer_first``), the knot test the last reading asked for (``defer_knot_test``; a
        node calls this after publishing the command, :meth:`observe` first if nobody did) and
        the next part of a spread knot test (``slice_knot_test``).
        True when that changed the command given: :meth:`command` then gives the revised one (a
        node sends it at once; a step run on the first one is not paired with it). ``spread``
        False: the deferred test only (a spread test moves on after a command, not twice)."""
        lock, knot, p = self.lock, self.knot, self.params
        deadline, rows = None, knots.budget_rows(p, self.rig.work_scale)  # (this reading's)
        due, hop = lock.take_deferred()
        if due:  # (answer_first: the command given aims by the prediction, the fit acts next)
            self._track(hop)
        aimed = (lock.estimate, lock.drift)  # what the command given aims by
        if knot.job is not None:
            job, knot.job = knot.job, None
            # the state the test starts from: as it was before the answer
            lock.drift, lock.path = job.drift_before, job.path
            lock.objective, lock.ratio = job.objective, job.ratio
            deadline, noisy = knots.deadline(p), self._noisy()
            predicted, x, drift, cost, u, y, age, ratio = job.fit
            over = knots.over_budget(p, self.stage, len(u), noisy, self.rig.work_scale)
            if knots.spreads(p, deadline, noisy, over):
                if knot.run is None:  # (one under way: this reading goes untested)
                    run = self._start_knot_run(predicted, u, y, age, ratio, spread=True)
                    if run.fits.run(deadline, rows):  # done within the budget: not spread
                        x, drift, cost = self._knot_choice(run.fits.result(), x, drift, cost)
                    else:  # on over the next readings; this one takes the plain fit
                        knot.run = run
                        knot.tests_spread += 1
                    rows = None if rows is None else rows - run.fits.rows
            else:
                x, drift, cost = self._knot_fit(*job.fit, deadline=deadline)
            self._finish_track(predicted, x, drift, cost, u, y, age, ratio, deadline)
        if spread and knot.run is not None and (rows is None or rows > 0):
            self._advance_knot_run(deadline or knots.deadline(p), rows)
        changed = not all(map(np.array_equal, aimed, (lock.estimate, lock.drift)))
        self.loop.revise = self.loop.awaiting and changed
        return self.loop.revise

    # ------------------------------------------------------------------ state changes
    def _take_noisy_window(self) -> None:
        """Fits take the noisy detector's longer window from the next reading on."""
        self.window.lengthen(fit_window(self.params, True))

    def _check_false_lock(self, power: float) -> None:
        """Drop a lock whose readings are mostly low (:meth:`.tracking.Guard.false_lock`): the
        tracker acquires again, from the nominal detector."""
        if not self.guard.false_lock(self.params, self.lock, power):
            return
        self.lock.estimate, self.lock.bad_fits = None, 0
        self.search.job = None
        self.calibration.reset_detector()

    def _watch_reading(self, y: np.ndarray) -> None:
        """The latency check's share of a reading; a latency it found is taken."""
        loop, rig = self.loop, self.rig
        args = (rig, self._tolerance, self._check_rng)
        found = self.watch.reading(self.params, loop.step, y, loop.last_power, *args)
        if found is not None:
            self._take_latency(found)

    def _take_latency(self, latency: int) -> None:
        """Pair readings with commands ``latency`` steps back from now on, and acquire anew."""
        acting, in_flight = self.watch.take(latency, self.loop.step)
        self.loop.requeue(acting, in_flight)
        self.lock.lose()
        self.lock.bad_fits = 0
        self.search.job = None
        self.knot.job = self.knot.run = None  # (a test of the old pairing: nothing left to test)
        self.loop.revise = False
        self.window.clear()

    def _whole_cycle_move(self):
        """Whole cycles added to the set-points now (:meth:`.period.Period.move`): off a
        line's limit, or a hop on a clean lock (no bad fit, no knot test and no knot within a
        window, a good reading); the hop, or None."""
        lock, loop, knot = self.lock, self.loop, self.knot
        clean = not lock.bad_fits and not knot.testing and loop.last_power >= HOP_POWER
        clean = clean and loop.tick - knot.tick >= self.window.length
        noisy = self.rig.told_noisy or self.rig.weights is not None
        args = (self.params, self.rig, loop.base, loop.tick, noisy, clean, lock.drift)
        return self.period.move(*args)

    def _adopt_optics(self) -> None:
        """Take the calibration's wavelength and width into the model and re-express the state
        (estimate, drift, set-points, the window's commands) in the new cycles."""
        ratio = self.rig.adopt(self.calibration)
        self.lock.rescale(ratio, self.window.latest[0])
        self.loop.rescale(ratio)
        self.window.rescale(ratio)

    def _calibrate(self, u: np.ndarray, path: np.ndarray) -> None:
        """Feed the window's fit to the calibration; every ``calibration_every`` readings, move
        the model's wavelength and pulse width and re-express the state in the new cycles."""
        raw = self.window.arrays(self.calibration, raw=True)[1]
        optics = self.params.calibrate_optics
        rig = self.rig
        self.calibration.observe(rig.expected, u, path, raw, rig.period_fs, optics, rig.weights)
        if not optics or self.loop.tick % self.params.calibration_every:
            return
        if self.calibration.update_optics():
            self._adopt_optics()

    # ------------------------------------------------------------------ estimation
    def _window(self, readings=None, raw: bool = False):
        """:meth:`.window.Window.arrays` with the calibration now."""
        return self.window.arrays(self.calibration, readings, raw)

    def _noisy(self) -> bool:
        return self.noise.noisy(self.params)

    def _tolerance(self, base: float | None = None) -> float:
        return self.noise.tolerance(self.params, base)

    def _knot_setting(self, name: str):
        return knots.setting(self.params, name, self._noisy())

    def _detector_settled(self) -> bool:
        return detector_settled(self.params, self.calibration)

    def _fit_run(self, x_now, drift, u, y, age, iterations: int, **kwargs) -> fit.PathFitRun:
        """A path fit of M starts (x_now, drift: (M, N)) on the window (u, y, age), not yet run:
        a :class:`.fit.PathFitRun` (``kwargs``: its ``ratio``, ``knots``, ``prune``, ``path0``,
        ``chunk``). The readings weigh by the reading std the noise implies, the walk by the
        model's; the drift's prior and the detector line's are those of now."""
        p, rig, tick, knot, lock = self.params, self.rig, self.loop.tick, self.knot, self.lock
        prior = drift_prior(p, self._noisy(), tick - knot.tick, knot.cut_short, lock.remembered())
        gain = gain_prior(p, tick - lock.lock_tick, self.window.length)
        steps = self.loop.step - age.astype(np.int64)  # (a told vibration: the window's arrival)
        kwargs.setdefault("arrival", self.lock.arrival(steps, rig.arrival_sd(p)))
        return fit.PathFitRun(
            rig.fit_stacker,
            rig.period_fs,
            x_now,
            drift,
            u,
            rig.weighed(y),
            age,
            iterations,
            r_sd=self.noise.reading_sd(p),
            w_sd=rig.walk_sigma,
            drift_prior=np.full(drift.shape, prior),
            knot_prior=p.knot_prior_cycles,
            gain_prior=gain,
            level_prior=level_prior(p, gain),
            **kwargs,
        )

    def _fit_paths(self, *args, deadline=None, **kwargs) -> fit.PathFits:
        """:meth:`_fit_run` run to its end or until ``deadline`` (many starts: one batched
        evaluation of the physics per iteration instead of one each)."""
        run = self._fit_run(*args, **kwargs)
        run.run(deadline)
        return run.result()

    def _fit_path(self, x_now, drift, u, y, age, iterations: int, ratio=False, deadline=None):
        """Moving-horizon fit of the window from x_now (the errors at the latest reading) and the
        drift: the errors at every reading and the drift, most probable given the readings, a
        random walk between readings and the drift's prior (``ratio``: and the model's period
        error, identifiable when the window holds a whole-cycle move). Kept as the lock's last
        path fit; returns (x at the latest reading, drift, mean squared residual)."""
        fits = self._fit_paths(
            x_now[None], drift[None], u, y, age, iterations, ratio=ratio, deadline=deadline
        )
        return self.lock.take(fits)

    def _fit_detector_to(self, x, drift, u, age, **kwargs) -> bool:
        """:func:`.acquisition.fit_detector_to` on the model and window now."""
        return fit_detector_to(self.rig, self.calibration, self.window, x, drift, u, age, **kwargs)

    def _search_step(self) -> None:
        """The global search's share of this reading; an estimate it found within the
        tolerance is tracked from, carried on by its drift from the step the search started."""
        p, loop, rig = self.params, self.loop, self.rig
        args = (self._rng, self.window, self.calibration, self._tolerance, loop.step)
        start = partial(acquire, rig, p, *args)  # start(spread)
        if self.watch.spread:
            return  # the latency check decides the pairing first (its work is the reading's)
        whole = work.search_rows(p, self.stage, len(self.window)) * rig.work_scale
        found = self.search.step(p, start, whole)
        self.watch.wait_for(2 * self.search.readings(whole))  # (a spread search's readings)
        if found is None:
            return
        self.lock.residual = found.residual
        if found.residual <= self._tolerance():
            x = found.x + (loop.step - found.started) * found.drift
            self.lock.start(x, loop.tick, bounded(p, found.drift))
            self.search.acquisitions += 1

    def _track(self, hop=None) -> None:
        """Re-fit the window's path of errors and the drift from the prediction (``hop``: the
        whole-cycle move of the last command, if any: it measures the period, and its step is
        not taken for a knot)."""
        p, lock, loop = self.params, self.lock, self.loop
        u, y, age = self._window()
        if hop is not None:
            self.period.moved(loop.tick)
        ratio = self.period.in_window(loop.tick, len(u))
        predicted = lock.predicted(loop.gap)  # the errors now, by the drift
        x, drift, cost = self._fit_path(
            predicted, lock.drift, u, y, age, p.track_iterations, ratio=ratio
        )
        if hop is not None or not self._knot_due(cost, age):
            self._finish_track(predicted, x, drift, cost, u, y, age, ratio)
            return
        # A knot of one stage's drift? Fit the window under one hypothesis per stage, knot
        # position and side, and keep the best if it explains the readings clearly better (a
        # wrong drift otherwise pulls every stage's estimate off within a few readings). A
        # window with a whole-cycle move fits the period too: a model period off by r moves the
        # phase by 2r at the move, which is no knot.
        job = (predicted, x, drift, cost, u, y, age, ratio)
        if p.defer_knot_test:
            # Answer first: the next command aims by the plain fit, and think() (or the next
            # observe) runs the test and finishes the reading.
            self.knot.job = KnotJob(job, lock.drift, lock.path, lock.objective, lock.ratio)
            if cost <= self._tolerance(p.lost_tolerance):
                lock.estimate, lock.drift = x, bounded(p, drift)
            else:
                lock.estimate = predicted
            return
        deadline = knots.deadline(p)
        x, drift, cost = self._knot_fit(*job, deadline=deadline)
        self._finish_track(predicted, x, drift, cost, u, y, age, ratio, deadline)

    def _knot_due(self, cost: float, age: np.ndarray) -> bool:
        """Whether a tracking fit asks for the knot test: its residual past ``knot_tolerance``
        or its path's last step off the drift by ``knot_walk_sigmas``; not on a window with an
        outage in it (a walk over the gap explains anything), nor before the detector is
        settled (a misfit may be the detector's)."""
        p, lock = self.params, self.lock
        if p.knot_prior_cycles <= 0 or largest_gap(age) > KNOT_MAX_GAP:
            return False
        if not self._detector_settled():
            return False
        if cost > self._tolerance(p.knot_tolerance):
            return True
        jump = walk_jump(lock.path, lock.drift, self.loop.gap, self.rig.walk_sigma)
        return jump > self._knot_setting("knot_walk_sigmas")

    def _finish_track(self, predicted, x, drift, cost, u, y, age, ratio, deadline=None) -> None:
        """Take a tracking fit (x, drift, cost) of the window (u, y, age): iterate further if
        its readings left the model (until ``deadline``, if given), count a bad fit (keep the
        prediction) or take it."""
        p, lock = self.params, self.lock
        fitted_ratio = lock.ratio
        lost = self._tolerance(p.lost_tolerance)
        refitted = False
        if not self._detector_settled() and (cost > lost or self.calibration.detector_provisional):
            refitted = self._refit_detector(x, drift, u, age)
            if refitted:
                u, y, age = self._window()
        if cost > lost or refitted:  # a knot of the drift, a fast walk: iterate further
            x, drift, cost = self._fit_path(
                predicted, lock.drift, u, y, age, p.iterations, ratio=ratio, deadline=deadline
            )
            fitted_ratio = lock.ratio
        lock.residual = cost
        if lock.residual > lost:
            # The readings left the model (a knot of the drift, a jump): keep the prediction
            # once; the misses'th time in a row, re-lock locally with larger known excursions.
            lock.estimate = predicted
            lock.bad_fits += 1
            if lock.bad_fits >= p.misses:
                lock.recovering = []
            return
        lock.bad_fits = 0
        reads = self.noise.reads_fits(p) and lock.path.shape == u.shape and len(u) >= 2
        residuals = self.rig.slot_residuals(u, lock.path, y) if reads else None
        if self.noise.note_fit(p, cost, residuals):
            self._take_noisy_window()
        lock.drift = bounded(p, drift)
        self.calibration.take_fitted_line(lock.gain_step, lock.level_step)
        # Not wrapped to one period: set-point plus estimate stays the physical delay error, so
        # the model's pulse envelopes are evaluated where the pulses are (wrapped, the set-points
        # would carry the drift's whole cycles, and the residuals grow over a long run).
        lock.estimate = x
        lock.drift = bounded(p, lock.remember(lock.drift, self.loop.step))
        lock.keep_taken(self.loop.step - age.astype(np.int64))
        if p.calibrate:
            self._calibrate(u, lock.path)
        if ratio:
            self.period.correct(p, self.calibration, fitted_ratio)
            self._adopt_optics()

    def _refit_detector(self, x, drift, u, age) -> bool:
        """Fit the detector's line again on the readings since the lock (a lock whose detector
        was fitted by the acquisition only, or never, misfits by the detector's error; near the
        optimum a delay error moves the slot energies only to second order, so they measure the
        gain). Where the power does not pin the level (``power_weight`` 0), only on readings near
        the stack (``lock_refit_power``), for a window at most. Whether the line was fitted."""
        p, since = self.params, self.loop.tick - self.lock.lock_tick
        last = min(max(since, 1), len(u))
        waits = p.power_weight == 0.0 and since < self.window.length
        least = p.lock_refit_power if waits else 0.0
        return self._fit_detector_to(x, drift, u, age, last=last, min_power=least)

    def _recover(self) -> None:
        """A local re-fit of the errors and the drift to the readings since the fit failed,
        from the prediction with the present drift, no drift, and each stage's drift reversed;
        after a full window without success, a global acquisition."""
        p, lock = self.params, self.lock
        lock.estimate = lock.predicted(self.loop.gap)  # this reading's prediction
        readings = lock.recovering
        if len(readings) < p.recover_readings:
            return
        u, y, age = self._window(readings)
        drifts = relock_drifts(lock.drift)
        starts = np.tile(lock.estimate, (len(drifts), 1))
        fits = self._fit_paths(starts, drifts, u, y, age, p.iterations)
        i = int(np.argmin(fits.data_cost))
        x, drift, cost = fits.x[i], fits.drift[i], float(fits.data_cost[i])
        lock.path, lock.objective, lock.ratio = fits.path[i], fits.objective[i], 0.0
        lock.residual = cost
        if lock.residual <= self._tolerance():
            lock.bad_fits = 0
            lock.estimate, lock.drift = x, bounded(p, drift)
            self.window.refill(readings)
            lock.recovering = None
        elif len(readings) >= self.window.length:
            lock.lose()
            self.window.refill(readings)
            self._search_step()

    # ------------------------------------------------------------------ knot test
    def _start_knot_run(self, predicted, u, y, age, ratio=False, spread=False) -> knots.KnotRun:
        """The knot hypotheses on this window, from the prediction and the drift now."""
        noisy, steps = self._noisy(), self.window.steps()
        args = (predicted, self.lock.drift, steps, u, y, age, ratio, spread)
        return knots.start_run(self._fit_run, self.params, noisy, *args)

    def _knot_fit(self, predicted, x, drift, cost, u, y, age, ratio=False, deadline=None):
        """The best of the present fit (x, drift, cost) and the knot hypotheses
        (:func:`.knots.start_run`), all fitted at once; a hypothesis wins only by the knot
        penalty. A test its budget cuts short on a noisy detector is left inconclusive, and while
        they are, most are left out (:meth:`.knots.Knots.skipped`)."""
        noisy = self._noisy()
        if self.knot.skipped(deadline, noisy):
            return x, drift, cost
        run = self._start_knot_run(predicted, u, y, age, ratio)
        run.fits.run(deadline)
        if not self.knot.ran(deadline, noisy):
            return x, drift, cost
        return self._knot_choice(run.fits.result(), x, drift, cost)

    def _knot_choice(self, fits, x, drift, cost):
        """The best of the present fit (x, drift, cost) and a knot test's ``fits``
        (:func:`.knots.choose`), kept as the lock's last path fit."""
        lock = self.lock
        penalty = self._knot_setting("knot_penalty")
        choice = knots.choose(fits, (x, drift, cost), lock.fit_state(), penalty)
        lock.path, lock.objective, lock.ratio = choice.path, choice.objective, choice.ratio
        lock.gain_step, lock.level_step = choice.line
        if choice.won:  # (the drift memory lets go: the fit's drift is the knot's)
            self.knot.won(self.loop.tick)
            lock.let_go()
        return choice.best

    def _advance_knot_run(self, deadline, rows=None) -> None:
        """The knot test under way, on until ``deadline`` or ``rows`` evaluated (one unit at
        least); at its end its winner, if a hypothesis won, is tried on the window now
        (:meth:`_retry_knot`)."""
        run = self.knot.run
        if self.lock.estimate is None or self.lock.recovering is not None:
            self.knot.run = None  # the lock it was to refine is gone
            return
        if not run.fits.run(deadline, rows):
            return
        self.knot.run = None
        winner = knots.spread_winner(run, self._knot_setting("knot_penalty"))
        if winner is not None:
            self._retry_knot(run, *winner)

    def _retry_knot(self, run: knots.KnotRun, best: int, fits) -> None:
        """A knot a spread test found in its (older) window, fitted again on the window now
        against no knot (:func:`.knots.retry`), and taken if it still wins by the penalty."""
        lock, tick = self.lock, self.loop.tick
        u, y, age = self._window()
        ratio = self.period.in_window(tick, len(u))
        now = (self.window.steps(), lock.estimate, lock.drift, u, y, age, ratio)
        settings = (self._knot_setting("knot_iterations"), self._knot_setting("knot_penalty"))
        retry = knots.retry(self._fit_paths, run, best, fits, now, *settings)
        if retry is None:
            return
        lock.path, lock.objective, lock.ratio = retry.path[1], retry.objective[1], retry.ratio[1]
        lock.estimate, lock.drift = retry.x[1], bounded(self.params, retry.drift[1])
        lock.let_go()
        lock.keep_taken(self.loop.step - age.astype(np.int64))
        self.calibration.take_fitted_line(float(retry.gain[1]), float(retry.level[1]))
        self.knot.won(tick)
