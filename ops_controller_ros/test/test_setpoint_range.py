"""Set-points kept inside a rig's range by whole optical periods (``setpoint_range``): the rule
(pure function) and the loop node's keeper with SPGD-PID and a learned policy, driven in process
against the simulator whose drift carries the set-points out of a narrow range."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.setpoint_range import (
    MARGIN_CYCLES,
    RangeKeeper,
    inward_periods,
    movable,
    move_inwards,
)
from ops_controller_ros.spgd import SpgdPid
from range_loop import PERIOD_FS, centred_range, drive, inside

P = PERIOD_FS
M = MARGIN_CYCLES


def _draws(n=400, seed=0):
    """Random ranges (some wide, some too narrow for the moves) and set-points in and beyond
    them, for five stages."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        low = rng.uniform(-40.0, 10.0, 5)
        high = low + rng.uniform(0.0, 12.0, 5) * P
        x = rng.uniform(low - 3 * P, high + 3 * P)
        yield x, low, high


def test_a_set_point_near_a_limit_moves_whole_periods_into_the_kept_band():
    for x, low, high in _draws():
        moved, periods = move_inwards(x, low, high, P)
        assert periods.dtype.kind == "i"
        np.testing.assert_allclose(moved, x + periods * P)  # whole periods only
        wide = movable(low, high, P)
        due = wide & ((x - low < M * P) | (high - x < M * P))
        # where the range allows it, the moved set-point keeps the margin from both limits
        assert np.all(moved[due] >= low[due] + M * P - 1e-9)
        assert np.all(moved[due] <= high[due] - M * P + 1e-9)
        assert np.all(periods[due] != 0)
        # inside the band, or a range too narrow for the moves: nothing moves
        assert np.all(periods[~due] == 0)


def test_inside_the_band_nothing_moves():
    low, high = np.full(3, -10 * P), np.full(3, 10 * P)
    for x in np.linspace(-8 * P + 1e-6, 8 * P - 1e-6, 101):
        assert not inward_periods(np.full(3, x), low, high, P).any()


def test_a_move_goes_towards_the_middle_and_at_most_the_cap():
    low, high = np.array([0.0, 0.0]), np.array([20 * P, 20 * P])
    x = np.array([0.5 * P, 19.9 * P])  # near the low and the high limit
    assert inward_periods(x, low, high, P).tolist() == [10, -10]  # to the middle
    assert inward_periods(x, low, high, P, most_periods=1).tolist() == [1, -1]
    assert inward_periods(x, low, high, P, most_periods=0).tolist() == [1, -1]  # at least one


def test_a_range_too_narrow_for_the_moves_is_only_clipped():
    low, high = np.array([-2.0 * P]), np.array([2.0 * P])  # 4 periods < 2 margin + 1
    assert not movable(low, high, P)[0]
    keeper = RangeKeeper(low, high, P)
    assert keeper.narrow_stages() == [0]
    ctl = SpgdPid(1, setpoints_fs=[3.0 * P])
    assert keeper.keep(ctl, ctl.command()).tolist() == [2.0 * P]
    assert keeper.clipped == 1 and keeper.moves == 0


def test_the_keeper_moves_the_controller_with_the_command():
    low, high = centred_range(2, 2.6)
    ctl = SpgdPid(2, setpoints_fs=[2.5, -0.1], seed=1)
    keeper = RangeKeeper(low, high, P)
    command = keeper.keep(ctl, ctl.command())
    assert keeper.moves == 1 and keeper.last_move.tolist() == [-1, 0]
    np.testing.assert_allclose(ctl.setpoints_fs, [2.5 - P, -0.1])
    # the controller's next commands are around its moved set-points: nothing more moves
    np.testing.assert_allclose(command, ctl.command())
    assert keeper.keep(ctl, ctl.command()) is not None and keeper.moves == 1


# ---------------------------------------------------------------- in process, with drift
# A drift of 0.0005 cycles per step (the slowest of hard mode's test split), one slope shared by
# the stages: 3 cycles in 6000 steps. The range is +- 2.6 periods (+- 8.9 fs): a set-point is
# kept within 0.6 periods of 0, and without the moves the drift carries it beyond the range.
DRIFT = dict(drift_slope_min_cycles=0.0005, drift_slope_max_cycles=0.0005)


@pytest.mark.parametrize("latency", [0, 2])
def test_spgd_on_a_drifting_rig_stays_in_range_and_holds(latency):
    low, high = centred_range(5, 2.6)
    config = make_config(5, "easy", "test", latency_steps=latency, **DRIFT)
    for seed in (81, 83):  # one drifts up, one down
        free, _ = drive(SpgdPid(5, seed=seed, latency=latency), config, seed, 6000)
        assert not inside(free, low, high), seed  # the drift carries it out

        spgd = SpgdPid(5, seed=seed, latency=latency)
        keeper = RangeKeeper(low, high, config.optical_period_fs, reach_fs=6.4)
        commands, powers = drive(spgd, config, seed, 6000, keeper)
        assert inside(commands, low, high), seed
        assert keeper.moves > 0 and keeper.clipped == 0, seed
        assert np.mean(powers[300:] >= 0.95) >= 0.97, seed


MODEL = Path(__file__).resolve().parents[2] / "models" / "n5_hard_long"


def test_a_learned_policy_on_a_drifting_rig_stays_in_range_and_holds():
    """The policy runner's set-points are its own state (increments on them): the node moves
    them, and the policy observes them less the moves. Hard mode (the model's), 3000 steps: the
    drift alone carries the stack 1.5 periods, and the range keeps the set-points within 0.6
    periods of 0. A neural policy in a closed loop is chaotic (the last bits differ between
    CPUs), so the bound is loose: it holds the stack, not a figure to the digit."""
    from ops_controller_ros.policy_node import PolicyController
    from ops_controller_ros.runner_factory import load_model

    model = load_model(MODEL)
    low, high = centred_range(5, 2.6)
    config = make_config(5, "hard", "test", **DRIFT)
    for seed in (81, 82):
        ctl = PolicyController(model.build(), model.meta.max_step_fs, np.zeros(5))
        keeper = RangeKeeper(low, high, config.optical_period_fs, reach_fs=6.4)
        commands, powers = drive(ctl, config, seed, 3000, keeper, first=True)
        assert inside(commands, low, high), seed
        assert keeper.moves > 0 and keeper.clipped == 0, seed
        periods = ctl.moved_fs / config.optical_period_fs
        np.testing.assert_allclose(periods, np.round(periods), atol=1e-9)
        assert np.median(powers[300:]) >= 0.95 and powers[300:].mean() >= 0.85, seed
