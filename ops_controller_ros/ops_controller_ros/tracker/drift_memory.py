"""The drift remembered under a told vibration: the slope of the estimates taken over a long
span, the drift prior's mean, let go stage by stage where one stage leaves its line and all at
once where the whole drift reverses.

One window's fit moves its drift by what its few readings say, and under a vibration they say
mostly the walk and the vibration's slow part: the drift estimate wanders by tens of percent
within seconds, and the estimate follows it off. The estimates taken over a minute tell the
drift to a few percent (the walk's sigma over the root of the steps).

Two kinds of release, because they have different causes:

- **One stage off its line** by ``turn`` cycles over the last window is, far more often than a
  turn, that stage's walk and vibration. Its slope let go of is still the best drift it has, so
  it is carried on, the stage's fits take their own drift under the looser ``after`` prior
  (the stage's line may have turned), and its memory fills again from there. The other stages
  keep theirs. Carrying on that window's slope instead carries on the excursion that set the
  release off (up to 0.0015 cycles a step on the ``lab`` rig), and a lock is lost to it.
- **The whole drift reversing** lets go of every stage: a common cause (the lab's temperature)
  that turns, so that each line's drift is the cause's rate times the line's own coefficient.
  It is told by two things at once: the filled stages' displacement over the last window lies
  along the reversal of their slopes (-slope) by ``turn``, and the line bent to the last two
  windows (the slope let go of up to a step, a new one from there; :func:`bent_line_slope`)
  runs against the old slopes after the bend. A walk that takes every stage off its line
  together meets the first and seldom the second. The drift carried on is the slopes let go
  of times the bent line's share of them (negative): one number fitted from every stage, where
  each stage's own bent slope, from the few readings since the turn, is several times noisier.

After a release a stage's drift is believed no faster than :data:`TURN_SPEED` times the
fastest stage's slope let go of, until its memory holds ``least`` steps again.
"""

from __future__ import annotations

import numpy as np

#: Steps between two fits taken (per ``fit_every``) beyond which the estimates before are
#: forgotten (a re-lock, an outage: the estimate may have moved by more than the drift).
MEMORY_MAX_GAP = 5
#: After a release, the fastest drift believed until the memory holds a slope again, in times
#: the fastest stage's slope let go of (a drift that turns does not run off to many times its
#: speed; a knot fit at the turn, its drift told by a few readings, can).
TURN_SPEED = 2.0
#: Fewest estimates after a turn's step that the bent line's fit takes it from.
AFTER_TURN_LEAST = 5


