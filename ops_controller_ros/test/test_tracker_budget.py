"""The knot test's work budget (``work_budget``): a test whose work would exceed a reading's share
runs on over the next readings, a bounded share in each; the default holds every test at N <= 5
whole."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams, knots
from ops_sim_ros.simulation import BatchedSimulation

P = TrackerParams()


def _locked_then_knot(seed: int, budget: float, readings: int):
    """A tracker locked in hard mode for 100 readings; then stage 2's slope turns by 0.015
    cycles per step and ``readings`` more are taken. Each test spread over readings is logged:
    (its units of work, the readings it ran on)."""
    config = make_config(stage=5, mode="hard", split="test")
    sim = BatchedSimulation(config, num_envs=1, seed=seed)
    r = sim.reset(seed=seed)
    tracker = PhaseTracker(config, TrackerParams(work_budget=budget), r.setpoints_fs[0], seed)
    spans: list[list] = []  # [run, readings it ran on]

    def step():
        command = next_command(tracker)  # (think() runs the test's share of this reading)
        run = tracker.knot.run
        if run is not None:
            if not spans or spans[-1][0] is not run:
                spans.append([run, 0])
            spans[-1][1] += 1
        res = sim.step_setpoints(command[None, :])
        tracker.observe(res.power[0], res.pulse_energies[0])
        return res.power[0]

    before = [step() for _ in range(100)]
    assert min(before[-20:]) > 0.95
    old = sim.noise.slope[0].copy() / sim.optical_period_fs
    sim.noise.slope[0, 2] += 0.015 * sim.optical_period_fs
    sim.noise._update_bound_safe()
    after = [step() for _ in range(readings)]
    new = sim.noise.slope[0] / sim.optical_period_fs
    return tracker, after, old, new, spans


@pytest.mark.parametrize("seed", [5, 6])
def test_a_knot_test_over_budget_resumes_over_readings_each_reading_a_share(seed):
    """With the default budget the test runs whole in the reading after the knot, and takes
    it. With a budget of one row the test is spread: every reading runs one unit of it, so a
    test of U units has ended within U readings of its start; its outcome comes late (here the
    tracking fits have followed the new slope by then, and it is no knot any more), and the
    tracker has followed the knot on stage 2 all the same, the others keeping their drift, and
    holds the lock."""
    whole, _, old, new, spans = _locked_then_knot(seed, P.work_budget, 30)
    assert whole.knots >= 1 and whole.knot_tests_spread == 0 and not spans
    assert abs(whole.drift[2] - new[2]) < 0.003, (whole.drift, new)
    tracker, after, old, new, spans = _locked_then_knot(seed, 1.0, 30)
    assert tracker.knot_tests_spread >= 1 and spans
    for run, read_on in spans:
        assert 0 < read_on <= run.fits.units, (read_on, run.fits.units)
    assert abs(tracker.drift[2] - new[2]) < 0.003, (tracker.drift, new)
    others = [0, 1, 3, 4]
    assert np.abs(tracker.drift[others] - old[others]).max() < 0.003, (tracker.drift, old)
    assert min(after[-10:]) > 0.95, after


def test_the_default_budget_holds_every_test_at_n5_whole_and_spreads_n7():
    """The largest knot test at N = 5 (a noisy detector's window and settings) is within the
    default budget; a clean detector's at N = 7 is several times over it."""
    scale = {n: (2**n / 32.0) ** 2 for n in (3, 5, 7)}
    noisy = knots.test_rows(5, P.noisy_window, P.noisy_knot_readings, P.noisy_knot_iterations)
    assert noisy * scale[5] <= P.work_budget
    assert knots.test_rows(3, P.noisy_window, 5, 12) * scale[3] <= P.work_budget
    clean7 = knots.test_rows(7, P.window, P.knot_readings, P.knot_iterations)
    assert clean7 * scale[7] > 4 * P.work_budget
    assert not knots.over_budget(P, 5, P.noisy_window, True, scale[5])
    assert knots.over_budget(P, 7, P.window, False, scale[7])
