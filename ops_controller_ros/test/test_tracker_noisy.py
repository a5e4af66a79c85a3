"""Any noise the tracker is told of counts as noisy (issue 30): a digitized trace however fine,
the detector's noise, the source's pulse noise; and on a noisy detector the drift estimate moves
slowly, so the noise does not walk it away (docs/tracker.md, "Any told noise is noisy")."""

from __future__ import annotations

import numpy as np
import pytest
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_sim_ros.config import make_config
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


def _knot_counts(budget_ms: float, seed: int = 1003, steps: int = 1500) -> tuple[int, int]:
    """(knots taken, knot tests cut short) of a continuous `lab` run, hard, with a budget and,
    as over DDS, 15 % of the commands a step late (the rig stepped once more on the old one)."""
    config = make_config(5, "hard", "test", realism="lab")
    sim = BatchedSimulation(config, 1, seed=seed)
    params = TrackerParams(knot_budget_ms=budget_ms, quiet_drift_prior_cycles=0.0)
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
        tracker.think()  # the node runs a deferred knot test once the command is out
        before = command
    return tracker.knots, tracker.knot_tests_cut


def test_a_knot_test_cut_short_on_a_noisy_detector_takes_no_knot():
    """A knot test iterated once or twice wins on the noise: on a noisy detector a test its
    real-time budget cuts short is left inconclusive (no knot, counted); without a budget the
    same run's tests run to the end and are never counted as cut."""
    knots, cut = _knot_counts(budget_ms=1e-6)  # always past the deadline
    assert knots == 0 and cut > 0
    _, cut = _knot_counts(budget_ms=0.0)
    assert cut == 0


def test_a_quiet_drift_is_held_stiffer_until_a_knot_or_a_cut_knot_test():
    """On a noisy detector the drift prior is quiet_drift_prior_cycles once no knot was taken
    for quiet_after readings, knotted_drift_prior_cycles within as many readings of a knot,
    and never the quiet one while the knot tests are cut short (no knot could be seen: then
    noisy_drift_prior_cycles); a clean detector keeps its own."""
    params = TrackerParams()
    noisy = PhaseTracker(make_config(5, "hard", "test", realism="lab"), params, seed=2)
    noisy._tick = params.quiet_after + 5
    assert noisy._drift_prior() == params.quiet_drift_prior_cycles
    noisy._knot_tick = noisy._tick - 3  # a knot taken three readings ago: the slope changes
    assert noisy._drift_prior() == params.knotted_drift_prior_cycles
    noisy._knot_tick = noisy._tick - params.quiet_after  # long ago: quiet again
    assert noisy._drift_prior() == params.quiet_drift_prior_cycles
    noisy._knot_tick = -(10**9)
    noisy._knot_cut_short = True  # the last knot test was cut short
    assert noisy._drift_prior() == params.noisy_drift_prior_cycles
    clean = PhaseTracker(make_config(5, "hard", "test"), params, seed=2)
    clean._tick = params.quiet_after + 5
    assert clean._drift_prior() == params.drift_prior_cycles
    off = PhaseTracker(
        make_config(5, "hard", "test", realism="lab"),
        TrackerParams(quiet_drift_prior_cycles=0.0),
        seed=2,
    )
    off._tick = params.quiet_after + 5
    assert off._drift_prior() == params.noisy_drift_prior_cycles


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
