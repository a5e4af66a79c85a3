"""The steps a gap in a rig's readings spans, from the times the rig published them.

A rig publishes a reading per tick of its own timer, but not while its scope is gone (an outage,
a timed-out read): its DDS sequence numbers then go on by one across seconds in which the
stacker drifted. A controller told "one step" predicts the drift of one step and finds the
stack far from it (7-18 readings to re-lock after a 5 s outage in process, and over the rig
often more than 2 s). The rig's own clock tells the truth: the source
timestamps of its messages. The period of its ticks is the median spacing of messages whose
sequence numbers follow each other; a gap of at least ``MIN_MISSED_TICKS`` more ticks than the
sequence numbers say counts as the ticks it spans (at most ``MAX_GAP_TICKS``).

Only for a rig (``rig_config``): a simulator's step is its own clock, not the wall's (a starved
simulator node steps less often, and its stacker drifts per step), and its sequence numbers
count its steps already.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .command_tracker import MAX_STEPS_BETWEEN_READINGS

#: Consecutive messages whose spacing gives the tick period (their median).
PERIOD_SAMPLES = 50
#: ... and the fewest before the period is trusted.
MIN_PERIOD_SAMPLES = 10
#: A gap of the rig's clock counts as at most this many ticks, as a gap in the sequence numbers
#: does (over the rig, a 5 s outage of 270 ticks told as all of them was back >= 0.95 later than
#: told as 100: 6 of 12 tests within the 2 s goal, against 15 of 18; docs/rig.md).
MAX_GAP_TICKS = MAX_STEPS_BETWEEN_READINGS
#: A gap counts only if it spans at least this many ticks more than the sequence numbers say
#: (a late timer tick or a little jitter is no outage).
MIN_MISSED_TICKS = 3


def source_stamp(info) -> float | None:
    """The publisher's time of a message (s) from its ``MessageInfo`` (None without one)."""
    stamp = info.get("source_timestamp") if isinstance(info, dict) else None
    return stamp * 1e-9 if isinstance(stamp, int) and stamp > 0 else None


class TickClock:
    """The tick period of a free-running rig, and the ticks between two of its readings."""

    def __init__(self):
        self._spacings: deque = deque(maxlen=PERIOD_SAMPLES)
        self._last = None  # (sequence number, source time) of the last message

    def on_message(self, seq, stamp) -> None:
        """Every message of the rig's reading topic, used or not."""
        if not isinstance(seq, int) or stamp is None:
            return
        if self._last is not None and seq == self._last[0] + 1 and stamp > self._last[1]:
            spacing, period = stamp - self._last[1], self.period_s
            if period is None or spacing < MIN_MISSED_TICKS * period:  # not an outage's
                self._spacings.append(spacing)
        self._last = (seq, stamp)

    @property
    def period_s(self) -> float | None:
        """The median spacing of consecutive messages (None before enough were seen)."""
        if len(self._spacings) < MIN_PERIOD_SAMPLES:
            return None
        return float(np.median(self._spacings))

    def steps(self, since, stamp, seq_steps: int) -> int:
        """The ticks between the readings published at ``since`` and ``stamp`` (source times):
        ``seq_steps`` (from the sequence numbers) unless the time between them spans at least
        ``MIN_MISSED_TICKS`` more."""
        period = self.period_s
        if period is None or since is None or stamp is None or stamp <= since:
            return seq_steps
        ticks = round((stamp - since) / period)
        return ticks if ticks >= seq_steps + MIN_MISSED_TICKS else seq_steps
