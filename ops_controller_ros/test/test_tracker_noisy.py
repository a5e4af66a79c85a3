"""Any noise the tracker is told of counts as noisy: a digitized trace however fine,
the detector's noise, the source's pulse noise; and on a noisy detector the drift estimate moves
slowly, so the noise does not walk it away (docs/tracker.md, "Noise")."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_sim_ros.simulation import BatchedSimulation

P = TrackerParams()


@pytest.mark.parametrize(
    "rig",
    [
        dict(trace_adc_bits=10, trace_full_scale=1.25),  # rounding alone: 0.0007 rms as told
        dict(trace_adc_bits=12, trace_full_scale=1.25),
        dict(detector_noise=0.0005),
        dict(pulse_amplitude_noise=0.01),
    ],
)
def test_a_told_noise_takes_the_noisy_fit_window(rig):
    tracker = PhaseTracker(make_config(5, "hard", "test", **rig), seed=1)
    assert tracker.window_length == max(P.window, P.noisy_window)


def test_an_ideal_detector_keeps_the_short_window():
    tracker = PhaseTracker(make_config(5, "hard", "test"), seed=1)
    assert tracker.window_length == P.window


def _held(seed: int, steps: int = 700) -> float:
    """Share of readings 150..steps >= 0.95, `lab` rig told, hard, one continuous run."""
    config = make_config(5, "hard", "test", realism="lab")
    sim = BatchedSimulation(config, 1, seed=seed)
    tracker = PhaseTracker(config, seed=seed)
    sim.reset(seed=seed)
    powers = []
    for _ in range(steps):
        res = sim.step_setpoints(next_command(tracker)[None])
        tracker.observe(float(res.power[0]), res.pulse_energies[0])
        powers.append(float(res.power[0]))
    return float(np.mean(np.array(powers[150:]) >= 0.95))


def test_the_lab_rig_is_held_near_the_top():
    """Before the slower drift estimate on a noisy detector (noisy_drift_prior_cycles 0.002),
    3000 readings of seeds 1000 and 1001 held 95.1 % and 95.8 % >= 0.95; now 99.45 % each."""
    held = [_held(seed) for seed in (71, 72)]
    assert min(held) >= 0.97, held


def _knot_run(
    budget_ms: float,
    seed: int = 1003,
    steps: int = 1500,
    spread: bool = False,
    mode="hard",
    units: int = 1,
) -> PhaseTracker:
    """The tracker after a continuous `lab` run (hard) with a budget and, as over DDS, 15 % of
    the commands a step late (the rig stepped once more on the old one). ``units``: think()
    calls a reading; with a budget of 1e-6 ms each runs one unit of a spread knot test, so the
    test moves on ``units`` units a reading whatever the machine's speed."""
    config = make_config(5, mode, "test", realism="lab")
    sim = BatchedSimulation(config, 1, seed=seed)
    # (no false-lock drops: a budget of 1e-6 ms leaves extreme mode's lock poor, and a lock
    # dropped and acquired again would move the knot tests these runs compare)
    params = TrackerParams(
        knot_budget_ms=budget_ms,
        quiet_drift_prior_cycles=0.0,
        slice_knot_test=spread,
        false_lock_readings=0,
    )
    tracker = PhaseTracker(config, params, seed=seed)
    sim.reset(seed=seed)
    rng = np.random.default_rng(seed)
    before = None
    for _ in range(steps):
        command = next_command(tracker)
        late = before is not None and rng.random() < 0.15
        if late:
            sim.step_setpoints(before[None])
        res = sim.step_setpoints(command[None])
        tracker.observe(float(res.power[0]), res.pulse_energies[0], steps=1 + late, command_age=0)
        for _ in range(units):  # the node runs a deferred knot test once the command is out
            tracker.think()
        before = command
    return tracker


def test_a_knot_test_cut_short_on_a_noisy_detector_takes_no_knot():
    """A knot test iterated once or twice wins on the noise: on a noisy detector a test its
    real-time budget cuts short is left inconclusive (no knot, counted); without a budget the
    same run's tests run to the end and are never counted as cut (slice_knot_test off)."""
    cut_short = _knot_run(budget_ms=1e-6)  # always past the deadline
    assert cut_short.knots == 0 and cut_short.knot_tests_cut > 0
    assert _knot_run(budget_ms=0.0).knot_tests_cut == 0


