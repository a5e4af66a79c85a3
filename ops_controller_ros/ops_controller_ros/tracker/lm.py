"""Compiled kernels (numba) of the path fits' Levenberg-Marquardt (:class:`~.fit.PathFitRun`):
the points the physics evaluates, the residuals and the Jacobian read from its output, the whole
cost, and one iteration's normal equations solved into the trial step.

The physics itself stays numpy's (:meth:`~ops_sim_ros.physics.PulseStacker.energies_and_power`,
float32): these kernels do only the float64 arithmetic around it, start by start, which numpy
spreads over a few dozen small calls per iteration. The points and the residuals take the same
operations in the same order as numpy did, so the physics sees the same rows; the sums (the
normal equations, the costs) run in another order and differ from numpy's in the last bits.

The start ``s`` of a problem reads its own rows of the per-start arrays (``prior_w``,
``prior_mean``; ``walk`` and ``walk_normal`` where each start has its own, a knot test's, else
their single row). Signatures are declared, so the kernels compile (or load from numba's cache)
when this module is imported, not in a reading: the first import after a change of this file
compiles them (about 20 s of CPU), later ones load them from numba's cache (its ``__pycache__``
beside this file, or where the tree is not writable the user's cache directory; writes there
are atomic, so processes that compile at once are safe). Where no cache directory is writable
they compile at every import.
"""

from __future__ import annotations

try:
    import numba
except ImportError as exc:  # pragma: no cover - the requirements install it
    raise ImportError(
        "the tracker's path fits need numba (requirements/python.txt; `make setup` installs it)"
    ) from exc
import warnings

import numpy as np


def _probe():  # pragma: no cover - never called: its decoration finds numba's cache directory
    return 0


def _cacheable() -> bool:
    """Whether numba finds a writable cache directory for this file (its decoration of a
    function here raises where it does not)."""
    try:
        numba.njit(cache=True)(_probe)
    except RuntimeError:
        warnings.warn(
            "numba finds no writable cache directory for the tracker's kernels: they compile at "
            "every import (set NUMBA_CACHE_DIR to keep them)",
            stacklevel=2,
        )
        return False
    return True


_KERNEL = {"nogil": True, "error_model": "numpy"}  # (the helpers: compiled into the entries)
_ENTRY = {**_KERNEL, "cache": _cacheable()}  # the kernels fit.py calls
_W1, _W2, _W3, _W4 = (
    numba.float64[:],
    numba.float64[:, :],
    numba.float64[:, :, :],
    numba.float64[:, :, :, :],
)  # written
_R1, _R2, _R3, _R4 = (
    numba.types.Array(numba.float64, d, "A", readonly=True) for d in (1, 2, 3, 4)
)  # read only
_I1 = numba.types.Array(numba.int64, 1, "A", readonly=True)
_I, _B, _F = numba.int64, numba.boolean, numba.float64


@numba.njit(inline="always")
def _entry(energies, power, row, r, s, gain, level, scale, offset):
    """Entry r of a predicted reading: a slot energy (scaled, offset) or the power."""
    if r == s:
        return power[row]
    value = energies[row, r]
    if gain >= 0:
        value = value * scale
    if level >= 0:
        value = value + offset
    return value


@numba.njit(**_KERNEL)
def _residuals1(energies, power, row0, x, gain, level, y, h, e, jac, with_jacobian):
    """One start's predicted minus read readings e (K, R) from the physics' output (slot
    energies (B, S), power (B,)) at its points (from row ``row0``), and ``with_jacobian`` d
    prediction / d path (K, R, N): the slot energies (not the power) times 1 + g where g is
    fitted (``gain`` >= 0), plus o where o is (``level`` >= 0)."""
    k, r_all = y.shape
    s = r_all - 1
    n = jac.shape[2] if with_jacobian else 0
    scale = 1.0 + x[gain] if gain >= 0 else 1.0
    offset = x[level] if level >= 0 else 0.0
    for kk in range(k):
        row = row0 + kk * (n + 1)
        for r in range(r_all):
            p0 = _entry(energies, power, row, r, s, gain, level, scale, offset)
            e[kk, r] = p0 - y[kk, r]
            for j in range(n):
                pj = _entry(energies, power, row + 1 + j, r, s, gain, level, scale, offset)
                jac[kk, r, j] = (pj - p0) / h


