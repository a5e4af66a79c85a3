"""A rig drawn anew for every episode (ops_contract.rig_randomization; training on
the rig): the draws stay in their ranges, differ between episodes and environments, repeat for the
same seed, and a bad range is refused naming the figure and what it may be.

Property-style: each property is checked over many ranges and seeds drawn from a fixed stream
(no extra test library)."""

import numpy as np
import pytest
from ops_contract.config import IDEAL_ZERO, INT_FIELDS, LIMITS, RIG_KEYS, make_config
from ops_contract.rig_randomization import RANGE_PRESETS, RigRanges
from ops_sim_ros.env import OpsEnv
from ops_sim_ros.simulation import BatchedSimulation
from ops_sim_ros.vec_env import OpsVectorEnv

#: Sensible spans to draw test ranges from (LIMITS goes to 1000 steps of latency).
_SPAN = {
    "latency_steps": (0, 6),
    "actuator_lag_steps": (0.0, 3.0),
    "dac_bits": (0, 20),
    "trace_adc_bits": (0, 14),
    "trace_full_scale": (0.5, 2.0),
    "trace_averages": (1, 4),
}


def _random_ranges(rng: np.random.Generator) -> dict:
    """Valid ranges of a random subset of the rig's figures."""
    keys = rng.choice(RIG_KEYS, size=rng.integers(1, len(RIG_KEYS) + 1), replace=False)
    out = {}
    for key in keys:
        low, high = _SPAN.get(key, LIMITS[key])
        if key in INT_FIELDS:
            a, b = sorted(rng.integers(low, high + 1, size=2))
            out[str(key)] = (int(a), int(b))
        else:
            a, b = sorted(rng.uniform(low, high, size=2))
            out[str(key)] = (float(a), float(b))
    return out


@pytest.mark.parametrize("case", range(40))
def test_draws_stay_in_their_ranges_integers_where_integer(case):
    rng = np.random.default_rng(1000 + case)
    ranges = RigRanges(_random_ranges(rng))
    for _ in range(50):
        rig = ranges.draw(rng)
        assert set(rig) == set(ranges.ranges)
        for key, value in rig.items():
            low, high = ranges.ranges[key]
            assert low <= value <= high, (key, value, low, high)
            assert isinstance(value, int) == (key in INT_FIELDS)
        make_config(stage=3, **rig)  # every draw is a valid rig


@pytest.mark.parametrize("case", range(20))
def test_the_same_seed_draws_the_same_rigs_and_episodes_differ(case):
    ranges = RigRanges(_random_ranges(np.random.default_rng(case)))
    seq = [[ranges.draw(np.random.default_rng(seed)) for _ in range(3)] for seed in (7, 7)]
    assert seq[0] == seq[1]
    rng = np.random.default_rng(case)
    draws = [ranges.draw(rng) for _ in range(30)]
    wide = {k for k, (lo, hi) in ranges.ranges.items() if hi > lo}
    for key in wide:  # 30 draws of a range wider than a point: not all the same
        assert len({d[key] for d in draws}) > 1, key


def test_integer_draws_reach_both_ends():
    rng = np.random.default_rng(3)
    seen = {RigRanges({"latency_steps": (0, 2)}).draw(rng)["latency_steps"] for _ in range(60)}
    assert seen == {0, 1, 2}


def test_command_line_items_presets_and_fixed_values():
    ranges = RigRanges.parse(["lab", "latency_steps=0:3", "trace_averages=2"])
    assert ranges.ranges["latency_steps"] == (0, 3)  # a later item wins
    assert ranges.ranges["trace_averages"] == (2, 2)
    assert ranges.ranges["actuator_hysteresis"] == RANGE_PRESETS["lab"]["actuator_hysteresis"]
    assert RigRanges.from_value(ranges.to_dict()) == ranges  # metadata round trip
    assert not RigRanges.parse(None) and not RigRanges.from_value(None)
    assert ranges.max_latency() == 3 and RigRanges({}).max_latency(1) == 1
    for key, (low, high) in RANGE_PRESETS["lab"].items():  # the preset holds the lab value
        assert low <= make_config(realism="lab").to_dict()[key] <= high, key


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("latency_steps=0:2000", "latency_steps=0:2000: latency_steps must be from 0 to 1000"),
        ("latency_steps=-1:2", "latency_steps must be from 0 to 1000"),
        ("latency_steps=0:1.5", "latency_steps is an integer"),
        ("actuator_hysteresis=0:1", "actuator_hysteresis must be from 0.0 to 0.99"),
        ("trace_adc_bits=4:33", "trace_adc_bits must be 0 (an ideal trace) or from 1 to 32"),
        ("pulse_amplitude_noise=0.02:0.01", "the low bound must not exceed the high bound"),
        ("pulse_amplitude_noise=0:x", "'x' is not a number"),
        ("wavelength_nm=1000:1100", "wavelength_nm: not a figure of the rig; allowed: latency"),
        ("latency_steps", "write KEY=LOW:HIGH"),
        ("burst_envelope=0:inf", "the bounds must be finite"),
    ],
)
def test_a_bad_range_is_refused_naming_the_figure_and_its_range(item, message):
    with pytest.raises(ValueError, match="--rig-randomize") as err:
        RigRanges.parse([item])
    assert message in str(err.value)