def test_a_knot_test_spread_over_readings_still_takes_knots():
    """slice_knot_test: a test the budget would cut runs on over the next readings, and its
    winner is tried again on the window it ends at: knots are taken (extreme mode's slopes
    turn every 40-120 steps; cut short, none would be), no test is cut, and without a budget
    nothing is spread. At 4 units a reading (a test of 31 units ends ~8 readings on) seeds
    1000-1007 took 5-8 knots in 800 readings, seeds 1001, 1003 and 1005 2-3 in 400 (unspread:
    8-23); at one unit a reading the winner is ~31 readings stale and 0-2 were taken in 800, so
    the run pins its units, not the machine's speed."""
    spread = _knot_run(budget_ms=1e-6, spread=True, mode="extreme", steps=400, units=4)
    assert spread.knot_tests_cut == 0
    assert spread.knot_tests_spread > 0 and spread.knots > 0
    cut = _knot_run(budget_ms=1e-6, spread=False, mode="extreme", steps=400)
    assert cut.knots == 0 and cut.knot_tests_cut > 0
    whole = _knot_run(budget_ms=0.0, spread=True, mode="extreme", steps=400)  # not spread
    assert whole.knot_tests_spread == 0 and whole.knots > spread.knots


def test_a_quiet_drift_is_held_stiffer_until_a_knot_or_a_cut_knot_test():
    """On a noisy detector the drift prior is quiet_drift_prior_cycles once no knot was taken
    for quiet_after readings, knotted_drift_prior_cycles within as many readings of a knot,
    and never the quiet one while the knot tests are cut short (no knot could be seen: then
    noisy_drift_prior_cycles); a clean detector keeps its own."""
    params = TrackerParams()
    noisy = PhaseTracker(make_config(5, "hard", "test", realism="lab"), params, seed=2)
    noisy.loop.tick = params.quiet_after + 5
    assert _drift_prior(noisy) == pytest.approx(params.quiet_drift_prior_cycles, rel=1e-12)
    noisy.knot.tick = noisy.loop.tick - 3  # a knot taken three readings ago: the slope changes
    assert _drift_prior(noisy) == pytest.approx(params.knotted_drift_prior_cycles, rel=1e-12)
    noisy.knot.tick = noisy.loop.tick - params.quiet_after  # long ago: quiet again
    assert _drift_prior(noisy) == pytest.approx(params.quiet_drift_prior_cycles, rel=1e-12)
    noisy.knot.tick = -(10**9)
    noisy.knot.cut_short = True  # the last knot test was cut short
    assert _drift_prior(noisy) == pytest.approx(params.noisy_drift_prior_cycles, rel=1e-12)
    clean = PhaseTracker(make_config(5, "hard", "test"), params, seed=2)
    clean.loop.tick = params.quiet_after + 5
    assert _drift_prior(clean) == pytest.approx(params.drift_prior_cycles, rel=1e-12)
    off = PhaseTracker(
        make_config(5, "hard", "test", realism="lab"),
        TrackerParams(quiet_drift_prior_cycles=0.0),
        seed=2,
    )
    off.loop.tick = params.quiet_after + 5
    assert _drift_prior(off) == pytest.approx(params.noisy_drift_prior_cycles, rel=1e-12)


def _drift_prior(tracker: PhaseTracker) -> float:
    """The drift prior a path fit of ``tracker`` would take now (its fit run's std)."""
    u, y, age = np.zeros((2, 5)), np.zeros((2, 32)), np.array([1.0, 0.0])
    run = tracker._fit_run(np.zeros((1, 5)), np.zeros((1, 5)), u, y, age, 1)
    weight = run._pb.prior_w[0, 2 * 5]  # the drift's prior weight: 1 / std^2
    return float(weight**-0.5)


def test_a_noisy_detector_looks_for_a_knot_further_back():
    """A knot shows through the noise readings later: on a noisy detector a smaller jump of the
    path asks for the knot test (noisy_knot_walk_sigmas), which places the knot among the
    window's last noisy_knot_readings readings; a clean detector keeps knot_walk_sigmas and
    knot_readings (the node's knot test there stays within its 4 ms)."""
    params = TrackerParams()
    assert params.noisy_knot_readings > params.knot_readings
    noisy = PhaseTracker(make_config(5, "extreme", "test", realism="lab"), params, seed=3)
    clean = PhaseTracker(make_config(5, "extreme", "test"), params, seed=3)
    assert noisy._knot_setting("knot_readings") == params.noisy_knot_readings
    assert clean._knot_setting("knot_readings") == params.knot_readings
    assert noisy._knot_setting("knot_walk_sigmas") == params.noisy_knot_walk_sigmas
    assert clean._knot_setting("knot_walk_sigmas") == params.knot_walk_sigmas
    assert noisy.window_length >= params.noisy_knot_readings + 1  # a reading before the knot


