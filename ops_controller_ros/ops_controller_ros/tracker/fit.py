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
    iteration and returns (x, cost) (``x, cost = yield from refine(...)``).

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
        yield
    return x, c


class PathProblem(NamedTuple):
    """What a path fit of M starts over one window holds fixed: the model, the window, the
    weights, and the normal equations' parts that do not depend on the variables (the walk
    between readings, linear, and the priors). The variables z (M, D): the path (K * N), the
    drift (N), then r (if ``ratio``), then g (if ``gain`` >= 0), then o (if ``level`` >= 0),
    then the knot's change (if knots)."""

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
    walk: np.ndarray  # (M, (K - 1) N, D) the walk's residuals per unit of w_sd
    walk_normal: np.ndarray  # (M, D, D) walk^T walk / w_sd^2
    prior_w: np.ndarray  # (M, D) the priors' weights (1 / std^2)
    prior_mean: np.ndarray  # (M, D)
    offsets: np.ndarray  # (N + 1, N) finite-difference points of the Jacobian
    blocks: np.ndarray  # (K, N) the path's indices per reading
    evaluated: list  # [rows the physics evaluated for it so far]: its work


@functools.lru_cache(maxsize=64)
def _walk_rows(k: int, n: int, d: int, gaps: tuple) -> np.ndarray:
    """The walk between readings as rows over the variables: X_i - X_i-1 - gap mu, scaled to
    std walk (gap: steps between the readings); read-only, kept for the next window of the same
    shape and gaps."""
    nz = k * n + n
    walk = np.zeros(((k - 1) * n, d))
    for i in range(1, k):  # X_i - X_i-1 - gap mu, std walk sqrt(gap)
        rows = slice((i - 1) * n, i * n)
        gap = gaps[i - 1]
        walk[rows, i * n : (i + 1) * n] = np.eye(n) / gap**0.5
        walk[rows, (i - 1) * n : i * n] = -np.eye(n) / gap**0.5
        walk[rows, k * n : nz] = -np.eye(n) * gap**0.5
    walk.flags.writeable = False
    return walk


@functools.lru_cache(maxsize=64)
def _walk(k: int, n: int, d: int, gaps: tuple, m: int) -> np.ndarray:
    """The walk rows of M starts without knots: one read-only view (M, (K - 1) N, D)."""
    return np.broadcast_to(_walk_rows(k, n, d, gaps), (m, (k - 1) * n, d))


@functools.lru_cache(maxsize=64)
def _walk_normal(k: int, n: int, d: int, gaps: tuple, m: int, w_sd: float) -> np.ndarray:
    """walk^T walk / w_sd^2 (M, D, D) of M starts without knots (read-only, kept)."""
    walk = _walk(k, n, d, gaps, m)
    out = walk.transpose(0, 2, 1) @ walk / w_sd**2
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=16)
def _index(k: int, n: int, h: float) -> tuple:
    """(offsets (N + 1, N): the Jacobian's finite-difference points; blocks (K, N): the path's
    variables per reading), read-only."""
    offsets = np.concatenate([np.zeros((1, n)), h * np.eye(n)])
    blocks = (np.arange(k)[:, None] * n + np.arange(n)[None]).reshape(k, n)
    offsets.flags.writeable = blocks.flags.writeable = False
    return offsets, blocks


