"""The global search and the latency check within a reading's work (``search_work_budget``,
``spread_rows``): whole at N <= 5, spread over readings at N = 7, where a spread search refines
what it found on the readings that came meanwhile and locks all the same."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams, work
from ops_controller_ros.tracker import latency_check as lc
from ops_sim_ros.simulation import BatchedSimulation

P = TrackerParams()


def _units(*rows):
    """A job of units with these rows; it returns their count."""
    yield from rows
    return len(rows)


def test_advance_runs_whole_without_a_cap_and_stops_before_a_unit_would_overrun():
    assert work.advance(_units(5, 5, 5)) == (True, 3)
    job = _units(4, 4, 4, 4, 4)
    # 10 rows a reading: two units of 4 (a third would overrun what is left)
    assert work.advance(job, rows=10) == (False, None)
    assert work.advance(job, rows=10) == (False, None)
    assert work.advance(job, rows=10) == (True, 5)
    job = _units(50, 1)
    assert work.advance(job, rows=10) == (False, None)  # at least one unit a reading
    assert work.advance(_units(1, 1, 1), units=2) == (False, None)


def test_rows_are_weighed_by_the_stage():
    assert list(work.scaled(_units(2, None, 3), 16.0)) == [32.0, 0.0, 48.0]


@pytest.mark.parametrize("stage", [3, 5])
def test_at_n5_and_below_the_search_and_the_latency_check_run_whole(stage):
    """The defaults keep every search and latency candidate of N <= 5 in one reading, as the
    tracker's figures were measured."""
    n_rows = work.search_rows(P, stage, max(P.window, P.noisy_window))
    scale = (2**stage / 32.0) ** 2
    assert work.spread_rows(P, n_rows * scale) is None
    assert work.spread_rows(P, lc.candidate_rows(stage) * scale) is None


def test_at_n7_both_are_spread():
    scale = (2**7 / 32.0) ** 2
    assert work.spread_rows(P, work.search_rows(P, 7, P.window) * scale) == P.spread_rows
    assert work.spread_rows(P, lc.candidate_rows(7) * scale) == P.spread_rows


class WorkLog:
    """work.advance as the searches call it, each reading's rows counted (``spent``)."""

    def __init__(self):
        self.spent = [0.0]

    def advance(self, job, rows=None, units=0, budget_ms=0.0):
        def counted():
            while True:
                try:
                    done = next(job)
                except StopIteration as end:
                    return end.value
                self.spent[-1] += done or 0.0
                yield done

        return work.advance(counted(), rows, units, budget_ms)


@pytest.fixture
def work_log(monkeypatch):
    from ops_controller_ros.tracker import acquisition

    log = WorkLog()
    monkeypatch.setattr(acquisition, "advance", log.advance)
    monkeypatch.setattr(lc, "advance", log.advance)
    return log


def _run(log, stage, seed, readings, rig_latency=0):
    """The tracker on a hard rig of ``stage``, told no latency; each reading's rows of search
    and latency-check work, and the readings."""
    config = make_config(stage=stage, mode="hard", split="test", latency_steps=rig_latency)
    told = make_config(stage=stage, mode="hard", split="test")
    sim = BatchedSimulation(config, num_envs=1, seed=seed)
    r = sim.reset(seed=seed)
    tracker = PhaseTracker(told, P, r.setpoints_fs[0], seed)
    power = []
    for _ in range(readings):
        command = next_command(tracker)
        res = sim.step_setpoints(command[None, :])
        tracker.observe(res.power[0], res.pulse_energies[0])
        power.append(float(res.power[0]))
        log.spent.append(0.0)
    return tracker, np.array(log.spent[:-1]), np.array(power)


@pytest.mark.parametrize("seed", [1, 2])
def test_at_n7_a_spread_search_locks_and_no_reading_does_more_than_its_share(seed, work_log):
    """Hard mode at N = 7: the search runs over many readings, no reading's search work past
    spread_rows by more than one unit, and the tracker locks and holds (seed 2's search
    needed the detector's line fitted on the readings it searched, not the newer ones)."""
    tracker, spent, power = _run(work_log, 7, seed, 160)
    unit = work.refine_rows(P.refine, 14, P.window, 1) * 16  # the largest unit: drift refine
    assert (spent > 0).sum() >= 10  # spread over readings
    assert spent.max() <= P.spread_rows + unit
    assert tracker.acquisitions >= 1
    assert np.mean(power[-60:] >= 0.95) >= 0.98, power[-60:].min()


def test_at_n7_the_latency_check_is_spread_and_still_finds_an_untold_latency(work_log):
    """A rig one step late, the tracker told none: the check runs over readings (the search
    waits for it) and takes the latency, and the tracker then locks."""
    tracker, spent, power = _run(work_log, 7, 1, 480, rig_latency=1)
    unit = work.refine_rows(lc.KEEP, 14, lc.CHECK_READINGS, 1) * 16
    assert tracker.watch.latency == 1 and tracker.watch.changes == 1
    assert spent.max() <= 2 * (P.spread_rows + unit)  # a reading: the search's and the check's
    assert np.mean(power[-60:] >= 0.95) >= 0.98, power[-60:].min()
