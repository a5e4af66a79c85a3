"""Pairing a controller's commands with the readings they produced.

The simulator publishes a step's set-points on ``ops/delays`` before that step's readings. A
controller sends a command, then uses a reading only while the latest set-points it has seen equal
that command: such a reading cannot predate the command. This class holds that bookkeeping for
every controller node (no rclpy, so it is tested on its own).

Re-sending: a command whose set-points have not come back is sent again after a time measured
from the link itself, as TCP does: the smoothed round trip (command sent -> its set-points seen)
plus four times its mean deviation, at least ``min_resend_s`` and at most ``timeout_s``. On a
100 Hz simulator that is a few sample periods, so a lost command or reading costs tens of
milliseconds instead of ``timeout_s``; a re-sent command's answer is no round-trip sample (it
could answer either copy). Until the first sample, ``timeout_s`` applies.
"""

from __future__ import annotations

from collections import Counter, deque

import numpy as np

#: float32 on the wire: set-points of up to ~100 fs come back to ~1e-5 fs.
MATCH_TOLERANCE_FS = 1e-3
#: A gap longer than this (a stalled loop, a simulator that ran on for seconds) counts as this
#: many steps: a drift prediction over it means nothing anyway.
MAX_STEPS_BETWEEN_READINGS = 100


def steps_between(last_seq, seq) -> int:
    """Simulator steps between two readings from the DDS publication sequence numbers of their
    ``ops/power`` messages (the simulator publishes one per step): 1 when either is unknown
    (``None``: the first reading, a middleware without numbers) or the numbers went back (a
    restarted simulator); at most :data:`MAX_STEPS_BETWEEN_READINGS`."""
    if not isinstance(seq, int) or not isinstance(last_seq, int) or seq <= last_seq:
        return 1
    return min(seq - last_seq, MAX_STEPS_BETWEEN_READINGS)


def sequence_number(info) -> int | None:
    """The DDS publication sequence number of a message's ``MessageInfo`` (None without one)."""
    seq = info.get("publication_sequence_number") if isinstance(info, dict) else None
    return seq if isinstance(seq, int) else None


class StepPairing:
    """Which messages belong to one simulator step, from their DDS sequence numbers.

    Each step publishes one message on ``ops/delays``, ``ops/intensity`` and ``ops/power``, so
    within one simulator run the sequence numbers of a step's messages on two topics differ by a
    fixed offset (0 for this project's simulator), learned as the most common difference over the
    last ``window`` power messages. Two things break a pairing by arrival:

    - a lost message: at 20 % loss a fifth of the power readings came without their own trace,
      and the latest trace was an older step's;
    - the executor: callbacks ready together run in subscription order (delays, trace, power),
      so after a busy spell a step's power is handled after the next step's trace and delays.

    So the traces (and the simulator's applied delays, for a policy that observes them) are kept
    by number (:meth:`take`, the last few) and a reading takes those of its own step
    (:meth:`kept_for`); ``None`` when one was lost. Without sequence numbers (a middleware that
    gives none) the latest message is taken, as before.
    """

    TOPICS = ("delays", "trace", "actual")
    KEPT = ("trace", "actual")  # the topics whose messages a reading takes by number

    def __init__(self, window: int = 50, keep: int = 16):
        self._kept: dict[str, dict[int, object]] = {t: {} for t in self.KEPT}
        self._keep = int(keep)
        self._newest: dict[str, object] = dict.fromkeys(self.KEPT)
        self.latest: dict[str, int | None] = dict.fromkeys(self.TOPICS)
        self._differences = {t: deque(maxlen=int(window)) for t in self.TOPICS}
        # the differences counted, and each topic's offset once known (None: to be found), so
        # that a reading finds an offset without sorting the window (this runs every step)
        self._counts: dict[str, Counter] = {t: Counter() for t in self.TOPICS}
        self._offsets: dict[str, int | None] = dict.fromkeys(self.TOPICS)
        self._last_power: int | None = None

    def is_copy(self, topic: str, seq: int | None) -> bool:
        """Whether the message numbered ``seq`` on ``topic`` is the copy of one already taken
        (the latched and the best-effort subscription of ``ops/delays`` both deliver it)."""
        return seq is not None and seq == self.latest[topic]

    def take(self, topic: str, seq: int | None, value=None) -> bool:
        """A message of ``topic`` (one of :data:`TOPICS`; the trace or the applied delays as
        ``value``); False for a copy of a message already taken (the latched and the
        best-effort subscription of ``ops/delays`` both deliver it): ignore it."""
        if self.is_copy(topic, seq):
            return False
        latest = self.latest[topic]
        if seq is not None and (latest is None or seq > latest or latest - seq > 1000):
            self.latest[topic] = seq  # (a jump back by more: a restarted publisher)
        if topic in self.KEPT:
            self._newest[topic] = value
            kept = self._kept[topic]
            if seq is not None:
                kept[seq] = value
                for old in [k for k in kept if k <= seq - self._keep]:
                    del kept[old]
        return True

    def offset(self, topic: str) -> int:
        """Sequence number of a step's power minus that of its message on ``topic``: the most
        common difference of the window (the smallest of the most common ones)."""
        found = self._offsets[topic]
        if found is None:
            counts = self._counts[topic]
            if not counts:
                return 0
            most = max(counts.values())
            found = self._offsets[topic] = min(d for d, n in counts.items() if n == most)
        return found

    def _count(self, topic: str, difference: int) -> None:
        seen, counts = self._differences[topic], self._counts[topic]
        if len(seen) == seen.maxlen:
            oldest = seen[0]
            counts[oldest] -= 1
            if not counts[oldest]:
                del counts[oldest]
        seen.append(difference)
        counts[difference] += 1
        self._offsets[topic] = None

    def on_power(self, power_seq: int | None) -> None:
        """Learn the offsets from a power message (call it for every one, used or not)."""
        if power_seq is None:
            return
        if self._last_power is not None and power_seq < self._last_power - 1000:
            for topic, seen in self._differences.items():  # a restarted simulator: learn again
                seen.clear()
                self._counts[topic].clear()
                self._offsets[topic] = None
            for kept in self._kept.values():
                kept.clear()
        self._last_power = power_seq
        for topic in self.TOPICS:
            if self.latest[topic] is not None:
                self._count(topic, power_seq - self.latest[topic])

    def step_of(self, power_seq: int, topic: str) -> int:
        """The sequence number on ``topic`` of the step of this power message."""
        return power_seq - self.offset(topic)

    def kept_for(self, topic: str, power_seq: int | None):
        """The message on ``topic`` (one of :data:`KEPT`) of this power message's step; None
        when it did not come."""
        if power_seq is None:
            return self._newest[topic]
        return self._kept[topic].get(self.step_of(power_seq, topic))


