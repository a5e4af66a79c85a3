"""Noise statistics, modes and configuration (ops_sim_ros.noise, .config, .simulation)."""

import numpy as np
import pytest
from ops_contract.config import OpsConfig, make_config
from ops_sim_ros.noise import DelayNoise
from ops_sim_ros.simulation import BatchedSimulation


def _truncnorm_std(clip_sigmas: float) -> float:
    """Std of a standard normal clipped (not truncated) at +- clip_sigmas."""
    from math import erf, exp, pi, sqrt

    c = clip_sigmas
    inside = erf(c / sqrt(2)) - 2 * c * exp(-c * c / 2) / sqrt(2 * pi)  # E[x^2; |x| < c]
    tail = c * c * (1 - erf(c / sqrt(2)))
    return sqrt(inside + tail)


def _walk_increments(mode, split="train", stage=3, envs=2000, steps=50, seed=0):
    cfg = make_config(stage=stage, mode=mode, split=split)
    noise = DelayNoise.from_config(cfg, num_envs=envs, rng=np.random.default_rng(seed))
    noise.new_episodes(np.ones(envs, dtype=bool))
    e = np.stack([noise.sample(advance=False)] + [noise.sample() for _ in range(steps)])
    return cfg, np.diff(e, axis=0) / cfg.optical_period_fs  # (steps, envs, stage), cycles


@pytest.mark.parametrize("mode", ["easy", "medium"])
def test_delays_random_walk_with_the_papers_sigma_and_no_drift(mode):
    """Each step adds N(0, 0.001 cycles) clipped at +-3 sigma to every delay (a random walk)."""
    cfg, inc = _walk_increments(mode)
    sigma = cfg.jitter_sigma_cycles
    assert sigma == 0.001 and cfg.jitter_clip_sigmas == 3.0
    assert inc.std() == pytest.approx(sigma * _truncnorm_std(3.0), rel=0.02)
    assert abs(inc.mean()) < 4 * sigma / np.sqrt(inc.size)
    assert np.abs(inc).max() <= 3 * sigma + 1e-12
    # a walk, not jitter around the set-point: the spread grows like sqrt(steps)
    walked = inc.sum(axis=0)
    assert walked.std() == pytest.approx(sigma * np.sqrt(inc.shape[0]), rel=0.1)
    assert not cfg.drift_enabled


def test_hard_drift_is_one_constant_mu_per_episode_shared_by_all_stages():
    cfg, inc = _walk_increments("hard", envs=3000, steps=60)
    mu = inc.mean(axis=0)  # (envs, stage): each episode's mean increment
    sigma = cfg.jitter_sigma_cycles
    # shared by the stages: the per-stage means differ only by the walk's noise
    spread = (mu - mu.mean(axis=1, keepdims=True)).std()
    assert spread < 1.5 * sigma / np.sqrt(inc.shape[0])
    # constant within the episode: first and second halves agree within the noise
    halves = inc[:30].mean(axis=0) - inc[30:].mean(axis=0)
    assert halves.std() < 1.5 * sigma * np.sqrt(2 / 30)
    # uniform in +-0.001 cycles per step
    episode_mu = mu.mean(axis=1)
    assert np.abs(episode_mu).max() < 0.001 + 5 * sigma / np.sqrt(60 * 3)
    assert episode_mu.std() == pytest.approx(0.002 / np.sqrt(12), rel=0.1)
    assert cfg.drift_knot_min_steps == cfg.drift_knot_max_steps == 0


def test_hard_test_split_drifts_from_a_shifted_range():
    cfg_test, inc = _walk_increments("hard", split="test", envs=3000, steps=60)
    mu = np.abs(inc.mean(axis=(0, 2)))
    assert (cfg_test.drift_slope_min_cycles, cfg_test.drift_slope_max_cycles) == (0.0005, 0.0015)
    assert mu.min() > 0.0005 - 0.0004 and mu.max() < 0.0015 + 0.0004
    _, inc_train = _walk_increments("hard", split="train", envs=3000, steps=60)
    mu_train = np.abs(inc_train.mean(axis=(0, 2)))
    assert mu.mean() > 1.8 * mu_train.mean()  # twice the training drift on average
    assert (mu > 0.0011).mean() > 0.25  # a third drift faster than any training episode


