"""The steps a gap in a rig's readings spans, from its messages' source timestamps
(``reading_gaps``): an outage the rig published nothing in counts as the ticks it lasted."""

from __future__ import annotations

import pytest
from ops_controller_ros.reading_gaps import MIN_PERIOD_SAMPLES, TickClock, source_stamp


def _clock(period: float = 0.02, messages: int = 30, jitter: float = 0.002) -> TickClock:
    clock = TickClock()
    for i in range(messages):
        clock.on_message(i, 100.0 + i * period + (jitter if i % 2 else -jitter))
    return clock


def test_the_tick_period_is_the_median_spacing_of_consecutive_messages():
    assert _clock().period_s == pytest.approx(0.02, abs=0.005)
    assert _clock(messages=MIN_PERIOD_SAMPLES - 1).period_s is None  # too few yet
    clock = TickClock()
    for i in range(0, 60, 2):  # every other message lost: no spacing of consecutive ones
        clock.on_message(i, 100.0 + i * 0.02)
    assert clock.period_s is None


def test_an_outage_counts_as_the_ticks_it_lasted():
    clock = _clock(jitter=0.0)
    # 5 s without a message, its sequence numbers going on by one
    assert clock.steps(100.58, 105.58, 1) == 250
    assert clock.steps(100.58, 105.58, 3) == 250
    # an outage's spacing does not enter the period
    clock.on_message(30, 105.6)
    assert clock.period_s == pytest.approx(0.02)


def test_jitter_and_a_late_tick_keep_the_sequence_numbers_count():
    clock = _clock(jitter=0.0)
    assert clock.steps(100.0, 100.03, 1) == 1  # a tick 1.5 periods late
    assert clock.steps(100.0, 100.05, 1) == 1  # 2.5 periods: under MIN_MISSED_TICKS more
    assert clock.steps(100.0, 100.20, 9) == 9  # the numbers already say it
    assert clock.steps(None, 100.0, 2) == 2  # no earlier reading
    assert TickClock().steps(100.0, 105.0, 1) == 1  # no period yet


def test_source_stamp_reads_a_message_info():
    assert source_stamp({"source_timestamp": 1_500_000_000}) == pytest.approx(1.5)
    assert source_stamp({"source_timestamp": 0}) is None
    assert source_stamp(None) is None
