"""The first readings of a lock on a rig (docs/rig.md, "Where the losses fall"): a rig's
calibrated full scale is 0.4-2 % off, some commands come a step late, and the first pair of
readings may be taken while a line still moves. The tracker fits its detector when a fresh
lock misfits, tests no knot before that fit, and measures a noise that would widen its fits
twice."""

from __future__ import annotations

import numpy as np
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_controller_ros.tracker.tracking import gain_prior, level_prior
from ops_sim_ros.simulation import BatchedSimulation


def _held_with_a_gain_off(
    seed: int,
    gain: float = 1.02,
    p_late: float = 0.15,
    steps=500,
    p_gap: float = 0.0,
    offset: float = 0.0,
    **params,
):
    """(share of readings 50.. >= 0.95, knots taken, fitted gain) in hard mode when the slot
    energies read ``gain`` times high (plus ``offset``) and, as over DDS, ``p_late`` of the
    commands are a step late (the rig stepped once more on the one before; told by the step
    count) and ``p_gap`` of them 2-5 steps late (a tracker slow for a moment: the node tells the
    steps and that the reading's step took the command). ``params``: the tracker's."""
    config = make_config(5, "hard", "test")
    sim = BatchedSimulation(config, 1, seed=seed)
    tracker = PhaseTracker(config, TrackerParams(power_weight=0.0, **params), seed=seed)
    sim.reset(seed=seed)
    rng = np.random.default_rng(seed)
    before, held = None, []
    for step in range(steps):
        command = next_command(tracker)
        extra = int(before is not None and rng.random() < p_late)
        if p_gap and before is not None and rng.random() < p_gap:
            extra = int(rng.integers(2, 6))
        for _ in range(extra):
            sim.step_setpoints(before[None])
        res = sim.step_setpoints(command[None])
        energies = gain * res.pulse_energies[0] + offset
        power = min(float(np.sum(np.maximum(energies, 0.0) ** 2)), 1.0)
        age = 0 if p_gap else None
        tracker.observe(power, energies, steps=1 + extra, command_age=age)
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


def test_a_detector_the_acquisition_fitted_wrong_is_fitted_again_at_the_lock():
    """On a rig (``power_weight`` 0) nothing but the excursions pins the slot energies' level.
    An acquisition that fits the detector to its low readings was seen 1 % off (hard, seed 8,
    an exact detector): the lock then read the gain's error as delay errors, took 237 false
    knots and held 47 % of its readings. The first window after the lock fits the gain too
    (``lock_gain_walk``): it holds, with the gain back at 1."""
    held, knots, gain = _held_with_a_gain_off(8, gain=1.0, p_late=0.0, steps=300)
    assert held >= 0.98, (held, knots, gain)
    assert knots <= 5, (held, knots, gain)
    assert abs(gain - 1.0) < 0.003, (held, knots, gain)
    # the fit of the gain is no part of the in-process tracker (its power pins the level)
    in_process = PhaseTracker(make_config(5, "hard", "test"), seed=1)
    assert gain_prior(in_process.params, 0, in_process.window_length) == 0.0


def test_a_lock_with_a_gain_off_holds_through_a_slow_tracker():
    """Readings 2-5 steps apart now and then (a tracker slow for a moment, as over DDS after
    a lock), the slot energies 1.6 % high. Before the gain fit, seeds 1-20 held 0.416-1.0
    with 385 knots between them; these four 96.8 / 41.6 / 95.2 / 96.8 % with 290 knots (a
    gain fitted a fraction of a percent off, and knots taken for it). Now seeds 1-20 hold
    0.992-1.0, with 11 knots (these four with OpenBLAS's Prescott kernels: 1.0 / 0.996 / 1.0 /
    0.976)."""
    runs = [_held_with_a_gain_off(s, 1.016, 0.15, 300, p_gap=0.1) for s in (5, 8, 12, 18)]
    assert all(held >= 0.95 for held, _, _ in runs), runs
    assert np.mean([held for held, _, _ in runs]) >= 0.985, runs
    assert sum(knots for _, knots, _ in runs) <= 20, runs
    assert all(abs(g - 1.016) < 0.003 for _, _, g in runs), runs