def test_hard_drift_is_redrawn_at_each_reset():
    cfg = make_config(stage=2, mode="hard", jitter_sigma_cycles=0.0)
    sim = BatchedSimulation(cfg, num_envs=200, seed=4)
    slopes = []
    for _ in range(3):
        sim.reset()
        a = sim.step_setpoints(np.zeros((200, 2))).applied_fs
        b = sim.step_setpoints(np.zeros((200, 2))).applied_fs
        slopes.append(b - a)
    assert not np.allclose(slopes[0], slopes[1])
    np.testing.assert_allclose(slopes[0][:, 0], slopes[0][:, 1])  # shared by the stages


def test_extreme_drift_is_piecewise_linear_per_stage_and_bounded():
    cfg = make_config(stage=2, mode="extreme", jitter_sigma_cycles=0.0)
    noise = DelayNoise.from_config(cfg, num_envs=4, rng=np.random.default_rng(1))
    noise.new_episodes(np.ones(4, dtype=bool))
    mu = np.stack([noise.sample() for _ in range(2000)])  # no jitter: e == e_0 + mu
    slopes = np.diff(mu, axis=0)
    changes = np.abs(np.diff(slopes, axis=0)) > 1e-12
    # piecewise linear: slopes constant except at a few knots (segments >= 100 steps)
    assert changes.sum(axis=0).max() <= 2000 // 100 + 25
    assert changes.sum() > 4
    assert not np.allclose(slopes[:, :, 0], slopes[:, :, 1])  # each stage its own
    assert np.abs(slopes).max() <= cfg.cycles_to_fs(cfg.drift_slope_max_cycles) + 1e-12
    bound = cfg.cycles_to_fs(cfg.drift_bound_cycles)
    assert np.abs(noise.mu).max() <= bound + np.abs(slopes).max()
    # strong: over a 200-step episode the delays move up to ~2 optical cycles
    moves = np.abs(mu[200::200] - mu[:-200:200]).max()
    assert moves > 0.5 * cfg.optical_period_fs


def test_extreme_test_split_drifts_faster_and_turns_more_often():
    def slopes(split):
        cfg = make_config(stage=1, mode="extreme", split=split, jitter_sigma_cycles=0.0)
        noise = DelayNoise.from_config(cfg, num_envs=500, rng=np.random.default_rng(2))
        mu = np.stack([noise.sample() for _ in range(300)])
        s = np.abs(np.diff(mu, axis=0)) / cfg.optical_period_fs
        knots = (np.abs(np.diff(np.diff(mu, axis=0), axis=0)) > 1e-12).sum()
        return s.mean(), knots

    (s_train, k_train), (s_test, k_test) = slopes("train"), slopes("test")
    assert s_test > 1.5 * s_train
    assert k_test > 1.5 * k_train


def test_extreme_slopes_run_on_across_resets_and_restart_with_a_seed():
    cfg = make_config(stage=3, mode="extreme", jitter_sigma_cycles=0.0)
    sim = BatchedSimulation(cfg, num_envs=2, seed=5)
    sim.reset()
    for _ in range(150):
        sim.step_setpoints(np.zeros((2, 3)))
    slope = sim.noise.slope.copy()
    sim.reset()  # no seed: a new episode, the slope process goes on where it was
    np.testing.assert_array_equal(sim.noise.slope, slope)
    assert sim.noise.global_step == 150 and np.abs(sim.noise.mu).max() == 0.0
    sim.reset(seed=5)  # seeded: the world restarts
    assert sim.noise.global_step == 0


# Initial delay error per stage (cycles): the clipped normal of each mode, plus hard's offset.
_INITIAL = {"easy": (0.16, 0.0), "medium": (0.26, 0.0), "hard": (0.30, 1.0), "extreme": (0.30, 1.0)}


