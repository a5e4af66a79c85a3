"""The first readings of a lock on a rig (docs/rig.md, "Where the losses fall"): a rig's
calibrated full scale is 0.4-2 % off, some commands come a step late, and the first pair of
readings may be taken while a line still moves. The tracker fits its detector when a fresh
lock misfits, tests no knot before that fit, and measures a noise that would widen its fits
twice."""

from __future__ import annotations

import numpy as np
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_sim_ros.config import make_config
from ops_sim_ros.simulation import BatchedSimulation


def _held_with_a_gain_off(seed: int, gain: float = 1.02, p_late: float = 0.15, steps=500):
    """(share of readings 50.. >= 0.95, knots taken, fitted gain) in hard mode when the slot
    energies read ``gain`` times high and, as over DDS, ``p_late`` of the commands are a step
    late (the rig stepped once more on the one before; told by the step count)."""
    config = make_config(5, "hard", "test")
    sim = BatchedSimulation(config, 1, seed=seed)
    tracker = PhaseTracker(config, TrackerParams(power_weight=0.0), seed=seed)
    sim.reset(seed=seed)
    rng = np.random.default_rng(seed)
    before, held = None, []
    for step in range(steps):
        command = next_command(tracker)
        late = before is not None and rng.random() < p_late
        if late:
            sim.step_setpoints(before[None])
        res = sim.step_setpoints(command[None])
        energies = gain * res.pulse_energies[0]
        tracker.observe(min(float(np.sum(energies**2)), 1.0), energies, steps=1 + late)
        tracker.think()
        before = command
        if step >= 50:
            held.append(float(res.power[0]) >= 0.95)
    return float(np.mean(held)), tracker.knots, tracker.calibration.gain


def test_a_lock_on_a_detector_2_percent_off_holds_through_late_commands():
    """Before (the misfit of the unfitted detector taken for knots, fits refused until a
    recovery): seeds 1-4 held 99.8 / 93.6 / 93.6 / 100 % with 141 knots in all (hard mode has
    none); now 100 / 99.6 / 100 / 100 % with 8."""
    runs = [_held_with_a_gain_off(seed) for seed in (1, 2, 3, 4)]
    held, knots, gains = zip(*runs, strict=True)
    assert min(held) >= 0.98, runs
    assert sum(knots) <= 20, runs
    assert all(abs(g - 1.02) < 0.005 for g in gains), runs


def test_no_knot_test_before_the_detector_is_fitted():
    tracker = PhaseTracker(make_config(5, "hard", "test"), seed=1)
    assert not tracker._detector_settled()
    tracker.calibration.detector_fitted = True
    assert tracker._detector_settled()
    tracker.calibration.reset_detector()  # a dropped lock goes back to the nominal detector
    assert not tracker._detector_settled()
    off = PhaseTracker(make_config(5, "hard", "test"), TrackerParams(calibrate=False), seed=1)
    assert off._detector_settled()  # nothing to wait for


def test_a_noise_that_would_widen_the_fits_is_measured_twice():
    """The first pair taken while a line still moved reads 0.003 (below the noisy threshold,
    but three times its variance widens the fits' tolerance thirty-fold: over the rig such a
    tracker took fits that walked off the peak); the next pair, at rest, is the measure."""
    config = make_config(5, "hard", "test")
    sim = BatchedSimulation(config, 1, seed=3)
    tracker = PhaseTracker(config, seed=3)
    res = sim.reset(seed=3)
    y = res.pulse_energies[0].astype(np.float64)
    rng = np.random.default_rng(0)
    power = float(res.power[0])
    tracker.observe(power, y + rng.normal(0.0, 0.004, y.shape))  # a line still moving
    command = next_command(tracker)
    tracker.observe(power, y + rng.normal(0.0, 0.0002, y.shape))
    assert tracker._noise_var is None  # 0.003: to be confirmed
    np.testing.assert_array_equal(next_command(tracker), command)  # the repeat goes on
    tracker.observe(power, y + rng.normal(0.0, 0.0002, y.shape))
    assert tracker.measured_noise is not None and tracker.measured_noise < 0.001
    assert not tracker._noisy()