def _first_readings(gaps) -> PhaseTracker:
    """A tracker, ideal detector (hard), given its first readings with ``gaps`` steps between
    them (as a rig whose tracker was busy starting reports them), the simulator stepping on the
    commanded set-points for every step of a gap."""
    config = make_config(5, "hard", "test")
    sim = BatchedSimulation(config, 1, seed=3)
    tracker = PhaseTracker(config, seed=3)
    res = sim.reset(seed=3)
    tracker.observe(float(res.power[0]), res.pulse_energies[0])
    for gap in gaps:
        command = next_command(tracker)[None]
        for _ in range(gap):
            res = sim.step_setpoints(command)
        tracker.observe(float(res.power[0]), res.pulse_energies[0], steps=gap)
    return tracker


def test_the_detector_noise_is_measured_from_readings_a_step_apart():
    """The first reading is repeated to measure the noise; readings steps apart see the drift
    between them too (over a rig: 0.034 measured on a true 0.0003, and a tracker that took the
    detector as noisy held at 0.94). They are no measure: the repeat goes on until two come a
    step apart."""
    drifted = _first_readings([50])
    assert drifted.noise.var is None  # not measured from readings 50 steps apart
    assert np.array_equal(next_command(drifted), drifted.setpoints_fs)  # the repeat goes on
    measured = _first_readings([50, 1])
    assert measured.noise.var is not None and not measured._noisy()
    assert measured.window_length == P.window
    # Drift over 50 steps would have read as noise: the same readings a step apart, not
    # (the hard mode's drift between the first two readings is what made the 0.034)
    direct = _first_readings([1])
    assert direct.noise.var is not None and not direct._noisy()


def test_two_identical_readings_are_no_measure_of_the_noise():
    """A reading given twice (a scope's last record when no new trigger came; the simulated
    rig's optics before they stepped) is no detector without noise: the repeat goes on, and
    the next pair that differs is the measure (over the rig: 0.0000 on a true 0.0003)."""
    config = make_config(5, "hard", "test", detector_noise=0.002)
    sim = BatchedSimulation(config, 1, seed=5)
    tracker = PhaseTracker(config, seed=5)
    res = sim.reset(seed=5)
    tracker.observe(float(res.power[0]), res.pulse_energies[0])
    command = next_command(tracker)
    tracker.observe(float(res.power[0]), res.pulse_energies[0])  # the same acquisition again
    assert tracker.noise.var is None
    np.testing.assert_array_equal(next_command(tracker), command)  # the repeat goes on
    res = sim.step_setpoints(command[None])
    tracker.observe(float(res.power[0]), res.pulse_energies[0])
    assert tracker.measured_noise is not None and 0.0005 < tracker.measured_noise < 0.008


def test_a_detector_never_read_a_step_apart_stays_unmeasured():
    """A rig that never gives two readings a step apart: after a few repeats the tracker goes
    on acquiring, the noise unmeasured (taken as clean unless told)."""
    tracker = _first_readings([3] * 12)
    assert tracker.noise.var is None and not tracker._noisy()
    assert tracker.locked or tracker.window_length == P.window


def test_no_knot_test_on_a_window_across_an_outage():
    """A rig's outage: readings 270 steps apart, told as 100 (the loop node counts them from
    the rig's clock, at most 100). The window's walk over the gap explains anything, so no knot
    is looked for while the window holds it (without that guard a knot test runs here), and the
    lock is back at once by the drift's prediction."""
    config = make_config(5, "hard", "test")
    sim = BatchedSimulation(config, 1, seed=4)
    tracker = PhaseTracker(config, seed=4)
    res = sim.reset(seed=4)
    tracker.observe(float(res.power[0]), res.pulse_energies[0])
    for _ in range(300):
        res = sim.step_setpoints(next_command(tracker)[None])
        tracker.observe(float(res.power[0]), res.pulse_energies[0])
    held = next_command(tracker)[None]
    for _ in range(270):  # the rig holds its set-points through a 5.4 s outage at 50 Hz
        res = sim.step_setpoints(held)
    tracker.observe(float(res.power[0]), res.pulse_energies[0], steps=100)
    assert tracker.knot.job is None
    powers = []
    for _ in range(tracker.window_length - 1):  # the gap still in the window
        res = sim.step_setpoints(next_command(tracker)[None])
        tracker.observe(float(res.power[0]), res.pulse_energies[0])
        assert tracker.knot.job is None
        powers.append(float(res.power[0]))
    assert tracker.locked and min(powers[2:]) >= 0.95, powers