class DriftMemory:
    """The estimates of the last ``span`` steps and, per stage, the least-squares slope of
    those since the stage's last release (module docstring). A stage holds its slope once it
    has ``least`` steps of them; ``slope`` (N,) is then its drift carried on and the fits'
    prior mean with std ``tight``. ``window``: the steps whose displacement the releases test.
    Running sums keep a take's cost independent of ``span``."""

    def __init__(
        self,
        span: int,
        least: int,
        window: int,
        prior: float,
        turn: float,
        after: float = 0.0,
        max_gap: int = MEMORY_MAX_GAP,
    ) -> None:
        self.span, self.least, self.window = int(span), int(least), int(window)
        self.max_gap = int(max_gap)
        self.tight, self.turn, self.after = float(prior), float(turn), float(after)
        self.turns = 0  # releases of every stage (the whole drift reversed)
        self.stage_turns = 0  # releases of one stage
        self.knots = 0  # releases of every stage at a knot taken
        self._cap = self.span + 2
        self._t = np.zeros(self._cap, dtype=np.int64)
        self._x: np.ndarray | None = None  # (cap, N) once the first estimate is taken
        self.reset()

    def reset(self) -> None:
        """Forget every estimate (a new lock, new cycles, an outage, a reversal)."""
        self._head = 0  # ring index of the oldest estimate
        self._count = 0
        self.since: np.ndarray | None = None  # (N,) each stage's first step of its slope
        self.slope: np.ndarray | None = None  # (N,) each stage's slope (None: none yet)
        self.held: np.ndarray | None = None  # (N,) bool: a stage's slope is its drift
        self.limit: np.ndarray | None = None  # (N,) after a release: fastest drift believed
        self._sums: np.ndarray | None = None  # (5, N): n, t, x, tt, tx of each stage's span
        self._ref = (0, None)  # (step, x) the sums are taken relative to

    @property
    def active(self) -> bool:
        """Whether it gives the drift prior now: a stage holds its slope or a release's
        limit holds."""
        return self.held is not None and (bool(self.held.any()) or self.limit is not None)

    def priors(self, base: float) -> np.ndarray:
        """(N,) the drift prior's std per stage: ``tight`` where the slope is held, ``after``
        elsewhere (``base``, the fits' own prior, where ``after`` is 0)."""
        loose = self.after if self.after > 0.0 else base
        return np.where(self.held, self.tight, loose)

    def take(self, step: int, x: np.ndarray, drift: np.ndarray) -> np.ndarray:
        """Hold the estimate ``x`` (N,) taken at ``step``; the drift to carry on with: the
        slope where a stage holds one, else the fit's own ``drift`` (within ``limit``)."""
        if self._count and step - self._last_step() > self.max_gap:
            self.reset()
        self._append(int(step), np.asarray(x, dtype=np.float64))
        filled = step - self.since >= self.least
        slope = self._slopes()
        self.slope, self.held = slope, filled
        if not filled.any():
            self.slope = None
            return self._within(drift)
        if self.limit is not None:
            self.limit[filled] = np.inf
            if np.isinf(self.limit).all():
                self.limit = None
        off = self._off(slope, filled)
        after_turn = self._reversal(off, slope, filled)
        if after_turn is not None:
            return self._release_all(after_turn, slope, filled)
        single = filled & (np.abs(off) > self.turn)
        if single.any():
            self._release(single, step, TURN_SPEED * float(np.max(np.abs(slope[filled]))))
        carried = np.where(self.held, slope, self._within(drift))
        return np.where(single, slope, carried)  # (a stage let go: on from its slope)

    def knotted(self, drift: np.ndarray) -> np.ndarray:
        """A knot taken (the fits found the drift's slope changed): let go of every stage held,
        on with the knot fit's ``drift`` within TURN_SPEED times the fastest slope let go of (a
        held slope carried on past a knot undoes the knot's drift and leaves its path behind)."""
        if self.held is None or not self.held.any():
            return self._within(drift)
        self.knots += 1
        return self._let_go_all(drift, self.slope, self.held)

    # --- the releases -------------------------------------------------------------------------

    def _off(self, slope: np.ndarray, filled: np.ndarray) -> np.ndarray:
        """(N,) each filled stage's displacement over the last window off its slope (0 for the
        others)."""
        k = min(self.window, self._count) - 1
        last, first = self._at(self._count - 1), self._at(self._count - 1 - k)
        dt = float(self._t[last] - self._t[first])
        off = self._x[last] - self._x[first] - dt * slope
        return np.where(filled, off, 0.0)

    def _reversal(self, off: np.ndarray, slope: np.ndarray, filled: np.ndarray):
        """The drift after a reversal of the whole drift (N,), or None where there is none
        (module docstring): the filled stages' slopes times the bent line's share of them."""
        s = np.where(filled, slope, 0.0)
        size = float(np.linalg.norm(s))
        if size == 0.0 or -float(off @ s) / size <= self.turn:
            return None
        k = min(2 * self.window, self._count)
        idx = self._at(np.arange(self._count - k, self._count))
        t, x = self._t[idx].astype(np.float64), self._x[idx]
        share = float(np.where(filled, bent_line_slope(t, x, s, self.window), 0.0) @ s) / size**2
        return share * s if share < 0.0 else None

    def _release(self, stages: np.ndarray, step: int, limit: float) -> None:
        """Let go of ``stages``: their memory starts again at ``step`` and their drift is
        believed no faster than ``limit`` until it holds a slope again (with ``after`` > 0)."""
        self.stage_turns += int(stages.sum())
        self.held = self.held & ~stages
        self.since = np.where(stages, step, self.since)
        self._sums[:, stages] = 0.0
        i = self._at(self._count - 1)
        self._add(self._t[i], self._x[i], stages, 1.0)
        if self.after > 0.0:
            if self.limit is None:
                self.limit = np.full(stages.size, np.inf)
            self.limit[stages] = limit

    def _release_all(self, after: np.ndarray, slope: np.ndarray, filled: np.ndarray):
        """Let go of every stage at a reversal; the drift ``after`` it carried on (module
        docstring), with ``after`` > 0 no faster than TURN_SPEED times the fastest slope."""
        self.turns += 1
        return self._let_go_all(after, slope, filled)

    def _let_go_all(self, carried: np.ndarray, slope: np.ndarray, held: np.ndarray):
        """Forget every estimate; ``carried`` (N,) goes on, with ``after`` > 0 no faster than
        TURN_SPEED times the fastest of the ``held`` stages' ``slope`` until the memory fills."""
        limit = TURN_SPEED * float(np.max(np.abs(slope[held])))
        self.reset()
        self.held = np.zeros(slope.size, dtype=bool)
        if self.after <= 0.0:
            return carried
        self.limit = np.full(slope.size, limit)
        return np.clip(carried, -limit, limit)

    def _within(self, drift: np.ndarray) -> np.ndarray:
        return drift if self.limit is None else np.clip(drift, -self.limit, self.limit)

    # --- the ring of estimates and its running sums -----------------------------------------

    def _at(self, i):
        return (self._head + i) % self._cap

    def _last_step(self) -> int:
        return int(self._t[self._at(self._count - 1)])

    def _append(self, step: int, x: np.ndarray) -> None:
        if self._x is None or self._x.shape[1] != x.size:
            self._x = np.zeros((self._cap, x.size))
        if self._count == 0:
            self.since = np.full(x.size, step, dtype=np.int64)
            self._sums = np.zeros((5, x.size))
            self._ref = (step, x.copy())
        elif step - self._ref[0] > 4 * self.span:
            self._rebase()
        i = self._at(self._count)
        self._t[i], self._x[i] = step, x
        self._count += 1
        self._add(step, x, np.ones(x.size, dtype=bool), 1.0)
        while step - self._t[self._head] > self.span:
            old = self._head
            self._add(self._t[old], self._x[old], self._t[old] >= self.since, -1.0)
            self._head = self._at(1)
            self._count -= 1

    def _add(self, step, x: np.ndarray, stages: np.ndarray, sign: float) -> None:
        """Add (``sign`` 1) or remove (-1) one estimate from the sums of ``stages``."""
        t = float(step - self._ref[0])
        dx = np.where(stages, x - self._ref[1], 0.0)
        w = sign * stages
        self._sums += np.array([w, w * t, sign * dx, w * t * t, sign * t * dx])

    def _rebase(self) -> None:
        """The sums again, relative to the oldest estimate held (their terms stay small)."""
        first = self._head
        self._ref = (int(self._t[first]), self._x[first].copy())
        self._sums[:] = 0.0
        for i in range(self._count):
            j = self._at(i)
            self._add(self._t[j], self._x[j], self._t[j] >= self.since, 1.0)

    def _slopes(self) -> np.ndarray:
        """(N,) each stage's least-squares slope over its span (0 with fewer than 2)."""
        n, st, sx, stt, stx = self._sums
        with np.errstate(invalid="ignore", divide="ignore"):
            var = stt - st * st / n
            slope = (stx - st * sx / n) / var
        return np.where((n >= 2) & (var > 0.0), slope, 0.0)


