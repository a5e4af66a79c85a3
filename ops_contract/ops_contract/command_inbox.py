"""Delay commands of a free-running simulator, read once per step instead of once per message.

A free-running simulator applies the latest valid command at its next step; what arrives in
between only matters through that one. With a subscription callback, rclpy's executor runs
Python for every message (~tens of microseconds each), so a flood on ``ops/delay_cmd`` - one
careless script at 30,000 messages/s - takes the simulator's CPU and its step rate with it (with
a plain subscription the simulator fell to 80 steps/s and the lock to 26 %). Here the
subscription belongs to a callback group that the executor never waits on; at each step
:meth:`CommandInbox.take_latest` takes what queued in the DDS reader (serialized: a message is
read once, not once per copy, straight from its bytes:
:func:`~ops_contract.ros_interface.array_of`), checks each, and keeps the newest valid one.
Identical serialized messages share one verdict, so a flood of one rejected message costs a
dictionary lookup each. The reader keeps ``depth`` messages: a valid command is kept through a
flood of up to ``depth`` messages between two steps (4000).

The events executor (``-p executor:=events``, ops_contract.executors) ignores callback groups: it
takes each message as it comes (in C++) and passes it, serialized, to the subscription's
callback, which queues it (the last ``depth`` kept) for the next step; the step takes those first,
then any still in the reader.

A lockstep simulator steps on each command, so it keeps its callback (``sim_node``).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

import numpy as np
from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float32MultiArray

from .ros_interface import MessageError, array_of

#: Messages the reader keeps between two steps (KEEP_LAST: older ones are dropped by DDS).
INBOX_DEPTH = 4000
#: Verdicts remembered per distinct serialized message (a flood repeats one message).
_VERDICTS_KEPT = 256


class _NeverWaited(CallbackGroup):
    """A callback group the executor leaves out of its wait set: its entities are polled."""

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        pass


#: ``check(values)``: why a command's values (float32, its layout found right) cannot be used,
#: or None.
Check = Callable[[np.ndarray], "str | None"]


def command_verdict(raw: bytes, check: Check) -> tuple[str | None, np.ndarray | None]:
    """The problem of a serialized ``Float32MultiArray`` command (its layout's, its encoding's or
    ``check``'s) and, when there is none, its values (float32)."""
    try:
        _, values = array_of(raw)
    except MessageError as exc:
        return str(exc), None
    problem = check(values)
    return problem, None if problem else values


class CommandInbox:
    """``check(values)`` returns a problem (str) or None (see :data:`Check`); ``take_latest``
    returns the values of the newest valid command since the last call (or None) and counts the
    rejected ones by problem."""

    def __init__(self, node: Node, topic: str, check: Check, depth: int = INBOX_DEPTH):
        self._node = node
        self._check = check
        qos = QoSProfile(
            depth=depth, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE
        )
        # Messages the events executor took for us (the default one never calls back)
        self._delivered: deque[bytes] = deque(maxlen=depth)
        self.subscription = node.create_subscription(
            Float32MultiArray,
            topic,
            self._deliver,
            qos,
            callback_group=_NeverWaited(),
            raw=True,
        )
        self._verdicts: dict[bytes, str | None] = {}
        self.rejected: dict[str, int] = {}  # problem -> count since they were last reported
        self.taken = 0  # messages taken so far
        self._reported_at = float("-inf")

    def _verdict(self, raw: bytes) -> tuple[str | None, np.ndarray | None]:
        known = self._verdicts.get(raw)  # None: unknown, or valid (then it is read)
        if known is not None:
            return known, None
        problem, values = command_verdict(raw, self._check)
        if len(self._verdicts) >= _VERDICTS_KEPT:
            self._verdicts.clear()
        self._verdicts[raw] = problem
        return problem, values

    def _deliver(self, raw: bytes) -> None:
        self._delivered.append(raw)

    def _take_all(self) -> list[bytes]:
        raw = list(self._delivered)
        self._delivered.clear()
        handle = self.subscription.handle
        with handle:
            while True:
                got = handle.take_message(Float32MultiArray, True)
                if got is None:
                    return raw
                raw.append(got[0])

    def take_latest(self) -> np.ndarray | None:
        queued = self._take_all()
        self.taken += len(queued)
        latest = None
        for raw in queued:
            problem, values = self._verdict(raw)
            if problem is None:
                latest = values
            else:
                self.rejected[problem] = self.rejected.get(problem, 0) + 1
        return latest

    def rejections_to_report(self, period_s: float) -> tuple[int, str] | None:
        """The rejected messages to warn about, at most once per ``period_s``: their number and
        ``"<n> x <problem>; ..."``; None when there are none or the last report is too recent.
        A report clears the counts."""
        now = time.monotonic()
        if not self.rejected or now - self._reported_at < period_s:
            return None
        total = sum(self.rejected.values())
        problems = "; ".join(f"{n} x {problem}" for problem, n in self.rejected.items())
        self.rejected.clear()
        self._reported_at = now
        return total, problems

    def destroy(self) -> None:
        self._node.destroy_subscription(self.subscription)
