"""The rig between controller and optics (ops_sim_ros.rig): latency, DAC, hysteresis,
actuator lag and the trace's digitizer, each as a property of the simulation."""

import re

import numpy as np
import pytest
from ops_contract.config import REALISM_PRESETS, make_config
from ops_sim_ros.rig import Actuator, digitize, quantize
from ops_sim_ros.simulation import BatchedSimulation


def _sim(stage=2, seed=0, **rig):
    cfg = make_config(stage=stage, mode="easy", jitter_sigma_cycles=0.0, **rig)
    sim = BatchedSimulation(cfg, num_envs=1, seed=seed)
    sim.reset(seed=seed)
    return sim


def test_the_ideal_rig_is_the_simulation_it_always_was():
    """No figure moves: the default and realism=ideal give the same numbers, bit for bit."""
    runs = []
    for rig in ({}, {"realism": "ideal"}):
        cfg = make_config(stage=3, mode="hard", detector_noise=0.01, **rig)
        sim = BatchedSimulation(cfg, num_envs=2, seed=4)
        sim.reset(seed=4)
        rng = np.random.default_rng(1)
        out = [sim.step_setpoints(rng.normal(0, 2, (2, 3))) for _ in range(20)]
        runs.append(np.concatenate([np.c_[r.applied_fs, r.pulse_energies, r.power] for r in out]))
        assert sim.actuator is None and sim.digitizer is None
    assert np.array_equal(runs[0], runs[1])


@pytest.mark.parametrize("latency", [1, 2, 4])
def test_a_command_acts_latency_steps_after_it_was_sent(latency):
    sim = _sim(latency_steps=latency)
    offset = sim.last.applied_fs[0] - sim.last.setpoints_fs[0]
    target = np.array([1.5, -0.7])
    moved = []
    for _ in range(latency + 2):
        r = sim.step_setpoints(target[None])
        assert np.allclose(r.setpoints_fs[0], target)  # reported as commanded at once
        moved.append(np.allclose(r.applied_fs[0] - offset, target))
    assert moved == [False] * latency + [True, True]


def test_lag_is_a_first_order_response():
    sim = _sim(actuator_lag_steps=5.0)
    start = sim.last.applied_fs[0].copy()
    for _ in range(5):
        r = sim.step_setpoints(np.array([[2.0, 2.0]]))
    reached = (r.applied_fs[0] - start) / 2.0
    assert np.allclose(reached, 1.0 - np.exp(-1.0), atol=1e-9)  # 63 % after one time constant


def test_the_dac_puts_the_delay_lines_on_its_levels():
    sim = _sim(dac_bits=6)
    half = sim.range_fs
    step = 2 * half / (2**6 - 1)
    offset = sim.last.applied_fs[0] - sim.actuator.position[0]
    for x in np.linspace(-half, half, 37):
        r = sim.step_setpoints(np.array([[x, x / 3]]))
        levels = (r.applied_fs[0] - offset + half) / step
        assert np.allclose(levels, np.round(levels), atol=1e-6)
        assert np.all(np.abs(r.applied_fs[0] - offset - [x, x / 3]) <= step / 2 + 1e-9)


def _sweep(fraction: float, amplitude: float = 1.0, points: int = 201):
    """Positions on the way up and on the way down of a sweep over +- amplitude x the range."""
    cfg = make_config(stage=1, actuator_hysteresis=fraction)
    act = Actuator(cfg, num_envs=1)
    half = cfg.actuator_range_fs
    x = np.linspace(-amplitude * half, amplitude * half, points)
    act.reset(np.array([[x[0]]]))
    for _ in range(2):  # a first cycle settles the operators' memory
        up = np.array([act.move(np.array([[v]]))[0, 0] for v in x])
        down = np.array([act.move(np.array([[v]]))[0, 0] for v in x[::-1]])[::-1]
    return x, up, down, 2 * half


