"""The tracker's latency check: a latency it was not told, or a wrong one, is found from the
readings and taken, instead of a silent collapse."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_controller_ros.tracker.latency_check import pair_readings
from ops_sim_ros.simulation import BatchedSimulation


def run(rig: int, told: int, mode: str, seed: int, steps: int = 150, params=None):
    """A rig of latency ``rig`` and a tracker told ``told`` (``params``: TrackerParams or the
    defaults), in process: (tracker, reading at which it took a latency or None, every
    reading's P_N/P_max)."""
    sim = BatchedSimulation(make_config(5, mode, "test", latency_steps=rig), 1, seed=seed)
    tracker = PhaseTracker(make_config(5, mode, "test", latency_steps=told), params, seed=seed)
    sim.reset(seed=seed)
    taken_at, powers = None, []
    for k in range(steps):
        res = sim.step_setpoints(next_command(tracker)[None])
        tracker.observe(float(res.power[0]), res.pulse_energies[0])
        powers.append(float(res.power[0]))
        if tracker.latency_changes and taken_at is None:
            taken_at = k + 1
    return tracker, taken_at, np.array(powers)


def test_readings_pair_with_the_command_acting_that_many_steps_before():
    commands = [(1, np.array([1.0])), (2, np.array([2.0])), (3, np.array([3.0]))]
    readings = [(1, np.array([10.0])), (2, np.array([20.0])), (3, np.array([30.0]))]
    u, y, age = pair_readings(commands, readings, 0)
    assert u.ravel().tolist() == [1.0, 2.0, 3.0] and age.tolist() == [2.0, 1.0, 0.0]
    u, y, age = pair_readings(commands, readings, 1)
    assert u.ravel().tolist() == [1.0, 2.0] and y.ravel().tolist() == [20.0, 30.0]
    assert pair_readings(commands, readings, 5) is None


@pytest.mark.parametrize(("rig", "told", "seed"), [(2, 1, 41), (1, 0, 42), (0, 1, 43)])
def test_a_wrong_latency_is_found_within_50_readings_and_the_tracker_recovers(rig, told, seed):
    tracker, found_at, powers = run(rig, told, "hard", seed)
    assert tracker.latency == rig and tracker.latency_told == told
    assert found_at is not None and found_at <= 50, found_at
    assert f"a latency of {rig} steps, not the {told}" in tracker.latency_note
    assert powers[-20:].mean() >= 0.95


def test_the_told_latency_is_kept_and_the_check_can_be_switched_off():
    tracker, found_at, powers = run(2, 2, "hard", 44)
    assert found_at is None and tracker.latency == 2 and tracker.latency_note is None
    assert powers[-20:].mean() >= 0.95
    off = TrackerParams(latency_check_after=0)
    tracker, found_at, powers = run(2, 1, "hard", 45, steps=80, params=off)
    assert found_at is None and tracker.latency_checks == 0  # told wrong, never checked
    assert powers[-20:].mean() < 0.5  # what the check is there for


def test_taking_a_latency_drops_the_work_of_the_old_pairing():
    """Seen over DDS: a deferred knot test of the old pairing, run after the window was
    emptied, crashed the node. Taking a latency drops it; the tracker acquires anew."""
    tracker, _, _ = run(1, 1, "hard", 46, steps=60)
    assert tracker.locked
    tracker.knot.job = object()  # a knot test still to run (defer_knot_test)
    tracker._take_latency(2)
    assert tracker.knot.job is None and not tracker.locked and tracker.latency == 2
    assert not tracker.think()
    assert np.all(np.isfinite(next_command(tracker)))


def _run_with_late_commands(latency, mode, seed, tell, p_late=0.15, steps=300):
    """A free-running rig in process: with probability ``p_late`` a command comes after the
    rig's next step (that step runs on the old set-points, its reading is not used), as over
    DDS on a busy machine; ``tell``: the tracker is told the command's age (0: taken by the
    reading's own step), as the loop node reads it from ops/delays."""
    config = make_config(5, mode, "test", latency_steps=latency)
    sim = BatchedSimulation(config, 1, seed=seed)
    tracker = PhaseTracker(config, seed=seed)
    sim.reset(seed=seed)
    rng = np.random.default_rng(seed + 1)
    previous, powers = sim.setpoints_fs[0].copy(), []
    for _ in range(steps):
        u = next_command(tracker)
        n = 1
        while n < 3 and rng.random() < p_late:
            sim.step_setpoints(previous[None])
            n += 1
        res = sim.step_setpoints(u[None])
        previous = u
        age = 0 if tell else None
        tracker.observe(float(res.power[0]), res.pulse_energies[0], steps=n, command_age=age)
        powers.append(float(res.power[0]))
    return tracker, np.array(powers[100:])


def test_late_commands_told_by_their_age_are_not_taken_for_a_longer_latency():
    """A command that came after the rig's next step acts a step later than the tracker
    expects; told its age (the step that took it), the tracker pairs it right and holds."""
    told, untold = [], []
    for latency, mode, seed in [(1, "medium", 52), (2, "hard", 53)]:
        tracker, powers = _run_with_late_commands(latency, mode, seed, tell=True)
        assert tracker.latency == latency and tracker.latency_changes == 0
        told.append(np.mean(powers >= 0.95))
        _, powers = _run_with_late_commands(latency, mode, seed, tell=False)
        untold.append(np.mean(powers >= 0.95))
    assert min(told) >= 0.98, told
    assert np.mean(untold) < np.mean(told)  # what the age is there for
