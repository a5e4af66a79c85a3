"""Noise statistics, modes and configuration (ops_sim_ros.noise, .config, .simulation)."""

import numpy as np
import pytest
from ops_sim_ros.config import OpsConfig, make_config
from ops_sim_ros.noise import DelayNoise
from ops_sim_ros.simulation import BatchedSimulation


def test_jitter_sigma_and_zero_mean_without_drift():
    cfg = make_config(stage=3, mode="medium")
    noise = DelayNoise.from_config(cfg, num_envs=2000, rng=np.random.default_rng(0))
    e = np.stack([noise.sample() for _ in range(5)])
    assert e.std() == pytest.approx(cfg.jitter_sigma_fs, rel=0.02)
    assert abs(e.mean()) < 3 * cfg.jitter_sigma_fs / np.sqrt(e.size)
    assert cfg.jitter_sigma_fs == pytest.approx(0.001 * cfg.optical_period_fs)


def test_hard_drift_is_piecewise_linear_and_bounded():
    cfg = make_config(stage=2, mode="hard", jitter_sigma_cycles=0.0)
    noise = DelayNoise.from_config(cfg, num_envs=4, rng=np.random.default_rng(1))
    mu = np.stack([noise.sample() for _ in range(2000)])  # no jitter: e == mu
    slopes = np.diff(mu, axis=0)
    changes = np.abs(np.diff(slopes, axis=0)) > 1e-12
    # piecewise linear: slopes constant except at a few knots (segments >= 100 steps)
    assert changes.sum(axis=0).max() <= 2000 // 100 + 25
    assert changes.sum() > 4
    assert np.abs(slopes).max() <= cfg.cycles_to_fs(cfg.drift_slope_max_cycles) + 1e-12
    assert (
        np.abs(mu).max() <= cfg.cycles_to_fs(cfg.drift_bound_cycles) + 1e-9 + np.abs(slopes).max()
    )
    # the drift is large: over a 200-step episode mu moves up to ~2 optical cycles
    moves = np.abs(mu[200::200] - mu[:-200:200]).max()
    assert moves > 0.5 * cfg.optical_period_fs


def test_train_and_test_drift_differ():
    def slopes(split):
        cfg = make_config(stage=1, mode="hard", split=split, jitter_sigma_cycles=0.0)
        noise = DelayNoise.from_config(cfg, num_envs=500, rng=np.random.default_rng(2))
        mu = np.stack([noise.sample() for _ in range(300)])
        s = np.abs(np.diff(mu, axis=0)) / cfg.optical_period_fs
        knots = (np.abs(np.diff(np.diff(mu, axis=0), axis=0)) > 1e-12).sum()
        return s.mean(), knots

    (s_train, k_train), (s_test, k_test) = slopes("train"), slopes("test")
    assert s_test > 1.5 * s_train  # test drifts faster ...
    assert k_test > 1.5 * k_train  # ... and turns more often


def test_drift_persists_across_resets_and_restarts_with_a_seed():
    cfg = make_config(stage=3, mode="hard", jitter_sigma_cycles=0.0)
    sim = BatchedSimulation(cfg, num_envs=2, seed=5)
    sim.reset()
    for _ in range(150):
        r = sim.step_setpoints(np.zeros((2, 3)))
    mu_before = r.applied_fs.copy()
    r0 = sim.reset()  # no seed: the drift goes on where it was
    np.testing.assert_allclose(r0.applied_fs - r0.setpoints_fs, mu_before, atol=1e-12)
    assert sim.noise.global_step == 150
    sim.reset(seed=5)  # seeded: world restarts
    assert sim.noise.global_step == 0
    assert np.abs(sim.noise.mu).max() == 0.0


def test_easy_mode_is_near_optimum_and_medium_is_spread():
    def initial(mode):
        sim = BatchedSimulation(make_config(stage=5, mode=mode), num_envs=4000, seed=3)
        r = sim.reset()
        return r.setpoints_fs / sim.optical_period_fs, r.power

    easy_sp, easy_p = initial("easy")
    med_sp, med_p = initial("medium")
    hard_sp, _ = initial("hard")
    assert np.abs(easy_sp).max() <= 0.1
    assert np.abs(med_sp).max() <= 0.5 and np.abs(med_sp).max() > 0.49
    assert med_sp.std() == pytest.approx(1 / np.sqrt(12), rel=0.05)  # uniform over one period
    assert hard_sp.std() == pytest.approx(1 / np.sqrt(12), rel=0.05)
    assert np.median(easy_p) > 0.4 > np.median(med_p)


def test_medium_has_no_drift_and_hard_does():
    assert not make_config(mode="medium").drift_enabled
    assert not make_config(mode="easy").drift_enabled
    assert make_config(mode="hard").drift_enabled
    assert make_config(mode="hard", split="test").drift_slope_max_cycles > 0.01