@pytest.mark.parametrize("fraction", [0.05, 0.15, 0.5])
def test_hysteresis_opens_a_loop_its_fraction_of_the_travel_wide(fraction):
    _, up, down, travel = _sweep(fraction)
    width = np.max(down - up) / travel
    assert 0.8 * fraction <= width <= 1.05 * fraction, width
    assert np.all(down >= up - 1e-9)  # the way down lies above the way up: a loop
    assert np.all(np.diff(up) >= -1e-9) and np.all(np.diff(down) >= -1e-9)  # monotonic
    # a small sweep opens a smaller loop (a piezo's loop scales with its excursion)
    _, up, down, travel = _sweep(fraction, amplitude=0.2)
    assert np.max(down - up) / travel < 0.1 * fraction
    # small moves go as far as commanded (the rig's calibration is made with them)
    x, up, down, travel = _sweep(fraction, amplitude=0.01)
    assert np.allclose(np.diff(up), np.diff(x), rtol=0.05)


def test_the_digitizer_rounds_to_its_levels_and_clips_at_full_scale():
    rng = np.random.default_rng(0)
    e = np.array([[0.0, 0.1, 0.5, 0.97, 1.3, -0.01]])
    out = digitize(e, 0.0, 1, 8, 1.0, rng)
    assert np.allclose(out * 255, np.round(out * 255))
    assert out.max() == 1.0 and out.min() == 0.0
    assert np.all(np.abs(out - np.clip(e, 0, 1)) <= 0.5 / 255 + 1e-12)
    assert np.array_equal(quantize(np.array([0.3]), 0.0, 1.0, 1), [0.0])


def test_averaging_traces_lowers_the_noise_by_the_root_of_their_number():
    rng = np.random.default_rng(2)
    e = np.full((4000, 3), 0.4)
    one = digitize(e, 0.02, 1, 12, 1.0, rng).std()
    sixteen = digitize(e, 0.02, 16, 12, 1.0, rng).std()
    assert 3.0 < one / sixteen < 5.5  # sqrt(16) = 4


def test_an_8_bit_trace_in_the_simulation():
    sim = _sim(stage=3, trace_adc_bits=8, trace_full_scale=0.5)
    e = sim.step_setpoints(np.zeros((1, 3))).pulse_energies
    assert np.allclose(e * 255 / 0.5, np.round(e * 255 / 0.5)) and e.max() <= 0.5


def test_the_lab_preset_and_its_overrides():
    lab = make_config(realism="lab")
    for key, value in REALISM_PRESETS["lab"].items():
        assert getattr(lab, key) == value
    assert make_config(realism="lab", latency_steps=3).latency_steps == 3
    assert make_config(realism="lab").to_dict() == lab.replace().to_dict()  # round trip
    sim = BatchedSimulation(lab.replace(stage=2), num_envs=3, seed=1)
    r = sim.reset(seed=1)
    for _ in range(5):
        r = sim.step_setpoints(r.setpoints_fs + 0.5)
    assert np.all(np.isfinite(r.pulse_energies)) and np.all(np.isfinite(r.power))


@pytest.mark.parametrize(
    "bad, says",
    [
        (dict(latency_steps=-1), "latency_steps must be from 0 to 1000"),
        (dict(trace_adc_bits=40), "trace_adc_bits must be 0 (an ideal trace) or from 1 to 32"),
        (dict(dac_bits=33), "dac_bits must be 0 (an ideal DAC) or from 1 to 32"),
        (dict(actuator_hysteresis=1.0), "actuator_hysteresis must be from 0.0 to 0.99"),
        (dict(trace_averages=0), "trace_averages must be from 1 to 10000"),
        (dict(realism="garage"), "realism must be one of ideal, lab"),
    ],
)
def test_bad_rig_figures_are_named_with_their_range(bad, says):
    with pytest.raises(ValueError, match=re.escape(says)):
        make_config(**bad)