@pytest.mark.parametrize("case", range(12))
def test_every_allowed_end_is_accepted(case):
    rng = np.random.default_rng(case)
    key = str(rng.choice(RIG_KEYS))
    low, high = LIMITS[key]
    if key in IDEAL_ZERO:
        low = 0
    RigRanges({key: (low, high)})


def test_each_env_draws_its_own_rig_at_every_reset_repeatably():
    ranges = {"latency_steps": (0, 2), "trace_adc_bits": (6, 12), "burst_envelope": (0.0, 0.3)}
    envs = [OpsEnv(stage=3, mode="hard", realism="lab", rig_randomize=ranges) for _ in range(2)]
    rigs = {}
    for i, env in enumerate(envs):
        env.reset(seed=i)
        rigs[i] = [dict(env.rig)]
        for _ in range(5):
            env.reset()
            rigs[i].append(dict(env.rig))
            sim_cfg = env.sim.config
            assert sim_cfg.latency_steps == env.rig["latency_steps"]
            assert sim_cfg.trace_adc_bits == env.rig["trace_adc_bits"]
            assert sim_cfg.burst_envelope == env.rig["burst_envelope"]
            assert sim_cfg.dac_bits == 16 and sim_cfg.realism == "lab"  # the rest: the preset
            assert env.sim.actuator.latency == env.rig["latency_steps"]
        assert env.config.latency_steps == 1  # the env's own configuration stays
    assert rigs[0] != rigs[1]  # environments differ
    assert len({r["burst_envelope"] for r in rigs[0]}) == 6  # episodes differ
    again = OpsEnv(stage=3, mode="hard", realism="lab", rig_randomize=ranges)
    replay = []
    for k in range(6):
        again.reset(seed=0 if k == 0 else None)
        replay.append(dict(again.rig))
    assert replay == rigs[0]  # the same seed, the same rigs
    obs, _ = again.reset(seed=0)
    first, _ = envs[0].reset(seed=0)
    assert np.array_equal(obs, first)  # ... and the same episode


def test_a_drawn_rig_runs_as_a_rig_built_with_those_figures():
    """use_rig: a simulation switched to a rig runs exactly as one built with it."""
    lab = make_config(stage=3, mode="hard", realism="lab", latency_steps=2, trace_adc_bits=6)
    built = BatchedSimulation(lab, num_envs=2, seed=5)
    switched = BatchedSimulation(make_config(stage=3, mode="hard"), num_envs=2, seed=5)
    switched.use_rig(lab)
    results = []
    for sim in (built, switched):
        sim.reset(seed=5)
        rng = np.random.default_rng(2)
        steps = [sim.step_setpoints(rng.normal(0, 3, (2, 3))) for _ in range(15)]
        results.append(np.concatenate([np.c_[r.applied_fs, r.pulse_energies] for r in steps]))
    assert np.array_equal(results[0], results[1])
    with pytest.raises(ValueError, match="stage must stay 3"):
        switched.use_rig(make_config(stage=2))


def test_ranges_are_checked_with_the_envs_rig_and_the_batched_env_refuses_them():
    with pytest.raises(ValueError, match="latency_steps must be from 0 to 1000"):
        OpsEnv(stage=2, rig_randomize={"latency_steps": (0, 1001)})
    with pytest.raises(ValueError, match="rig_randomize: the batched envs share one rig"):
        OpsVectorEnv(num_envs=2, stage=2, rig_randomize={"latency_steps": (0, 2)})
