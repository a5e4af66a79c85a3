"""The path fits' compiled kernels (tracker/lm.py) against the numpy they replace: the same
residuals and Jacobian to the bit (the physics sees the same points), the same whole cost and
Levenberg-Marquardt trial to float64 rounding (their sums run in another order)."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.tracker import fit, lm
from ops_controller_ros.tracker.knots import knot_hypotheses
from ops_sim_ros.physics import stacker_from_config

H = fit.PATH_STEP


def _numpy_residuals(pb, z):
    """Predicted minus read readings (M, K, R) and d prediction / d path (M, K, R, N)."""
    k, n = pb.u.shape
    m = z.shape[0]
    xs = z[:, : k * n].reshape(m, k, n)
    pts = pb.u[None] + xs + (z[:, pb.nz, None, None] * pb.u_centred[None] if pb.ratio else 0.0)
    offsets = np.concatenate([np.zeros((1, n)), H * np.eye(n)])
    rows = (pts[:, :, None, :] + offsets[None, None]).reshape(-1, n)
    energies, power = pb.stacker.energies_and_power(rows * pb.period_fs)
    pred = np.concatenate([energies, power[:, None]], axis=1)
    if pb.gain >= 0:
        pred[:, :-1] *= np.repeat(1.0 + z[:, pb.gain], pred.shape[0] // m)[:, None]
    if pb.level >= 0:
        pred[:, :-1] += np.repeat(z[:, pb.level], pred.shape[0] // m)[:, None]
    pred = pred.reshape(m, k, n + 1, -1)
    jac = (pred[:, :, 1:] - pred[:, :, :1]).transpose(0, 1, 3, 2) / H
    return pred[:, :, 0] - pb.y[None], jac


def _numpy_objective(pb, z, err):
    walk = np.broadcast_to(pb.walk, (z.shape[0], *pb.walk.shape[1:]))
    walk_res = np.einsum("mrd,md->mr", walk, z)
    dz = z - pb.prior_mean
    return (
        np.einsum("mkr,mkr->m", err, err) / pb.r_sd**2
        + np.einsum("mr,mr->m", walk_res, walk_res) / pb.w_sd**2
        + np.einsum("md,md,md->m", dz, dz, pb.prior_w)
    )


def _numpy_trial(pb, z, err, jac, lam):
    """The damped normal equations of the whole cost, dense, solved by numpy."""
    m, d = z.shape
    k, n = pb.u.shape
    r_var = pb.r_sd**2
    walk = np.broadcast_to(pb.walk, (m, *pb.walk.shape[1:]))
    full = np.zeros((m, k, err.shape[2], d))  # d prediction / d z, reading by reading
    for i in range(k):
        full[:, i, :, i * n : (i + 1) * n] = jac[:, i]
    if pb.ratio:
        full[:, :, :, pb.nz] = np.einsum("mkrn,kn->mkr", jac, pb.u_centred)
    if pb.gain >= 0:
        level = z[:, pb.level, None, None] if pb.level >= 0 else 0.0
        f = (err + pb.y[None] - level) / (1.0 + z[:, pb.gain])[:, None, None]
        f[:, :, -1] = 0.0
        full[:, :, :, pb.gain] = f
    if pb.level >= 0:
        full[:, :, :-1, pb.level] = 1.0
    full = full.reshape(m, -1, d)
    res = err.reshape(m, -1)
    jtj = full.transpose(0, 2, 1) @ full / r_var + walk.transpose(0, 2, 1) @ walk / pb.w_sd**2
    jtr = np.einsum("mrd,mr->md", full, res) / r_var
    jtr += np.einsum("mde,me->md", walk.transpose(0, 2, 1) @ walk / pb.w_sd**2, z)
    jtj[:, np.arange(d), np.arange(d)] += pb.prior_w
    jtr += pb.prior_w * (z - pb.prior_mean)
    jtj[:, np.arange(d), np.arange(d)] *= 1.0 + lam[:, None]
    jtj[:, np.arange(d), np.arange(d)] += lam[:, None] * 1e-12
    step = -np.linalg.solve(jtj, jtr[:, :, None])[:, :, 0]
    return z + np.clip(step, -0.1, 0.1)


@pytest.mark.parametrize("stage", [3, 5, 7])
@pytest.mark.parametrize("ratio", [False, True])
@pytest.mark.parametrize("line", [False, True])
@pytest.mark.parametrize("knots", [False, True])
def test_the_kernels_compute_what_numpy_computes(stage, ratio, line, knots):
    config = make_config(stage, "hard", "test")
    stacker, period = stacker_from_config(config), config.optical_period_fs
    rng = np.random.default_rng(stage)
    k, n = 7, stage
    u = rng.normal(0.0, 0.05, (k, n))
    age = np.array([7.0, 6.0, 4.0, 3.0, 2.0, 1.0, 0.0])  # a gap of two steps
    out = stacker.evaluate((u + rng.normal(0.0, 0.05, n)) * period)
    y = np.concatenate([out.slot_energies, out.power[:, None]], axis=1)
    y = y + rng.normal(0.0, 1e-3, y.shape)
    hypotheses = knot_hypotheses(n, k, 3, 0.02) if knots else None
    m = hypotheses[0].size if knots else 3
    drift = rng.normal(0.0, 0.003, (m, n))
    gain = 0.005 if line else 0.0
    pb = fit.path_problem(
        stacker, period, u, y, age, drift, 3e-4, 0.002, np.full((m, n), 0.004), ratio,
        hypotheses, 0.015, gain, gain / 10,
    )  # fmt: skip
    z = rng.normal(0.0, 0.05, (m, pb.d))
    z[:, k * n : pb.nz] = drift
    starts = np.arange(m)
    want_err, want_jac = _numpy_residuals(pb, z)
    err, jac = np.empty_like(want_err), np.empty_like(want_jac)
    fit.path_residuals(pb, z, starts, err, jac)
    np.testing.assert_array_equal(err, want_err)
    np.testing.assert_array_equal(jac, want_jac)
    cost, data_cost = np.empty(m), np.empty(m)
    fit.path_objective(pb, z, starts, err, cost, data_cost)
    np.testing.assert_allclose(cost, _numpy_objective(pb, z, err), rtol=1e-13)
    np.testing.assert_allclose(data_cost, np.mean(err**2, axis=(1, 2)), rtol=1e-13)
    lam = np.full(m, 1e-3)
    trial = np.empty_like(z)
    fixed = (pb.walk_normal, pb.prior_w, pb.prior_mean, lam, pb.u_centred, pb.y)
    flags = (pb.nz, pb.ratio, pb.gain, pb.level, pb.r_sd)
    no_rows = np.empty((0, n))
    lm.trial_step(z, starts, err, jac, *fixed, *flags, trial, u, H, period, False, no_rows)
    np.testing.assert_allclose(trial, _numpy_trial(pb, z, err, jac, lam), rtol=0, atol=1e-11)
