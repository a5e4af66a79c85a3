"""Does the rig's latency match the one the tracker was told?

A tracker told the wrong latency pairs each reading with the wrong command: its fits do not
explain the window, it never locks, and nothing says why. The check re-pairs the last readings
with the commands under each candidate latency and runs a small global search (random starts,
then Levenberg-Marquardt; :mod:`.fit`) on each pairing: the latency whose pairing the model
explains best, by a clear margin and within the fit tolerance, is the rig's. Pure functions; the
tracker's :class:`LatencyWatch` starts :func:`measure_latency` once most of its last
``latency_check_after`` readings were dim, and again every as many readings while that lasts.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .fit import cost, refine
from .work import advance, refine_rows, scaled, spread_rows

#: A candidate wins if its residual is at most this share of the told latency's.
MARGIN = 0.25
#: Readings the check re-pairs (the latest): about two fit windows.
CHECK_READINGS = 12
#: Random starts of a pairing's global search, and the best of them refined: fewer starts miss
#: the rig's own pairing in a good share of the checks.
CANDIDATES = 512
KEEP = 8
#: Checks that find nothing are run again at once this many times (on the newer readings)
#: before the window starts over: a search misses the rig's pairing in about one check in
#: eight when the readings are flat (an acquisition probing about one point).
RETRIES = 2
#: Random starts scored per unit of work of a check spread over readings.
CHUNK = 64


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


def pairing_cost(
    stacker, period_fs, window, tolerance, rng, candidates=CANDIDATES, keep=KEEP, chunk=None
):
    """The smallest mean squared residual that a global search finds for one pairing: static
    errors first, then errors and a drift per stage from the best starts. A generator that
    yields the rows of each unit of work (unweighed, :mod:`.work`; the random starts scored
    ``chunk`` at a time, None: all at once) and returns it."""
    u, y, age = window
    n = u.shape[1]
    start = rng.uniform(-0.5, 0.5, size=(candidates, n))
    scores = []
    chunk = chunk or candidates
    for i in range(0, candidates, chunk):
        scores.append(cost(stacker, period_fs, start[i : i + chunk], u, y, age, np.zeros(n)))
        yield len(scores[-1]) * len(u)
    best = start[np.argsort(np.concatenate(scores))[:keep]]
    x, c = yield from refine(stacker, period_fs, best, u, y, age, np.zeros(n), 8)
    if c.min() <= tolerance:
        return float(c.min())
    z = np.concatenate([x, np.zeros_like(x)], axis=1)
    _, c2 = yield from refine(stacker, period_fs, z, u, y, age, None, 6)
    return float(min(c.min(), c2.min()))


def candidate_rows(n: int, readings: int = CHECK_READINGS) -> int:
    """The most work of one candidate's :func:`pairing_cost`, unweighed (:mod:`.work`)."""
    return (
        CANDIDATES * readings
        + refine_rows(KEEP, n, readings, 8)
        + refine_rows(KEEP, 2 * n, readings, 6)
    )


def measure_latency(
    stacker,
    period_fs,
    commands,
    readings,
    told: int,
    tolerance: float,
    rng,
    longest: int = 4,
    scale: float = 1.0,
):
    """A generator that returns (the latency the readings fit, {candidate: residual}); the
    latency is None when no candidate other than ``told`` fits clearly better (within
    ``tolerance`` and by :data:`MARGIN`). With ``scale`` (the rows' weight, :mod:`.work`) it
    yields the rows of each unit of work; without (None), once per candidate latency."""
    costs = {}
    for latency in range(max(longest, told + 2) + 1):
        window = pair_readings(commands, readings, latency)
        if window is not None and len(window[0]) >= 6:
            chunk = None if scale is None else CHUNK
            job = pairing_cost(stacker, period_fs, window, tolerance, rng, chunk=chunk)
            if scale is None:
                costs[latency] = advance(job)[1]  # (run to its end)
            else:
                costs[latency] = yield from scaled(job, scale)
        if scale is None:
            yield
    if told not in costs:
        return None, costs
    best = min(costs, key=costs.get)
    if best != told and costs[best] <= tolerance and costs[best] <= MARGIN * costs[told]:
        return best, costs
    return None, costs


