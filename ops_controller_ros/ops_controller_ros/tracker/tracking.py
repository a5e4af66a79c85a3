"""The lock: the estimate of the hidden delay errors and their drift, the last path fit of the
window, and the misses that lead to a local re-lock; and the priors the path fits take.
"""

from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass

import numpy as np

from .drift_memory import DriftMemory
from .fit import PathFits, wrap
from .params import TrackerParams

#: No knot test on a window with readings further apart than this many steps (a rig's outage): a
#: walk over the gap explains anything, and a knot cannot be placed in it.
KNOT_MAX_GAP = 10


@dataclass
class Lock:
    """The estimate of one run (from a reset), in cycles of the model."""

    stage: int
    # hidden delay errors now (None: not acquired), followed continuously from the acquisition's
    # estimate (which is within half a period), and their drift per step
    estimate: np.ndarray | None = None
    drift: np.ndarray = None
    residual: float = float("nan")  # mean squared residual of the last fit
    path: np.ndarray = None  # the last path fit: the errors at each reading of its window
    objective: float = float("nan")  # ... its whole normalized cost
    ratio: float = 0.0  # ... the period error it fitted (over a whole-cycle move)
    gain_step: float = 0.0  # ... the detector's relative gain it fitted (lock_gain_walk)
    level_step: float = 0.0  # ... and the offset (lock_offset_walk)
    # the path of the last fit taken and the step of each of its readings: the next fits'
    # arrival prior (None: none since the lock, or its cycles changed)
    taken: tuple | None = None
    bad_fits: int = 0  # fits in a row whose readings left the model
    recovering: list | None = None  # readings since then, while re-locking
    lock_tick: int = 0  # the reading an acquisition locked on
    # a tracking fit put off until the command is out (answer_first): (hop, the estimate the
    # fit starts from); meanwhile ``estimate`` is the prediction the command aims by
    deferred: tuple | None = None
    unfitted: int = 0  # readings since the last tracking fit answered by the prediction alone
    # under a told vibration, the slope of the estimates taken (None: not remembered)
    memory: DriftMemory | None = None

    def __post_init__(self):
        if self.drift is None:
            self.drift = np.zeros(self.stage)
        if self.path is None:
            self.path = np.zeros((0, self.stage))

    @property
    def locked(self) -> bool:
        return self.estimate is not None

    def take(self, fits: PathFits, i: int = 0):
        """Keep start ``i`` of ``fits`` as the last path fit; (x, drift, mean squared residual)."""
        self.path, self.objective, self.ratio = fits.path[i], fits.objective[i], fits.ratio[i]
        self.gain_step, self.level_step = float(fits.gain[i]), float(fits.level[i])
        return fits.x[i], fits.drift[i], float(fits.data_cost[i])

    def fit_state(self) -> tuple:
        """(path, objective, ratio, (gain step, level step)) of the last path fit."""
        return self.path, self.objective, self.ratio, (self.gain_step, self.level_step)

    def start(self, x: np.ndarray, tick: int, drift: np.ndarray | None = None) -> None:
        """Track from an acquired estimate x (wrapped to one period) and drift (default: none)."""
        self.estimate = wrap(x)
        self.drift = np.zeros(self.stage) if drift is None else drift
        self.lock_tick = tick
        self.taken = None
        self.deferred = None
        self.unfitted = 0
        self.forget()

    def lose(self) -> None:
        """No estimate any more (an acquisition follows)."""
        self.estimate = None
        self.recovering = None
        self.taken = None
        self.deferred = None
        self.unfitted = 0
        self.forget()

    def skips_fit(self, fit_every: int, hop) -> bool:
        """Whether this reading is answered by the prediction alone (``fit_every``): not one
        with a whole-cycle move, which measures the period."""
        if hop is not None or self.unfitted + 1 >= fit_every:
            self.unfitted = 0
            return False
        self.unfitted += 1
        return True

    def forget(self) -> None:
        """The estimates taken so far no longer tell the drift (a new lock, new cycles)."""
        if self.memory is not None:
            self.memory.reset()

    def remember(self, drift: np.ndarray, step: int) -> np.ndarray:
        """The drift to carry on with after a fit taken at ``step`` (the estimate set), whose
        own drift is ``drift``: the remembered slope where there is one (:class:`DriftMemory`)."""
        if self.memory is None:
            return drift
        return self.memory.take(step, self.estimate, drift)

    def let_go(self) -> None:
        """A knot taken: the drift memory lets go, on with the knot's drift
        (:meth:`DriftMemory.knotted`)."""
        if self.memory is not None:
            self.drift = self.memory.knotted(self.drift)

    def remembered(self) -> DriftMemory | None:
        """The drift memory, where it gives the drift prior now (not while recovering)."""
        memory = self.memory
        if memory is None or self.recovering is not None or not memory.active:
            return None
        return memory

    def defer(self, hop, gap: int) -> None:
        """Put this reading's tracking fit off until the command is out (``answer_first``):
        the command aims by the prediction ``gap`` steps on, the fit runs in ``think()``."""
        self.deferred = (hop, self.estimate)
        self.estimate = self.predicted(gap)

    def take_deferred(self) -> tuple[bool, tuple | None]:
        """(whether a fit put off is due, its hop), the estimate it starts from restored; a
        lock dropped or recovering meanwhile has none due."""
        deferred, self.deferred = self.deferred, None
        if deferred is None or self.estimate is None or self.recovering is not None:
            return False, None
        self.estimate = deferred[1]
        return True, deferred[0]

    def keep_taken(self, steps: np.ndarray) -> None:
        """The last path fit is taken; its readings were at ``steps`` (K,)."""
        if self.path.shape[0] == steps.shape[0]:
            self.taken = (steps, self.path)

    def arrival(self, steps: np.ndarray, sd: float):
        """(mean (N,), std) of the prior on the errors at the first of readings at ``steps``:
        the last path taken there, or None where it holds no such reading (or ``sd`` is 0)."""
        if self.taken is None or sd <= 0.0 or steps.shape[0] == 0:
            return None
        before, path = self.taken
        i = np.flatnonzero(before == steps[0])
        return None if i.size == 0 else (path[int(i[0])], sd)

    def predicted(self, gap: int) -> np.ndarray:
        """The errors ``gap`` steps on, by the drift."""
        return self.estimate + gap * self.drift

    def rescale(self, ratio: float, latest_u: np.ndarray) -> None:
        """The estimate and drift in new cycles, ``ratio`` of them per old one (the latest
        reading's set-points ``latest_u``, in old cycles, keep their phase)."""
        self.estimate = self.estimate + latest_u - latest_u * ratio  # same phase
        self.drift = self.drift * ratio
        self.taken = None
        self.forget()