@pytest.mark.parametrize("mode", list(_INITIAL))
def test_initial_delay_errors_follow_the_mode(mode):
    sigma, offset = _INITIAL[mode]
    sim = BatchedSimulation(make_config(stage=5, mode=mode), num_envs=6000, seed=3)
    r = sim.reset()
    assert np.all(r.setpoints_fs == 0.0)  # the controller starts from zero set-points
    err = r.applied_fs / sim.optical_period_fs
    want_std = sigma * np.sqrt(_truncnorm_std(2.0) ** 2 + offset**2 / 3)
    assert err.std() == pytest.approx(want_std, rel=0.03)
    assert np.abs(err).max() <= sigma * (2 + offset) + 1e-12
    if offset:
        # one offset per episode shared by the stages: the stages are correlated
        c = np.corrcoef(err[:, 0], err[:, 1])[0, 1]
        assert c == pytest.approx(
            offset**2 / 3 / (_truncnorm_std(2.0) ** 2 + offset**2 / 3), abs=0.05
        )
    else:
        assert np.abs(err).max() > 1.95 * sigma  # the clip is reached


def test_easy_starts_closer_to_the_optimum_than_medium_and_hard():
    def median_power(mode):
        sim = BatchedSimulation(make_config(stage=5, mode=mode), num_envs=2000, seed=1)
        return np.median(sim.reset().power)

    easy, medium, hard = median_power("easy"), median_power("medium"), median_power("hard")
    assert easy > medium > hard


def test_modes_and_drift_switches():
    assert not make_config(mode="medium").drift_enabled
    assert not make_config(mode="easy").drift_enabled
    assert make_config(mode="hard").drift_enabled
    assert make_config(mode="extreme", split="test").drift_slope_max_cycles == 0.015


def test_config_validation_names_parameter_and_choices():
    with pytest.raises(
        ValueError, match=r"mode must be one of easy, medium, hard, extreme \(got 'brutal'\)"
    ):
        make_config(mode="brutal")
    with pytest.raises(ValueError, match="split must be one of train, test"):
        make_config(split="validation")
    with pytest.raises(ValueError, match="detector must be one of polarizer, total"):
        make_config(detector="camera")
    with pytest.raises(ValueError, match="stage must be an integer from 1 to"):
        make_config(stage=0)
    with pytest.raises(ValueError, match="unknown parameter"):
        make_config(wavelength=1030)
    with pytest.raises(ValueError, match="max_step_cycles must be > 0"):
        make_config(max_step_cycles=0)
    with pytest.raises(ValueError, match="drift_per_stage must be true or false"):
        make_config(drift_per_stage=1)
    with pytest.raises(ValueError, match="drift_knot_min_steps and drift_knot_max_steps"):
        make_config(drift_knot_min_steps=0, drift_knot_max_steps=5)
    cfg = make_config(stage=4, mode="hard", split="test", jitter_sigma_cycles=0.01)
    assert OpsConfig.from_dict(cfg.to_dict()) == cfg
    assert cfg.jitter_sigma_cycles == 0.01
    total = make_config(detector="total")
    assert OpsConfig.from_dict(total.to_dict()).detector == "total"


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
    applied = ra.applied_fs.copy()
    r = a.reset(mask=np.array([False, True, False]))
    np.testing.assert_array_equal(r.setpoints_fs[[0, 2]], before[[0, 2]])
    np.testing.assert_array_equal(r.applied_fs[[0, 2]], applied[[0, 2]])
    assert np.all(r.setpoints_fs[1] == 0.0)
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