@numba.njit(**_KERNEL)
def _objective1(x, s, e, walk, prior_w, prior_mean, r_sd, w_sd):
    """(whole cost, mean squared residual) of one start at x with residuals e (K, R): the
    readings' (std r_sd), the walk's (std w_sd) and the priors' (start ``s``'s rows)."""
    k, r_all = e.shape
    d = x.size
    reads = 0.0
    for kk in range(k):
        for r in range(r_all):
            reads += e[kk, r] * e[kk, r]
    w = walk[s if walk.shape[0] > 1 else 0]
    steps = 0.0
    for i in range(w.shape[0]):
        v = 0.0
        for c in range(d):
            v += w[i, c] * x[c]
        steps += v * v
    priors = 0.0
    for c in range(d):
        dz = x[c] - prior_mean[s, c]
        priors += dz * dz * prior_w[s, c]
    return reads / r_sd**2 + steps / w_sd**2 + priors, reads / (k * r_all)


@numba.njit(**_KERNEL)
def _points(z, u, u_centred, nz, ratio, h, period_fs, with_jacobian, out):
    """The delays (fs) the physics evaluates for starts z (M, D) into ``out``: per start and
    reading the path's point (u + X + r (u - mean u)) and, ``with_jacobian``, after it the
    point moved by h in each stage (rows M K (N + 1), else M K); the same operations in the
    same order as numpy's broadcast sums, so the same figures."""
    m = z.shape[0]
    k, n = u.shape
    per = n + 1 if with_jacobian else 1
    row = 0
    for a in range(m):
        r = z[a, nz] if ratio else 0.0
        for kk in range(k):
            for jj in range(per):
                for j in range(n):
                    base = u[kk, j] + z[a, kk * n + j]
                    base = base + (r * u_centred[kk, j] if ratio else 0.0)
                    if with_jacobian:
                        base = base + (h if jj - 1 == j else 0.0)
                    out[row, j] = base * period_fs
                row += 1


@numba.njit(inline="always")
def _add_cross(a_mat, p, col, jac, kk, i, dp, upto, r_var):
    """J^T J's entries (p, col) and (col, p): the path variable p against an extra variable
    whose derivative is ``dp`` over the first ``upto`` entries (``upto`` < 0: 1 on the first
    -upto entries, the level)."""
    v = 0.0
    if upto > 0:
        for r in range(upto):
            v += jac[kk, r, i] * dp[kk, r]
    else:
        for r in range(-upto):
            v += jac[kk, r, i]
    a_mat[p, col] += v / r_var
    a_mat[col, p] += v / r_var


@numba.njit(**_KERNEL)
def _add_extra(a_mat, b, e, g, f, nz, ratio, gain, level, r_var):
    """The normal equations' entries among r, g and o, and their J^T r."""
    k, r_all = e.shape
    slots = r_all - 1
    gg = ge = ff = fe = gf = ee = g1 = f1 = 0.0
    for kk in range(k):
        for r in range(r_all):
            gg += g[kk, r] * g[kk, r]
            ge += g[kk, r] * e[kk, r]
            ff += f[kk, r] * f[kk, r]
            fe += f[kk, r] * e[kk, r]
            gf += g[kk, r] * f[kk, r]
            if r < slots:
                ee += e[kk, r]
                g1 += g[kk, r]
                f1 += f[kk, r]
    if ratio:
        a_mat[nz, nz] += gg / r_var
        b[nz] += ge / r_var
    if gain >= 0:
        a_mat[gain, gain] += ff / r_var
        b[gain] += fe / r_var
        if ratio:
            a_mat[nz, gain] += gf / r_var
            a_mat[gain, nz] += gf / r_var
    if level >= 0:
        a_mat[level, level] += (k * slots) / r_var
        b[level] += ee / r_var
        if ratio:
            a_mat[nz, level] += g1 / r_var
            a_mat[level, nz] += g1 / r_var
        if gain >= 0:
            a_mat[gain, level] += f1 / r_var
            a_mat[level, gain] += f1 / r_var


