"""The source's imperfections: a burst of unequal pulses and pulse-to-pulse energy noise."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import REALISM_PRESETS, make_config
from ops_sim_ros.physics import PulseStacker, stacker_from_config
from ops_sim_ros.simulation import BatchedSimulation
from ops_sim_ros.source import amplitude_noise, burst_amplitudes


@pytest.mark.parametrize("droop", [0.1, 0.5, 0.9])
def test_a_burst_droops_by_its_figure_and_keeps_the_mean_pulse_energy(droop):
    energies = burst_amplitudes(4, droop) ** 2
    assert energies.shape == (16,)
    assert energies.mean() == pytest.approx(1.0)
    assert energies[-1] / energies[0] == pytest.approx(1.0 - droop)
    assert np.all(np.diff(energies) < 0)
    assert burst_amplitudes(4, 0.0) is None


def test_an_even_burst_is_the_stacker_of_before():
    d = np.random.default_rng(0).normal(0.0, 300.0, (5, 5))
    plain = PulseStacker(5)
    for det in ("polarizer", "total"):
        built = stacker_from_config(make_config(5, detector=det))
        ref = PulseStacker(5, detector=det)
        np.testing.assert_array_equal(built.power(d), ref.power(d))
    assert plain.reachable_fraction == 1.0


@pytest.mark.parametrize("detector", ["polarizer", "total"])
def test_an_uneven_burst_is_normalized_by_what_it_can_reach(detector):
    """Unequal pulses cannot stack to the even burst's P_max: the power is normalized by their
    own maximum (every path in phase), so 1 stays reachable and nothing exceeds it."""
    fractions = []
    for droop in (0.2, 0.5, 0.9):
        st = PulseStacker(5, detector=detector, amplitudes=burst_amplitudes(5, droop))
        assert float(st.power(np.zeros(5))) == pytest.approx(1.0, abs=1e-6)
        d = np.random.default_rng(1).normal(0.0, 0.5, (4000, 5))  # near the optimum
        assert st.power(d).max() <= 1.0 + 1e-6
        far = np.random.default_rng(2).normal(0.0, 1000.0, (200, 5))
        assert st.power(far).max() < 1.0
        fractions.append(st.reachable_fraction)
        if detector == "polarizer":  # detected + rejected = the burst's (mean 1) input energy
            near = np.random.default_rng(5).normal(0.0, 5.0, (200, 5))  # within a few cycles
            out = st.evaluate(near, rejected_port=True)
            total = out.slot_energies.sum(1) + out.rejected_energy
            np.testing.assert_allclose(total, 1.0, atol=1e-4)
    assert 1.0 > fractions[0] > fractions[1] > fractions[2] > 0.5


@pytest.mark.parametrize("detector", ["polarizer", "total"])
@pytest.mark.parametrize("batch", [1, 6])
def test_pulses_of_their_own_match_the_stacker_when_they_are_its_pulses(detector, batch):
    """Per-env factors equal to 1 give the stacker's own energies and power; factors equal to a
    burst's amplitudes give that burst's stacker (before its normalization)."""
    d = np.random.default_rng(3).normal(0.0, 250.0, (batch, 5))
    st = PulseStacker(5, detector=detector)
    e0, p0 = st.energies_and_power(d)
    e1, p1 = st.energies_and_power_of_pulses(d, np.ones((batch, 32)))
    np.testing.assert_allclose(e1, e0, atol=2e-6)
    np.testing.assert_allclose(p1, p0, atol=2e-6)
    amps = burst_amplitudes(5, 0.4)
    burst = PulseStacker(5, detector=detector, amplitudes=amps, dtype=np.float64)
    e2, p2 = PulseStacker(5, detector=detector, dtype=np.float64).energies_and_power_of_pulses(
        d, np.tile(amps, (batch, 1))
    )
    e3, p3 = burst.energies_and_power(d)
    np.testing.assert_allclose(e2, e3, atol=1e-9)
    np.testing.assert_allclose(p2, p3 * burst.reachable_fraction, atol=1e-9)


def test_amplitude_noise_has_its_rms_and_never_a_negative_energy():
    rng = np.random.default_rng(4)
    factors = amplitude_noise(rng, (2000, 32), 0.03)
    assert np.std(factors**2) == pytest.approx(0.03, rel=0.05)
    assert np.all(amplitude_noise(rng, (200, 32), 0.3) >= 0.0)


def test_noisy_pulses_make_the_reading_at_the_optimum_fluctuate_with_the_noise():
    """At perfect delays the power fluctuates about its maximum, more with more noise; the
    simulation without noise is untouched (same seed, same numbers)."""
    spread = []
    for noise in (0.0, 0.01, 0.03):
        cfg = make_config(5, "easy", jitter_sigma_cycles=0.0, pulse_amplitude_noise=noise)
        sim = BatchedSimulation(cfg, num_envs=8, seed=5)
        sim.reset(seed=5)
        sim.place(delay_errors_fs=np.zeros((8, 5)))
        powers = np.array([sim.step_setpoints(np.zeros((8, 5))).power for _ in range(30)])
        spread.append(powers.std())
        assert powers.mean() == pytest.approx(1.0, abs=6 * noise + 1e-6)
        assert np.all(np.isfinite(powers))
    assert spread[0] < 1e-6 < spread[1] < spread[2]
    a = BatchedSimulation(make_config(5, "hard"), num_envs=3, seed=7)
    b = BatchedSimulation(make_config(5, "hard", pulse_amplitude_noise=0.0), num_envs=3, seed=7)
    a.reset(seed=7)
    b.reset(seed=7)
    for _ in range(5):
        np.testing.assert_array_equal(
            a.step_increments(np.ones((3, 5))).power, b.step_increments(np.ones((3, 5))).power
        )


def test_the_source_figures_are_checked_and_in_the_presets():
    for name in ("pulse_amplitude_noise", "burst_envelope"):
        assert REALISM_PRESETS["ideal"][name] == 0.0
        assert REALISM_PRESETS["lab"][name] > 0.0
        with pytest.raises(ValueError, match=name):
            make_config(5, **{name: -0.1})
    with pytest.raises(ValueError, match=r"burst_envelope must be from 0.0 to 0.9"):
        make_config(5, burst_envelope=1.0)
