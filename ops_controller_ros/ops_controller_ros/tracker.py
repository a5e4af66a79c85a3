"""Model-based phase retrieval with drift tracking: a stacking controller that needs no training.

The controller knows the stacker's physics (:class:`ops_sim_ros.physics.PulseStacker` built from
the *nominal* configuration: stage, wavelength, pulse width, detector) and estimates the hidden
delay errors x (one per stage, the part of each applied delay it did not command) from the stream
of (commanded set-points u_k, detected slot energies and power y_k) pairs:

    y_k ~ f(u_k + x_k),    x_k = x_t - (t - k) mu     (mu: each stage's drift per step)

One reading does not determine x (different delay vectors give the same slot energies, and x and
-x always do). The controller's own known moves are the phase diversity that makes the fit unique:
it fits x to the last ``window`` readings, taken at different set-points, by Levenberg-Marquardt
in units of optical cycles, and then commands u = -(x + mu) (the stacking point, with the drift
fed forward) plus a small known excursion.

* **Acquire** (no estimate): excursions of ``acquire_dither_cycles`` with random signs around the
  present set-points; once ``window`` readings are in, a global search scores ``candidates``
  random delay vectors over one period per stage against them and refines the ``refine`` best
  (with each stage's drift as well where a static fit does not explain the window). The estimate
  is accepted only when its residual is within ``residual_tolerance`` (plus the expected detector
  noise); otherwise the controller keeps its set-points, keeps dithering and searches again (it
  never moves on an estimate it does not trust).
* **Track**: each reading re-fits the window as a path, a moving-horizon estimate: the errors at
  every reading of the window and one drift per stage, most probable given the readings, a random
  walk between readings (``walk_cycles`` per step; by default six times the model's jitter, so a
  rig noisier than nominal is still followed) and the drift's present estimate
  (``drift_prior_cycles``). The excursion is ``hold_dither_cycles`` on one stage at a time,
  alternating in sign, so the window stays diverse and the sign of a small error stays visible.
* **Recover**: ``misses`` fits in a row whose readings' residual exceeds ``lost_tolerance`` (a
  knot of the drift, a jump; a single one keeps the prediction) switch to acquisition-sized
  excursions around the prediction; after ``recover_readings`` readings the path is re-fitted to
  them from the present drift, no drift, and each stage's drift reversed; if that fails for a
  whole window, a global acquisition follows.
* **Knots** (a stage's drift changes slope): a tracking fit that does not explain its readings
  is tried again under one hypothesis per stage, knot position and side (``knot_*`` parameters).
  With ``defer_knot_test`` (the node's default) that test waits until the command is out:
  :meth:`PhaseTracker.think` runs it within ``knot_budget_ms`` and tells the caller when the
  command it gave should be revised.

Detector noise: the first two readings of an acquisition are taken at the same set-points; their
difference measures the noise variance, which widens the residual tolerance and the tracking
excursion (``detector_noise`` gives a floor when the noise is known); from a noise std of
``noisy_threshold`` on, fits take ``noisy_window`` readings instead of ``window``.

Assumptions, stated: the landscape is periodic in each delay with the optical period (the envelope
walk-off of a few cycles against a pulse of hundreds of fs is ignored), the random walk of the
delays over one window is small against the excursions, and detector noise is Gaussian with std
``detector_noise`` (0: noise-free readings; a residual floor is kept anyway). A model that does not
fit (a wrong wavelength or pulse width) raises the residual: the tolerance scales with the
readings' own spread, and the controller then falls back to acquiring rather than running away.
Set-points always move by the smallest step that reaches the target modulo one period and stay
within the actuator range.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import asdict, dataclass, replace
from typing import NamedTuple

import numpy as np

from .calibration import ModelCalibration


@dataclass(frozen=True)
class TrackerParams:
    window: int = 7  # readings per fit (>= 2: the phase diversity)
    # On a noisy detector (noise std, assumed or measured, >= noisy_threshold) a fit takes
    # max(window, noisy_window) readings: more readings average the noise, while a short window
    # follows the drift's knots sooner (measured: docs/tracker.md, issue 20).
    noisy_window: int = 10
    noisy_threshold: float = 0.005
    acquire_dither_cycles: float = 0.02  # excursion per stage while acquiring (actuator size)
    hold_dither_cycles: float = 0.012  # excursion while tracking (its length over the stages)
    hold_pattern: str = "all"  # excursion: one stage at a time, or all at once (Hadamard)
    # A fast drift needs a stronger probe (a knot must show in the next reading): the excursion
    # is at least this many times the fastest stage's estimated drift per step.
    drift_dither_gain: float = 2.0
    candidates: int = 512  # random delay vectors scored by the global search
    refine: int = 8  # best candidates refined by Levenberg-Marquardt
    iterations: int = 12  # LM iterations of a global refinement
    track_iterations: int = 3  # LM iterations per reading while tracking
    walk_cycles: float | None = None  # random walk per step allowed (None: 6x the model's jitter)
    drift_prior_cycles: float = 0.004  # how far one window may move the drift estimate (std)
    noisy_drift_prior_cycles: float = 0.002  # ... on a noisy detector (docs/tracker.md)
    # The fastest drift the tracker believes, cycles per step (a fit beyond is clipped): on a
    # periodic landscape a drift near a cycle per step reads like none (seen: a stage's drift
    # estimate run up to 1.0 by knot hypotheses on a model 2 % off; extreme drifts <= 0.015).
    max_drift_cycles: float = 0.1
    residual_tolerance: float = 1e-6  # mean squared residual that counts as a fit (to lock)
    # The least std of a reading about the model that the path fits assume (normalized
    # energies), added to what the fits' own residuals show (the model's accuracy on a clean
    # detector is ~1e-5): the readings' weight against the random walk and the drift prior.
    fit_noise_floor: float = 3e-4
    lost_tolerance: float = 1e-5  # mean squared residual of a tracking fit that counts as lost
    detector_noise: float = 0.0  # assumed std of the detector noise (normalized energies)
    misses: int = 3  # bad fits in a row before recovering
    # Knots of the drift (a stage's slope changes): a tracking fit whose residual exceeds
    # knot_tolerance (or whose path jumps, knot_walk_sigmas) is tried again under one hypothesis
    # per stage, knot position (the window's last knot_readings steps) and side: from the knot
    # on, that stage's drift changes by a variable with prior std knot_prior_cycles (0: never
    # try); a hypothesis is taken if its whole cost plus knot_penalty is the lowest. The prior
    # keeps the hypotheses off the mirror images of a change (a path that reads the same with
    # the change's sign turned, at twice its size): extreme, seeds 1000 and 1001 x 3000 steps
    # of scripts/tracker_knots.py, 96.0-96.5 % locked with 0.03, 97.6-97.8 % with 0.015.
    knot_tolerance: float = 1e-6
    knot_prior_cycles: float = 0.015
    knot_start_cycles: float = 0.02  # the knot fits start this far off the prediction
    knot_readings: int = 3  # a knot is looked for in the window's last this many steps
    knot_iterations: int = 6  # LM iterations of the knot hypotheses (30 starts at N = 5)
    noisy_knot_iterations: int = 12  # ... on a noisy detector (noisy readings converge slower)
    # After knot_prune_after iterations only the knot_keep best hypotheses iterate on (0: all):
    # the Jacobians of the losing hypotheses are most of the knot test's compute.
    knot_prune_after: int = 2
    knot_keep: int = 0
    # Compute allowed to the knot test, ms (0: all its iterations): a rig steps on its own
    # clock, and a knot test's outcome is worth most before the next step (the node: 4 ms).
    knot_budget_ms: float = 0.0
    knot_walk_sigmas: float = 2.0  # a path step this far off the drift (walk stds) tries knots
    knot_penalty: float = 4.0  # a knot hypothesis wins if its cost + this is the lowest
    # ... on a noisy detector (noise std >= noisy_threshold) the knot test fires on the noise
    # far more often, and a hypothesis must win by this much (measured in docs/tracker.md)
    noisy_knot_penalty: float = 8.0
    # Answer first, test for knots after: the command after a suspicious reading aims by the
    # plain fit and the knot test runs once it is out (think()), its outcome acting from the
    # next command. In real time a knot test (5-15 ms) does not fit before a 100 Hz rig's next
    # step: done first, the command came a step late, exactly after the knots (docs/tracker.md).
    defer_knot_test: bool = False
    recover_readings: int = 4  # readings after a failed fit before a local re-fit
    acquire_drift: bool = True  # fit each stage's drift too when a static fit fails
    step_budget_ms: float = 0.0  # global search per reading (0: all in the reading that starts it)
    calibrate: bool = True  # estimate the detector's gain and offset online
    calibrate_optics: bool = False  # estimate wavelength and pulse width too (experimental)
    calibration_every: int = 25  # tracking readings between updates of wavelength and pulse width
    calibration_memory: float = 500.0  # readings over which the calibration statistics are kept
    # Readings without lock after which the detector's gain and offset go back to nominal: a fit
    # to a wrong estimate, or to readings that did not belong together (a starved machine), must
    # not keep the tracker from ever locking again (seen: gain 0.56 on a true 1.0).
    calibration_reset_after: int = 500
    # A "lock" whose readings stay below false_lock_power for false_lock_readings in a row is no
    # lock: the estimate is dropped, the detector calibration goes back to nominal and the
    # tracker acquires again (0: never). Seen over DDS in extreme mode: a wrong estimate that the
    # detector gain's fit followed to its bound (gain 20 on a true 1.0), "locked" at P_N 0.02 for
    # 20,000 readings.
    false_lock_power: float = 0.5
    false_lock_readings: int = 50
    # Wavelength from known whole-cycle moves: every hop_every tracking readings one stage's
    # set-point moves by hop_cycles periods of the model (the landscape repeats, so the lock
    # stays where the model is right); a model period off by a fraction r moves that stage's
    # phase by hop_cycles * r, which the path fits of the next readings measure (r is fitted
    # with the path), and the wavelength is corrected by hop_gain of it per fit (0: no moves).
    # A move waits for a clean lock (no knot in the window, a reading >= 0.98, the stage's drift
    # < 0.005 cycles per step).
    hop_every: int = 10
    hop_cycles: int = 2
    hop_gain: float = 0.05  # per fit of a window that holds a move (about 6 fits per move)

    def __post_init__(self):
        checks = (
            ("window", self.window >= 2, ">= 2"),
            ("noisy_window", self.noisy_window >= 2, ">= 2"),
            ("noisy_threshold", self.noisy_threshold > 0, "> 0"),
            ("acquire_dither_cycles", 0 < self.acquire_dither_cycles <= 0.25, "in (0, 0.25]"),
            ("hold_dither_cycles", 0 <= self.hold_dither_cycles <= 0.25, "in [0, 0.25]"),
            ("hold_pattern", self.hold_pattern in ("one", "all"), "one or all"),
            ("drift_dither_gain", 0 <= self.drift_dither_gain <= 10, "in [0, 10]"),
            ("candidates", self.candidates >= 1, ">= 1"),
            ("refine", 1 <= self.refine <= self.candidates, "in [1, candidates]"),
            ("iterations", self.iterations >= 1, ">= 1"),
            ("track_iterations", self.track_iterations >= 1, ">= 1"),
            ("walk_cycles", self.walk_cycles is None or self.walk_cycles > 0, "> 0 or None"),
            ("drift_prior_cycles", self.drift_prior_cycles > 0, "> 0"),
            ("noisy_drift_prior_cycles", self.noisy_drift_prior_cycles > 0, "> 0"),
            ("max_drift_cycles", 0 < self.max_drift_cycles <= 0.5, "in (0, 0.5]"),
            ("residual_tolerance", self.residual_tolerance > 0, "> 0"),
            ("detector_noise", self.detector_noise >= 0, ">= 0"),
            ("misses", self.misses >= 1, ">= 1"),
            ("knot_tolerance", self.knot_tolerance > 0, "> 0"),
            ("knot_prior_cycles", self.knot_prior_cycles >= 0, ">= 0"),
            ("knot_readings", self.knot_readings >= 1, ">= 1"),
            ("knot_iterations", self.knot_iterations >= 1, ">= 1"),
            ("knot_prune_after", self.knot_prune_after >= 0, ">= 0"),
            ("knot_keep", self.knot_keep >= 0, ">= 0"),
            ("knot_budget_ms", self.knot_budget_ms >= 0, ">= 0"),
            ("noisy_knot_iterations", self.noisy_knot_iterations >= 1, ">= 1"),
            ("fit_noise_floor", self.fit_noise_floor > 0, "> 0"),
            ("noisy_knot_penalty", self.noisy_knot_penalty >= 0, ">= 0"),
            ("recover_readings", 2 <= self.recover_readings <= self.window, "in [2, window]"),
            ("step_budget_ms", self.step_budget_ms >= 0, ">= 0"),
            ("calibration_every", self.calibration_every >= 1, ">= 1"),
            ("hop_every", self.hop_every >= 0, ">= 0"),
            ("hop_cycles", 1 <= self.hop_cycles <= 10, "in [1, 10]"),
            ("hop_gain", 0 < self.hop_gain <= 1, "in (0, 1]"),
            ("calibration_memory", self.calibration_memory >= 1, ">= 1"),
            ("calibration_reset_after", self.calibration_reset_after >= 1, ">= 1"),
            ("false_lock_power", 0.0 <= self.false_lock_power < 1.0, "in [0, 1)"),
            ("false_lock_readings", self.false_lock_readings >= 0, ">= 0"),
        )
        for name, ok, allowed in checks:
            if not ok:
                raise ValueError(f"{name} must be {allowed} (got {getattr(self, name)!r})")

    def to_dict(self) -> dict:
        return asdict(self)


FIT_VAR_FITS = 25  # tracking fits whose residuals give the readings' std (their median)
FIT_VAR_MIN = 5  # ... once this many are in
SEARCH_CHUNK = 128  # candidates scored per unit of the global search
MAX_HOP_RATIO = 0.05  # largest period error one fit may report (relative)
HOP_RATIO_PRIOR = 0.05  # prior std of the period error fitted over a window with a move
HOP_POWER = 0.98  # a whole-cycle move waits for a reading at least this good
HOP_MAX_DRIFT = 0.005  # ... and for a stage drifting slower than this (cycles per step)
HOP_GAIN_MOVES = 20.0  # the period correction's gain halves after this many moves ...
HOP_GAIN_FLOOR = 0.05  # ... and falls no lower than this share of hop_gain


class _KnotJob(NamedTuple):
    """A knot test left for :meth:`PhaseTracker.think`: the arguments of ``_knot_fit`` and the
    tracker's state before the answer (the plain fit's path, objective and period error)."""

    fit: tuple  # (predicted, x, drift, cost, u, y, age, ratio)
    drift_before: np.ndarray
    path: np.ndarray
    objective: float
    ratio: float


@dataclass(frozen=True)
class PathFits:
    """M moving-horizon fits (:meth:`PhaseTracker._fit_paths`): errors at the latest reading
    x (M, N), drift (M, N), mean squared residual of the readings (M,), the path (M, K, N), the
    whole normalized cost (M,) and the fitted period error r (M,; zeros when not fitted)."""

    x: np.ndarray
    drift: np.ndarray
    data_cost: np.ndarray
    path: np.ndarray
    objective: np.ndarray
    ratio: np.ndarray


def _wrap(cycles):
    """Reduce to [-1/2, 1/2) cycle."""
    return cycles - np.floor(cycles + 0.5)


def _told_noise(params: TrackerParams, model) -> TrackerParams:
    """The parameters with the detector noise the rig's model implies (its detector noise and
    digitizer, :func:`ops_sim_ros.rig.reading_noise_std`) when that is more than assumed."""
    from ops_sim_ros.rig import reading_noise_std

    noise = reading_noise_std(model) if hasattr(model, "trace_adc_bits") else 0.0
    return replace(params, detector_noise=noise) if noise > params.detector_noise else params


class PhaseTracker:
    """Model-based stacking controller (see the module docstring): reset / command / observe."""

    def __init__(self, model, params: TrackerParams | None = None, setpoints_fs=None, seed=None):
        from ops_sim_ros.physics import stacker_from_config
        from ops_sim_ros.rig import lag_gain

        self.model = model
        self.stage = int(model.stage)
        self.params = _told_noise(params or TrackerParams(), model)
        self.calibration = ModelCalibration(model, self.params.calibration_memory)
        self.stacker = stacker_from_config(model)
        self.period_fs = model.optical_period_fs
        self.range_cycles = model.actuator_range_cycles
        # The rig's latency, as the model says (issue 30): a command acts this many steps late,
        # so a reading is matched to the command in effect then, and a command aims that far.
        self.latency = int(getattr(model, "latency_steps", 0))
        # ... and its delay lines' first-order response: a reading is matched to where they are
        lag = float(getattr(model, "actuator_lag_steps", 0.0))
        self.lag_gain = lag_gain(lag) if lag > 0.0 else None
        self._rng = np.random.default_rng(seed)
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
        noisy = self.params.detector_noise >= self.params.noisy_threshold
        self._window_len = self._fit_window(noisy)
        self._history: deque = deque(maxlen=self._window_len)
        self.estimate = None  # hidden delay errors now, cycles (None: not acquired; followed
        # continuously from the acquisition's estimate, which is within half a period)
        self.drift = np.zeros(self.stage)  # per step, cycles
        self.residual = float("nan")
        self.acquisitions = 0
        self._recovering = None  # readings since a fit failed, while re-locking locally
        self._bad_fits = 0
        self._noise_var = None  # detector noise variance measured from a repeated reading
        self._fit_vars: deque = deque(maxlen=FIT_VAR_FITS)  # residuals of tracking fits
        self._tick = 0  # readings taken
        self._step = 0  # simulator (or rig) steps up to the latest reading
        self._gap = 1  # steps between the last two readings
        self._unlocked_readings = 0  # readings since the tracker last held a lock
        self._low_readings = 0  # readings in a row below false_lock_power while "locked"
        self.false_locks = 0  # locks dropped for that
        self.calibration_resets = 0
        self.knots = 0  # knot hypotheses taken while tracking
        self.hops = 0  # whole-cycle moves made to measure the wavelength
        self._hop = None  # (stage, cycles) of the move in the command just sent
        self._hop_next = 0  # tick of the next move
        self._hop_tick = None  # tick of the reading after the last move
        self._knot_tick = -(10**9)  # tick of the last knot hypothesis taken
        self._ratio = 0.0
        self._path = np.zeros((0, self.stage))
        self._objective = float("nan")
        self._search = None  # the global search under way (a generator), if any
        self._knot_job = None  # the knot test think() is to run (defer_knot_test)
        self._revise = False  # think() changed the command given: command() gives it anew
        self.last_power = float("nan")

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
            self._base = self._base + _wrap(target - self._base)
        if self.estimate is None or self._recovering is not None:
            # acquiring, or recovering (excursions around the prediction)
            if self.estimate is None and len(self._history) == 1 and self._noise_var is None:
                u = self._history[0][0].copy()  # the first reading twice: the detector's noise
            else:
                signs = self._rng.choice((-1.0, 1.0), size=self.stage)
                u = self._base + p.acquire_dither_cycles * signs
        else:
            self._hop = self._plan_hop()
            u = self._base + self._hold_dither() * self._excursion(self._tick)
        if self.lag_gain is not None:  # a command that brings the lagging lines there in a step
            u = self._position + (u - self._position) / self.lag_gain
        u = np.clip(u, -self.range_cycles, self.range_cycles)
        self._last_command = u
        self._awaiting = True
        if self.latency:
            self._in_flight.append([self._step + 1, u.copy(), self._hop])
            self._hop = None
        return u * self.period_fs

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

    def _plan_hop(self):
        """A whole-cycle move of one stage's set-point now, if one is due: (stage, cycles)."""
        p = self.params
        if (
            not p.hop_every
            or self._bad_fits
            or self._knot_job is not None
            or self._tick < self._hop_next
        ):
            return None
        # only on a clean lock: not right after a knot of the drift, not on a low reading
        if self._tick - self._knot_tick < self._window_len or not self.last_power >= HOP_POWER:
            return None
        j = self.hops % self.stage
        if abs(self.drift[j]) >= HOP_MAX_DRIFT:  # a fast drift: its knots cost more than a hop
            return None
        k = -p.hop_cycles if self._base[j] > 0 else p.hop_cycles  # towards the middle
        self._base[j] += k
        self.hops += 1
        self._hop_next = self._tick + p.hop_every
        return j, k

    def observe(self, power: float, pulse_energies=None, steps: int = 1) -> None:
        """The reading produced by the last :meth:`command`; updates the estimate.

        ``steps``: the simulator (or rig) steps since the previous reading, 1 when every step's
        reading is used (in process, lockstep). A free-running simulator steps every 10 ms
        whether or not the command came: a late command costs a step on the old set-points,
        and the drift moved the delays on by one more step than the reading before suggests."""
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
        self.think()  # a deferred knot test nobody ran: its outcome first
        self._awaiting = False
        self.last_power = float(power)
        self._tick += 1
        self._step += steps
        self._gap = steps
        u_now, hop = self._reading_setpoints()
        if self._noise_var is None and self._history:
            last_u, last_y, _ = self._history[-1]
            if np.array_equal(last_u, u_now):  # the same set-points twice
                diff = y[:-1] - last_y[:-1]
                self._noise_var = float(np.mean(diff * diff)) / 2.0
                if self._noise_var >= self.params.noisy_threshold**2:
                    self._window_len = self._fit_window(True)
                    self._history = deque(self._history, maxlen=self._window_len)
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
        self._unlocked_readings = 0 if self.locked else self._unlocked_readings + 1
        if self._unlocked_readings >= self.params.calibration_reset_after:
            self._unlocked_readings = 0
            if self.calibration.reset_detector():
                self.calibration_resets += 1

    def _check_false_lock(self, power: float) -> None:
        """Drop a lock whose readings stay low (see ``false_lock_power``): whatever the model and
        its calibration say, a stacker at its optimum reads high."""
        p = self.params
        low = self.locked and self._recovering is None and power < p.false_lock_power
        self._low_readings = self._low_readings + 1 if low else 0
        if not p.false_lock_readings or self._low_readings < p.false_lock_readings:
            return
        self._low_readings = 0
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

    def _hold_dither(self) -> float:
        """The tracking excursion's length: ``hold_dither_cycles``, larger on a noisy detector
        (a reading near the optimum is quadratic in the error, so the excursion must lift its
        signal above the noise: 0.3 sqrt(sigma) cycles, 0.03 at sigma = 0.01). With the
        all-stage pattern each stage moves by length / sqrt(N) in every reading instead of the
        whole length in one reading of N: the same information per reading and the same cost
        in power (measured: sqrt(N) times the length lost 7 % of the power at sigma = 0.01)."""
        noise = max(self.params.detector_noise**2, self._noise_var or 0.0) ** 0.5
        drift = self.params.drift_dither_gain * float(np.max(np.abs(self.drift)))
        return max(self.params.hold_dither_cycles, 0.3 * noise**0.5, drift)

    def _tolerance(self, base: float | None = None) -> float:
        """Mean squared residual that still counts as a fit: the base tolerance plus three times
        the detector's noise variance (the assumed one, or the one measured from a repeated
        reading, whichever is larger)."""
        noise_var = max(self.params.detector_noise**2, self._noise_var or 0.0)
        return (self.params.residual_tolerance if base is None else base) + 3.0 * noise_var

    def _predict(self, x: np.ndarray, u: np.ndarray, age: np.ndarray, drift) -> np.ndarray:
        """Readings (M, K, S + 1) for candidate present errors x (M, N) cycles."""
        m, k = x.shape[0], u.shape[0]
        drift = np.broadcast_to(drift, x.shape)  # (N,) shared or (M, N) per candidate
        delays = u[None, :, :] + x[:, None, :] - age[None, :, None] * drift[:, None, :]
        out = self.stacker.evaluate(delays.reshape(m * k, self.stage) * self.period_fs)
        pred = np.concatenate([out.slot_energies, out.power[:, None]], axis=1)
        return pred.reshape(m, k, -1)

    def _cost(self, x, u, y, age, drift) -> np.ndarray:
        r = self._predict(x, u, age, drift) - y[None]
        return np.mean(r * r, axis=(1, 2))

    def _refine(self, x, u, y, age, drift, iterations: int):
        """Batched Levenberg-Marquardt from starts x (M, N), a generator that yields after each
        iteration and returns (x, cost) (``x, cost = yield from self._refine(...)``).

        ``drift`` (N,) is held fixed; with ``drift=None`` each start's drift is fitted too
        (x is then (M, 2N): the errors now and their drift per step)."""
        m, dim = x.shape
        n = self.stage

        def split(z):
            return (z, drift) if drift is not None else (z[:, :n], z[:, n:])

        h = 1e-3  # finite-difference step, cycles (or cycles per step)
        lam = np.full(m, 1e-2)
        steps = np.concatenate([np.zeros((1, dim)), h * np.eye(dim)])  # (dim + 1, dim)
        cost = None
        for _ in range(iterations):
            pts = (x[:, None, :] + steps[None]).reshape(m * (dim + 1), dim)
            pred = self._predict(*split(pts)[:1], u, age, split(pts)[1])
            pred = pred.reshape(m, dim + 1, -1)
            r = pred[:, 0] - y.ravel()[None]  # (M, R)
            jac = (pred[:, 1:] - pred[:, :1]) / h  # (M, dim, R)
            cost = np.mean(r * r, axis=1)
            jtj = jac @ jac.transpose(0, 2, 1)
            jtr = jac @ r[:, :, None]
            diag = np.einsum("mii->mi", jtj)
            a = jtj + (lam[:, None] * (diag + 1e-9))[:, :, None] * np.eye(dim)[None]
            delta = -np.linalg.solve(a, jtr)[:, :, 0]
            delta = np.clip(delta, -0.1, 0.1)  # at most a tenth of a cycle per iteration
            trial = x + delta
            new_cost = self._cost(*split(trial)[:1], u, y, age, split(trial)[1])
            better = new_cost < cost
            x = np.where(better[:, None], trial, x)
            cost = np.where(better, new_cost, cost)
            lam = np.where(better, lam * 0.3, lam * 4.0)
            yield
        return x, cost

    def _search_step(self) -> None:
        """Advance the global search by this reading's share: all of it with ``step_budget_ms``
        0, else work units until the budget is spent (the commands keep dithering meanwhile)."""
        if self._search is None:
            self._search = self._acquire()
        budget = self.params.step_budget_ms
        deadline = time.perf_counter() + budget / 1e3 if budget > 0 else float("inf")
        try:
            while True:
                next(self._search)
                if time.perf_counter() >= deadline:
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
            # A detector off its calibration: fit its gain and offset to the best estimate's
            # predictions, then refine again on the corrected readings.
            pred = self._predict(x[i : i + 1], u, age, fitted_drift)[0]
            if self.calibration.fit_detector(pred, self._window(raw=True)[1][-len(u) :]):
                y = self.calibration.correct(self._window(raw=True)[1][-len(u) :])
                z = np.concatenate([x, np.tile(fitted_drift, (len(x), 1))], axis=1)
                z, cost = yield from self._refine(z, u, y, age, None, p.iterations)
                i = int(np.argmin(cost))
                x, fitted_drift = z[:, : self.stage], z[i, self.stage :]
        self.residual = float(cost[i])
        if self.residual <= self._tolerance():
            self._start_tracking(x[i] + (self._step - started) * fitted_drift)
            self.drift = self._bounded(fitted_drift)
            self.acquisitions += 1

    def _start_tracking(self, x: np.ndarray) -> None:
        """Track from the acquired estimate x (cycles)."""
        self.estimate = _wrap(x)
        self.drift = np.zeros(self.stage)

    def _noisy(self) -> bool:
        """A detector noise (assumed or measured) of at least ``noisy_threshold``."""
        p = self.params
        return max(p.detector_noise**2, self._noise_var or 0.0) >= p.noisy_threshold**2

    def _reading_sd(self) -> float:
        """The std of a reading about the model that the path fits assume: ``fit_noise_floor``
        plus the largest of the detector noise assumed (``detector_noise``), the noise measured
        from the repeated first reading where it makes the detector noisy (``noisy_threshold``),
        and the median mean squared residual of the last ``FIT_VAR_FITS`` tracking fits (the
        model's misfit as the fits find it; before those, the lock tolerance plus the measured
        noise). Weighting every reading by the lock tolerance plus the measured noise (~1e-6
        in extreme mode, where the "noise" of the repeated reading is the drift between the two)
        let the random walk absorb a knot of the drift for three or four readings (extreme,
        `scripts/tracker_knots.py`: 92.7 % locked against 96.5 % with the fits' own residuals;
        docs/tracker.md). On a noisy detector the fits' residuals alone are too small (the path
        follows part of the noise) and the measured noise is kept."""
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
        return fit.x[0], fit.drift[0], float(fit.data_cost[0])

    def _fit_paths(
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
        deadline=None,
    ):
        """:meth:`_fit_path` for M starts at once (x_now, drift: (M, N); drift_prior: (M, N)
        or None), each its own Levenberg-Marquardt: the hypotheses of a knot or a recovery cost
        one batched evaluation of the physics per iteration instead of one each (the tracker's
        slowest readings, measured in docs/tracker.md). Returns a :class:`PathFits`.

        ``knots``: (stage (M,), first (M,), change (M,)) a knot hypothesis per start: from
        reading ``first`` of the window on, that stage drifts by mu + delta, delta one more
        variable (start ``change``, prior std ``knot_prior_cycles``); the path before the knot
        keeps the drift mu and its prior. The returned drift is the one after the knot.

        ``prune``: (iterations, keep): after that many iterations only the ``keep`` starts of
        lowest cost iterate on (the others return where they were); most of the cost is the
        Jacobian of every start at every iteration. ``path0``: (M, K, N) the starts' paths (by
        default straight back from x_now by the drift). ``deadline`` (time.perf_counter()): no
        iteration starts after it (at least one runs)."""
        p = self.params
        k, n = u.shape
        m = x_now.shape[0]
        u_centred = u - u.mean(axis=0)
        r_sd = self._reading_sd()
        w_sd = self._walk_sigma()
        if drift_prior is None:
            prior = p.noisy_drift_prior_cycles if self._noisy() else p.drift_prior_cycles
            drift_prior = np.full((m, n), prior)
        if path0 is None:  # the straight path back from x_now by the drift
            path0 = x_now[:, None, :] - age[None, :, None] * drift[:, None, :]
        path = path0
        extra = np.zeros((m, 1)) if ratio else np.zeros((m, 0))
        change = np.zeros((m, 0)) if knots is None else np.asarray(knots[2], float)[:, None]
        z = np.concatenate([path.reshape(m, k * n), drift, extra, change], axis=1)
        mu0 = drift.copy()
        d = z.shape[1]
        nz = k * n + n  # the path and the drift (then r, if fitted, then the knot's change)
        # The normal equations by their parts (no full Jacobian is formed): the readings (block
        # diagonal in the path, plus r), the walk between readings (linear; the same for every
        # start except in a knot's column) and the drift prior (diagonal, per start).
        gaps = np.maximum(age[:-1] - age[1:], 1.0)  # steps between consecutive readings
        walk = np.zeros(((k - 1) * n, d))
        for i in range(1, k):  # X_i - X_i-1 - gap mu, std walk sqrt(gap)
            rows = slice((i - 1) * n, i * n)
            gap = gaps[i - 1]
            walk[rows, i * n : (i + 1) * n] = np.eye(n) / gap**0.5
            walk[rows, (i - 1) * n : i * n] = -np.eye(n) / gap**0.5
            walk[rows, k * n : nz] = -np.eye(n) * gap**0.5
        walk = np.broadcast_to(walk, (m, *walk.shape))
        prior_w = np.zeros((m, d))  # the prior's weights (1 / std^2) on the drift and r
        prior_w[:, k * n : nz] = 1.0 / drift_prior**2
        if ratio:
            prior_w[:, nz] = 1.0 / HOP_RATIO_PRIOR**2
        if knots is not None:  # the walk steps after each start's knot: minus gap * delta
            walk = walk.copy()
            for i in range(1, k):
                after = np.flatnonzero(i >= np.asarray(knots[1]))
                rows = (i - 1) * n + np.asarray(knots[0])[after]
                walk[after, rows, d - 1] = -(gaps[i - 1] ** 0.5)
            prior_w[:, d - 1] = 1.0 / p.knot_prior_cycles**2
        walk_normal = walk.transpose(0, 2, 1) @ walk / w_sd**2
        prior_mean = np.zeros((m, d))
        prior_mean[:, k * n : nz] = mu0
        h = 1e-4
        offsets = np.concatenate([np.zeros((1, n)), h * np.eye(n)])  # (N + 1, N)
        blocks = (np.arange(k)[:, None] * n + np.arange(n)[None]).reshape(k, n)  # path indices

        def readings(z, with_jacobian):
            """Predicted minus measured readings (M, K, R), d prediction / d path (M, K, R, N);
            z: (M, D), any number M of the starts."""
            m = z.shape[0]
            xs = z[:, : k * n].reshape(m, k, n)
            pts = u[None] + xs + (z[:, nz, None, None] * u_centred[None] if ratio else 0.0)
            if with_jacobian:
                pts = pts[:, :, None, :] + offsets[None, None]  # (M, K, N + 1, N)
            out = self.stacker.evaluate(pts.reshape(-1, n) * self.period_fs)
            pred = np.concatenate([out.slot_energies, out.power[:, None]], axis=1)
            if not with_jacobian:
                return pred.reshape(m, k, -1) - y[None], None
            pred = pred.reshape(m, k, n + 1, -1)
            jac_k = (pred[:, :, 1:] - pred[:, :, :1]).transpose(0, 1, 3, 2) / h  # M, K, R, N
            return pred[:, :, 0] - y[None], jac_k

        def objective(z, err, i):
            """The whole cost of starts i at z (len(i), D)."""
            dz = z - prior_mean[i]
            walk_res = np.einsum("mrd,md->mr", walk[i], z)
            return (
                np.einsum("mkr,mkr->m", err, err) / r_sd**2
                + np.einsum("mr,mr->m", walk_res, walk_res) / w_sd**2
                + np.einsum("md,md,md->m", dz, dz, prior_w[i])
            )

        def normal_equations(z, err, jac_k, i):
            """J^T J (M, D, D) and J^T r (M, D) of the whole cost of starts i at z."""
            jtj = walk_normal[i]
            jtr = np.einsum("mde,me->md", jtj, z)
            data_jtj = np.einsum("mkri,mkrj->mkij", jac_k, jac_k) / r_sd**2  # (M, K, N, N)
            jtj[:, blocks[:, :, None], blocks[:, None, :]] += data_jtj
            jtr[:, blocks] += np.einsum("mkri,mkr->mki", jac_k, err) / r_sd**2
            if ratio:  # d phase / d r = the centred set-points
                g = np.einsum("mkrn,kn->mkr", jac_k, u_centred)
                cross = np.einsum("mkri,mkr->mki", jac_k, g) / r_sd**2
                jtj[:, blocks, nz] += cross
                jtj[:, nz, blocks] += cross
                jtj[:, nz, nz] += np.einsum("mkr,mkr->m", g, g) / r_sd**2
                jtr[:, nz] += np.einsum("mkr,mkr->m", g, err) / r_sd**2
            idx = np.arange(d)
            jtj[:, idx, idx] += prior_w[i]
            jtr += prior_w[i] * (z - prior_mean[i])
            return jtj, jtr

        err, jac_k = readings(z, True)
        act = np.arange(m)  # the starts still iterating
        cost = objective(z, err, act)
        data_cost = np.mean(err * err, axis=(1, 2))
        lam = np.full(m, 1e-3)
        eye = np.eye(d)
        for it in range(iterations):
            if it and deadline is not None and time.perf_counter() >= deadline:
                break
            if prune is not None and it == prune[0] and act.size > prune[1]:
                act = np.sort(np.argsort(cost)[: prune[1]])
            za = z[act]
            jtj, jtr = normal_equations(za, err[act], jac_k[act], act)
            diag = np.einsum("mii->mi", jtj)
            a = jtj + (lam[act, None] * (diag + 1e-12))[:, :, None] * eye[None]
            step = -np.linalg.solve(a, jtr[:, :, None])[:, :, 0]
            trial = za + np.clip(step, -0.1, 0.1)
            t_err, _ = readings(trial, False)
            t_cost = objective(trial, t_err, act)
            better = t_cost < cost[act]
            lam[act] = np.where(better, lam[act] * 0.3, lam[act] * 10.0)
            if better.any():  # the Jacobian again only where a start moved
                moved = act[better]
                z[moved] = trial[better]
                cost[moved] = t_cost[better]
                data_cost[moved] = np.mean(t_err[better] ** 2, axis=(1, 2))
                err[moved], jac_k[moved] = readings(z[moved], True)
        fitted_ratio = z[:, nz] if ratio else np.zeros(m)
        x = z[:, (k - 1) * n : k * n] + fitted_ratio[:, None] * u_centred[-1]
        fitted_drift = z[:, k * n : nz].copy()
        if knots is not None:
            fitted_drift[np.arange(m), np.asarray(knots[0])] += z[:, d - 1]
        return PathFits(
            x=x,
            drift=fitted_drift,
            data_cost=data_cost,
            path=z[:, : k * n].reshape(m, k, n),  # the fitted errors at every reading
            objective=cost,  # each fit's whole normalized cost (readings, walk, prior)
            ratio=fitted_ratio,
        )

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
            and (cost > self._tolerance(p.knot_tolerance) or self._walk_jump() > p.knot_walk_sigmas)
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
                self._knot_job = _KnotJob(job, self.drift, self._path, self._objective, self._ratio)
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

    def think(self) -> bool:
        """Work that may wait until the command is out: the knot test the last reading asked
        for, with ``defer_knot_test`` (a node calls this after publishing the command, in the
        time before the next step; :meth:`observe` calls it first if nobody did). True when its
        outcome changed the command already given: :meth:`command` then gives the revised one
        (a node sends it at once; if the step ran on the first one, its reading is not paired
        with the revised command and is not used)."""
        if self._knot_job is None:
            return False
        job, self._knot_job = self._knot_job, None
        aimed = (self.estimate, self.drift)  # what the command given aims by
        # the state the test starts from: as it was before the answer
        self.drift, self._path = job.drift_before, job.path
        self._objective, self._ratio = job.objective, job.ratio
        deadline = self._knot_deadline()
        x, drift, cost = self._knot_fit(*job.fit, deadline=deadline)
        predicted, _, _, _, u, y, age, ratio = job.fit
        self._finish_track(predicted, x, drift, cost, u, y, age, ratio, deadline)
        changed = not all(map(np.array_equal, aimed, (self.estimate, self.drift)))
        self._revise = self._awaiting and changed
        return self._revise

    def _knot_deadline(self):
        """When the knot test and the fits after it must stop (``knot_budget_ms``), or None."""
        budget = self.params.knot_budget_ms
        return time.perf_counter() + budget / 1e3 if budget else None

    def _finish_track(self, predicted, x, drift, cost, u, y, age, ratio, deadline=None) -> None:
        """Take a tracking fit (x, drift, cost) of the window (u, y, age): iterate further if
        its readings left the model (until ``deadline``, if given), count a bad fit (keep the
        prediction) or take it."""
        p = self.params
        fitted_ratio = self._ratio
        lost = self._tolerance(p.lost_tolerance)
        if cost > lost:  # a knot of the drift, a fast walk: iterate further before giving up
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
        self.drift = self._bounded(drift)
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

    def _knot_fit(self, predicted, x, drift, cost, u, y, age, ratio=False, deadline=None):
        """The best of the present fit (x, drift, cost) and the knot hypotheses, all fitted at
        once: each stage's slope changed from each of the last ``knot_readings`` readings of the
        window on, started either way (one reading is even in the change); the steps before the
        knot keep the present drift. Taken in turn, a hypothesis wins only if its whole cost plus
        ``knot_penalty`` (``noisy_knot_penalty`` on a noisy detector) is below the best so far
        (the path and period error of the winner are kept).

        The first start is no knot (its knot after the window): the present fit iterated as
        long as the hypotheses, so that a knot must beat the best fit without one, not a fit of
        fewer iterations (seen: a model 2 % off in wavelength, whose moves a well-started
        knot fit explained better than a three-iteration path fit: knots at the moves)."""
        p = self.params
        n, k = self.stage, len(u)
        firsts = np.arange(k - 1, max(k - 1 - p.knot_readings, 0), -1)
        stage, first, sign = (
            np.concatenate([[value], a.ravel()])
            for value, a in zip(
                (0, k, 0.0),
                np.meshgrid(np.arange(n), firsts, [1.0, -1.0], indexing="ij"),
                strict=True,
            )
        )
        change = sign * p.knot_start_cycles
        m = stage.size
        # start: the path of the prediction (back from it by the drift), bent at the knot: the
        # knotted stage moved on by the change for every step since the reading before the knot
        # (a straight path through the bent end needed twice the iterations for the same fits).
        # In a window with a whole-cycle move (ratio) the path starts straight, moved by the
        # change throughout: bent starts explained the phase step of a move on a model off in
        # wavelength as a knot before the period fit could (medium, wavelength -2 %, seeds 0
        # and 3: readings of 0.07 after the lock; extreme unchanged: seeds 1000/1001 x 3000
        # steps 97.90/97.63 % straight, 97.90/97.66 % bent).
        line = predicted[None] - age[:, None] * self.drift[None]  # (K, N)
        path0 = np.tile(line, (m, 1, 1))
        if ratio:
            since = np.broadcast_to(age[first - 1][:, None], (m, k))
        else:
            since = np.clip(age[first - 1][:, None] - age[None, :], 0.0, None)  # (M, K)
        path0[np.arange(m)[:, None], np.arange(k)[None], stage[:, None]] += change[:, None] * since
        drift0 = np.tile(self.drift, (m, 1))
        knots = (stage, first, change)
        iterations = p.noisy_knot_iterations if self._noisy() else p.knot_iterations
        prune = (p.knot_prune_after, p.knot_keep) if p.knot_keep else None
        fits = self._fit_paths(
            path0[:, -1],
            drift0,
            u,
            y,
            age,
            iterations,
            ratio=ratio,
            knots=knots,
            prune=prune,
            path0=path0,
            deadline=deadline,
        )
        best, best_path, best_obj = (x, drift, cost), self._path, self._objective
        best_ratio, won = self._ratio, False
        penalty = p.noisy_knot_penalty if self._noisy() else p.knot_penalty
        for i in range(m):
            if fits.objective[i] + (penalty if i else 0.0) < best_obj:
                best = (fits.x[i], fits.drift[i], float(fits.data_cost[i]))
                best_path, best_obj, won = fits.path[i], fits.objective[i], i > 0
                best_ratio = fits.ratio[i]
        self._path, self._objective, self._ratio = best_path, best_obj, best_ratio
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

    def _correct_period(self, r: float) -> None:
        """A window fit with a whole-cycle move found the model's period off by r (model over
        true, minus 1): move the wavelength by hop_gain of it."""
        r = float(np.clip(r, -MAX_HOP_RATIO, MAX_HOP_RATIO))
        # A gain that falls with the moves made (an average of the measurements, not the last
        # few): with a constant gain the estimate random-walked with its measurements' noise
        # (docs/tracker.md, "Over DDS"; scripts/bench_tracker_wavelength.py measures it).
        share = max(HOP_GAIN_MOVES / (HOP_GAIN_MOVES + self.hops), HOP_GAIN_FLOOR)
        self.calibration.wavelength_nm /= 1.0 + self.params.hop_gain * share * r
        self._adopt_optics()

    def _adopt_optics(self) -> None:
        """Take the calibration's wavelength and width into the model and re-express the
        state (estimate, drift, set-points, the window's commands) in the new cycles."""
        old_period = self.period_fs
        self.stacker = self.calibration.stacker()
        self.period_fs = self.calibration.period_fs
        ratio = old_period / self.period_fs  # the same fs are this many new cycles per old one
        latest = self._history[-1][0]
        self.estimate = self.estimate + latest - latest * ratio  # same phase
        self.drift = self.drift * ratio
        self._base = self._base * ratio
        self._last_command = self._last_command * ratio
        self._acting = self._acting * ratio
        self._position = self._position * ratio
        for entry in self._in_flight:
            entry[1] = entry[1] * ratio
        self._history = deque(
            ((h[0] * ratio, h[1], h[2]) for h in self._history), maxlen=self._window_len
        )

    def _calibrate(self, u: np.ndarray, path: np.ndarray) -> None:
        """Feed the window's fit to the calibration; every ``calibration_every`` readings, move
        the model's wavelength and pulse width and re-express the state in the new cycles."""
        raw = self._window(raw=True)[1]
        optics = self.params.calibrate_optics
        self.calibration.observe(self.stacker, u, path, raw, self.period_fs, optics)
        if not optics or self._tick % self.params.calibration_every:
            return
        if self.calibration.update_optics():
            self._adopt_optics()

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