@numba.njit(**_KERNEL)
def _add_readings(a_mat, b, x, e, jac, u_centred, y, nz, ratio, gain, level, r_sd):
    """The readings' part of the normal equations (J^T J, J^T r over std r_sd): block diagonal
    in the path, and the columns of r (d phase / d r: the centred set-points), g (the slot
    energies at 1 + g = 1) and o (1 on every slot energy)."""
    k, r_all, n = jac.shape
    r_var = r_sd**2
    slots = r_all - 1
    g = np.zeros((k, r_all))  # d prediction / d r
    f = np.zeros((k, r_all))  # d prediction / d g
    if ratio:
        for kk in range(k):
            for r in range(r_all):
                v = 0.0
                for j in range(n):
                    v += jac[kk, r, j] * u_centred[kk, j]
                g[kk, r] = v
    if gain >= 0:
        lev = x[level] if level >= 0 else 0.0
        for kk in range(k):
            for r in range(slots):
                f[kk, r] = (e[kk, r] + y[kk, r] - lev) / (1.0 + x[gain])
    for kk in range(k):
        o = kk * n
        for i in range(n):
            for j in range(n):
                v = 0.0
                for r in range(r_all):
                    v += jac[kk, r, i] * jac[kk, r, j]
                a_mat[o + i, o + j] += v / r_var
            v = 0.0
            for r in range(r_all):
                v += jac[kk, r, i] * e[kk, r]
            b[o + i] += v / r_var
            if ratio:
                _add_cross(a_mat, o + i, nz, jac, kk, i, g, r_all, r_var)
            if gain >= 0:
                _add_cross(a_mat, o + i, gain, jac, kk, i, f, r_all, r_var)
            if level >= 0:
                _add_cross(a_mat, o + i, level, jac, kk, i, f, -slots, r_var)
    _add_extra(a_mat, b, e, g, f, nz, ratio, gain, level, r_var)


@numba.njit(inline="always")
def _eliminate(a_mat, b, c, i, band, rest):
    """Row i minus its multiple that zeroes column c (the pivot's row c holds its figures in
    columns c + 1 .. band - 1 and rest .. D - 1)."""
    factor = a_mat[i, c] / a_mat[c, c]
    if factor != 0.0:
        for j in range(c + 1, band):
            a_mat[i, j] -= factor * a_mat[c, j]
        for j in range(rest, b.size):
            a_mat[i, j] -= factor * a_mat[c, j]
        b[i] -= factor * b[c]