class LatencyWatch:
    """The latency check's state: the latency in use, what the checks found (kept over resets),
    and the commands and readings the next check re-pairs (from a reset). Once most of the last
    ``latency_check_after`` readings are below ``latency_check_below`` a check runs, one
    candidate per reading, and a latency the readings clearly fit better than the one in use is
    taken (``note`` says so).

    Most, not all: an acquisition search under a wrong latency still hits a bright point now and
    then, and a count of dim readings in a row would start over at each. After a check that
    takes a latency, or :data:`RETRIES` + 1 that find nothing, the count starts over."""

    def __init__(self, told: int, p) -> None:
        self.latency = told  # in use: a command acts this many steps after the step that took it
        self.told = told
        self.note = None  # why the latency in use is not the told one
        self.changes = 0
        self.checks = 0
        self.costs: dict = {}  # the last check's residual per candidate latency
        self.restart(p)

    def restart(self, p) -> None:
        self.commands: deque = deque(maxlen=64)  # (step it acts at without latency, u)
        self.readings: deque = deque(maxlen=CHECK_READINGS)  # (step, weighed reading)
        self.dim: deque = deque(maxlen=max(p.latency_check_after, 1))
        self.retries = 0
        self.job = None
        self.rows = None  # the check's work per reading (None: one candidate a reading)

    def wait_for(self, readings: int) -> None:
        """Count dim readings over at least ``readings`` (a search spread over readings: the
        readings it takes are dim, and a check would start before it can lock)."""
        if readings > self.dim.maxlen:
            self.dim = deque(self.dim, maxlen=readings)

    @property
    def spread(self) -> bool:
        """A check spread over readings is under way (a search waits for it)."""
        return self.job is not None and self.rows is not None

    def command(self, step: int, u: np.ndarray) -> None:
        """A command given after the reading at ``step``."""
        self.commands.append((step + 1, u.copy()))

    def command_taken(self, taken: int, expected: int) -> None:
        """The last command, expected at step ``expected``, was taken at step ``taken``."""
        if taken > expected and self.commands and self.commands[-1][0] == expected:
            self.commands[-1] = (taken, self.commands[-1][1])

    def reading(self, p, step: int, y, power: float, rig, tolerance, rng):
        """A reading ``y`` at ``step`` whose power read ``power``; a check runs on the model now
        (``rig``, a :class:`~.model.RigModel`), taking a fit within ``tolerance()``, its random
        starts drawn from ``rng``. Returns a latency to take, or None."""
        self.readings.append((step, rig.weighed(y)))
        if not p.latency_check_after:
            return None
        if self.job is not None:
            finished, value = advance(self.job, self.rows, units=1 if self.rows is None else 0)
            if not finished:
                return None
            self.job = None
            found, self.costs = value
            self.retries = self.retries + 1 if found is None else 0
            if found is not None or self.retries > RETRIES:
                self.dim.clear()
                self.retries = 0
            return found
        self.dim.append(power < p.latency_check_below)
        count = self.dim.maxlen
        if len(self.dim) == count and 4 * sum(self.dim) >= 3 * count:
            self.checks += 1
            # one candidate latency a reading, or (N = 7) spread_rows of work a reading
            self.rows = spread_rows(p, candidate_rows(rig.stage) * rig.work_scale)
            self.job = measure_latency(
                rig.fit_stacker,
                rig.period_fs,
                list(self.commands),
                list(self.readings),
                self.latency,
                tolerance(),
                rng,
                p.latency_check_longest,
                None if self.rows is None else rig.work_scale,
            )
        return None

    def take(self, latency: int, step: int):
        """Pair readings with commands ``latency`` steps back from now (``step``) on; (the
        set-points acting now, or None if no command given acts yet; the commands still on their
        way, as :attr:`.commands.Loop.in_flight` holds them)."""
        self.note = (
            f"the readings fit a latency of {latency} steps, not the {self.latency} in use (the "
            f"rig it was told of: {self.told}); using {latency}"
        )
        self.latency = latency
        self.changes += 1
        acting = [u for at, u in self.commands if at <= step - latency]
        in_flight = deque([at, u.copy(), None] for at, u in self.commands if at > step - latency)
        return (acting[-1].copy() if acting else None), in_flight