def test_config_validation_names_parameter_and_choices():
    with pytest.raises(
        ValueError, match=r"mode must be one of easy, medium, hard \(got 'extreme'\)"
    ):
        make_config(mode="extreme")
    with pytest.raises(ValueError, match="split must be one of train, test"):
        make_config(split="validation")
    with pytest.raises(ValueError, match="stage must be an integer from 1 to"):
        make_config(stage=0)
    with pytest.raises(ValueError, match="unknown parameter"):
        make_config(wavelength=1030)
    with pytest.raises(ValueError, match="max_step_cycles must be > 0"):
        make_config(max_step_cycles=0)
    cfg = make_config(stage=4, mode="hard", split="test", jitter_sigma_cycles=0.01)
    assert OpsConfig.from_dict(cfg.to_dict()) == cfg
    assert cfg.jitter_sigma_cycles == 0.01


def test_setpoints_are_clipped_to_the_actuator_range():
    cfg = make_config(stage=2)
    sim = BatchedSimulation(cfg, num_envs=1, seed=0)
    sim.reset()
    r = sim.step_setpoints(np.array([[1e6, 1.0]]))
    assert r.setpoints_fs[0, 0] == cfg.actuator_range_fs
    assert r.clipped.tolist() == [[True, False]]
    with pytest.raises(ValueError):
        sim.step_setpoints(np.array([[np.nan, 0.0]]))
    r = sim.step_increments(np.array([[5.0, -5.0]]))  # increments clipped to one max step
    assert r.setpoints_fs[0, 1] == pytest.approx(1.0 - cfg.max_step_fs)


def test_simulation_seeding_and_partial_reset():
    cfg = make_config(stage=3, mode="hard")
    a, b = BatchedSimulation(cfg, 3, seed=7), BatchedSimulation(cfg, 3, seed=7)
    ra, rb = a.reset(), b.reset()
    np.testing.assert_array_equal(ra.applied_fs, rb.applied_fs)
    for _ in range(10):
        act = np.full((3, 3), 0.5)
        ra, rb = a.step_increments(act), b.step_increments(act)
    np.testing.assert_array_equal(ra.power, rb.power)
    before = ra.setpoints_fs.copy()
    r = a.reset(mask=np.array([False, True, False]))
    np.testing.assert_array_equal(r.setpoints_fs[[0, 2]], before[[0, 2]])
    assert r.step_count.tolist() == [10, 0, 10]
    assert a.trace(r).shape == (3, 7 * cfg.samples_per_slot)


def _reference_drift_step(mu, slope, steps_left, bound, redraw):
    """The drift update checked every step (what DelayNoise.sample must equal)."""
    mu += slope
    out = np.abs(mu) > bound
    if out.any():
        slope[out] = -np.sign(mu[out]) * np.abs(slope[out])
    steps_left -= 1
    knot = steps_left <= 0
    if knot.any():
        redraw(knot)


@pytest.mark.parametrize("bound, knots", [(0.5, (3, 9)), (2.0, (0, 4)), (np.inf, (50, 60))])
def test_drift_with_skipped_checks_equals_checking_every_step(bound, knots):
    kw = dict(
        num_envs=3,
        stage=4,
        jitter_sigma_fs=0.01,
        drift_slope_min_fs=0.01,
        drift_slope_max_fs=0.08,
        drift_knot_min_steps=knots[0],
        drift_knot_max_steps=knots[1],
        drift_bound_fs=bound,
    )
    fast = DelayNoise(rng=np.random.default_rng(7), **kw)
    ref = DelayNoise(rng=np.random.default_rng(7), **kw)
    for step in range(3000):
        got = fast.sample(advance=step % 97 != 0)
        e = ref.rng.standard_normal((3, 4)) * ref.sigma
        if step % 97 != 0:
            _reference_drift_step(ref.mu, ref.slope, ref.steps_left, ref.bound, ref._redraw)
        np.testing.assert_array_equal(got, e + ref.mu)
        np.testing.assert_array_equal(fast.slope, ref.slope)
    if np.isfinite(bound):
        assert np.abs(fast.mu).max() <= bound + 0.08


@pytest.mark.parametrize("num_envs", [1, 3])
def test_step_result_fields_equal_the_physics_output(num_envs):
    """The simulation's per-step path (scalar for one env, arrays for a batch) reports exactly
    what PulseStacker.evaluate gives for the applied delays, and reward = -(1 - power)^2."""
    cfg = make_config(stage=4, mode="hard")
    sim = BatchedSimulation(cfg, num_envs=num_envs, seed=11)
    sim.reset()
    for _ in range(5):
        r = sim.step_increments(np.full((num_envs, 4), 0.7))
        want = sim.stacker.evaluate(r.applied_fs)
        np.testing.assert_allclose(r.power, want.power, rtol=0, atol=1e-12)
        np.testing.assert_allclose(r.pulse_energies, want.slot_energies, rtol=0, atol=1e-12)
        np.testing.assert_allclose(r.main_pulse_energy, want.main_pulse_energy, atol=1e-12)
        np.testing.assert_allclose(r.rejected_energy, want.rejected_energy, atol=1e-12)
        np.testing.assert_array_equal(r.reward, -((1.0 - r.power) ** 2))
        for arr in (r.power, r.reward, r.main_pulse_energy, r.rejected_energy):
            assert arr.shape == (num_envs,) and arr.dtype == np.float64
