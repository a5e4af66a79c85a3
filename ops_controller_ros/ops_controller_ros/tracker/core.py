"""The tracker's state machine: :class:`PhaseTracker` (reset / command / observe / think).

Acquiring (no estimate: :mod:`.acquisition`), tracking (each reading re-fits the window's path,
:mod:`.fit`; a fit that does not explain its readings asks for the knot test, :mod:`.knots`),
recovering (a local re-lock, :mod:`.acquisition`) and the period's moves and calibration
(:mod:`.period`). The package docstring (:mod:`ops_controller_ros.tracker`) describes the method.
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np

from ..calibration import ModelCalibration
from . import fit
from .acquisition import Acquisition
from .knots import KnotJob, KnotTest
from .latency_check import LatencyWatch
from .params import TrackerParams
from .period import PeriodCalibration
from .weights import WeightedStacker, source_noise_weights

FIT_VAR_FITS = 25  # tracking fits whose residuals give the readings' std (their median)
FIT_VAR_MIN = 5  # ... once this many are in
#: No knot test on a window with readings further apart than this many steps (a rig's outage): a
#: walk over the gap explains anything, and a knot cannot be placed in it (over the rig, after a
#: 5 s outage, knots taken on the first readings lost the lock: 2.16 s to be back, not 0.5).
KNOT_MAX_GAP = 10
NOISE_TRIES = 4  # repeats of the first reading to measure the noise, a step apart


def _told_noise(params: TrackerParams, model) -> TrackerParams:
    """The parameters with the detector noise the rig's model implies (its detector noise and
    digitizer, :func:`ops_sim_ros.rig.reading_noise_std`) when that is more than assumed."""
    from ops_sim_ros.rig import reading_noise_std

    noise = 0.0
    if hasattr(model, "trace_adc_bits"):  # the source's noise is weighed per entry (.weights)
        noise = reading_noise_std(replace(model, pulse_amplitude_noise=0.0))
    return replace(params, detector_noise=noise) if noise > params.detector_noise else params


class PhaseTracker(Acquisition, KnotTest, PeriodCalibration, LatencyWatch):
    """Model-based stacking controller (see the module docstring): reset / command / observe."""

    def __init__(
        self,
        model,
        params: TrackerParams | None = None,
        setpoints_fs=None,
        seed=None,
        setpoint_range_fs=None,
        reach_fs=None,
    ):
        """``setpoint_range_fs``: (low (N,), high (N,)) the set-points each line can take (a
        rig's channel limits through its calibration; default: the model's +- actuator range);
        ``reach_fs``: how far the slowest line moves in one reading (None: any distance)."""
        from ops_sim_ros.physics import stacker_from_config
        from ops_sim_ros.rig import lag_gain

        self.model = model
        self.stage = int(model.stage)
        self.params = _told_noise(params or TrackerParams(), model)
        self.calibration = ModelCalibration(model, self.params.calibration_memory)
        self.stacker = stacker_from_config(model)
        floor = max(self.params.detector_noise, self.params.fit_noise_floor)
        self._weights = source_noise_weights(
            self.stage, float(getattr(model, "pulse_amplitude_noise", 0.0)), floor
        )
        if self.params.power_weight < 1.0:
            if self._weights is None:
                self._weights = np.ones(self.stacker.num_slots + 1)
            self._weights[-1] *= self.params.power_weight
        self._weighted_stacker = None  # _fit_stacker's, for the model now
        self.period_fs = model.optical_period_fs
        self.range_cycles = model.actuator_range_cycles
        if setpoint_range_fs is None:
            reach = self.range_cycles * self.period_fs
            setpoint_range_fs = (np.full(self.stage, -reach), np.full(self.stage, reach))
        self.range_fs = tuple(
            np.asarray(r, dtype=np.float64).reshape(-1) for r in setpoint_range_fs
        )
        self.reach_fs = reach_fs
        self.range_moves = 0  # whole-cycle moves off a line's limit (period.py)
        # The rig's latency, as the model says (issue 30): a command acts this many steps late,
        # so a reading is matched to the command in effect then, and a command aims that far.
        self.latency = int(getattr(model, "latency_steps", 0))
        self.latency_told = self.latency
        self.latency_note = None  # why the latency in use is not the told one
        self.latency_changes = 0
        self.latency_checks = 0
        self.latency_costs = {}  # the last check's residual per candidate latency
        # ... and its delay lines' first-order response: a reading is matched to where they are
        lag = float(getattr(model, "actuator_lag_steps", 0.0))
        self.lag_gain = lag_gain(lag) if lag > 0.0 else None
        self._rng = np.random.default_rng(seed)
        # the latency check's own stream: a check leaves the commands' random signs as they were
        self._check_rng = self._rng.spawn(1)[0]
        self.reset(np.zeros(self.stage) if setpoints_fs is None else setpoints_fs)

    # ------------------------------------------------------------------ interface
    def reset(self, setpoints_fs) -> None:
        """Start again from ``setpoints_fs``: forget the estimate and the readings."""
        u = np.asarray(setpoints_fs, dtype=np.float64).reshape(self.stage) / self.period_fs
        self._base = u.copy()  # set-points (cycles) around which the excursions are made
        self._last_command = u.copy()
        # latency > 0: commands on their way, [step it acts at without latency, set-points
        # (cycles), whole-cycle move], and the set-points acting on the delay lines now
        self._in_flight: deque = deque()
        self._acting = u.copy()
        self._position = u.copy()  # the delay lines' positions (actuator_lag_steps > 0)
        self._awaiting = False  # a command was given and its reading has not come yet
        self._window_len = self._fit_window(self._told_noisy())
        self._history: deque = deque(maxlen=self._window_len)
        self.estimate = None  # hidden delay errors now, cycles (None: not acquired; followed
        # continuously from the acquisition's estimate, which is within half a period)
        self.drift = np.zeros(self.stage)  # per step, cycles
        self.residual = float("nan")
        self.acquisitions = 0
        self._recovering = None  # readings since a fit failed, while re-locking locally
        self._bad_fits = 0
        self._noise_var = None  # detector noise variance measured from a repeated reading
        self._noise_tries = 0  # repeated readings that came steps apart (no measure of noise)
        self._noise_first = None  # a noisy first measure, to be confirmed by a second
        self._fit_vars: deque = deque(maxlen=FIT_VAR_FITS)  # residuals of tracking fits
        # noise variances of the tracking fits' residuals, read from their changes from one
        # reading to the next (:meth:`_note_fit_noise`), and whether they found the detector
        # noisy (kept)
        self._white_vars: deque = deque(maxlen=FIT_VAR_FITS)
        self._fits_noisy = False
        self._tick = 0  # readings taken
        self._step = 0  # simulator (or rig) steps up to the latest reading
        self._gap = 1  # steps between the last two readings
        self._unlocked_readings = 0  # readings since the tracker last held a lock
        # of the readings while "locked" (not recovering), the last false_lock_readings: was
        # each below false_lock_power?
        self._low_readings: deque = deque(maxlen=max(self.params.false_lock_readings, 1))
        self.false_locks = 0  # locks dropped for that
        self.calibration_resets = 0
        self.knots = 0  # knot hypotheses taken while tracking
        # knot tests on a noisy detector its budget cut short or left out: no knot taken
        self.knot_tests_cut = 0
        self.knot_tests_spread = 0  # knot tests run over several readings (slice_knot_test)
        self._knot_cut_short = False  # the last knot test run was cut short (knots.py)
        self._knot_skips = 0
        self.hops = 0  # whole-cycle moves made to measure the wavelength
        self._hop = None  # (stage, cycles) of the move in the command just sent
        self._hop_next = 0  # tick of the next move
        self._hop_tick = None  # tick of the reading after the last move
        self._knot_tick = -(10**9)  # tick of the last knot hypothesis taken
        self._lock_tick = 0  # tick of the reading an acquisition locked on
        self._ratio = 0.0
        self._gain_step = 0.0  # the relative gain the last path fit found (lock_gain_walk)
        self._level_step = 0.0  # ... and the offset (lock_offset_walk)
        self._path = np.zeros((0, self.stage))
        self._objective = float("nan")
        self._search = None  # the global search under way (a generator), if any
        self._knot_job = None  # the knot test think() is to run (defer_knot_test)
        self._knot_run = None  # a knot test spread over readings (knots.KnotRun), under way
        self._revise = False  # think() changed the command given: command() gives it anew
        self.last_power = float("nan")
        self._watch_reset()

    def _fit_window(self, noisy: bool) -> int:
        """Readings per fit: ``window``, or on a noisy detector the longer ``noisy_window``."""
        p = self.params
        return max(p.window, p.noisy_window) if noisy else p.window

    @property
    def window_length(self) -> int:
        """The readings each fit takes now (longer once the detector is found noisy)."""
        return self._window_len

    @property
    def locked(self) -> bool:
        return self.estimate is not None

    @property
    def setpoints_fs(self) -> np.ndarray:
        """The set-points the controller aims at (cycles -> fs), without the excursion."""
        return self._base * self.period_fs

    def command(self) -> np.ndarray:
        """Set-points (fs) to apply now. Asked again before the reading (a node re-sending a
        command whose reading did not come), the same set-points: a second call must not draw
        new excursions or undo a whole-cycle move that the first one made (seen over DDS: the
        re-sent command lost its move while the tracker fitted the period on it)."""
        if self._awaiting and not self._revise:
            return self._last_command * self.period_fs
        self._revise = False
        p = self.params
        if self.estimate is not None:
            # aim at the stacking point of the step the command acts at, by the smallest move
            # modulo a period
            target = -(self.estimate + (1 + self.latency) * self.drift)
            self._base = self._base + fit.wrap(target - self._base)
        if self.estimate is None or self._recovering is not None:
            # acquiring, or recovering (excursions around the prediction)
            if self.estimate is None and self._measuring_noise():
                u = self._history[-1][0].copy()  # the first reading twice: the detector's noise
            else:
                signs = self._rng.choice((-1.0, 1.0), size=self.stage)
                u = self._base + p.acquire_dither_cycles * signs
        else:
            moved = self._range_move()
            self._hop = None if moved else self._plan_hop()
            u = self._base + self._hold_dither() * self._excursion(self._tick)
        if self.lag_gain is not None:  # a command that brings the lagging lines there in a step
            u = self._position + (u - self._position) / self.lag_gain
        u = np.clip(u, self.range_fs[0] / self.period_fs, self.range_fs[1] / self.period_fs)
        self._last_command = u
        self._awaiting = True
        self._watch_command(u)
        if self.latency:
            self._in_flight.append([self._step + 1, u.copy(), self._hop])
            self._hop = None
        return u * self.period_fs

    def _command_taken(self, taken: int, expected: int) -> None:
        """The last command (sent after the previous reading, so expected at step ``expected``)
        was taken at step ``taken``: it acts from ``taken`` + latency."""
        if taken <= expected:
            return
        if self._in_flight and self._in_flight[-1][0] == expected:
            self._in_flight[-1][0] = taken
        if self._commands_sent and self._commands_sent[-1][0] == expected:
            self._commands_sent[-1] = (taken, self._commands_sent[-1][1])

    def _reading_setpoints(self):
        """(set-points (cycles), whole-cycle move) that shaped the reading at ``self._step``:
        the last command, or with latency the one in effect ``latency`` steps before; with a
        lag, where the delay lines got to on their way to it."""
        if not self.latency:
            hop, self._hop = self._hop, None
            acting = self._last_command
        else:
            hop = None
            while self._in_flight and self._in_flight[0][0] <= self._step - self.latency:
                _, self._acting, moved = self._in_flight.popleft()
                hop = moved if moved is not None else hop
            acting = self._acting
        if self.lag_gain is None:
            return acting, hop
        for _ in range(min(self._gap, 100)):  # (the steps between readings: the newest command)
            self._position = self._position + self.lag_gain * (acting - self._position)
        return self._position, hop

    def observe(
        self, power: float, pulse_energies=None, steps: int = 1, command_age: int | None = None
    ) -> None:
        """The reading produced by the last :meth:`command`; updates the estimate.

        ``steps``: the simulator (or rig) steps since the previous reading, 1 when every step's
        reading is used (in process, lockstep). A free-running simulator steps every 10 ms
        whether or not the command came: a late command costs a step on the old set-points,
        and the drift moved the delays on by one more step than the reading before suggests.

        ``command_age``: steps from the step that took the last command to this reading's (0:
        this step took it; the nodes read it from ``ops/delays``). With a latency, a command
        acts that many steps after the step that took it, not after the reading it answered:
        a late command told as such is no longer mistaken for a longer latency (over DDS,
        ~13 % late commands made the latency check flip between 1 and 2). None: taken by the
        step after the previous reading (in process, lockstep)."""
        if pulse_energies is None:
            raise ValueError("the tracker needs the detected pulse energies, not only the power")
        y = np.append(np.asarray(pulse_energies, dtype=np.float64).ravel(), float(power))
        if y.size != self.stacker.num_slots + 1 or not np.all(np.isfinite(y)):
            raise ValueError(
                f"expected {self.stacker.num_slots} finite pulse energies and a finite power"
            )
        steps = int(steps)
        if steps < 1:
            raise ValueError(f"steps since the previous reading must be >= 1 (got {steps})")
        self.think(spread=False)  # a deferred knot test nobody ran: its outcome first
        self._awaiting = False
        self.last_power = float(power)
        self._tick += 1
        self._step += steps
        self._gap = steps
        if command_age is not None:
            self._command_taken(self._step - int(command_age), self._step - steps + 1)
        u_now, hop = self._reading_setpoints()
        if self._measuring_noise():
            self._measure_noise(u_now, y, steps)
        reading = (u_now.copy(), y, self._step)
        self._history.append(reading)
        if self._recovering is not None:
            self._recovering.append(reading)
            self._recover()
        elif self.estimate is not None:
            self._track(hop)
        elif len(self._history) == self._window_len or self._search is not None:
            self._search_step()
        self._check_false_lock(float(power))
        self._watch_reading(y)
        self._unlocked_readings = 0 if self.locked else self._unlocked_readings + 1
        if self._unlocked_readings >= self.params.calibration_reset_after:
            self._unlocked_readings = 0
            if self.calibration.reset_detector():
                self.calibration_resets += 1

    def _check_false_lock(self, power: float) -> None:
        """Drop a lock whose readings are mostly low (see ``false_lock_power``): whatever the
        model and its calibration say, a stacker at its optimum reads high. Mostly, not all: a
        wrong lock whose knots and fits jump it about reads high now and then (seen on the
        simulated rig under load: "locked", a knot every 5 readings, 64 % of its readings below
        0.5, and never dropped while the rule asked for 50 low readings in a row)."""
        p = self.params
        if not p.false_lock_readings or not self.locked:
            self._low_readings.clear()
            return
        if self._recovering is not None:
            return  # its own search; neither a good nor a bad reading of the lock
        self._low_readings.append(power < p.false_lock_power)
        window = self._low_readings
        if len(window) < window.maxlen or 2 * sum(window) <= window.maxlen:
            return
        window.clear()
        self.false_locks += 1
        self.estimate = None
        self._search = None
        self._bad_fits = 0
        self.calibration.reset_detector()
        self._history = deque(list(self._history)[-self._window_len :], maxlen=self._window_len)

    # ------------------------------------------------------------------ estimation
    def _window(self, readings=None, raw: bool = False):
        """(set-points (K, N) cycles, readings (K, S + 1), age (K,) steps before the latest) of
        ``readings`` (default: the window); the detected energies corrected by the estimated
        detector gain and offset unless ``raw``."""
        readings = self._history if readings is None else readings
        u = np.stack([h[0] for h in readings])
        y = np.stack([h[1] for h in readings])
        if not raw:
            y = self.calibration.correct(y)
        steps = np.array([h[2] for h in readings], dtype=np.float64)
        age = steps[-1] - steps  # steps before the latest
        return u, y, age

    def _excursion(self, tick: int) -> np.ndarray:
        """The tracking excursion's direction at ``tick`` (N,): ``one`` stage at a time,
        alternating in sign; ``all``: every stage at once, the signs of a row of a Hadamard
        matrix (the rows cycle, so every stage's sign is seen against every other's)."""
        n = self.stage
        out = np.zeros(n)
        if self.params.hold_pattern == "one":
            out[tick % n] = 1.0 if (tick // n) % 2 == 0 else -1.0
            return out
        size = 1 << max(n, 1).bit_length()  # a Hadamard order > n (Sylvester)
        row = tick % size
        cols = np.arange(1, n + 1)  # skip the all-ones column
        bits = np.array([bin(row & c).count("1") & 1 for c in cols])
        return (1.0 - 2.0 * bits) / np.sqrt(n)

    def _drift_prior(self) -> float:
        """How far one window may move the drift estimate (std, cycles per step): looser on a
        clean detector, stiff on a noisy one; there looser again within ``quiet_after``
        readings of a knot taken, and stiffer still while no knot has been taken for as long
        and the knot tests run to their end (see TrackerParams)."""
        p = self.params
        if not self._noisy():
            return p.drift_prior_cycles
        # Quiet only where a knot would be seen: not while the knot tests are cut short (a
        # real-time budget on a slow machine, docs/tracker.md): over DDS, `lab`, the stiff prior
        # with no knot test lost the lock for 8 minutes of 10 when the drift turned.
        since_knot = self._tick - self._knot_tick
        if since_knot < p.quiet_after and p.knotted_drift_prior_cycles:
            return p.knotted_drift_prior_cycles  # the drift's slope changes: follow it
        quiet = since_knot >= p.quiet_after and not self._knot_cut_short
        if quiet and p.quiet_drift_prior_cycles:
            return p.quiet_drift_prior_cycles
        return p.noisy_drift_prior_cycles

    def _hold_dither(self) -> float:
        """The tracking excursion's length: ``hold_dither_cycles``, larger on a noisy detector
        (a reading near the optimum is quadratic in the error, so the excursion must lift its
        signal above the noise: ``noisy_dither_factor`` sqrt(sigma) cycles, 0.03 at sigma =
        0.01). With the all-stage pattern each stage moves by length / sqrt(N) in every reading
        instead of the whole length in one reading of N: the same information per reading and
        the same cost in power (measured: sqrt(N) times the length lost 7 % of the power at
        sigma = 0.01)."""
        noise = self._noise_var_assumed() ** 0.5
        drift = self.params.drift_dither_gain * float(np.max(np.abs(self.drift)))
        return max(
            self.params.hold_dither_cycles, self.params.noisy_dither_factor * noise**0.5, drift
        )

    def _tolerance(self, base: float | None = None) -> float:
        """Mean squared residual that still counts as a fit: the base tolerance plus three times
        the detector's noise variance (:meth:`_noise_var_assumed`)."""
        noise_var = self._noise_var_assumed()
        return (self.params.residual_tolerance if base is None else base) + 3.0 * noise_var

    def _noise_var_assumed(self) -> float:
        """The detector's noise variance the excursion and the tolerance are sized for: the
        assumed one (``detector_noise``), the one measured from the repeated first reading, and
        once the fits found the detector noisy (``fit_noisy_threshold``) the one they found,
        whichever is largest."""
        var = max(self.params.detector_noise**2, self._noise_var or 0.0)
        if self._fits_noisy:
            var = max(var, self._white_var())
        return var

    def _predict(self, x: np.ndarray, u: np.ndarray, age: np.ndarray, drift) -> np.ndarray:
        """Readings (M, K, S + 1) for candidate present errors x (M, N) cycles."""
        return fit.predict(self.stacker, self.period_fs, x, u, age, drift)

    @property
    def _fit_stacker(self):
        """The model as the fits see it: readings weighed per entry (.weights); built once per
        model (the calibration replaces ``self.stacker`` when it adopts new optics)."""
        if self._weights is None:
            return self.stacker
        cached = self._weighted_stacker
        if cached is None or cached.inner is not self.stacker:
            cached = self._weighted_stacker = WeightedStacker(self.stacker, self._weights)
        return cached

    def _weighed(self, y):
        return y if self._weights is None else y * self._weights

    def _cost(self, x, u, y, age, drift) -> np.ndarray:
        return fit.cost(self._fit_stacker, self.period_fs, x, u, self._weighed(y), age, drift)

    def _refine(self, x, u, y, age, drift, iterations: int):
        """:func:`.fit.refine` on the model now (a generator)."""
        y = self._weighed(y)
        return fit.refine(self._fit_stacker, self.period_fs, x, u, y, age, drift, iterations)

    @property
    def measured_noise(self) -> float | None:
        """The detector's noise std measured from the repeated first reading (None before)."""
        return None if self._noise_var is None else self._noise_var**0.5

    @property
    def fit_noise(self) -> float | None:
        """The detector's noise std as the tracking fits find it (:meth:`_note_fit_noise`; the
        median of their last 25 figures), None before the first five."""
        if len(self._white_vars) < FIT_VAR_MIN:
            return None
        return self._white_var() ** 0.5

    def _white_var(self) -> float:
        """The median of the tracking fits' last noise variances (:meth:`_note_fit_noise`)."""
        return float(np.median(self._white_vars))

    @property
    def noisy(self) -> bool:
        """Whether the tracker takes its detector as noisy (told, or measured so)."""
        return self._noisy()

    def _measure_noise(self, u_now, y, steps: int) -> None:
        """The detector's noise from this reading and the one before, if they were taken at the
        same set-points a step apart and differ (:meth:`_measuring_noise`). A noise the tracker
        was not told of that would count (noisy, or at least a third of ``residual_tolerance``
        in variance: it widens the fits' tolerance) is measured once more, and the smaller
        taken: a delay line still moving or a drift between the two inflates it, never deflates
        it (over a rig: 0.0066 on a true 0.0003, then a tracker that fitted a detector gain of
        1.07 and lost the lock; 0.0035, whose tolerance of 4e-5 took fits that walked off the
        peak)."""
        last_u, last_y, _ = self._history[-1]
        diff = y[:-1] - last_y[:-1]
        # (two identical readings are one acquisition read twice, not a detector without
        # noise: seen over the simulated rig, whose optics had not stepped between them, and a
        # scope gives its last record again when no new trigger came)
        if steps == 1 and np.array_equal(last_u, u_now) and np.any(diff):
            var = float(np.mean(diff * diff)) / 2.0
            p = self.params
            counts = var >= min(p.noisy_threshold**2, p.residual_tolerance / 3.0)
            if self._noise_first is not None or not counts or self._told_noisy():
                self._set_noise(var if self._noise_first is None else min(var, self._noise_first))
                return
            self._noise_first = var  # to be confirmed by the next pair
        # else steps apart (their drift is no detector noise; seen over a rig whose tracker was
        # busy starting: 0.034 on a true 0.0003, and a noisy tracker held at 0.94), or one
        # reading given twice
        self._noise_tries += 1
        if self._noise_tries >= NOISE_TRIES and self._noise_first is not None:
            self._set_noise(self._noise_first)

    def _set_noise(self, var: float) -> None:
        self._noise_var = var
        if var >= self.params.noisy_threshold**2:
            self._take_noisy_window()

    def _take_noisy_window(self) -> None:
        """Fits take the noisy detector's longer window from the next reading on."""
        self._window_len = self._fit_window(True)
        self._history = deque(self._history, maxlen=self._window_len)

    def _measuring_noise(self) -> bool:
        """Whether the detector's noise is still to be measured: the first reading is repeated
        (:meth:`command`) until two readings at the same set-points come a step apart, at
        most ``NOISE_TRIES`` times (then it stays unmeasured: taken as clean unless told)."""
        return self._noise_var is None and bool(self._history) and self._noise_tries < NOISE_TRIES

    def _told_noisy(self) -> bool:
        """A detector noise assumed of at least ``told_noisy_threshold``, or a source told
        noisy (``pulse_amplitude_noise``: it moves the stacked slot, which the fits lean on;
        medium, 1 % pulse noise, tuning seeds: 0.950, worst 0.26, against 0.993, worst 0.97,
        with the noisy settings; docs/tracker.md)."""
        p = self.params
        source = float(getattr(self.model, "pulse_amplitude_noise", 0.0)) > 0.0
        return source or p.detector_noise >= p.told_noisy_threshold

    def _noisy(self) -> bool:
        """Told noisy (:meth:`_told_noisy`), a noise measured of at least ``noisy_threshold``,
        or found noisy by the tracking fits (:meth:`_note_fit_noise`)."""
        measured = self._noise_var or 0.0
        return self._told_noisy() or measured >= self.params.noisy_threshold**2 or self._fits_noisy

    def _note_fit_noise(self, u, y) -> None:
        """The detector's noise as the tracking fit of the window (u, y) just taken sees it, and
        the detector taken as noisy from then on (with the longer window) once the median of
        the last ``FIT_VAR_FITS`` such figures reaches ``fit_noisy_threshold`` (squared).

        The figure is half the mean squared change of the slot energies' residuals from one
        reading to the next, at the fitted path: a detector's noise is new in every reading,
        while a misfit of the model changes slowly. The residuals' own level would not tell
        them apart: on a clean detector in extreme mode some episodes misfit by 1-2e-4 (std)
        for hundreds of readings, more in a knot's wake; their changes stay below 1e-4 (20
        seeds x 300 readings), and read a noise of 5e-4 as 4.4-5.3e-4."""
        threshold = self.params.fit_noisy_threshold
        if self._noisy() or not threshold:
            return  # (one told or measured noisy keeps its sizing)
        if self._path.shape != u.shape or len(u) < 2:
            return
        residual = self.stacker.evaluate((u + self._path) * self.period_fs).slot_energies
        change = np.diff(residual - y[:, :-1], axis=0)
        self._white_vars.append(float(np.mean(change * change)) / 2.0)
        if len(self._white_vars) < FIT_VAR_FITS:
            return  # (the median of fewer, even of 5 at twice the threshold, took knot wakes)
        if self._white_var() >= threshold**2:
            self._fits_noisy = True
            self._take_noisy_window()

    def _reading_sd(self) -> float:
        """The std of a reading about the model that the path fits assume: ``fit_noise_floor``
        plus the largest of the detector noise assumed (``detector_noise``), the noise measured
        from the repeated first reading where it makes the detector noisy (``noisy_threshold``),
        and the median mean squared residual of the last ``FIT_VAR_FITS`` tracking fits (the
        model's misfit as the fits find it; before those, the lock tolerance plus the measured
        noise). Weighting every reading by the lock tolerance plus the measured noise (~1e-6
        in extreme mode, where the "noise" of the repeated reading is the drift between the two)
        let the random walk absorb a knot of the drift for three or four readings (extreme,
        `ops-bench tracker-knots` at commit 51e857d: 92.7 % locked against 96.5 % with the fits'
        own residuals; docs/tracker.md). On a noisy detector the fits' residuals alone are too
        small (the path follows part of the noise) and the measured noise is kept."""
        p = self.params
        measured = self._noise_var or 0.0
        if len(self._fit_vars) >= FIT_VAR_MIN:
            var = float(np.median(self._fit_vars))
        else:
            var = p.residual_tolerance + measured
        if self._noisy():
            var = max(var, measured)
        return (p.fit_noise_floor**2 + max(var, p.detector_noise**2)) ** 0.5

    def _bounded(self, drift: np.ndarray) -> np.ndarray:
        """A fitted drift as the tracker takes it: within +- ``max_drift_cycles``."""
        limit = self.params.max_drift_cycles
        return np.clip(drift, -limit, limit)

    def _walk_sigma(self) -> float:
        w = self.params.walk_cycles
        return max(6.0 * self.model.jitter_sigma_cycles, 1e-4) if w is None else w

    def _fit_path(
        self, x_now, drift, u, y, age, iterations: int, drift_prior=None, ratio=False, deadline=None
    ):
        """Moving-horizon fit of the window: the errors at every reading X (K, N) and the drift
        mu (N,), most probable given the readings (std sqrt(tolerance + noise)), a random walk
        between readings (X_k - X_k-1 - mu, std ``walk``) and the drift's prior (the present
        estimate, std ``drift_prior_cycles``). Starts from x_now (the errors at the latest
        reading) and the drift; returns (x at the latest reading, mu, mean squared residual of
        the readings), and leaves the fitted path and the whole cost in ``self._path`` and
        ``self._objective``.

        ``ratio``: also fit r, the model's period over the true one minus 1 (a reading's phase is
        u + r (u - mean u) + X): identifiable when the window holds a whole-cycle move. It is
        left in ``self._ratio`` and the returned x is the error as the model sees it (r applied
        at the latest reading)."""
        prior = None if drift_prior is None else np.asarray(drift_prior)[None]
        fit = self._fit_paths(
            x_now[None], drift[None], u, y, age, iterations, prior, ratio, deadline=deadline
        )
        self._path, self._objective, self._ratio = fit.path[0], fit.objective[0], fit.ratio[0]
        self._gain_step, self._level_step = float(fit.gain[0]), float(fit.level[0])
        return fit.x[0], fit.drift[0], float(fit.data_cost[0])

    def _fit_paths(self, *args, deadline=None, **kwargs) -> fit.PathFits:
        """:meth:`_fit_path` for M starts at once (the arguments of :meth:`_path_fit_run`), run
        to its end or until ``deadline`` (:func:`.fit.fit_paths`): the hypotheses of a knot or
        a recovery cost one batched evaluation of the physics per iteration instead of one
        each."""
        run = self._path_fit_run(*args, **kwargs)
        run.run(deadline)
        return run.result()

    def _path_fit_run(
        self,
        x_now,
        drift,
        u,
        y,
        age,
        iterations: int,
        drift_prior=None,
        ratio=False,
        knots=None,
        prune=None,
        path0=None,
        chunk=None,
    ) -> fit.PathFitRun:
        """M starts (x_now, drift: (M, N); drift_prior: (M, N) or None) of a path fit, not yet
        run: a :class:`.fit.PathFitRun` (which describes ``knots``, ``prune`` and ``path0``) to
        run an iteration at a time (a knot test spread over readings). The readings weigh by
        :meth:`_reading_sd`, the walk by :meth:`_walk_sigma`."""
        p = self.params
        if drift_prior is None:
            drift_prior = np.full(drift.shape, self._drift_prior())
        return fit.PathFitRun(
            self._fit_stacker,
            self.period_fs,
            x_now,
            drift,
            u,
            self._weighed(y),
            age,
            iterations,
            r_sd=self._reading_sd(),
            w_sd=self._walk_sigma(),
            drift_prior=drift_prior,
            ratio=ratio,
            knots=knots,
            knot_prior=p.knot_prior_cycles,
            prune=prune,
            path0=path0,
            chunk=chunk,
            gain_prior=self._gain_prior(),
            level_prior=self._level_prior(),
        )

    def _gain_prior(self) -> float:
        """The prior std of the gain a path fit fits: ``lock_gain_walk`` within a window of an
        acquisition's lock, where the power does not pin the slot energies' level
        (``power_weight`` 0) and the detector is calibrated; else 0 (none fitted)."""
        p = self.params
        if not p.calibrate or p.power_weight > 0.0:
            return 0.0
        return p.lock_gain_walk if self._tick - self._lock_tick <= self._window_len else 0.0

    def _level_prior(self) -> float:
        """The prior std of the offset a path fit fits: ``lock_offset_walk`` where and when
        :meth:`_gain_prior` fits the gain; else 0 (none fitted)."""
        return self.params.lock_offset_walk if self._gain_prior() > 0.0 else 0.0

    def _track(self, hop=None) -> None:
        """Re-fit the window's path of errors and the drift from the prediction (``hop``: the
        whole-cycle move of the last command, if any: it measures the period, and its step is not
        taken for a knot)."""
        p = self.params
        u, y, age = self._window()
        if hop is not None:
            self._hop_tick = self._tick
        # a window that holds a whole-cycle move (the reading before it too) measures the period
        ratio = self._hop_tick is not None and self._tick - self._hop_tick <= len(u) - 2
        predicted = self.estimate + self._gap * self.drift  # the errors now, by the drift
        x, drift, cost = self._fit_path(
            predicted, self.drift, u, y, age, p.track_iterations, ratio=ratio
        )
        if (
            hop is None
            and p.knot_prior_cycles > 0
            and float(np.max(-np.diff(age), initial=0.0)) <= KNOT_MAX_GAP
            and self._detector_settled()
            and (
                cost > self._tolerance(p.knot_tolerance)
                or self._walk_jump() > self._knot_setting("knot_walk_sigmas")
            )
        ):
            # A knot of one stage's drift? Fit the window under one hypothesis per stage, knot
            # position and side (_knot_fit), and keep the best if it explains the readings
            # clearly better (a wrong drift otherwise pulls every stage's estimate off within a
            # few readings).
            # A window with a whole-cycle move fits the period too: a model period off by r
            # moves the phase by 2r at the move, which is no knot (seen: medium, wavelength
            # -2 %, every move taken for a knot until a stage "drifted" a cycle per step).
            job = (predicted, x, drift, cost, u, y, age, ratio)
            if p.defer_knot_test:
                # Answer first: the next command aims by the plain fit, and think() (or the
                # next observe) runs the test and finishes the reading.
                self._knot_job = KnotJob(job, self.drift, self._path, self._objective, self._ratio)
                if cost <= self._tolerance(p.lost_tolerance):
                    self.estimate, self.drift = x, self._bounded(drift)
                else:
                    self.estimate = predicted
                return
            deadline = self._knot_deadline()
            x, drift, cost = self._knot_fit(*job, deadline=deadline)
            self._finish_track(predicted, x, drift, cost, u, y, age, ratio, deadline)
            return
        self._finish_track(predicted, x, drift, cost, u, y, age, ratio)

    def _detector_settled(self) -> bool:
        """Whether a misfit may be a knot: not before the detector's gain and offset are first
        fitted (``calibrate``; five tracked readings after a start or a reset). Until then a
        lock's readings misfit by the detector's error (a rig's calibrated full scale 0.4-2 %
        off), and a knot test explains that as a knot: one taken at the first reading after the
        lock that came a step late put the drift wrong and lost the lock (simulated rig, hard,
        gain 2 % off, 15 % of the commands late; docs/rig.md).

        Nor while the fit is an acquisition's only (``detector_provisional``): fitted to its low
        readings, where a delay error moves the slot energies as much as the gain does, it was
        seen 2 % off on the simulated rig (1.022 against 1.003) and 6 % in process (0.939 against
        1.000): the lock then misfit, its knots were false, and it was lost. The first locked
        reading fits the detector again (:meth:`_finish_track`)."""
        cal = self.calibration
        return not self.params.calibrate or (cal.detector_fitted and not cal.detector_provisional)

    def _finish_track(self, predicted, x, drift, cost, u, y, age, ratio, deadline=None) -> None:
        """Take a tracking fit (x, drift, cost) of the window (u, y, age): iterate further if
        its readings left the model (until ``deadline``, if given), count a bad fit (keep the
        prediction) or take it."""
        p = self.params
        fitted_ratio = self._ratio
        lost = self._tolerance(p.lost_tolerance)
        refitted = False
        unsettled = not self._detector_settled()
        if unsettled and (cost > lost or self.calibration.detector_provisional):
            # A lock whose detector was never fitted, or fitted by the acquisition only: its
            # misfit may be the detector's (a gain 2 % off misfits a lock by 1e-5, past
            # lost_tolerance, while the low readings of the acquisition fitted). Fitted again
            # on the readings since the lock (near the optimum a delay error moves the slot
            # energies only to second order: they measure the gain); the fit below then takes
            # the corrected readings, as the acquisition does when it does not fit. Where the
            # power does not pin the level (power_weight 0), only on readings near the stack
            # (``lock_refit_power``): over DDS one at 0.91 gave a gain 3 % off, and the lock
            # was lost; until such a reading comes the fit stays provisional (no knot test), for
            # a window at most (slot energies that read low never show such a power). Weighed
            # in, the power corrects such a gain in the fits (there the filter moved 14 of 100
            # `lab` episodes, by -0.00014 in all).
            since_lock = min(max(self._tick - self._lock_tick, 1), len(u))
            waits = p.power_weight == 0.0 and self._tick - self._lock_tick < self._window_len
            least = p.lock_refit_power if waits else 0.0
            refitted = self._fit_detector_to(x, drift, u, age, last=since_lock, min_power=least)
            if refitted:
                u, y, age = self._window()
        if cost > lost or refitted:  # a knot of the drift, a fast walk: iterate further
            x, drift, cost = self._fit_path(
                predicted, self.drift, u, y, age, p.iterations, ratio=ratio, deadline=deadline
            )
            fitted_ratio = self._ratio
        self.residual = cost
        if self.residual > lost:
            # The readings left the model (a knot of the drift, a jump): keep the prediction
            # once; the second time in a row, re-lock locally with larger known excursions.
            self.estimate = predicted
            self._bad_fits += 1
            if self._bad_fits >= p.misses:
                self._recovering = []
            return
        self._bad_fits = 0
        self._fit_vars.append(cost)
        self._note_fit_noise(u, y)
        self.drift = self._bounded(drift)
        self.calibration.take_fitted_line(self._gain_step, self._level_step)
        # Not wrapped to one period: the estimate follows the delays continuously, so set-point
        # plus estimate stays the physical delay error (near 0 at the lock) and the model's pulse
        # envelopes are evaluated where the pulses are. Wrapped, the set-points carried the
        # drift's whole cycles and the model saw the envelopes that many cycles apart: after a
        # few thousand steps of hard mode's drift (and each whole-cycle move) the residuals grew
        # to the knot tolerance and knot hypotheses fired hundreds of times (hard, continuous
        # 30,000 steps x 2 seeds: 97.96 % of readings >= 0.95 wrapped, 100 % unwrapped;
        # docs/results.md, continuous table).
        self.estimate = x
        if p.calibrate:
            self._calibrate(u, self._path)
        if ratio:
            self._correct_period(fitted_ratio)
