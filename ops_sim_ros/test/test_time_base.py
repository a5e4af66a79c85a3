"""Physical time (``time_base``, ``step_s``) and vibration (ops_sim_ros.noise, .vibration)."""

import itertools
from math import erf, exp, pi, sqrt

import numpy as np
import pytest
from ops_contract.config import REFERENCE_STEP_S, VIBRATIONS, make_config
from ops_sim_ros.noise import DelayNoise, loop_steps
from ops_sim_ros.simulation import BatchedSimulation
from ops_sim_ros.vibration import PRESETS, Vibration, VibrationPreset


def _episodes(cfg, envs=3, episodes=3, steps=250, seed=11):
    """Every applied delay and detected energy of a few episodes under random increments."""
    sim = BatchedSimulation(cfg, num_envs=envs, seed=seed)
    actions = np.random.default_rng(seed + 1)
    out = [sim.reset().applied_fs]
    for _ in range(episodes):
        for _ in range(steps):
            r = sim.step_increments(actions.uniform(-1, 1, (envs, cfg.stage)))
            out += [r.applied_fs, r.pulse_energies, r.power[:, None]]
        sim.reset(mask=np.arange(envs) % 2 == 0)
    return np.concatenate([x.ravel() for x in out])


@pytest.mark.parametrize("mode", ["easy", "medium", "hard", "extreme"])
@pytest.mark.parametrize("split", ["train", "test"])
@pytest.mark.parametrize("realism", ["ideal", "lab"])
def test_seconds_at_the_papers_step_gives_the_same_episodes_bit_for_bit(mode, split, realism):
    kw = dict(stage=3, mode=mode, split=split, realism=realism)
    step = _episodes(make_config(**kw))
    seconds = _episodes(make_config(**kw, time_base="seconds", step_s=REFERENCE_STEP_S))
    assert np.array_equal(step, seconds)
    # and step_s means nothing to the noise under time_base step
    assert np.array_equal(step, _episodes(make_config(**kw, step_s=0.001)))


def _noise(step_s, mode="medium", envs=4000, seed=0, **overrides):
    cfg = make_config(stage=2, mode=mode, time_base="seconds", step_s=step_s, **overrides)
    noise = DelayNoise.from_config(cfg, num_envs=envs, rng=np.random.default_rng(seed))
    noise.new_episodes(np.ones(envs, dtype=bool))
    return cfg, noise


@pytest.mark.parametrize("step_s", [0.1, 0.02, 0.004, 0.001])
def test_the_walks_variance_per_simulated_second_does_not_depend_on_step_s(step_s):
    """After 1 s the walk has the variance of 10 of the paper's steps, at any rate: 8000
    independent lines estimate it to 1.6 % (one sigma); the tolerance is 5 sigma."""
    cfg, noise = _noise(step_s)
    start = noise.offset
    for _ in range(round(1.0 / step_s)):
        noise.sample()
    var = ((noise.offset - start) / cfg.optical_period_fs).var()
    # the variance of a standard normal clipped (not truncated) at +-3
    clipped = erf(3 / sqrt(2)) - 6 * exp(-4.5) / sqrt(2 * pi) + 9 * (1 - erf(3 / sqrt(2)))
    expected = cfg.jitter_sigma_cycles**2 * clipped * (1.0 / REFERENCE_STEP_S)
    assert var == pytest.approx(expected, rel=5 * np.sqrt(2 / noise.walk.size))