class CommandTracker:
    def __init__(
        self,
        timeout_s: float,
        tolerance_fs: float = MATCH_TOLERANCE_FS,
        min_resend_s: float = 0.02,
    ):
        self.timeout_s = float(timeout_s)
        self.tolerance_fs = float(tolerance_fs)
        self.min_resend_s = float(min_resend_s)
        self.pending: np.ndarray | None = None  # the command awaiting its reading
        self.sent_at = float("-inf")
        self.matched = False  # the latest set-points equal the pending command
        self.rtt_s: float | None = None  # smoothed round trip
        self.rtt_dev_s = 0.0  # its smoothed mean deviation
        self.resends = 0
        self._resent = False  # the pending command was sent more than once

    def sent(self, command, now: float) -> np.ndarray:
        """Record a command just published; returns it as a float array."""
        command = np.asarray(command, dtype=np.float64).copy()
        again = self.pending is not None and self._same(command, self.pending)
        self._resent = again
        self.resends += again
        self.pending = command
        # A re-sent command whose set-points already came back stays matched: the simulator
        # holds them, and every later step's reading is the command's (un-matching on each
        # re-send would cost the loop another set-points message per loss).
        self.matched = self.matched and again
        self.sent_at = now
        return self.pending

    @property
    def resent(self) -> bool:
        """The pending command was sent more than once (the last send was a re-send)."""
        return self._resent

    def is_pending(self, setpoints) -> bool:
        """These set-points are the pending command's."""
        return self.pending is not None and self._same(
            np.asarray(setpoints, dtype=np.float64), self.pending
        )

    def _same(self, a: np.ndarray, b: np.ndarray) -> bool:
        # (as np.allclose with rtol 0, a NaN never the same, at a tenth of its cost)
        return a.shape == b.shape and bool(np.max(np.abs(a - b), initial=0.0) <= self.tolerance_fs)

    def resend_after(self) -> float:
        """How long a command waits for its set-points before it is sent again."""
        if self.rtt_s is None:
            return self.timeout_s
        rto = self.rtt_s + 4.0 * self.rtt_dev_s
        return min(self.timeout_s, max(self.min_resend_s, rto))

    def _sample(self, rtt: float) -> None:
        if self.rtt_s is None:
            self.rtt_s, self.rtt_dev_s = rtt, rtt / 2.0
        else:
            self.rtt_dev_s += 0.25 * (abs(rtt - self.rtt_s) - self.rtt_dev_s)
            self.rtt_s += 0.125 * (rtt - self.rtt_s)

    def on_setpoints(
        self, setpoints, accept_without_command: bool = False, now: float | None = None
    ) -> bool:
        """The set-points of a new step; True when readings that follow belong to our command.

        ``accept_without_command``: with no command pending, readings count too (a runner that
        starts on a free-running simulator takes its first observation as it comes). ``now``
        (monotonic s): the first match of a command sent once is a round-trip sample.
        """
        if self.pending is None:
            self.matched = accept_without_command
        else:
            was = self.matched
            self.matched = self._same(np.asarray(setpoints, dtype=np.float64), self.pending)
            if self.matched and not was and now is not None and not self._resent:
                self._sample(now - self.sent_at)
        return self.matched

    def answered(self) -> None:
        """The pending command got its reading; later readings need a new command."""
        self.pending = None
        self.matched = False

    def overdue(self, now: float) -> bool:
        """A command has waited longer than :meth:`resend_after` for its reading."""
        return self.pending is not None and now - self.sent_at > self.resend_after()