def _add_knots(walk, prior_w, knots, gaps, k: int, n: int, d: int, knot_prior: float):
    """The walk steps after each start's knot: minus gap * delta (the knot's change, the last
    variable, with prior std ``knot_prior``)."""
    walk = walk.copy()
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
):
    """The :class:`PathProblem` of M starts (``drift`` (M, N) the starts' drifts, also the
    prior's mean; ``drift_prior`` (M, N) its std; ``gain_prior`` > 0: g is fitted, with that
    prior std about 0; ``level_prior`` > 0: o too)."""
    k, n = u.shape
    m = drift.shape[0]
    fits_gain, fits_level = gain_prior > 0.0, level_prior > 0.0
    nz = k * n + n
    gain = nz + (1 if ratio else 0) if fits_gain else -1
    level = nz + (1 if ratio else 0) + (1 if fits_gain else 0) if fits_level else -1
    d = nz + (1 if ratio else 0) + fits_gain + fits_level + (0 if knots is None else 1)
    gaps = np.maximum(age[:-1] - age[1:], 1.0)  # steps between consecutive readings
    gap_key = tuple(gaps.tolist())
    walk = _walk(k, n, d, gap_key, m)
    prior_w = np.zeros((m, d))
    prior_w[:, k * n : nz] = 1.0 / drift_prior**2
    if ratio:
        prior_w[:, nz] = 1.0 / HOP_RATIO_PRIOR**2
    if fits_gain:
        prior_w[:, gain] = 1.0 / gain_prior**2
    if fits_level:
        prior_w[:, level] = 1.0 / level_prior**2
    if knots is not None:
        walk = _add_knots(walk, prior_w, knots, gaps, k, n, d, knot_prior)
    prior_mean = np.zeros((m, d))
    prior_mean[:, k * n : nz] = drift.copy()
    if knots is None:
        walk_normal = _walk_normal(k, n, d, gap_key, m, float(w_sd))
    else:
        walk_normal = walk.transpose(0, 2, 1) @ walk / w_sd**2
    offsets, blocks = _index(k, n, 1e-4)
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
        offsets=offsets,
        blocks=blocks,
        evaluated=[0],
    )


