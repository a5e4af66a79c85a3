"""The tracker's shortcuts give exactly the figures of the long way: a stacker retuned to another
wavelength, the median of a few floats, the views the normal equations are summed into."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.tracker import fit
from ops_controller_ros.tracker.model import at_wavelength
from ops_controller_ros.tracker.noise import median
from ops_sim_ros.physics import stacker_from_config


@pytest.mark.parametrize("stage", [3, 5, 7])
@pytest.mark.parametrize("detector", ["polarizer", "total"])
@pytest.mark.parametrize("envelope", [0.0, 0.2])
def test_a_stacker_retuned_to_a_wavelength_evaluates_as_one_built_for_it(stage, detector, envelope):
    config = make_config(stage, detector=detector, burst_envelope=envelope)
    rng = np.random.default_rng(stage)
    for wavelength in (1009.4, 1031.7, 1062.0):
        built = stacker_from_config(config.replace(wavelength_nm=wavelength))
        retuned = at_wavelength(stacker_from_config(config), wavelength)
        assert retuned.optical_period_fs == built.optical_period_fs
        for rows in (1, 7, 40):  # one row takes the float64 path, more the batched one
            delays = rng.normal(0.0, 400.0, (rows, stage))
            for got, want in zip(
                retuned.energies_and_power(delays), built.energies_and_power(delays), strict=True
            ):
                np.testing.assert_array_equal(got, want)
            np.testing.assert_array_equal(
                retuned.evaluate(delays).slot_energies, built.evaluate(delays).slot_energies
            )


def test_the_median_of_a_few_floats_is_numpys():
    rng = np.random.default_rng(1)
    for n in range(1, 26):
        for _ in range(200):
            values = [float(v) for v in rng.lognormal(-12.0, 3.0, n)]
            assert median(values) == float(np.median(values))
    assert np.isnan(median([1.0, float("nan"), 2.0]))


@pytest.mark.parametrize(("m", "k", "n", "extra"), [(1, 7, 5, 0), (3, 10, 5, 3), (2, 7, 7, 2)])
def test_the_normal_equations_views_are_the_blocks_and_the_diagonal(m, k, n, extra):
    d = k * n + n + extra
    blocks = np.arange(k)[:, None] * n + np.arange(n)[None]
    values = np.arange(m * k * n * n, dtype=float).reshape(m, k, n, n) + 1.0
    a = np.zeros((m, d, d))
    fit._path_blocks(a, k, n)[...] += values
    want = np.zeros((m, d, d))
    want[:, blocks[:, :, None], blocks[:, None, :]] += values
    np.testing.assert_array_equal(a, want)
    fit._diagonal(a)[...] += 0.5
    want[:, np.arange(d), np.arange(d)] += 0.5
    np.testing.assert_array_equal(a, want)
