"""Does the rig's latency match the one the tracker was told (issue 30)?

A tracker told the wrong latency pairs each reading with the wrong command: its fits do not
explain the window, it never locks, and nothing says why. The check re-pairs the last readings
with the commands under each candidate latency and runs a small global search (random starts,
then Levenberg-Marquardt; :mod:`.fit`) on each pairing: the latency whose pairing the model
explains best, by a clear margin and within the fit tolerance, is the rig's. Pure functions; the
tracker calls :func:`measure_latency` once it has gone ``latency_check_after`` readings without a
lock, and again every as many readings while it stays unlocked.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .fit import cost, refine

#: A candidate wins if its residual is at most this share of the told latency's.
MARGIN = 0.25
#: Readings the check re-pairs (the latest): about two fit windows.
CHECK_READINGS = 12
#: Random starts of a pairing's global search, and the best of them refined: with 128 and 4 the
#: search missed the rig's own pairing in 4 of 12 checks (medium, rig 4 steps, told 2).
CANDIDATES = 512
KEEP = 8
#: Checks that find nothing are run again at once this many times (on the newer readings)
#: before the window starts over: a search misses the rig's pairing in about one check in
#: eight when the readings are flat (an acquisition probing about one point).
RETRIES = 2


def pair_readings(commands, readings, latency: int):
    """(u (K, N), y (K, S + 1), age (K,)): each reading at step t with the newest command that
    acts at or before t - ``latency``; ``commands``: (step it acts at without latency, set-points
    in cycles), oldest first; ``readings``: (step, reading), oldest first. Readings made before
    the first known command are left out."""
    us, ys, steps = [], [], []
    i, acting = 0, None
    for step, y in readings:
        while i < len(commands) and commands[i][0] <= step - latency:
            acting = commands[i][1]
            i += 1
        if acting is not None:
            us.append(acting)
            ys.append(y)
            steps.append(step)
    if not us:
        return None
    steps = np.asarray(steps, dtype=np.float64)
    return np.array(us), np.array(ys), steps[-1] - steps


def _finish(generator):
    """Run a :func:`.fit.refine` generator to its end; its return value."""
    while True:
        try:
            next(generator)
        except StopIteration as done:
            return done.value


def pairing_cost(
    stacker, period_fs, window, tolerance, rng, candidates=CANDIDATES, keep=KEEP
) -> float:
    """The smallest mean squared residual that a global search finds for one pairing: static
    errors first, then errors and a drift per stage from the best starts."""
    u, y, age = window
    n = u.shape[1]
    start = rng.uniform(-0.5, 0.5, size=(candidates, n))
    best = start[np.argsort(cost(stacker, period_fs, start, u, y, age, np.zeros(n)))[:keep]]
    x, c = _finish(refine(stacker, period_fs, best, u, y, age, np.zeros(n), 8))
    if c.min() <= tolerance:
        return float(c.min())
    z = np.concatenate([x, np.zeros_like(x)], axis=1)
    _, c2 = _finish(refine(stacker, period_fs, z, u, y, age, None, 6))
    return float(min(c.min(), c2.min()))


def measure_latency(
    stacker, period_fs, commands, readings, told: int, tolerance: float, rng, longest: int = 4
):
    """A generator, one candidate latency per step (``yield``), that returns (the latency the
    readings fit, {candidate: residual}); the latency is None when no candidate other than
    ``told`` fits clearly better (within ``tolerance`` and by :data:`MARGIN`)."""
    costs = {}
    for latency in range(max(longest, told + 2) + 1):
        window = pair_readings(commands, readings, latency)
        if window is not None and len(window[0]) >= 6:
            costs[latency] = pairing_cost(stacker, period_fs, window, tolerance, rng)
        yield
    if told not in costs:
        return None, costs
    best = min(costs, key=costs.get)
    if best != told and costs[best] <= tolerance and costs[best] <= MARGIN * costs[told]:
        return best, costs
    return None, costs


class LatencyWatch:
    """The latency check of :class:`~.core.PhaseTracker` (a mixin on the tracker's state):
    commands and readings are kept; once most of the last ``latency_check_after`` readings are
    below ``latency_check_below`` the check runs, one candidate per reading, and a latency the
    readings clearly fit better than the told one is taken (``latency_note`` says so).

    Most, not all: an acquisition search under a wrong latency still hits a bright point now
    and then, and a count of readings in a row started over at each (a check at reading 75
    instead of 26, over DDS). After a check that takes a latency, or :data:`RETRIES` + 1 that
    find nothing, the window starts over."""

    def _watch_reset(self) -> None:
        self._commands_sent: deque = deque(maxlen=64)  # (step it acts at without latency, u)
        self._readings_kept: deque = deque(maxlen=CHECK_READINGS)  # (step, reading)
        self._dim_flags: deque = deque(maxlen=max(self.params.latency_check_after, 1))
        self._retries = 0
        self._latency_job = None

    def _watch_command(self, u: np.ndarray) -> None:
        self._commands_sent.append((self._step + 1, u.copy()))

    def _watch_reading(self, y: np.ndarray) -> None:
        p = self.params
        self._readings_kept.append((self._step, self._weighed(y)))
        if not p.latency_check_after:
            return
        if self._latency_job is not None:
            try:
                next(self._latency_job)
            except StopIteration as done:
                self._latency_job = None
                self.latency_costs = done.value[1]
                if done.value[0] is not None:
                    self._take_latency(done.value[0])
                self._retries = self._retries + 1 if done.value[0] is None else 0
                if done.value[0] is not None or self._retries > RETRIES:
                    self._dim_flags.clear()
                    self._retries = 0
            return
        self._dim_flags.append(self.last_power < p.latency_check_below)
        full = len(self._dim_flags) == p.latency_check_after
        if full and 4 * sum(self._dim_flags) >= 3 * p.latency_check_after:
            self.latency_checks += 1
            self._latency_job = measure_latency(
                self._fit_stacker,
                self.period_fs,
                list(self._commands_sent),
                list(self._readings_kept),
                self.latency,
                self._tolerance(),
                self._check_rng,
                p.latency_check_longest,
            )

    def _take_latency(self, latency: int) -> None:
        """Pair readings with commands ``latency`` steps back from now on, and acquire anew."""
        self.latency_note = (
            f"the readings fit a latency of {latency} steps, not the {self.latency} in use (the "
            f"rig it was told of: {self.latency_told}); using {latency}"
        )
        self.latency = latency
        self.latency_changes += 1
        acting = [u for at, u in self._commands_sent if at <= self._step - latency]
        if acting:
            self._acting = acting[-1].copy()
        self._in_flight = deque(
            [at, u.copy(), None] for at, u in self._commands_sent if at > self._step - latency
        )
        self.estimate = None
        self._search = None
        self._recovering = None
        self._knot_job = None  # a deferred knot test of the old pairing: nothing left to test
        self._knot_run = None
        self._revise = False
        self._bad_fits = 0
        self._history.clear()