class Guard:
    """Locks that are none, of one run (from a reset): a lock whose readings are mostly low
    (``false_lock_power``) is dropped, whatever the model and its calibration say (a stacker at
    its optimum reads high); and a tracker long without a lock sends the detector's calibration
    back to nominal (a fit to a wrong estimate, or to readings that did not belong together,
    must not keep it from ever locking again)."""

    def __init__(self, p: TrackerParams) -> None:
        # of the readings while locked (not recovering), the last false_lock_readings: was each
        # below false_lock_power?
        self.low: deque = deque(maxlen=max(p.false_lock_readings, 1))
        self.false_locks = 0  # locks dropped for that
        self.unlocked = 0  # readings since the tracker last held a lock
        self.calibration_resets = 0

    def false_lock(self, p: TrackerParams, lock: Lock, power: float) -> bool:
        """Whether to drop the lock after a reading of ``power``: more than half of its last
        ``false_lock_readings`` readings low. Mostly, not all: a wrong lock whose knots and fits
        jump it about reads high now and then."""
        if not p.false_lock_readings or not lock.locked:
            self.low.clear()
            return False
        if lock.recovering is not None:
            return False  # its own search; neither a good nor a bad reading of the lock
        self.low.append(power < p.false_lock_power)
        if len(self.low) < self.low.maxlen or 2 * sum(self.low) <= self.low.maxlen:
            return False
        self.low.clear()
        self.false_locks += 1
        return True

    def unlocked_too_long(self, p: TrackerParams, locked: bool, calibration) -> None:
        """Count a reading; after ``calibration_reset_after`` in a row without a lock, the
        detector's calibration goes back to nominal."""
        self.unlocked = 0 if locked else self.unlocked + 1
        if self.unlocked >= p.calibration_reset_after:
            self.unlocked = 0
            if calibration.reset_detector():
                self.calibration_resets += 1