@pytest.mark.parametrize(
    "bound, knots, per_stage",
    [(0.5, (3, 9), True), (2.0, (1, 4), False), (np.inf, (50, 60), True)],
)
def test_drift_with_skipped_checks_equals_checking_every_step(bound, knots, per_stage):
    kw = dict(
        num_envs=3,
        stage=4,
        jitter_sigma_fs=0.01,
        drift_slope_min_fs=0.01,
        drift_slope_max_fs=0.08,
        drift_per_stage=per_stage,
        drift_knot_min_steps=knots[0],
        drift_knot_max_steps=knots[1],
        drift_bound_fs=bound,
    )
    fast = DelayNoise(rng=np.random.default_rng(7), **kw)
    ref = DelayNoise(rng=np.random.default_rng(7), **kw)
    for step in range(3000):
        got = fast.sample(advance=step % 97 != 0)
        if step % 97 != 0:
            inc = np.clip(ref.rng.standard_normal((3, 4)) * ref.sigma, -ref.clip, ref.clip)
            ref.walk += inc
            _reference_drift_step(ref.mu, ref.slope, ref.steps_left, ref.bound, ref._redraw_knots)
        np.testing.assert_array_equal(got, ref.walk + ref.mu)
        np.testing.assert_array_equal(fast.slope, ref.slope)
        if not per_stage:
            assert np.all(fast.slope == fast.slope[:, :1])
    if np.isfinite(bound):
        assert np.abs(fast.mu).max() <= bound + 0.08


@pytest.mark.parametrize("detector", ["polarizer", "total"])
@pytest.mark.parametrize("num_envs", [1, 3])
def test_step_result_fields_equal_the_physics_output(num_envs, detector):
    """The simulation's per-step path (scalar for one env, arrays for a batch) reports exactly
    what PulseStacker.evaluate gives for the applied delays, and reward = -(1 - power)^2."""
    cfg = make_config(stage=4, mode="hard", detector=detector)
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


@pytest.mark.parametrize("turn_steps", [1, 7, 40])
def test_a_smooth_turn_reverses_the_slope_evenly_and_peaks_at_the_bound(turn_steps):
    """drift_turn_steps > 0: at the bound the slope goes from v to -v in turn_steps equal
    steps (no faster), the accumulated drift peaks within one step's drift of the bound, and
    the drift goes on back and forth between the bounds."""
    v, bound = 0.05, 3.0
    noise = DelayNoise(
        num_envs=2,
        stage=3,
        jitter_sigma_fs=0.0,
        drift_slope_min_fs=v,
        drift_slope_max_fs=v,
        drift_bound_fs=bound,
        drift_turn_steps=turn_steps,
        rng=np.random.default_rng(3),
    )
    noise.new_episodes(np.ones(2, dtype=bool))
    slopes, mus = [], []
    for _ in range(1000):
        noise.sample()
        slopes.append(noise.slope.copy())
        mus.append(noise.mu.copy())
    slopes, mus = np.array(slopes), np.array(mus)
    change = np.abs(np.diff(slopes, axis=0))
    assert change.max() <= 2 * v / turn_steps + 1e-12
    assert np.all(np.isclose(np.abs(slopes), v) | (np.abs(slopes) < v))
    assert np.abs(mus).max() <= bound + v
    assert mus.max() > bound - 2 * v and mus.min() < -bound + 2 * v  # both bounds reached
    # each turn takes turn_steps steps from +-v to -+v: the slope is strictly between them for
    # turn_steps - 1 steps in a row
    assert np.count_nonzero(np.diff(np.sign(slopes[:, 0, 0]))) >= 2
    inside = np.abs(slopes[:, 0, 0]) < v - 1e-9
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, inside.astype(int), 0])))[::2]
    if turn_steps > 1:
        assert runs.size >= 2 and np.all(runs == turn_steps - 1)
    else:
        assert not inside.any()


def test_smooth_turns_count_seconds_of_physical_time():
    """drift_turn_s becomes steps of the loop: 0.1 s a step under time_base step, step_s under
    seconds; 0 keeps the one-step turn."""
    turns = {}
    for time_base, step_s in (("step", 0.1), ("seconds", 0.01), ("seconds", 0.1)):
        cfg = make_config(5, "hard", time_base=time_base, step_s=step_s, drift_turn_s=12.0)
        turns[time_base, step_s] = DelayNoise.from_config(cfg, 1).turn_steps
    assert turns == {("step", 0.1): 120, ("seconds", 0.01): 1200, ("seconds", 0.1): 120}
    assert DelayNoise.from_config(make_config(5, "hard"), 1).turn_steps == 0
    with pytest.raises(ValueError, match=r"drift_turn_s must be from 0\.0 to 3600\.0"):
        make_config(5, "hard", drift_turn_s=-1.0)
