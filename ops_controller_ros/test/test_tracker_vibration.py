"""The tracker under a told vibration (tracker/vibration.py): the part a loop step does not keep
is noise of each reading, the rest a move of the path; the tracker then holds the `lab` preset
at 10 Hz on the `lab` rig (docs/loop_rate.md, "The tracker"), and nothing changes where no
vibration is told."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_controller_ros.tracker.vibration import told_vibration, under_vibration
from ops_sim_ros.simulation import BatchedSimulation
from ops_sim_ros.vibration import PRESETS


def _timed(rate_hz: float, vibration: str = "lab", **rig):
    """N = 5 hard (test split) on the `lab` rig in physical time at ``rate_hz``, latency and
    the lines' response 1 ms (as ops-bench rate-sweep)."""
    step_s = 1.0 / rate_hz
    return make_config(
        5,
        "hard",
        "test",
        realism="lab",
        time_base="seconds",
        step_s=step_s,
        vibration=vibration,
        latency_steps=round(0.001 / step_s),
        actuator_lag_steps=min(0.001 / step_s, 100.0),
        **rig,
    )


@pytest.mark.parametrize("rate", [10, 100, 1000])
def test_the_split_keeps_the_presets_variance(rate):
    model = told_vibration(TrackerParams(), _timed(rate))
    period = _timed(rate).optical_period_fs
    assert model.var == pytest.approx((PRESETS["lab"].rms_fs / period) ** 2, rel=0.01)
    # what is followed adds its move per step; what is not is all of its variance
    assert model.fast_var <= model.var
    assert model.walk_var >= 0.0


def test_a_slow_loop_reads_the_vibration_as_noise_and_a_fast_one_follows_it():
    slow = told_vibration(TrackerParams(), _timed(10))
    fast = told_vibration(TrackerParams(), _timed(1000))
    assert slow.fast_var > 0.5 * slow.var  # at 10 Hz most of it is new in every reading
    assert fast.fast_var < 0.1 * fast.var  # at 1 kHz most of it is followed
    assert fast.walk_var < 0.1 * fast.var  # ... and moves little per step


def test_no_vibration_told_changes_nothing():
    p = TrackerParams()
    for config in (make_config(5, "hard", "test"), _timed(10, "none")):
        assert under_vibration(p, config) is p
        assert PhaseTracker(config, seed=1).rig.vibration is None
    # a step-based model has no physical time to read a vibration at
    assert told_vibration(p, make_config(5, "hard", "test", vibration="lab")) is None
    # ... and one told "none" ignores the rig model's
    assert told_vibration(TrackerParams(vibration="none"), _timed(10)) is None


def test_the_walk_and_drift_prior_follow_the_loop_step():
    at_10 = PhaseTracker(_timed(10), seed=1).params
    at_1k = PhaseTracker(_timed(1000), seed=1).params
    assert at_1k.walk_cycles == pytest.approx(at_10.walk_cycles * 0.1)
    assert at_1k.noisy_drift_prior_cycles == pytest.approx(at_10.noisy_drift_prior_cycles / 100)


def _run(seed: int, seconds: float = 60.0, rate: float = 10.0):
    """(share of readings >= 0.95 from the first lock on, rms phase per stage mrad, readings
    below 0.8 in a row at most) of one lockstep run."""
    config = _timed(rate)
    sim = BatchedSimulation(config, 1, seed=seed)
    res = sim.reset(seed=seed)
    tracker = PhaseTracker(config, setpoints_fs=res.setpoints_fs[0], seed=seed)
    period = config.optical_period_fs
    power, phase = [], []
    for _ in range(round(seconds * rate)):
        res = sim.step_setpoints(next_command(tracker)[None])
        tracker.observe(float(res.power[0]), res.pulse_energies[0])
        cycles = res.applied_fs[0] / period
        power.append(float(res.power[0]))
        phase.append((cycles - np.rint(cycles)) * 2000.0 * np.pi)
    power, phase = np.array(power), np.array(phase)
    first = int(np.argmax(power >= 0.95))
    low = power[first:] < 0.8
    longest = max((len(r) for r in "".join("1" if v else "0" for v in low).split("0")), default=0)
    rms = float(np.sqrt(np.mean(phase[first:] ** 2)))
    return float(np.mean(power[first:] >= 0.95)), rms, longest


