"""The tracker keeps its set-points inside the lines' range (a rig's channel limits): the drift
carries a lock towards a limit, and a rig refuses a command beyond it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from ops_contract.config import make_config
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from range_loop import drive, inside


def test_a_lock_drifting_to_a_limit_moves_whole_cycles_inwards_and_holds():
    """Hard mode's drift, whole-cycle hops off (as on a slow rig): without a range the
    set-points of these seeds wander 4-6 fs in 1500 steps. Inside [-12, 10] fs, where 2 cycles
    are kept from a limit, they must move back by whole cycles, never leave the range, and the
    stack must hold."""
    low, high = np.full(5, -12.0), np.full(5, 10.0)
    for seed in (81, 82):
        config = make_config(5, "hard", "test")
        params = replace(TrackerParams(), hop_every=0)
        tracker = PhaseTracker(
            config, params, seed=seed, setpoint_range_fs=(low, high), reach_fs=6.4
        )
        commands, powers = drive(tracker, config, seed, 1500)
        assert inside(commands, low, high)
        assert tracker.range_moves > 0, seed
        assert np.mean(powers[200:] >= 0.95) >= 0.97, seed