def bounded(p: TrackerParams, drift: np.ndarray) -> np.ndarray:
    """A fitted drift as the tracker takes it: within +- ``max_drift_cycles``."""
    limit = p.max_drift_cycles
    return np.minimum(np.maximum(drift, -limit), limit)  # (np.clip, without its overhead)


def detector_settled(p: TrackerParams, calibration) -> bool:
    """Whether a misfit may be a knot: not before the detector's gain and offset are first fitted
    (``calibrate``), nor while that fit is an acquisition's only. Until then a lock's readings
    misfit by the detector's error, and a knot test would explain that as a knot and put the
    drift wrong. An acquisition's fit of the detector is provisional: fitted to its low readings,
    where a delay error moves the slot energies as much as the gain does, it can be percents off;
    the first locked reading fits the detector again."""
    return not p.calibrate or (calibration.detector_fitted and not calibration.detector_provisional)


def drift_prior(p: TrackerParams, noisy: bool, since_knot: int, knot_cut_short: bool, memory=None):
    """How far one window may move the drift estimate (std, cycles per step): looser on a clean
    detector, stiff on a noisy one; there looser again within ``quiet_after`` readings of a knot
    taken, and stiffer still while no knot was taken for as long and the knot tests run to their
    end (a quiet drift is only known where a knot would have been seen). A drift ``memory``
    (:meth:`Lock.remembered`) gives its own, per stage (N,)."""
    base = _own_drift_prior(p, noisy, since_knot, knot_cut_short)
    return base if memory is None else memory.priors(base)


def _own_drift_prior(p: TrackerParams, noisy: bool, since_knot: int, knot_cut_short: bool):
    if not noisy:
        return p.drift_prior_cycles
    if since_knot < p.quiet_after and p.knotted_drift_prior_cycles:
        return p.knotted_drift_prior_cycles  # the drift's slope changes: follow it
    quiet = since_knot >= p.quiet_after and not knot_cut_short
    if quiet and p.quiet_drift_prior_cycles:
        return p.quiet_drift_prior_cycles
    return p.noisy_drift_prior_cycles


def gain_prior(p: TrackerParams, since_lock: int, window: int) -> float:
    """The prior std of the gain a path fit fits: ``lock_gain_walk`` within a window of an
    acquisition's lock, where the power does not pin the slot energies' level (``power_weight``
    0) and the detector is calibrated; else 0 (none fitted)."""
    if not p.calibrate or p.power_weight > 0.0:
        return 0.0
    return p.lock_gain_walk if since_lock <= window else 0.0


def level_prior(p: TrackerParams, gain: float) -> float:
    """The prior std of the offset a path fit fits: ``lock_offset_walk`` where the gain is
    fitted (``gain`` > 0); else 0 (none fitted)."""
    return p.lock_offset_walk if gain > 0.0 else 0.0


def walk_jump(path: np.ndarray, drift: np.ndarray, gap: int, walk_sigma: float) -> float:
    """The largest move of the fitted path over its last step, away from the drift, in units of
    the walk's std (a knot shows here before the readings' residual grows)."""
    if path.shape[0] < 2:
        return 0.0
    step = path[-1] - path[-2] - gap * drift
    return float(np.max(np.abs(step))) / (walk_sigma * gap**0.5)


def largest_gap(age: np.ndarray) -> float:
    """The most steps between two consecutive readings of a window."""
    ages = age.tolist()
    return max([0.0, *(a - b for a, b in itertools.pairwise(ages))])
