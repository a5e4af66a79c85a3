"""What a controller node says about its loop: ``locked``, ``searching`` or ``starved``.

Judged from the readings themselves, never from the controller's belief (the tracker once logged
"(locked)" at P_N/P_max = 0.015 while its model was off): ``locked`` when each of the last
``window`` readings the loop used is at least ``lock_threshold``, and, once locked, until
``unlock_after`` readings in a row fall below it (hysteresis: one low reading on a noisy link is
no lost lock, and the log does not flip several times a second); ``starved`` when no
reading came for ``starved_after_s`` (the simulator is gone, the link is down, or the CPU cannot
keep up), and before the first one; ``searching`` otherwise. Every controller node publishes it,
latched, on ``ops/controller/status`` (std_msgs/String) when it changes, and logs the change.
"""

from __future__ import annotations

from collections import deque

from ops_contract.node_params import ParamSpec

LOCKED, SEARCHING, STARVED = "locked", "searching", "starved"
STATES = (LOCKED, SEARCHING, STARVED)
TOPIC_CONTROLLER_STATUS = "ops/controller/status"

PARAMS = [
    ParamSpec(
        "status_lock_threshold",
        0.9,
        "ops/controller/status says locked when the last 10 readings are all at least this",
        low=0.01,
        high=1.0,
        read_only=True,
    ),
    ParamSpec(
        "status_unlock_after",
        3,
        "ops/controller/status leaves locked after this many readings in a row below the threshold",
        low=1,
        high=1000,
        read_only=True,
    ),
    ParamSpec(
        "status_starved_after_s",
        1.0,
        "ops/controller/status says starved after this long without a reading",
        low=0.05,
        high=3600.0,
        read_only=True,
    ),
]


class LoopStatus:
    def __init__(
        self,
        lock_threshold: float = 0.9,
        starved_after_s: float = 1.0,
        window: int = 10,
        unlock_after: int = 3,
    ):
        self.lock_threshold = float(lock_threshold)
        self.starved_after_s = float(starved_after_s)
        self.unlock_after = int(unlock_after)
        self._low_run = 0  # readings in a row below the threshold
        self._recent: deque[float] = deque(maxlen=int(window))
        self._last_reading_at: float | None = None
        self.state = STARVED

    def observe(self, power: float, now: float) -> None:
        """A reading the loop used (P_N/P_max), at monotonic time ``now``."""
        self._recent.append(float(power))
        self._last_reading_at = now
        self._low_run = self._low_run + 1 if power < self.lock_threshold else 0

    def judge(self, now: float) -> str:
        if self._last_reading_at is None or now - self._last_reading_at > self.starved_after_s:
            return STARVED
        full = len(self._recent) == self._recent.maxlen
        if full and min(self._recent) >= self.lock_threshold:
            return LOCKED
        if self.state == LOCKED and self._low_run < self.unlock_after:
            return LOCKED  # a low reading or two: not yet a lost lock
        return SEARCHING

    def update(self, now: float) -> str | None:
        """The new state when it changed since the last call, else None."""
        state = self.judge(now)
        if state == self.state:
            return None
        self.state = state
        return state

    def explain(self) -> str:
        if self.state == LOCKED:
            return f"the last {self._recent.maxlen} readings are all >= {self.lock_threshold:g}"
        if self.state == SEARCHING and self._low_run >= self.unlock_after and self._recent:
            return (
                f"{self._low_run} readings in a row below {self.lock_threshold:g}, the last "
                f"P_N/P_max = {self._recent[-1]:.3f}"
            )
        if self.state == STARVED:
            if self._last_reading_at is None:
                return "no reading yet"
            return f"no reading for more than {self.starved_after_s:g} s"
        return f"P_N/P_max = {self._recent[-1]:.3f}" if self._recent else "readings arriving"


class StatusReporter:
    """A node's :class:`LoopStatus` on ``ops/controller/status`` (latched) and in its log."""

    def __init__(self, node, values: dict):
        from ops_contract.ros_interface import QOS_STATE
        from std_msgs.msg import String

        self._node = node
        self._string = String
        self.status = LoopStatus(
            values["status_lock_threshold"],
            values["status_starved_after_s"],
            unlock_after=values["status_unlock_after"],
        )
        self._pub = node.create_publisher(String, TOPIC_CONTROLLER_STATUS, QOS_STATE)
        self._pub.publish(String(data=self.status.state))

    def observe(self, power: float, now: float) -> None:
        self.status.observe(power, now)
        self.check(now)

    def check(self, now: float) -> None:
        """Publish and log a change of state (call it often: starvation is a lack of calls
        to :meth:`observe`)."""
        was = self.status.state
        if self.status.update(now) is None:
            return
        self._pub.publish(self._string(data=self.status.state))
        self._node.get_logger().info(
            f"loop status: {was} -> {self.status.state} ({self.status.explain()})"
        )
