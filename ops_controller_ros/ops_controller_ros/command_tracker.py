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
        self.matched = False
        self.sent_at = now
        return self.pending

    def _same(self, a: np.ndarray, b: np.ndarray) -> bool:
        return a.shape == b.shape and bool(np.allclose(a, b, rtol=0.0, atol=self.tolerance_fs))

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