def path_residuals(pb: PathProblem, z: np.ndarray, with_jacobian: bool):
    """Predicted minus measured readings (M, K, R) and d prediction / d path (M, K, R, N) (None
    without ``with_jacobian``); z: (M, D), any number M of the starts."""
    k, n = pb.u.shape
    m = z.shape[0]
    h = pb.offsets[1, 0]
    xs = z[:, : k * n].reshape(m, k, n)
    pts = pb.u[None] + xs + (z[:, pb.nz, None, None] * pb.u_centred[None] if pb.ratio else 0.0)
    if with_jacobian:
        pts = pts[:, :, None, :] + pb.offsets[None, None]  # (M, K, N + 1, N)
    rows = pts.reshape(-1, n)
    pb.evaluated[0] += rows.shape[0]
    energies, power = pb.stacker.energies_and_power(rows * pb.period_fs)
    pred = np.concatenate([energies, power[:, None]], axis=1)
    if pb.gain >= 0:  # the slot energies (not the power) times 1 + g
        scale = np.repeat(1.0 + z[:, pb.gain], pred.shape[0] // m)
        pred[:, :-1] *= scale[:, None]
    if pb.level >= 0:  # ... plus o
        pred[:, :-1] += np.repeat(z[:, pb.level], pred.shape[0] // m)[:, None]
    if not with_jacobian:
        return pred.reshape(m, k, -1) - pb.y[None], None
    pred = pred.reshape(m, k, n + 1, -1)
    jac_k = (pred[:, :, 1:] - pred[:, :, :1]).transpose(0, 1, 3, 2) / h  # M, K, R, N
    return pred[:, :, 0] - pb.y[None], jac_k


def _rows(a: np.ndarray, i: np.ndarray) -> np.ndarray:
    """``a[i]`` for reading (``i``: sorted distinct starts): ``a`` itself where ``i`` takes every
    row (the same figures in the same layout, without the copy); a view the caller must not
    change."""
    if i.size == a.shape[0] and (a.shape[0] == 1 or a.strides[0] != 0):
        return a
    return a[i]


def _diagonal(a: np.ndarray) -> np.ndarray:
    """A writeable view (M, D) of the diagonals of the C-contiguous ``a`` (M, D, D)."""
    m, d = a.shape[:2]
    return a.reshape(m, d * d)[:, :: d + 1]


def _path_blocks(a: np.ndarray, k: int, n: int) -> np.ndarray:
    """A writeable view (M, K, N, N) of the K diagonal blocks of the C-contiguous ``a`` (M, D, D)
    over the path's variables (reading by reading): block b starts at flat b n (D + 1)."""
    m, d = a.shape[:2]
    flat = a.reshape(m, d * d)[:, : k * n * (d + 1)].reshape(m, k, n * (d + 1))
    return flat[:, :, : n * d].reshape(m, k, n, d)[..., :n]


def _mean_squares(e: np.ndarray) -> np.ndarray:
    """The mean square of each start's residuals (M, K, R) -> (M,): what ``np.mean(e ** 2,
    axis=(1, 2))`` computes (the same sum, then the same division), without its overhead."""
    return np.add.reduce(e * e, axis=(1, 2)) / (e.shape[1] * e.shape[2])


def path_objective(pb: PathProblem, z, err, i) -> np.ndarray:
    """The whole cost of starts i at z (len(i), D): readings, walk and priors."""
    dz = z - _rows(pb.prior_mean, i)
    walk_res = np.einsum("mrd,md->mr", _rows(pb.walk, i), z)
    return (
        np.einsum("mkr,mkr->m", err, err) / pb.r_sd**2
        + np.einsum("mr,mr->m", walk_res, walk_res) / pb.w_sd**2
        + np.einsum("md,md,md->m", dz, dz, _rows(pb.prior_w, i))
    )


def path_normal_equations(pb: PathProblem, z, err, jac_k, i):
    """J^T J (M, D, D) and J^T r (M, D) of the whole cost of starts i at z; no full Jacobian is
    formed: the readings (block diagonal in the path, plus r), the walk and the priors."""
    r_var, blocks, nz = pb.r_sd**2, pb.blocks, pb.nz
    k, n = blocks.shape
    jtj = pb.walk_normal[i]  # (a copy: the sums go into it)
    jtr = np.einsum("mde,me->md", jtj, z)
    data_jtj = np.einsum("mkri,mkrj->mkij", jac_k, jac_k) / r_var  # (M, K, N, N)
    _path_blocks(jtj, k, n)[...] += data_jtj
    path_part = jtr[:, : k * n].reshape(jtr.shape[0], k, n)  # (a view: the KN are contiguous)
    path_part += np.einsum("mkri,mkr->mki", jac_k, err) / r_var
    if pb.ratio:  # d phase / d r = the centred set-points
        g = np.einsum("mkrn,kn->mkr", jac_k, pb.u_centred)
        cross = np.einsum("mkri,mkr->mki", jac_k, g) / r_var
        jtj[:, blocks, nz] += cross
        jtj[:, nz, blocks] += cross
        jtj[:, nz, nz] += np.einsum("mkr,mkr->m", g, g) / r_var
        jtr[:, nz] += np.einsum("mkr,mkr->m", g, err) / r_var
    if pb.gain >= 0:  # d prediction / d g = the slot energies at 1 + g = 1
        gi = pb.gain
        level = z[:, pb.level, None, None] if pb.level >= 0 else 0.0
        f = (err + pb.y[None] - level) / (1.0 + z[:, gi])[:, None, None]
        f[:, :, -1] = 0.0
        cross = np.einsum("mkri,mkr->mki", jac_k, f) / r_var
        jtj[:, blocks, gi] += cross
        jtj[:, gi, blocks] += cross
        jtj[:, gi, gi] += np.einsum("mkr,mkr->m", f, f) / r_var
        jtr[:, gi] += np.einsum("mkr,mkr->m", f, err) / r_var
        if pb.ratio:
            both = np.einsum("mkr,mkr->m", g, f) / r_var
            jtj[:, nz, gi] += both
            jtj[:, gi, nz] += both
    if pb.level >= 0:  # d prediction / d o = 1 for every slot energy, 0 for the power
        li = pb.level
        ones = np.ones(err.shape[1:])
        ones[:, -1] = 0.0
        cross = np.einsum("mkri,kr->mki", jac_k, ones) / r_var
        jtj[:, blocks, li] += cross
        jtj[:, li, blocks] += cross
        jtj[:, li, li] += ones.sum() / r_var
        jtr[:, li] += np.einsum("mkr,kr->m", err, ones) / r_var
        if pb.ratio:
            both = np.einsum("mkr,kr->m", g, ones) / r_var
            jtj[:, nz, li] += both
            jtj[:, li, nz] += both
        if pb.gain >= 0:
            both = np.einsum("mkr,kr->m", f, ones) / r_var
            jtj[:, pb.gain, li] += both
            jtj[:, li, pb.gain] += both
    prior_w = _rows(pb.prior_w, i)
    _diagonal(jtj)[...] += prior_w
    jtr += prior_w * (z - _rows(pb.prior_mean, i))
    return jtj, jtr


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
    err = jac_k = None
    cost_, data_cost = np.full(m, np.inf), np.full(m, np.inf)
    for gi, g in enumerate(groups):
        zg = _rows(z, g)
        e, j = path_residuals(pb, zg, True)
        if len(groups) == 1:  # as they come (their layout sets the sums' rounding downstream)
            err, jac_k = e, j
        else:
            if err is None:
                err, jac_k = np.empty((m, *e.shape[1:])), np.empty((m, *j.shape[1:]))
            err[g], jac_k[g] = e, j
        cost_[g] = path_objective(pb, zg, e, g)
        data_cost[g] = _mean_squares(e)
        if chunk is not None or gi == len(groups) - 1:
            yield cost_, data_cost, iterations <= 0 and gi == len(groups) - 1
    lam = np.full(m, 1e-3)
    act = np.arange(m)  # the starts still iterating
    for it in range(iterations):
        if prune is not None and it == prune[0] and act.size > prune[1]:
            act = np.union1d(np.argsort(cost_)[: prune[1]], [0])  # the first iterates on
        parts = [act[a : a + size] for a in range(0, act.size, size)]
        for pi, part in enumerate(parts):
            _lm_step(pb, z, part, err, jac_k, cost_, data_cost, lam)
            yield cost_, data_cost, it == iterations - 1 and pi == len(parts) - 1


def _lm_step(pb: PathProblem, z, act, err, jac_k, cost_, data_cost, lam) -> None:
    """One Levenberg-Marquardt iteration of starts ``act``, in place."""
    za = _rows(z, act)
    jtj, jtr = path_normal_equations(pb, za, _rows(err, act), _rows(jac_k, act), act)
    damping = lam[act, None] * (np.einsum("mii->mi", jtj) + 1e-12)
    _diagonal(jtj)[...] += damping  # (jtj is the equations' own copy)
    step = -np.linalg.solve(jtj, jtr[:, :, None])[:, :, 0]
    trial = za + np.minimum(np.maximum(step, -0.1), 0.1)  # (np.clip, without its overhead)
    if act.size == 1:
        _try_one(pb, z, act, trial, err, jac_k, cost_, data_cost, lam)
        return
    t_err, _ = path_residuals(pb, trial, False)
    t_cost = path_objective(pb, trial, t_err, act)
    better = t_cost < cost_[act]
    lam[act] = np.where(better, lam[act] * 0.3, lam[act] * 10.0)
    if better.any():  # the Jacobian again only where a start moved
        moved = act[better]
        z[moved] = trial[better]
        cost_[moved] = t_cost[better]
        data_cost[moved] = _mean_squares(t_err[better])
        err[moved], jac_k[moved] = path_residuals(pb, z[moved], True)


def _try_one(pb: PathProblem, z, act, trial, err, jac_k, cost_, data_cost, lam) -> None:
    """The trial of a single start (a tracking fit's, which moves nearly every time): evaluated
    with its Jacobian at once, taken if it lowers the cost. The same figures as the trial's
    residuals first and the Jacobian after a move (the physics evaluates each row alone), with
    one evaluation less."""
    t_err, t_jac = path_residuals(pb, trial, True)
    t_cost = path_objective(pb, trial, t_err, act)
    a = int(act[0])
    if not t_cost[0] < cost_[a]:
        lam[a] *= 10.0
        return
    lam[a] *= 0.3
    rows = slice(a, a + 1)
    z[rows] = trial
    cost_[a] = t_cost[0]
    data_cost[a] = _mean_squares(t_err)[0]
    err[rows], jac_k[rows] = t_err, t_jac


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
    ):
        k, n = u.shape
        m = x_now.shape[0]
        fixed = (u, y, age, drift, r_sd, w_sd, drift_prior, ratio, knots, knot_prior)
        pb = path_problem(stacker, period_fs, *fixed, gain_prior, level_prior)
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
