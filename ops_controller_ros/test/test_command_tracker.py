"""Pairing of commands with readings: a reading counts only while the set-points reported for its
step equal the pending command."""

import numpy as np
from ops_controller_ros.command_tracker import CommandTracker


def test_readings_count_only_after_the_commanded_setpoints_arrive():
    t = CommandTracker(timeout_s=1.0)
    t.sent([1.0, 2.0], now=0.0)
    assert not t.matched
    assert not t.on_setpoints([0.0, 0.0])  # an older step: its readings predate the command
    assert t.on_setpoints(np.float32([1.0, 2.0]))  # float32 round trip still matches
    t.answered()
    assert t.pending is None and not t.matched


def test_a_later_step_with_other_setpoints_unmatches():
    t = CommandTracker(timeout_s=1.0)
    t.sent([1.0], now=0.0)
    assert t.on_setpoints([1.0])
    assert not t.on_setpoints([1.5])
    assert not t.on_setpoints([1.0, 1.0])  # another stage count never matches


def test_without_a_command_readings_count_only_when_asked():
    t = CommandTracker(timeout_s=1.0)
    assert not t.on_setpoints([0.3])
    assert t.on_setpoints([0.3], accept_without_command=True)


def test_overdue_after_the_timeout_only_while_pending():
    t = CommandTracker(timeout_s=0.5)
    assert not t.overdue(now=100.0)
    t.sent([0.0], now=10.0)
    assert not t.overdue(now=10.4)
    assert t.overdue(now=10.6)
    t.answered()
    assert not t.overdue(now=20.0)
