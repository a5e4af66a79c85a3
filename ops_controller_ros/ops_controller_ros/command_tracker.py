"""Pairing a controller's commands with the readings they produced.

The simulator publishes a step's set-points on ``ops/delays`` before that step's readings. A
controller sends a command, then uses a reading only while the latest set-points it has seen equal
that command: such a reading cannot predate the command. This class holds that bookkeeping for
every controller node (no rclpy, so it is tested on its own).
"""

from __future__ import annotations

import numpy as np

#: float32 on the wire: set-points of up to ~100 fs come back to ~1e-5 fs.
MATCH_TOLERANCE_FS = 1e-3


class CommandTracker:
    def __init__(self, timeout_s: float, tolerance_fs: float = MATCH_TOLERANCE_FS):
        self.timeout_s = float(timeout_s)
        self.tolerance_fs = float(tolerance_fs)
        self.pending: np.ndarray | None = None  # the command awaiting its reading
        self.sent_at = float("-inf")
        self.matched = False  # the latest set-points equal the pending command

    def sent(self, command, now: float) -> np.ndarray:
        """Record a command just published; returns it as a float array."""
        self.pending = np.asarray(command, dtype=np.float64).copy()
        self.matched = False
        self.sent_at = now
        return self.pending

    def on_setpoints(self, setpoints, accept_without_command: bool = False) -> bool:
        """The set-points of a new step; True when readings that follow belong to our command.

        ``accept_without_command``: with no command pending, readings count too (a runner that
        starts on a free-running simulator takes its first observation as it comes).
        """
        if self.pending is None:
            self.matched = accept_without_command
        else:
            sp = np.asarray(setpoints, dtype=np.float64)
            self.matched = sp.shape == self.pending.shape and bool(
                np.allclose(sp, self.pending, rtol=0.0, atol=self.tolerance_fs)
            )
        return self.matched

    def answered(self) -> None:
        """The pending command got its reading; later readings need a new command."""
        self.pending = None
        self.matched = False

    def overdue(self, now: float) -> bool:
        """A command has waited longer than the timeout for its reading."""
        return self.pending is not None and now - self.sent_at > self.timeout_s