def test_the_drift_per_simulated_second_does_not_depend_on_step_s():
    """Hard mode without the walk: the same episodes' drift after 2 s at 0.1, 0.01, 0.001 s."""
    drift = []
    for step_s in (0.1, 0.01, 0.001):
        _, noise = _noise(step_s, mode="hard", envs=50, jitter_sigma_cycles=0.0)
        start = noise.offset
        for _ in range(round(2.0 / step_s)):
            noise.sample()
        drift.append(noise.offset - start)
    assert np.abs(drift[0]).max() > 0.01  # a drift was there to compare
    np.testing.assert_allclose(drift[1], drift[0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(drift[2], drift[0], rtol=1e-9, atol=1e-12)


def test_extreme_knots_come_after_the_same_seconds_at_any_rate():
    """extreme / test redraws each stage's slope every 40-120 of the paper's steps (4-12 s):
    the knots drawn last that long at any rate, and 60 s hold 4 to 15 of them per stage."""
    for step_s in (0.1, 0.02):
        _, noise = _noise(step_s, mode="extreme", envs=20, split="test", jitter_sigma_cycles=0)
        assert noise.knot_min == loop_steps(40, step_s / 0.1) == round(4.0 / step_s)
        assert np.all(
            (noise.steps_left * step_s >= 4.0 - 1e-9) & (noise.steps_left * step_s <= 12.0 + 1e-9)
        )
        mu = np.stack([noise.sample() for _ in range(round(60.0 / step_s))])
        slope = np.diff(mu, axis=0)
        changed = np.abs(np.diff(slope, axis=0)) > 1e-9 * np.abs(slope).max()
        knots = changed.sum(axis=0)
        assert knots.min() >= 4 and knots.max() <= 15 + 2  # (+2: a turn at the drift bound)


def test_loop_steps_round_and_never_reach_zero():
    assert loop_steps(0, 0.01) == 0
    assert loop_steps(100, 1.0) == 100
    assert loop_steps(100, 0.1) == 1000
    assert loop_steps(3, 100.0) == 1


# ---------------------------------------------------------------------- vibration


def test_the_config_offers_exactly_the_presets():
    assert set(VIBRATIONS) == {"none", *PRESETS}


def _band_rms(series: np.ndarray, rate_hz: float, bands) -> np.ndarray:
    """rms of ``series`` (time, lines) in each [low, high) band (Hann-windowed periodogram)."""
    window = np.hanning(series.shape[0])[:, None]
    spectrum = np.abs(np.fft.rfft(series * window, axis=0)) ** 2
    spectrum *= 2.0 / (series.shape[0] ** 2 * np.mean(window**2))
    freqs = np.fft.rfftfreq(series.shape[0], 1.0 / rate_hz)
    return np.array(
        [np.sqrt(spectrum[(freqs >= lo) & (freqs < hi)].sum(axis=0)) for lo, hi in bands]
    )


def _sampled(preset, rate=5000.0, seconds=12.0, envs=8, stage=5, seed=7):
    vib = Vibration(preset, envs, stage, np.random.default_rng(seed))
    return np.stack([vib.at(i / rate) for i in range(int(seconds * rate))]).reshape(
        -1, envs * stage
    )


@pytest.mark.parametrize("slope", [1.0, 2.0])
def test_the_floor_puts_its_slopes_share_in_each_log_band(slope):
    """The floor alone, sampled at 2.5 kHz for 40 s (40 periods of its slowest part): each
    quarter of a decade from 1 Hz to 1 kHz holds the share of the variance that a 1/f^slope
    spectrum puts there (1/12 each for 1/f), within 10 % of the rms over 40 lines (one line's
    band, of two or three sinusoids, can lose a quarter of it when two of them lie closer than
    1/40 Hz at the band's edge)."""
    floor = VibrationPreset(
        lines=(), floor_rms_fs=0.05, floor_band_hz=(1.0, 1000.0), floor_slope=slope
    )
    edges = 10.0 ** np.arange(0.0, 3.01, 0.25)
    series = _sampled(floor, rate=2500.0, seconds=40.0)
    measured = _band_rms(series, 2500.0, list(itertools.pairwise(edges)))
    pooled = np.sqrt((measured**2).mean(axis=1))
    expected = [floor.band_rms_fs(lo, hi) for lo, hi in itertools.pairwise(edges)]
    np.testing.assert_allclose(pooled, expected, rtol=0.1)
    share = 1.0 / 3.0 if slope == 1.0 else (0.1 - 0.01) / (1.0 - 0.001)
    assert floor.band_rms_fs(10.0, 100.0) == pytest.approx(0.05 * np.sqrt(share))
    assert floor.band_rms_fs(0.1, 1e4) == pytest.approx(0.05)  # all of it lies in its band


def test_each_line_has_its_rms_at_its_frequency():
    """The lines alone: +-2 % around each nominal frequency holds the line's rms within 5 %."""
    lines = VibrationPreset(lines=PRESETS["lab"].lines, floor_rms_fs=0.0, floor_band_hz=(1, 1e3))
    series = _sampled(lines)
    for f, rms in lines.lines:
        got = _band_rms(series, 5000.0, [(f * 0.98, f * 1.02)])[0]
        np.testing.assert_allclose(got, rms, rtol=0.05)
    assert series.std() == pytest.approx(lines.rms_fs, rel=0.05)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_a_preset_has_its_rms_in_each_decade(name):
    """Lines and floor together: each decade's rms over 40 lines is the preset's."""
    preset = PRESETS[name]
    decades = [(1.0, 10.0), (10.0, 100.0), (100.0, 1000.0)]
    series = _sampled(preset, seed=8)
    for (lo, hi), got in zip(decades, _band_rms(series, 5000.0, decades), strict=True):
        assert np.sqrt(np.mean(got**2)) == pytest.approx(preset.band_rms_fs(lo, hi), rel=0.1)
    assert series.std() == pytest.approx(preset.rms_fs, rel=0.1)


def test_the_enclosed_lab_is_quiet_above_a_fast_loops_bandwidth():
    """``lab`` (an enclosed, floated table): 5-12 nm of path in all, most of it below 10 Hz, and
    under 2 nm above 100 Hz, where no loop slower than a kHz follows it; ``open`` is louder at
    every frequency, tens of nm, a third of its floor above 100 Hz."""
    lab, open_ = PRESETS["lab"], PRESETS["open"]
    assert 0.017 < lab.rms_fs < 0.04
    assert lab.band_rms_fs(1.0, 10.0) > 2 * lab.band_rms_fs(10.0, 1e4)
    assert lab.band_rms_fs(100.0, 1e4) < 0.0067
    assert 0.05 < open_.rms_fs < 0.1
    for lo, hi in ((1.0, 10.0), (10.0, 100.0), (100.0, 1e4)):
        assert open_.band_rms_fs(lo, hi) > lab.band_rms_fs(lo, hi)


def test_a_slow_loop_samples_the_same_vibration_a_fast_one_does():
    """No walk and no initial error: the offsets at step_s 0.01 are those at 0.1 at the same
    times (the same seed draws the same vibration), and their spread is the preset's."""
    runs = {}
    for step_s in (0.1, 0.01):
        cfg = make_config(
            stage=3, mode="easy", time_base="seconds", step_s=step_s, vibration="lab",
            jitter_sigma_cycles=0.0, initial_sigma_cycles=0.0,
        )  # fmt: skip
        sim = BatchedSimulation(cfg, num_envs=40, seed=3)
        sim.reset()
        runs[step_s] = np.stack(
            [sim.step_setpoints(np.zeros((40, 3))).applied_fs for _ in range(2000)]
        )
    np.testing.assert_allclose(runs[0.01][9::10][:200], runs[0.1][:200], atol=1e-5)
    assert runs[0.1].std() == pytest.approx(PRESETS["lab"].rms_fs, rel=0.1)


def test_vibration_adds_to_the_same_walk_and_is_deterministic_per_seed():
    kw = dict(stage=3, mode="hard")
    plain = BatchedSimulation(make_config(**kw), num_envs=8, seed=5)
    shaken = [
        BatchedSimulation(make_config(**kw, vibration="lab"), num_envs=8, seed=s) for s in (5, 5, 6)
    ]
    for sim in (plain, *shaken):
        sim.reset()
    steps = [
        [s.step_increments(np.full((8, 3), 0.3)).applied_fs for s in (plain, *shaken)]
        for _ in range(300)
    ]
    a, b, c, d = (np.stack(x) for x in zip(*steps, strict=True))
    assert np.array_equal(b, c)  # the same seed: the same episodes
    assert not np.allclose(b, d)
    diff = b - a  # the walk's draws are those without vibration: the difference is vibration
    assert diff.std() == pytest.approx(PRESETS["lab"].rms_fs, rel=0.2)
    assert np.abs(diff).max() < 8 * PRESETS["lab"].rms_fs


def test_place_and_with_config_keep_the_vibration_going():
    cfg = make_config(stage=2, vibration="lab", time_base="seconds", step_s=0.01)
    sim = BatchedSimulation(cfg, num_envs=4, seed=1)
    sim.reset()
    for _ in range(30):
        sim.step_setpoints(np.zeros((4, 2)))
    placed = sim.place(delay_errors_fs=np.full((4, 2), 0.5))
    np.testing.assert_allclose(placed.applied_fs, 0.5, atol=1e-12)
    other = sim.with_config(cfg.replace(jitter_sigma_cycles=0.002, step_s=0.02))
    assert other.noise.vibration is sim.noise.vibration
    assert other.noise.time_s == pytest.approx(0.3)
    other.step_setpoints(np.zeros((4, 2)))
    assert other.noise.time_s == pytest.approx(0.32)
