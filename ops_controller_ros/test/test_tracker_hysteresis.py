"""The tracker told of an open-loop piezo's hysteresis drives the lines through its inverse
(tracker/hysteresis.py): the lines then go where the tracker means them to, as they do with no
hysteresis at all; untold, or with ``compensate_hysteresis`` off, they do not."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_sim_ros.simulation import BatchedSimulation


def _run(seed: int, compensate: bool, readings: int = 150):
    """The largest gap (fs) between where the tracker meant the lines and where they went, and
    the share of readings >= 0.95 after the first lock, on an ideal rig but for a piezo's
    hysteresis (so a line's position is its hysteresis output)."""
    config = make_config(3, "hard", "test", actuator_hysteresis=0.15)
    sim = BatchedSimulation(config, 1, seed=seed)
    res = sim.reset(seed=seed)
    params = TrackerParams(compensate_hysteresis=compensate)
    tracker = PhaseTracker(config, params, setpoints_fs=res.setpoints_fs[0], seed=seed)
    gap, powers = 0.0, []
    for _ in range(readings):
        wire = next_command(tracker)
        assert np.array_equal(tracker.command(), wire)  # asked again: the same drive
        res = sim.step_setpoints(wire[None])
        meant = tracker.loop.last_command * tracker.rig.period_fs
        gap = max(gap, float(np.max(np.abs(sim.actuator.position[0] - meant))))
        tracker.observe(float(res.power[0]), res.pulse_energies[0])
        if tracker.locked or powers:
            powers.append(float(res.power[0]))
    return gap, float(np.mean(np.asarray(powers) >= 0.95))


@pytest.mark.parametrize("seed", [3, 4])
def test_compensated_lines_go_where_they_are_meant(seed):
    gap, held = _run(seed, compensate=True)
    assert gap < 1e-6, gap
    assert held > 0.9, held
    # without the compensation the acquisition's moves leave the lines elsewhere
    gap_off, _ = _run(seed, compensate=False)
    assert gap_off > 0.01, gap_off


def test_no_hysteresis_told_sends_the_set_points_as_they_are():
    config = make_config(3, "hard", "test", realism="lab", actuator_hysteresis=0.0)
    tracker = PhaseTracker(config, seed=1, setpoints_fs=np.array([1.0, -2.0, 0.5]))
    assert tracker.rig.compensation is None
    wire = tracker.command()
    assert np.allclose(wire, tracker.loop.last_command * tracker.rig.period_fs)
    assert PhaseTracker(make_config(3, "hard", "test", realism="lab")).rig.compensation


@pytest.mark.parametrize("fraction", [0.02, 0.05, 0.12, 0.3, 0.5])
def test_the_compiled_inverse_is_the_simulators(fraction):
    """The compensation's kernel against the simulator's hysteresis: jumps across the travel and
    past its ends, then the small moves of a held set-point; positions and operators' states
    agree, and a drive given again leaves the operators as they were."""
    from ops_controller_ros.tracker.hysteresis import HysteresisCompensation
    from ops_sim_ros.rig import hysteresis, hysteresis_radii

    config = make_config(4, "hard", "test", actuator_hysteresis=fraction)
    comp = HysteresisCompensation(config)
    comp.reset(np.zeros(4))
    half = config.actuator_range_fs
    radii = hysteresis_radii(half)
    plays = np.zeros((radii.size, 1, 4))
    rng = np.random.default_rng(7)
    meant = np.zeros(4)
    for t in range(400):
        if t % 50 == 0:
            meant = rng.uniform(-1.1 * half, 1.1 * half, 4)
        else:
            meant = meant + rng.normal(0.0, 0.03 if t % 100 < 50 else 2.0, 4)
        drive = comp.drive(meant)
        position, plays = hysteresis(drive[None], plays, radii, fraction)
        reachable = np.abs(drive) < half  # (past the travel's end the drive is clipped)
        assert np.allclose(position[0][reachable], meant[reachable], atol=1e-9), t
        assert np.allclose(comp.plays, plays[:, 0, :], atol=1e-12), t
        assert np.array_equal(comp.drive(meant), drive)  # asked again: the same drive ...
        assert np.allclose(comp.plays, plays[:, 0, :], atol=1e-12), t  # ... the same memory