def bent_line_slope(t: np.ndarray, x: np.ndarray, before: np.ndarray, window: int) -> np.ndarray:
    """(N,) the slope after a turn: of estimates ``x`` (K, N) at steps ``t`` (K,), the line that
    runs with slope ``before`` up to a step common to all stages and bends there, the step
    among the last ``window`` (at least :data:`AFTER_TURN_LEAST` estimates after it) whose
    least-squares fit leaves the least; the last window's plain slope where there is none."""
    k = t.size
    best, carried = np.inf, None
    for i in range(max(0, k - window), k - AFTER_TURN_LEAST + 1):
        dt = t - t[i]
        z = x - np.minimum(dt, 0.0)[:, None] * before  # what the slope before leaves
        a = np.maximum(dt, 0.0)
        am, zm = a.mean(), z.mean(axis=0)
        ac = a - am
        new = ac @ (z - zm) / float(ac @ ac)
        cost = float(np.sum((z - zm - np.outer(ac, new)) ** 2))
        if cost < best:
            best, carried = cost, new
    if carried is None:
        tail = slice(max(0, k - window), k)
        tc = t[tail] - t[tail].mean()
        carried = tc @ (x[tail] - x[tail].mean(axis=0)) / float(tc @ tc)
    return carried


def drift_memory(p, config, vibration) -> DriftMemory | None:
    """The lock's :class:`DriftMemory` under a told ``vibration`` with ``vibration_memory_s``
    set (its times in the loop's steps of ``config.step_s``); None otherwise."""
    if vibration is None or p.vibration_memory_s <= 0.0:
        return None
    step_s = float(getattr(config, "step_s", 0.1))
    if p.window * step_s < p.vibration_memory_min_window_s:
        return None  # (a window this short follows the vibration's slow part as drift)
    scale = float(getattr(config, "time_scale", 1.0))
    span = max(round(p.vibration_memory_s / step_s), 2 * p.window)
    prior = p.vibration_memory_prior_cycles * scale
    after = p.noisy_drift_prior_cycles  # (under a told vibration: vibration_drift_prior_cycles)
    least = max(span // 6, p.window)
    gap = MEMORY_MAX_GAP * p.fit_every  # (fit_every: the fits taken are that much further apart)
    return DriftMemory(span, least, p.window, prior, p.vibration_turn_cycles, after, gap)
