"""The tracker's fits as pure functions of the model (a stacker and its optical period) and the
readings: predicted readings, their cost, the batched Levenberg-Marquardt of the global search
(:func:`refine`) and the moving-horizon path fit (:func:`fit_paths`).

Units: delays and errors in optical cycles of the model; ``u`` (K, N) the set-points of the K
readings of a window, ``y`` (K, S + 1) the readings (slot energies and power), ``age`` (K,) each
reading's steps before the latest.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from . import lm

HOP_RATIO_PRIOR = 0.05  # prior std of the period error fitted over a window with a move


@dataclass(frozen=True)
class PathFits:
    """M moving-horizon fits (:func:`fit_paths`): errors at the latest reading x (M, N), drift
    (M, N), mean squared residual of the readings (M,), the path (M, K, N), the whole normalized
    cost (M,), the fitted period error r (M,; zeros when not fitted), the fitted relative
    gain of the slot energies g and their fitted offset o (M,; zeros when not fitted)."""

    x: np.ndarray
    drift: np.ndarray
    data_cost: np.ndarray
    path: np.ndarray
    objective: np.ndarray
    ratio: np.ndarray
    gain: np.ndarray
    level: np.ndarray


def wrap(cycles):
    """Reduce to [-1/2, 1/2) cycle."""
    return cycles - np.floor(cycles + 0.5)


def predict(stacker, period_fs, x: np.ndarray, u: np.ndarray, age: np.ndarray, drift):
    """Readings (M, K, S + 1) for candidate present errors x (M, N) cycles; ``drift`` (N,)
    shared or (M, N) per candidate."""
    m, k = x.shape[0], u.shape[0]
    drift = np.broadcast_to(drift, x.shape)
    delays = u[None, :, :] + x[:, None, :] - age[None, :, None] * drift[:, None, :]
    energies, power = stacker.energies_and_power(delays.reshape(m * k, x.shape[1]) * period_fs)
    pred = np.concatenate([energies, power[:, None]], axis=1)
    return pred.reshape(m, k, -1)


def cost(stacker, period_fs, x, u, y, age, drift) -> np.ndarray:
    """Mean squared residual (M,) of the readings for candidates x (M, N)."""
    r = predict(stacker, period_fs, x, u, age, drift) - y[None]
    return np.mean(r * r, axis=(1, 2))


def _split(z: np.ndarray, drift, n: int):
    """(errors, drift) of LM variables z: z itself with a fixed drift, else its two halves."""
    return (z, drift) if drift is not None else (z[:, :n], z[:, n:])


def refine(stacker, period_fs, x, u, y, age, drift, iterations: int):
    """Batched Levenberg-Marquardt from starts x (M, N), a generator that yields after each
    iteration (the rows it evaluated) and returns (x, cost) (``x, cost = yield from
    refine(...)``).

    ``drift`` (N,) is held fixed; with ``drift=None`` each start's drift is fitted too (x is
    then (M, 2N): the errors now and their drift per step)."""
    m, dim = x.shape
    n = u.shape[1]
    h = 1e-3  # finite-difference step, cycles (or cycles per step)
    lam = np.full(m, 1e-2)
    steps = np.concatenate([np.zeros((1, dim)), h * np.eye(dim)])  # (dim + 1, dim)
    c = None
    for _ in range(iterations):
        pts = (x[:, None, :] + steps[None]).reshape(m * (dim + 1), dim)
        xs, ds = _split(pts, drift, n)
        pred = predict(stacker, period_fs, xs, u, age, ds).reshape(m, dim + 1, -1)
        r = pred[:, 0] - y.ravel()[None]  # (M, R)
        jac = (pred[:, 1:] - pred[:, :1]) / h  # (M, dim, R)
        c = np.mean(r * r, axis=1)
        jtj = jac @ jac.transpose(0, 2, 1)
        jtr = jac @ r[:, :, None]
        diag = np.einsum("mii->mi", jtj)
        a = jtj + (lam[:, None] * (diag + 1e-9))[:, :, None] * np.eye(dim)[None]
        delta = -np.linalg.solve(a, jtr)[:, :, 0]
        delta = np.clip(delta, -0.1, 0.1)  # at most a tenth of a cycle per iteration
        trial = x + delta
        xs, ds = _split(trial, drift, n)
        new_cost = cost(stacker, period_fs, xs, u, y, age, ds)
        better = new_cost < c
        x = np.where(better[:, None], trial, x)
        c = np.where(better, new_cost, c)
        lam = np.where(better, lam * 0.3, lam * 4.0)
        yield m * (dim + 2) * u.shape[0]  # rows evaluated (tracker.work)
    return x, c


class PathProblem(NamedTuple):
    """What a path fit of M starts over one window holds fixed: the model, the window, the
    weights, and the normal equations' parts that do not depend on the variables (the walk
    between readings, linear, and the priors). The variables z (M, D): the path (K * N), the
    drift (N), then r (if ``ratio``), then g (if ``gain`` >= 0), then o (if ``level`` >= 0),
    then the knot's change (if knots). ``walk`` and ``walk_normal`` hold one row that every
    start shares, or (knots) one per start."""

    stacker: object
    period_fs: float
    u: np.ndarray  # (K, N) set-points
    u_centred: np.ndarray  # (K, N) set-points minus their mean (d phase / d r)
    y: np.ndarray  # (K, S + 1) readings
    ratio: bool  # r is fitted (variable nz)
    gain: int  # the variable of g, the slot energies' relative gain (-1: not fitted)
    level: int  # the variable of o, the slot energies' offset (-1: not fitted)
    nz: int  # K * N + N: the path and the drift
    d: int  # all variables
    r_sd: float  # std of a reading about the model
    w_sd: float  # std of the random walk per step
    walk: np.ndarray  # (1 or M, (K - 1) N, D) the walk's residuals per unit of w_sd
    walk_normal: np.ndarray  # (1 or M, D, D) walk^T walk / w_sd^2
    prior_w: np.ndarray  # (M, D) the priors' weights (1 / std^2)
    prior_mean: np.ndarray  # (M, D)
    evaluated: list  # [rows the physics evaluated for it so far]: its work


#: The finite-difference step of the path fits' Jacobian, cycles.
PATH_STEP = 1e-4
_NO_JACOBIAN = np.empty((0, 0, 0, 0))


@functools.lru_cache(maxsize=64)
def _walk_rows(k: int, n: int, d: int, gaps: tuple) -> np.ndarray:
    """The walk between readings as rows over the variables: X_i - X_i-1 - gap mu, scaled to
    std walk (gap: steps between the readings), as one start's (1, (K - 1) N, D); kept for the
    next window of the same shape and gaps."""
    nz = k * n + n
    walk = np.zeros((1, (k - 1) * n, d))
    for i in range(1, k):  # X_i - X_i-1 - gap mu, std walk sqrt(gap)
        rows = slice((i - 1) * n, i * n)
        gap = gaps[i - 1]
        walk[0, rows, i * n : (i + 1) * n] = np.eye(n) / gap**0.5
        walk[0, rows, (i - 1) * n : i * n] = -np.eye(n) / gap**0.5
        walk[0, rows, k * n : nz] = -np.eye(n) * gap**0.5
    return walk  # (shared: not to be changed)


@functools.lru_cache(maxsize=64)
def _walk_normal(k: int, n: int, d: int, gaps: tuple, w_sd: float) -> np.ndarray:
    """walk^T walk / w_sd^2 (1, D, D) of the starts without knots (kept)."""
    walk = _walk_rows(k, n, d, gaps)
    return walk.transpose(0, 2, 1) @ walk / w_sd**2  # (shared: not to be changed)


def _add_knots(walk, prior_w, knots, gaps, k: int, n: int, d: int, knot_prior: float):
    """Each start's walk (M, (K - 1) N, D): the walk steps after its knot minus gap * delta
    (the knot's change, the last variable, with prior std ``knot_prior``)."""
    m = prior_w.shape[0]
    walk = np.repeat(walk, m, axis=0)
    for i in range(1, k):
        after = np.flatnonzero(i >= np.asarray(knots[1]))
        rows = (i - 1) * n + np.asarray(knots[0])[after]
        walk[after, rows, d - 1] = -(gaps[i - 1] ** 0.5)
    prior_w[:, d - 1] = 1.0 / knot_prior**2
    return walk


def path_problem(
    stacker,
    period_fs,
    u,
    y,
    age,
    drift,
    r_sd,
    w_sd,
    drift_prior,
    ratio,
    knots,
    knot_prior,
    gain_prior=0.0,
    level_prior=0.0,
    arrival=None,
):
    """The :class:`PathProblem` of M starts (``drift`` (M, N) the starts' drifts, also the
    prior's mean; ``drift_prior`` (M, N) its std; ``gain_prior`` > 0: g is fitted, with that
    prior std about 0; ``level_prior`` > 0: o too; ``arrival``: (mean (N,), std) a prior on the
    errors at the window's first reading)."""
    k, n = u.shape
    m = drift.shape[0]
    fits_gain, fits_level = gain_prior > 0.0, level_prior > 0.0
    nz = k * n + n
    gain = nz + (1 if ratio else 0) if fits_gain else -1
    level = nz + (1 if ratio else 0) + (1 if fits_gain else 0) if fits_level else -1
    d = nz + (1 if ratio else 0) + fits_gain + fits_level + (0 if knots is None else 1)
    gaps = np.maximum(age[:-1] - age[1:], 1.0)  # steps between consecutive readings
    gap_key = tuple(gaps.tolist())
    walk = _walk_rows(k, n, d, gap_key)
    prior_w = np.zeros((m, d))
    prior_w[:, k * n : nz] = 1.0 / drift_prior**2
    if ratio:
        prior_w[:, nz] = 1.0 / HOP_RATIO_PRIOR**2
    if fits_gain:
        prior_w[:, gain] = 1.0 / gain_prior**2
    if fits_level:
        prior_w[:, level] = 1.0 / level_prior**2
    if knots is None:
        walk_normal = _walk_normal(k, n, d, gap_key, float(w_sd))
    else:
        walk = _add_knots(walk, prior_w, knots, gaps, k, n, d, knot_prior)
        walk_normal = walk.transpose(0, 2, 1) @ walk / w_sd**2
    prior_mean = np.zeros((m, d))
    prior_mean[:, k * n : nz] = drift
    if arrival is not None:
        prior_w[:, :n] = 1.0 / arrival[1] ** 2
        prior_mean[:, :n] = arrival[0]
    return PathProblem(
        stacker=stacker,
        period_fs=period_fs,
        u=u,
        u_centred=u - np.add.reduce(u, axis=0) / k,  # (u.mean(axis=0), without its overhead)
        y=y,
        ratio=ratio,
        gain=gain,
        level=level,
        nz=nz,
        d=d,
        r_sd=r_sd,
        w_sd=w_sd,
        walk=walk,
        walk_normal=walk_normal,
        prior_w=prior_w,
        prior_mean=prior_mean,
        evaluated=[0],
    )


def path_residuals(pb: PathProblem, z, starts, err, jac=_NO_JACOBIAN) -> None:
    """Predicted minus measured readings of starts ``starts`` at z (len(starts), D) into
    ``err[starts]`` (K, R), and with ``jac`` d prediction / d path into ``jac[starts]`` (K, R,
    N): the physics evaluates the points :func:`.lm.points` gives, in one batch."""
    k, n = pb.u.shape
    with_jacobian = jac.shape[0] > 0
    rows = np.empty((z.shape[0] * k * (n + 1 if with_jacobian else 1), n))
    lm.points(z, pb.u, pb.u_centred, pb.nz, pb.ratio, PATH_STEP, pb.period_fs, with_jacobian, rows)
    energies, power = _evaluate(pb, rows)
    lm.residuals(energies, power, z, starts, pb.gain, pb.level, pb.y, PATH_STEP, err, jac)


def _evaluate(pb: PathProblem, rows):
    """The physics at ``rows`` (B, N) of delays, fs: (slot energies (B, S), power (B,)), counted
    as the fit's work."""
    pb.evaluated[0] += rows.shape[0]
    return pb.stacker.energies_and_power(rows)


def path_objective(pb: PathProblem, z, starts, err, cost_, data_cost) -> None:
    """The whole cost of starts ``starts`` at z (readings, walk and priors) into
    ``cost_[starts]``, the readings' mean square into ``data_cost[starts]``."""
    args = (pb.walk, pb.prior_w, pb.prior_mean, pb.r_sd, pb.w_sd, cost_, data_cost)
    lm.objective(z, starts, err, *args)


def _diagonal(a: np.ndarray) -> np.ndarray:
    """A writeable view (M, D) of the diagonals of the C-contiguous ``a`` (M, D, D) (the
    normal equations' numpy form sums into it: test_tracker_kernels)."""
    m, d = a.shape[:2]
    return a.reshape(m, d * d)[:, :: d + 1]


def _path_blocks(a: np.ndarray, k: int, n: int) -> np.ndarray:
    """A writeable view (M, K, N, N) of the K diagonal blocks of the C-contiguous ``a`` (M, D, D)
    over the path's variables (reading by reading): block b starts at flat b n (D + 1)."""
    m, d = a.shape[:2]
    flat = a.reshape(m, d * d)[:, : k * n * (d + 1)].reshape(m, k, n * (d + 1))
    return flat[:, :, : n * d].reshape(m, k, n, d)[..., :n]


class _Scratch(NamedTuple):
    """A fit's arrays, written start by start: residuals (M, K, R), Jacobian (M, K, R, N), and
    ``costs`` (3, M): the whole cost, the mean squared residual and the damping; the trials'
    residuals and costs."""

    err: np.ndarray
    jac: np.ndarray
    costs: np.ndarray
    t_err: np.ndarray
    t_costs: np.ndarray

    @classmethod
    def of(cls, pb: PathProblem, m: int):
        k, n = pb.u.shape
        r = pb.y.shape[1]
        costs = np.empty((3, m))
        costs[:2], costs[2] = np.inf, 1e-3
        t_err = np.empty((m, k, r)) if m > 1 else None
        return cls(np.empty((m, k, r)), np.empty((m, k, r, n)), costs, t_err, np.empty((2, m)))


def _lm_iterations(pb: PathProblem, z, iterations: int, prune, chunk=None):
    """Levenberg-Marquardt of every start of ``pb`` from z (M, D), in place, as a generator of
    (cost, data_cost, finished) per start (see :func:`fit_paths` for ``prune``). Without
    ``chunk`` it yields at the start and after each iteration; with it the starts go in groups
    of ``chunk``, and it yields after each group's first evaluation and after each group's
    iteration (a unit of work a real-time loop can afford between readings; the starts are
    independent, so the fits are the same). ``finished``: the last unit has run."""
    m = z.shape[0]
    size = m if chunk is None else max(int(chunk), 1)
    groups = [np.arange(a, min(a + size, m)) for a in range(0, m, size)]
    sc = _Scratch.of(pb, m)
    cost_, data_cost = sc.costs[0], sc.costs[1]
    for gi, g in enumerate(groups):
        zg = z if len(groups) == 1 else z[g]
        path_residuals(pb, zg, g, sc.err, sc.jac)
        path_objective(pb, zg, g, sc.err, cost_, data_cost)
        if chunk is not None or gi == len(groups) - 1:
            yield cost_, data_cost, iterations <= 0 and gi == len(groups) - 1
    act = np.arange(m)  # the starts still iterating
    for it in range(iterations):
        if prune is not None and it == prune[0] and act.size > prune[1]:
            act = np.union1d(np.argsort(cost_)[: prune[1]], [0])  # the first iterates on
        parts = [act[a : a + size] for a in range(0, act.size, size)]
        for pi, part in enumerate(parts):
            _lm_step(pb, z, part, sc)
            yield cost_, data_cost, it == iterations - 1 and pi == len(parts) - 1


def _lm_step(pb: PathProblem, z, act, sc: _Scratch) -> None:
    """One Levenberg-Marquardt iteration of starts ``act``, in place: the trial step
    (:func:`.lm.trial_step`) taken where it lowers the cost. A single start's trial (a
    tracking fit's, which moves nearly every time) is evaluated with its Jacobian at once
    (:func:`.lm.accept_one`): the same figures as its residuals first and the Jacobian after
    a move, with one evaluation less."""
    k, n = pb.u.shape
    one = act.size == 1
    trial = np.empty((act.size, pb.d))
    rows = np.empty((act.size * k * (n + 1 if one else 1), n))
    fixed = (pb.walk_normal, pb.prior_w, pb.prior_mean, sc.costs[2], pb.u_centred, pb.y)
    flags = (pb.nz, pb.ratio, pb.gain, pb.level, pb.r_sd)
    lm.trial_step(
        z[act], act, sc.err, sc.jac, *fixed, *flags, trial, pb.u, PATH_STEP, pb.period_fs, one, rows
    )
    energies, power = _evaluate(pb, rows)
    if one:
        args = (pb.walk, pb.prior_w, pb.prior_mean, pb.r_sd, pb.w_sd, z, sc.err, sc.jac, sc.costs)
        lm.accept_one(
            energies, power, trial, int(act[0]), pb.gain, pb.level, pb.y, PATH_STEP, *args
        )
        return
    lm.residuals(
        energies, power, trial, act, pb.gain, pb.level, pb.y, PATH_STEP, sc.t_err, _NO_JACOBIAN
    )
    path_objective(pb, trial, act, sc.t_err, sc.t_costs[0], sc.t_costs[1])
    cost_, data_cost, lam = sc.costs
    better = sc.t_costs[0, act] < cost_[act]
    lam[act] = np.where(better, lam[act] * 0.3, lam[act] * 10.0)
    if better.any():  # the Jacobian again only where a start moved
        moved = act[better]
        z[moved] = trial[better]
        cost_[moved], data_cost[moved] = sc.t_costs[0, moved], sc.t_costs[1, moved]
        path_residuals(pb, z[moved], moved, sc.err, sc.jac)


def fit_paths(*args, deadline=None, **kwargs) -> PathFits:
    """A :class:`PathFitRun` of these arguments run to its end, or until ``deadline``
    (time.perf_counter()): no iteration starts after it (at least one runs)."""
    run = PathFitRun(*args, **kwargs)
    run.run(deadline)
    return run.result()


class PathFitRun:
    """Moving-horizon fits of a window for M starts at once (x_now, drift: (M, N); drift_prior:
    (M, N) the drift prior's std), each its own Levenberg-Marquardt: the errors at every reading
    X (K, N) and the drift mu (N,), most probable given the readings (std ``r_sd``), a random
    walk between readings (X_k - X_k-1 - mu, std ``w_sd`` per step) and the drift's prior (mean:
    the start's drift); :meth:`result` gives them as a :class:`PathFits`.

    ``ratio``: also fit r, the model's period over the true one minus 1 (a reading's phase is
    u + r (u - mean u) + X): identifiable when the window holds a whole-cycle move; the returned
    x is the error as the model sees it (r applied at the latest reading).

    ``knots``: (stage (M,), first (M,), change (M,)) a knot hypothesis per start: from reading
    ``first`` of the window on, that stage drifts by mu + delta, delta one more variable (start
    ``change``, prior std ``knot_prior``); the path before the knot keeps the drift mu and its
    prior. The returned drift is the one after the knot.

    ``gain_prior`` > 0: also fit g, the slot energies' gain over the readings' minus 1 (prior
    std ``gain_prior`` about 0): where nothing else pins their level (a rig's power is computed
    from the same trace), a gain a fraction of a percent off reads as delay errors that the
    excursions then contradict, and the tracker takes knots that are none.

    ``level_prior`` > 0: also fit o, an offset of every slot energy (prior std ``level_prior``
    about 0): a detector's reading of no light a few 1e-4 of the full scale off reads, in the
    empty slots of a stack, like delay errors (docs/rig.md, "The detector's offset, measured in
    every record").

    ``arrival``: (mean (N,), std) a prior on the errors at the window's first reading: the
    fit before's path there (a moving-horizon estimate's arrival cost), so that a window
    remembers what the readings before it said (under a vibration each reading says little).

    ``prune``: (iterations, keep): after that many iterations only the ``keep`` starts of
    lowest cost iterate on, and the first (no knot: the one the others must beat). ``path0``:
    (M, K, N) the starts' paths (by default straight back from x_now by the drift).

    Run a unit at a time: :meth:`run` until a deadline, again later, :meth:`result` from where
    it got to (a knot test spread over a rig's readings; :func:`fit_paths` runs one at once).
    ``chunk``: the starts go in groups of this many, a group's iteration a unit (51 knot
    hypotheses at once can take a step of a 100 Hz rig; see :func:`_lm_iterations`)."""

    def __init__(
        self,
        stacker,
        period_fs,
        x_now,
        drift,
        u,
        y,
        age,
        iterations: int,
        *,
        r_sd: float,
        w_sd: float,
        drift_prior,
        ratio=False,
        knots=None,
        knot_prior: float = 0.0,
        prune=None,
        path0=None,
        chunk=None,
        gain_prior: float = 0.0,
        level_prior: float = 0.0,
        arrival=None,
    ):
        k, n = u.shape
        m = x_now.shape[0]
        fixed = (u, y, age, drift, r_sd, w_sd, drift_prior, ratio, knots, knot_prior)
        pb = path_problem(stacker, period_fs, *fixed, gain_prior, level_prior, arrival)
        if path0 is None:  # the straight path back from x_now by the drift
            path0 = x_now[:, None, :] - age[None, :, None] * drift[:, None, :]
        extra = np.zeros((m, (1 if ratio else 0) + (pb.gain >= 0) + (pb.level >= 0)))
        change = np.zeros((m, 0)) if knots is None else np.asarray(knots[2], float)[:, None]
        self._pb, self._k, self._n, self._m, self._knots = pb, k, n, m, knots
        self._z = np.concatenate([path0.reshape(m, k * n), drift, extra, change], axis=1)
        self._steps = _lm_iterations(pb, self._z, iterations, prune, chunk)
        self._chunked = chunk is not None
        self.done = False
        self.units = 0  # units of work run so far (chunked: see run)
        self._unit_s = 0.0  # how long the last unit took
        self._unit_rows = 0  # ... and the rows the physics evaluated in it
        if not self._chunked:  # the start's evaluation, as part of building the fit
            self._objective, self._data_cost, self.done = next(self._steps)

    @property
    def rows(self) -> int:
        """The rows (delay vectors) the physics evaluated for this fit so far: its work."""
        return self._pb.evaluated[0]

    def run(self, deadline=None, rows=None) -> bool:
        """Run on until the end, until ``deadline`` (time.perf_counter()), or until ``rows``
        more rows were evaluated; whether the fit is done (as soon as its last unit ran). At
        least one unit runs. A unit is an iteration of every start; with ``chunk``, a group's
        first evaluation or iteration, and none starts that the last one's time (or rows) says
        would end past the deadline (or the rows)."""
        first, start = True, self.rows
        while not self.done and (first or self._may_go_on(deadline, rows, start)):
            first = False
            t0, before = time.perf_counter(), self.rows
            self._objective, self._data_cost, self.done = next(self._steps)
            self._unit_s = time.perf_counter() - t0
            self._unit_rows = self.rows - before
            self.units += 1
        return self.done

    def _may_go_on(self, deadline, rows, start) -> bool:
        if rows is not None and self.rows - start + self._unit_rows > rows:
            return False
        return deadline is None or self._has_time(deadline)

    def _has_time(self, deadline: float) -> bool:
        now = time.perf_counter()
        return now + (self._unit_s if self._chunked else 0.0) < deadline

    def result(self) -> PathFits:
        pb, k, n, m, z = self._pb, self._k, self._n, self._m, self._z
        nz = pb.nz
        fitted_ratio = z[:, nz].copy() if pb.ratio else np.zeros(m)
        x = z[:, (k - 1) * n : k * n] + fitted_ratio[:, None] * pb.u_centred[-1]
        fitted_drift = z[:, k * n : nz].copy()
        if self._knots is not None:
            fitted_drift[np.arange(m), np.asarray(self._knots[0])] += z[:, pb.d - 1]
        return PathFits(
            x=x,
            drift=fitted_drift,
            data_cost=self._data_cost.copy(),
            path=z[:, : k * n].reshape(m, k, n).copy(),  # the fitted errors at every reading
            objective=self._objective.copy(),  # each fit's whole normalized cost
            ratio=fitted_ratio,
            gain=z[:, pb.gain].copy() if pb.gain >= 0 else np.zeros(m),
            level=z[:, pb.level].copy() if pb.level >= 0 else np.zeros(m),
        )
