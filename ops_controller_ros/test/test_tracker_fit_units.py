"""A path fit run a unit at a time (fit.PathFitRun): the units a real-time loop spreads over
readings change when the work is done, never what it finds."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.tracker import fit
from ops_controller_ros.tracker.knots import knot_hypotheses, knot_starts
from ops_sim_ros.physics import stacker_from_config

K, N, ITERATIONS = 10, 5, 12


def _knot_run(chunk=None, seed: int = 3, iterations: int = ITERATIONS) -> fit.PathFitRun:
    """The knot hypotheses of a noisy detector (5 readings back, both sides: 51 starts) on a
    window of readings of a drifting path, as the tracker builds them."""
    config = make_config(N, "hard", "test")
    stacker = stacker_from_config(config)
    rng = np.random.default_rng(seed)
    age = np.arange(K - 1, -1, -1, dtype=float)
    drift = rng.normal(0.0, 0.004, N)
    x = rng.normal(0.0, 0.03, N)[None] - age[:, None] * drift[None]  # the true errors
    u = rng.normal(0.0, 0.01, (K, N))  # the dithered set-points
    out = stacker.evaluate((u + x) * config.optical_period_fs)
    y = np.concatenate([out.slot_energies, out.power[:, None]], axis=1)
    y = y + rng.normal(0.0, 0.003, y.shape)
    knots = knot_hypotheses(N, K, 5, 0.01)
    m = knots[0].size
    path0 = knot_starts(x[-1], drift, age, knots, False)
    return fit.PathFitRun(
        stacker,
        config.optical_period_fs,
        path0[:, -1],
        np.tile(drift, (m, 1)),
        u,
        y,
        age,
        iterations,
        r_sd=0.003,
        w_sd=0.002,
        drift_prior=np.full((m, N), 0.002),
        knots=knots,
        knot_prior=0.01,
        path0=path0,
        chunk=chunk,
    )


def _run_to_end(run: fit.PathFitRun) -> int:
    """Calls of ``run`` with the deadline already past until the fit is done."""
    calls = 0
    while not run.done:
        run.run(deadline=float("-inf"))
        calls += 1
    return calls


@pytest.mark.parametrize("chunk", [1, 8, 51, 64])
def test_a_fit_in_groups_finds_what_one_batch_finds(chunk):
    """The same fits, to the physics' float32 rounding (its GEMM sums a batch of another size
    in another order, and Levenberg-Marquardt carries that on): errors within 1e-3 cycles,
    costs within 1e-4 of themselves (the two sides of a knot end in a near tie, so not always
    the same one lowest); one group of all is the batch itself."""
    whole, grouped = _knot_run(), _knot_run(chunk)
    whole.run()
    _run_to_end(grouped)
    a, b = whole.result(), grouped.result()
    np.testing.assert_allclose(b.objective, a.objective, rtol=1e-4)
    for name in ("x", "drift", "path"):
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=0, atol=1e-3)
    if chunk >= a.objective.size:
        np.testing.assert_array_equal(b.x, a.x)


def test_a_unit_past_the_deadline_is_one_group_once():
    """Past its deadline a run does one unit per call: a group's first evaluation, then a
    group's iteration; done exactly after the last (no call wasted on finding out)."""
    m = _knot_run().result().objective.size
    groups = -(-m // 8)
    grouped = _knot_run(8)
    assert not grouped.done and grouped.units == 0
    assert _run_to_end(grouped) == groups * (ITERATIONS + 1) == grouped.units
    whole = _knot_run()  # built with its first evaluation; then an iteration per call
    assert _run_to_end(whole) == ITERATIONS == whole.units


def test_a_run_without_iterations_is_done_after_its_first_evaluation():
    assert _knot_run(iterations=0).done
    grouped = _knot_run(8, iterations=0)
    assert not grouped.done
    assert _run_to_end(grouped) == grouped.units == 7
