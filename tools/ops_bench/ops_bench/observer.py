"""TopicObserver: an rclpy node in the calling process that records the simulator's outputs
(ops/delays, ops/intensity, ops/power, ops/reward) and sends delay commands."""

from __future__ import annotations

import contextlib
import time

import numpy as np

from ops_bench.processes import log_tails

#: Commands the observer's writer keeps until the simulator has them (a 3 s flood at 3,000/s).
COMMANDS_KEPT = 10000


class TopicObserver:
    """An rclpy node in the test process: records the simulator's outputs, sends commands.

    Spins in a background thread on its own context (so each test starts clean); ``close()``
    stops it. Messages are kept as (monotonic time, value) per topic.
    """

    def __init__(self, namespace: str = "/"):
        import threading

        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float32, Float32MultiArray

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("test_observer", namespace=namespace, context=self.context)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.lock = threading.Lock()
        self.messages: dict[str, list] = {"delays": [], "intensity": [], "power": [], "reward": []}
        self.order: list[str] = []
        for name, mtype in (
            ("delays", Float32MultiArray),
            ("intensity", Float32MultiArray),
            ("power", Float32),
            ("reward", Float32),
        ):
            self.node.create_subscription(mtype, f"ops/{name}", self._recorder(name), qos)
        # A reliable KEEP_LAST writer drops its oldest samples that no reader has acknowledged
        # once its history is full: a flood of commands (a test's thousands a second) to a
        # simulator that a loaded machine keeps from acknowledging is kept whole up to here.
        cmd_qos = QoSProfile(depth=COMMANDS_KEPT, reliability=ReliabilityPolicy.RELIABLE)
        self.cmd_pub = self.node.create_publisher(Float32MultiArray, "ops/delay_cmd", cmd_qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        from rclpy.executors import ExternalShutdownException

        # close() shuts the executor down from another thread.
        with contextlib.suppress(ExternalShutdownException):
            self.executor.spin()

    def _recorder(self, name):
        def record(msg):
            value = list(msg.data) if hasattr(msg.data, "__len__") else float(msg.data)
            with self.lock:
                self.messages[name].append((time.monotonic(), value, msg))
                self.order.append(name)

        return record

    def count(self, name: str) -> int:
        with self.lock:
            return len(self.messages[name])

    def values(self, name: str) -> list:
        with self.lock:
            return [v for _, v, _ in self.messages[name]]

    def last(self, name: str):
        with self.lock:
            return self.messages[name][-1][1] if self.messages[name] else None

    def wait_until(self, condition, timeout: float = 30.0, what: str = "condition", logs=()):
        """Poll ``condition`` until it holds; past ``timeout`` s fail naming ``what``, with the
        end of the output of ``logs`` (:class:`~ops_bench.processes.Process`)."""
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"timed out after {timeout} s waiting for {what}{log_tails(logs)}"
                )
            time.sleep(0.02)

    def wait_count(self, name: str, n: int, timeout: float = 30.0):
        self.wait_until(lambda: self.count(name) >= n, timeout, f"{n} messages on ops/{name}")

    def wait_closed(self, level: float = 0.9, timeout: float = 60.0, logs=()):
        """Until the loop has closed: more than 50 readings on ops/power, the last 20 of them
        at ``level`` on average."""

        def closed() -> bool:
            return self.count("power") > 50 and np.mean(self.values("power")[-20:]) >= level

        self.wait_until(closed, timeout, f"the loop closed to P_N/P_max >= {level:g}", logs)

    def send(self, values):
        from std_msgs.msg import Float32MultiArray

        self.cmd_pub.publish(Float32MultiArray(data=[float(v) for v in values]))

    def wait_for_subscriber(self, timeout: float = 30.0):
        """Until the simulator's command subscription has matched our publisher."""
        self.wait_until(
            lambda: self.cmd_pub.get_subscription_count() > 0, timeout, "a delay_cmd subscriber"
        )

    def close(self):
        # The spinning thread ends before the node goes: destroyed under its wait, the node's
        # handles raised in that thread (InvalidHandle, "destruction was requested").
        self.executor.shutdown(timeout_sec=2.0)
        self._thread.join(timeout=5.0)
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)