@pytest.mark.parametrize("seed", [7001, 7002, 7003])
def test_the_tracker_holds_the_lab_vibration_at_10_hz(seed):
    held, mrad, longest = _run(seed)
    # measured 94-97 % and 84-90 mrad on these seeds, 60 s each (the tracker blind to the
    # vibration: 44 % and 209 mrad on the sweep's seeds, docs/loop_rate.md)
    assert held >= 0.9, held
    assert mrad <= 110.0, mrad
    assert longest <= 5, longest  # no lock lost


@pytest.mark.parametrize(("rate", "remembered"), [(10, True), (100, True), (300, False)])
def test_only_a_window_of_a_tenth_of_a_second_or_more_takes_the_drift_memory(rate, remembered):
    """A 20-reading window at 300 Hz spans 67 ms, in which the vibration's slow part is a slope
    its own drift follows: there the fits keep their own drift (docs/loop_rate.md)."""
    from ops_controller_ros.tracker.drift_memory import drift_memory

    config = _timed(rate)
    p = under_vibration(TrackerParams(), config)
    vibration = told_vibration(TrackerParams(), config)
    assert vibration is not None
    assert (drift_memory(p, config, vibration) is not None) is remembered
    shorter = replace(p, vibration_memory_min_window_s=0.0)
    assert drift_memory(shorter, config, vibration) is not None


def _reversing(seed: int, seconds: float, after: float | None = None):
    """(readings below 0.8 in a row at most from the first lock on, the drift memory's turns,
    the largest distance of the drift carried from the true one, cycles a step) of a lockstep
    run at 10 Hz whose common drift reverses at +- 0.6 cycles (every 80-240 s; the `lab` rig
    turns at 10); ``after``: the memory's drift prior after a turn (0: the fits' own)."""
    config = _timed(10, drift_bound_cycles=0.6)
    sim = BatchedSimulation(config, 1, seed=seed)
    res = sim.reset(seed=seed)
    tracker = PhaseTracker(config, setpoints_fs=res.setpoints_fs[0], seed=seed)
    if after is not None:
        tracker.lock.memory.after = after
    period = config.optical_period_fs
    run, longest, off, first = 0, 0, 0.0, None
    for i in range(round(seconds * 10)):
        res = sim.step_setpoints(next_command(tracker)[None])
        tracker.observe(float(res.power[0]), res.pulse_energies[0])
        power = float(res.power[0])
        first = i if first is None and power >= 0.95 else first
        if first is not None:
            run = run + 1 if power < 0.8 else 0
            longest = max(longest, run)
            true = sim.noise.slope[0] / period
            off = max(off, float(np.abs(tracker.lock.drift - true).max()))
    return longest, tracker.lock.memory.turns, off


@pytest.mark.parametrize("seed", [7101, 7103])
def test_the_tracker_follows_a_reversing_drift_without_a_loss(seed):
    # two reversals or more in 240 s: let go at each, no lock lost after the first lock, and
    # the drift carried never 0.004 cycles a step off the true one, about three times its
    # speed (measured 0.0027 and 0.0023; with the fits' own drift under the knot-loosened
    # prior after a turn, 7101's ran off by 0.028 at a knot taken there)
    longest, turns, off = _reversing(seed, 240.0)
    assert turns >= 2, turns
    assert longest <= 5, longest  # no lock lost
    assert off < 0.004, off


def test_the_trace_rounding_is_weighed_as_the_tracker_is_told():
    """A digitized trace's rounding counts ``quantization_noise_steps`` ADC steps (0.6 by
    default, under a vibration or not), as ops_sim_ros.rig.reading_noise_std weighs it."""
    from ops_sim_ros.rig import reading_noise_std

    for config in (make_config(5, "hard", "test", realism="lab"), _timed(10)):
        quiet = replace(config, pulse_amplitude_noise=0.0)
        told = PhaseTracker(config, seed=1).params.detector_noise
        assert told == pytest.approx(reading_noise_std(quiet, 0.6))
        light = TrackerParams(quantization_noise_steps=0.3)
        lighter = PhaseTracker(config, light, seed=1).params.detector_noise
        assert lighter == pytest.approx(reading_noise_std(quiet, 0.3)) and lighter < told
