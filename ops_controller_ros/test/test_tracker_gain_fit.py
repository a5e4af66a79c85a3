"""The slot energies' gain fitted with the path (``fit.PathFitRun(gain_prior=...)``): where
the power does not pin their level (a rig, ``power_weight`` 0), a gain off reads as delay
errors that the excursions contradict; fitted beside the path, it comes out, and the errors
with it."""

from __future__ import annotations

import numpy as np
from ops_contract.config import make_config
from ops_controller_ros.tracker import fit
from ops_controller_ros.tracker.weights import WeightedStacker
from ops_sim_ros.physics import stacker_from_config

K, N = 7, 5


def _window(seed: int, gain: float):
    """A tracking window near the optimum (errors ~0.005 cycles, a drift, excursions of
    0.012): the stacker weighing the power out, the readings with the energies ``gain``
    times high, and the true errors (K, N)."""
    config = make_config(N, "hard", "test")
    weights = np.ones(2**N)
    weights[-1] = 0.0
    stacker = WeightedStacker(stacker_from_config(config), weights)
    rng = np.random.default_rng(seed)
    age = np.arange(K - 1, -1, -1, dtype=float)
    drift = rng.normal(0.0, 0.001, N)
    x = rng.normal(0.0, 0.005, N)[None] - age[:, None] * drift[None]
    u = 0.012 * rng.choice((-1.0, 1.0), size=(K, N))
    out = stacker.inner.evaluate((u + x) * config.optical_period_fs)
    y = np.concatenate([gain * out.slot_energies, 0.0 * out.power[:, None]], axis=1)
    y = y + rng.normal(0.0, 2e-4, y.shape)
    return config, stacker, u, y, age, drift, x


def _fit(seed: int, gain: float, gain_prior: float):
    config, stacker, u, y, age, drift, x = _window(seed, gain)
    run = fit.PathFitRun(
        stacker,
        config.optical_period_fs,
        x[-1][None],
        drift[None],
        u,
        y,
        age,
        12,
        r_sd=3e-4,
        w_sd=0.002,
        drift_prior=np.full((1, N), 0.004),
        gain_prior=gain_prior,
    )
    run.run()
    fits = run.result()
    return float(fits.gain[0]), float(np.max(np.abs(fits.x[0] - x[-1])))


def test_a_gain_off_is_fitted_and_leaves_the_errors_right():
    """The gain within 0.1 % of the 1.2 % it is off, the errors within 0.0025-0.0074 cycles on
    these windows with OpenBLAS's Haswell kernels, 0.0025-0.0080 with its Sandybridge or
    Prescott ones (an exact detector with the gain fitted too: the same; with the gain held,
    0.013-0.018)."""
    for seed in range(4):
        gain, error = _fit(seed, 1.012, gain_prior=0.01)
        assert abs(gain - 0.012) < 0.002, (seed, gain, error)
        assert error < 0.0095, (seed, gain, error)


def test_without_the_gain_the_errors_take_it():
    """The same windows fitted with the gain held: the level's error goes into the errors."""
    errors = [_fit(seed, 1.012, gain_prior=0.0) for seed in range(4)]
    assert all(gain == 0.0 for gain, _ in errors)
    assert min(error for _, error in errors) > 0.011, errors


def test_an_exact_gain_stays():
    for seed in range(4):
        gain, error = _fit(seed, 1.0, gain_prior=0.01)
        assert abs(gain) < 0.002, (seed, gain, error)
        assert error < 0.008, (seed, gain, error)