@numba.njit(**_KERNEL)
def _solve(a_mat, b, n, kn) -> None:
    """b <- a_mat^-1 b for the normal equations of a path (a_mat overwritten): positive
    definite, and over the path's variables (the first ``kn``, N = ``n`` a reading)
    block-tridiagonal (the walk couples only consecutive readings), the rest dense. Gaussian
    elimination without pivoting (stable on a positive definite matrix) keeps that shape, so
    each pivot of the path touches only its own block, the next and the rest: O(K N^3)."""
    d = b.size
    for c in range(d):
        band = min((c // n + 2) * n, kn) if c < kn else c + 1
        rest = max(kn, c + 1)
        for i in range(c + 1, band):
            _eliminate(a_mat, b, c, i, band, rest)
        for i in range(rest, d):
            _eliminate(a_mat, b, c, i, band, rest)
    for i in range(d - 1, -1, -1):
        band = min((i // n + 2) * n, kn) if i < kn else i + 1
        v = b[i]
        for j in range(i + 1, band):
            v -= a_mat[i, j] * b[j]
        for j in range(max(kn, i + 1), d):
            v -= a_mat[i, j] * b[j]
        b[i] = v / a_mat[i, i]


@numba.njit(**_KERNEL)
def _step1(x, s, e, jac, walk_normal, prior_w, prior_mean, lam, u_centred, y, flags, a_mat, b):
    """One start's Levenberg-Marquardt step from x (residuals e, Jacobian jac): the normal
    equations of the whole cost, damped by lam[s], solved; x + the step clipped to a tenth
    of a cycle into b. ``flags``: (nz, ratio, gain, level); ``a_mat`` (D, D) scratch."""
    nz, ratio, gain, level, r_sd = flags
    d = x.size
    a_mat[:, :] = walk_normal[s if walk_normal.shape[0] > 1 else 0]
    for i in range(d):
        v = 0.0
        for c in range(d):
            v += a_mat[i, c] * x[c]
        b[i] = v
    _add_readings(a_mat, b, x, e, jac, u_centred, y, nz, ratio, gain, level, r_sd)
    for i in range(d):
        a_mat[i, i] += prior_w[s, i]
        b[i] += prior_w[s, i] * (x[i] - prior_mean[s, i])
    for i in range(d):
        a_mat[i, i] += lam[s] * (a_mat[i, i] + 1e-12)
    n = jac.shape[2]
    _solve(a_mat, b, n, nz - n)
    for i in range(d):
        step = -b[i]
        if step < -0.1:
            step = -0.1
        elif step > 0.1:
            step = 0.1
        b[i] = x[i] + step


# ---------------------------------------------------------------- the kernels fit.py calls
_FIXED = (_R3, _R2, _R2, _R1, _R2, _R2, _I, _B, _I, _I, _F)  # walk_normal, ..., r_sd


@numba.njit(numba.void(_R2, _R2, _R2, _I, _B, _F, _F, _B, _W2), **_ENTRY)
def points(z, u, u_centred, nz, ratio, h, period_fs, with_jacobian, out):
    """:func:`_points` of starts z into ``out``."""
    _points(z, u, u_centred, nz, ratio, h, period_fs, with_jacobian, out)


@numba.njit(numba.void(_R2, _R1, _R2, _I1, _I, _I, _R2, _F, _W3, _W4), **_ENTRY)
def residuals(energies, power, z, starts, gain, level, y, h, err, jac):
    """:func:`_residuals1` of starts z (A, D) from the physics' output at their
    :func:`points` into err[starts[a]] (K, R), and where ``jac`` is not empty the Jacobian
    into jac[starts[a]] (K, R, N)."""
    k = y.shape[0]
    with_jacobian = jac.shape[0] > 0
    per = jac.shape[3] + 1 if with_jacobian else 1
    for a in range(z.shape[0]):
        s, row0 = starts[a], a * k * per
        if with_jacobian:
            _residuals1(energies, power, row0, z[a], gain, level, y, h, err[s], jac[s], True)
        else:
            none = np.empty((0, 0, 0))
            _residuals1(energies, power, row0, z[a], gain, level, y, h, err[s], none, False)


@numba.njit(numba.void(_R2, _I1, _R3, _R3, _R2, _R2, _F, _F, _W1, _W1), **_ENTRY)
def objective(z, starts, err, walk, prior_w, prior_mean, r_sd, w_sd, cost, data_cost):
    """The whole cost of starts z (A, D) into cost[s] and the readings' mean square into
    data_cost[s], s = starts[a] (its residuals err[s], :func:`_objective1`)."""
    for a in range(z.shape[0]):
        s = starts[a]
        cost[s], data_cost[s] = _objective1(z[a], s, err[s], walk, prior_w, prior_mean, r_sd, w_sd)


@numba.njit(numba.void(_R2, _I1, _R3, _R4, *_FIXED, _W2, _R2, _F, _F, _B, _W2), **_ENTRY)
def trial_step(
    z,
    starts,
    err,
    jac,
    walk_normal,
    prior_w,
    prior_mean,
    lam,
    u_centred,
    y,
    nz,
    ratio,
    gain,
    level,
    r_sd,
    out,
    u,
    h,
    period_fs,
    with_jacobian,
    rows,
):
    """Each start's trial (:func:`_step1`, s = starts[a] from z[a] with err[s], jac[s]) into
    ``out`` (A, D); where ``rows`` is not empty, the trials' :func:`_points` into it too (the
    delays the physics is to evaluate, in the same call)."""
    flags = (nz, ratio, gain, level, r_sd)
    d = z.shape[1]
    a_mat, b = np.empty((d, d)), np.empty(d)
    for a in range(z.shape[0]):
        s = starts[a]
        fixed = (walk_normal, prior_w, prior_mean, lam, u_centred, y, flags)
        _step1(z[a], s, err[s], jac[s], *fixed, a_mat, b)
        out[a] = b
    if rows.shape[0] > 0:
        _points(out, u, u_centred, nz, ratio, h, period_fs, with_jacobian, rows)


@numba.njit(
    numba.boolean(_R2, _R1, _R2, _I, _I, _I, _R2, _F, _R3, _R2, _R2, _F, _F, _W2, _W3, _W4, _W2),
    **_ENTRY,
)
def accept_one(
    energies,
    power,
    trial,
    a,
    gain,
    level,
    y,
    h,
    walk,
    prior_w,
    prior_mean,
    r_sd,
    w_sd,
    z,
    err,
    jac,
    costs,
):
    """The trial (1, D) of start ``a`` from the physics' output at its points with the
    Jacobian: its residuals, Jacobian and whole cost, taken into z[a], err[a], jac[a] and
    ``costs`` (3, M: whole cost, mean squared residual, damping) if it lowers the cost (the
    damping times 0.3), else left (the damping times 10); whether it was taken."""
    e, j = np.empty(err.shape[1:]), np.empty(jac.shape[1:])
    _residuals1(energies, power, 0, trial[0], gain, level, y, h, e, j, True)
    cost, data = _objective1(trial[0], a, e, walk, prior_w, prior_mean, r_sd, w_sd)
    if not cost < costs[0, a]:
        costs[2, a] *= 10.0
        return False
    costs[2, a] *= 0.3
    z[a] = trial[0]
    costs[0, a], costs[1, a] = cost, data
    err[a], jac[a] = e, j
    return True


def _warm() -> None:
    """Call each kernel once on a tiny problem: numba's first call in a process (its type
    checks and the modules they load) takes a large part of a second, which belongs to the
    import, not to a reading."""
    k, n, r = 2, 1, 2
    d = k * n + n
    z, u, y = np.zeros((1, d)), np.zeros((k, n)), np.zeros((k, r))
    starts = np.zeros(1, dtype=np.int64)
    rows = np.empty((k * (n + 1), n))
    points(z, u, u, d - n, False, 1e-4, 1.0, True, rows)
    energies, power = np.ones((len(rows), r - 1)), np.ones(len(rows))
    err, jac = np.zeros((1, k, r)), np.zeros((1, k, r, n))
    residuals(energies, power, z, starts, -1, -1, y, 1e-4, err, jac)
    walk, normal, prior = np.zeros((1, n, d)), np.eye(d)[None], np.ones((1, d))
    costs = np.ones((3, 1))
    objective(z, starts, err, walk, prior, prior, 1.0, 1.0, costs[0], costs[1])
    fixed = (normal, prior, prior, costs[2], u, y, d - n, False, -1, -1, 1.0)
    trial_step(z, starts, err, jac, *fixed, np.empty_like(z), u, 1e-4, 1.0, True, rows)
    args = (prior, prior, 1.0, 1.0, z, err, jac, costs)
    accept_one(energies, power, z, 0, -1, -1, y, 1e-4, walk, *args)


_warm()
