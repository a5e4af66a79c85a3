"""Pairing of commands with readings: a reading counts only while the set-points reported for its
step equal the pending command."""

import numpy as np
from ops_controller_ros.command_tracker import (
    MAX_STEPS_BETWEEN_READINGS,
    CommandTracker,
    StepPairing,
    sequence_number,
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


def test_a_resent_command_stays_matched_once_its_setpoints_came_back():
    """Un-matching on a re-send would cost the loop another set-points message per loss."""
    t = CommandTracker(timeout_s=1.0)
    t.sent([1.0], now=0.0)
    assert t.on_setpoints([1.0], now=0.01)
    t.sent([1.0], now=0.05)  # re-sent (its reading was lost): the simulator holds it already
    assert t.resent and t.matched and t.is_pending([1.0])
    t.sent([2.0], now=0.06)  # a new command is matched only by its own set-points
    assert not t.resent and not t.matched and not t.is_pending([1.0])


def _step(pairing, seq, lost=()):
    """The simulator's step ``seq``: delays, trace, power, each unless ``lost``."""
    if "delays" not in lost:
        pairing.take("delays", seq)
    if "trace" not in lost:
        pairing.take("trace", seq, f"trace {seq}")
    if "power" not in lost:
        pairing.on_power(seq)


def test_a_reading_takes_its_own_steps_trace_or_none():
    p = StepPairing()
    for seq in range(1, 30):
        _step(p, seq)
    assert p.offset("trace") == 0 and p.kept_for("trace", 29) == "trace 29"
    _step(p, 30, lost=("trace",))  # the trace of step 30 was lost: not step 29's instead
    assert p.kept_for("trace", 30) is None
    _step(p, 31, lost=("delays",))
    assert p.kept_for("trace", 31) == "trace 31"


def test_the_executors_order_does_not_pair_a_power_with_the_next_steps_trace():
    """Callbacks ready together run in subscription order: step 41's trace and delays before
    step 40's power."""
    p = StepPairing()
    for seq in range(1, 40):
        _step(p, seq)
    p.take("delays", 40)
    p.take("trace", 40, "trace 40")
    p.take("delays", 41)
    p.take("trace", 41, "trace 41")
    p.on_power(40)
    assert p.kept_for("trace", 40) == "trace 40"
    assert p.step_of(40, "delays") == 40  # (the loop: a reading of step 40, not of step 41)


def test_offsets_are_learned_and_copies_refused():
    p = StepPairing()
    for seq in range(1, 60):  # a publisher whose power numbers run 3 ahead of its traces
        p.take("trace", seq, seq)
        p.on_power(seq + 3)
    assert p.offset("trace") == 3 and p.kept_for("trace", 50) == 47
    assert not p.is_copy("delays", 7)
    assert p.take("delays", 7) and not p.take("delays", 7)  # latched + best-effort copies
    assert p.is_copy("delays", 7) and not p.is_copy("delays", 8) and not p.is_copy("delays", None)
    assert sequence_number({"publication_sequence_number": 12}) == 12
    assert sequence_number(None) is None and sequence_number({}) is None


def test_without_sequence_numbers_the_latest_trace_is_taken():
    p = StepPairing()
    p.take("trace", None, "a")
    p.take("trace", None, "b")
    p.on_power(None)
    assert p.kept_for("trace", None) == "b"
