"""Pairing of commands with readings: a reading counts only while the set-points reported for its
step equal the pending command."""

import numpy as np
from ops_controller_ros.command_tracker import (
    MAX_STEPS_BETWEEN_READINGS,
    CommandTracker,
    steps_between,
)


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


def test_resend_after_follows_the_measured_round_trip():
    t = CommandTracker(timeout_s=1.0, min_resend_s=0.02)
    assert t.resend_after() == 1.0  # nothing measured yet
    for k in range(50):  # round trips of 10 ms
        t.sent([float(k)], now=k)
        assert t.on_setpoints([float(k)], now=k + 0.010)
        t.answered()
    assert 0.02 <= t.resend_after() < 0.05  # a few round trips, not the 1 s timeout
    t.sent([99.0], now=100.0)
    assert not t.overdue(now=100.0 + 0.9 * t.resend_after())
    assert t.overdue(now=100.0 + 1.1 * t.resend_after())
    # A slow link raises it (bounded by timeout_s) ...
    for k in range(50):
        t.sent([float(k)], now=200 + k)
        assert t.on_setpoints([float(k)], now=200 + k + 0.3)
        t.answered()
    assert 0.3 < t.resend_after() <= 1.0


def test_a_resent_command_gives_no_round_trip_sample():
    t = CommandTracker(timeout_s=1.0)
    t.sent([1.0], now=0.0)
    t.sent([1.0], now=1.0)  # the same command again: a re-send
    assert t.resends == 1
    t.on_setpoints([1.0], now=1.001)
    assert t.rtt_s is None  # ambiguous: it may answer the first copy


def test_steps_between_readings_from_the_publication_sequence_numbers():
    assert steps_between(41, 42) == 1  # the next step's reading
    assert steps_between(41, 44) == 3  # two steps ran before the command came
    assert steps_between(None, 7) == 1  # the first reading
    assert steps_between(41, None) == 1  # a middleware without numbers
    assert steps_between(900, 3) == 1  # a restarted simulator numbers from 1 again
    assert steps_between(0, 10**6) == MAX_STEPS_BETWEEN_READINGS  # a stall: capped