def test_a_lock_whose_detector_offset_is_off_holds():
    """A detector's reading of no light 4e-4 of the full scale high (a rig whose calibrated
    offset is off and that does not measure it in each record, docs/rig.md): every empty slot
    of the stack reads like leaking light, which the fits take for knots. Fitted with the gain
    in the first window after the lock (``lock_offset_walk``), it costs nothing; left out, the
    runs take false knots, and now and then lose the stack (seed 2: 0.81-1.00 held, 20-121
    knots).

    Each run is one chaotic trajectory: a change of the fits in the last bits (the order of a
    sum) moves a run's knots and lost readings, so the claims are sums over seeds 1-8 with a
    margin. Measured over the numpy and the compiled fits, and with the readings jittered by
    1e-12 (5 trajectories of each seed): fitted, 3-4 knots in all and no run below 0.992; left
    out, 43-144 knots in all (20-28 without seed 2)."""
    seeds = range(1, 9)
    gain_off = (1.016, 0.15, 300)
    fitted = [_held_with_a_gain_off(s, *gain_off, p_gap=0.1, offset=4e-4) for s in seeds]
    assert min(held for held, _, _ in fitted) >= 0.98, fitted
    assert np.mean([held for held, _, _ in fitted]) >= 0.995, fitted
    assert sum(knots for _, knots, _ in fitted) <= 10, fitted
    left_out = [
        _held_with_a_gain_off(s, *gain_off, p_gap=0.1, offset=4e-4, lock_offset_walk=0)
        for s in seeds
    ]
    assert sum(knots for _, knots, _ in left_out) >= 25, (left_out, fitted)
    # like the gain's, no part of the in-process tracker (its power pins the level)
    p = PhaseTracker(make_config(5, "hard", "test"), seed=1).params
    assert level_prior(p, gain_prior(p, 0, p.window)) == 0.0


def test_the_line_is_fitted_again_at_a_lock_on_readings_near_the_stack_only():
    """Away from the stack a delay error moves the slot energies as much as the gain does:
    over DDS refits on first locked readings of 0.90-0.91 gave gains 3-4 % off, and one of
    those locks was lost. Readings below ``lock_refit_power`` are left out; with none left
    nothing is fitted and the acquisition's fit stays provisional."""
    config = make_config(5, "hard", "test")
    sim = BatchedSimulation(config, 1, seed=1)
    tracker = PhaseTracker(config, TrackerParams(power_weight=0.0), seed=1)
    sim.reset(seed=1)
    while tracker.estimate is None:
        res = sim.step_setpoints(next_command(tracker)[None])
        energies = res.pulse_energies[0].astype(np.float64)
        tracker.observe(min(float(np.sum(energies**2)), 1.0), energies)
    u, _, age = tracker._window()
    cal = tracker.calibration
    before = (cal.gain, cal.offset, cal.detector_provisional)
    last_power = tracker.window.latest[1][-1]
    assert last_power < 0.95  # a lock is taken on the search's last reading, far from the stack
    fit = tracker._fit_detector_to
    assert not fit(tracker.estimate, tracker.drift, u, age, last=1, min_power=0.95)
    assert (cal.gain, cal.offset, cal.detector_provisional) == before
    assert fit(tracker.estimate, tracker.drift, u, age, last=1, min_power=0.0)


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
    assert tracker.noise.var is None  # 0.003: to be confirmed
    np.testing.assert_array_equal(next_command(tracker), command)  # the repeat goes on
    tracker.observe(power, y + rng.normal(0.0, 0.0002, y.shape))
    assert tracker.measured_noise is not None and tracker.measured_noise < 0.001
    assert not tracker._noisy()
