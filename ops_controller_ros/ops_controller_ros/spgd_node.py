"""The SPGD-PID controller node ``ops_spgd``: closes the loop on a running simulator (or rig).

Pairing of readings with set-points: the simulator publishes ``ops/delays`` (the set-points of a
step) before that step's ``ops/power``. After sending a command the node waits for a delays
message equal to it; only a power reading that arrives while the latest delays message matches the
command is used, so a reading never predates its perturbation. The stage count is taken from
``ops/delays``. If no matching reading arrives within ``timeout_s`` (simulator slow, restarted or
gone) the command is sent again; a simulator that comes back with another stage restarts the
controller from its set-points.
"""

from __future__ import annotations

import time

import numpy as np
from ops_sim_ros.node_params import ParamSpec, declare_all
from ops_sim_ros.ros_interface import (
    QOS_RELIABLE,
    QOS_STATE,
    TOPIC_DELAY_CMD,
    TOPIC_DELAYS,
    TOPIC_POWER,
    ParameterError,
    float_array_msg,
    run_node,
)
from rclpy.node import Node
from std_msgs.msg import Float32, Float32MultiArray

from . import controller_params
from .command_tracker import CommandTracker
from .spgd import SpgdParams, SpgdPid

_DEFAULTS = SpgdParams()
# The node's parameters of the algorithm: SpgdParams' own fields (their defaults and types),
# with the description and range the node declares; one table, read twice.
_SPGD_FIELDS = {
    "gain": ("SPGD gain: fs^2 per unit of normalized power", 0.0, 1e6, True),
    "perturbation_fs": ("dither amplitude per stage, fs", 0.0, 1e3, True),
    "kp": ("PID proportional gain on the SPGD update", -1e6, 1e6, False),
    "ki": ("PID integral gain", -1e6, 1e6, False),
    "kd": ("PID derivative gain", -1e6, 1e6, False),
    "momentum": ("momentum of the update, in [0, 1)", 0.0, 0.999, False),
    "max_update_fs": ("largest set-point change per iteration", 0.0, 1e3, True),
}
PARAMS = [
    *[
        ParamSpec(name, getattr(_DEFAULTS, name), desc, low=lo, high=hi, low_exclusive=excl)
        for name, (desc, lo, hi, excl) in _SPGD_FIELDS.items()
    ],
    ParamSpec(
        "rate_hz", 0.0, "largest command rate; 0: as fast as readings arrive", low=0.0, high=1e6
    ),
    controller_params.TIMEOUT,
    ParamSpec("seed", -1, "random seed of the perturbations; -1 draws one", low=-1, high=2**31 - 1),
    controller_params.LOG_PERIOD,
]


class SpgdNode(Node):
    def __init__(self):
        super().__init__("ops_spgd")
        v = declare_all(self, PARAMS)
        try:
            self._params = SpgdParams(**{name: v[name] for name in _SPGD_FIELDS})
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self._seed = None if v["seed"] < 0 else v["seed"]
        self._min_period = 1.0 / v["rate_hz"] if v["rate_hz"] > 0 else 0.0
        self._log_period = v["log_period_s"]

        self._ctrl: SpgdPid | None = None
        self._tracker = CommandTracker(v["timeout_s"])
        self._next_allowed = 0.0
        self._last_reading_at = float("-inf")  # monotonic time of the last used reading

        # Delays first: when both are ready the executor takes them in creation order.
        self.create_subscription(Float32MultiArray, TOPIC_DELAYS, self._on_delays, QOS_STATE)
        self.create_subscription(Float32, TOPIC_POWER, self._on_power, QOS_RELIABLE)
        self._pub_cmd = self.create_publisher(Float32MultiArray, TOPIC_DELAY_CMD, QOS_RELIABLE)
        self.create_timer(0.05, self._watchdog)
        self._log_timer = self.create_timer(self._log_period, self._log_progress)
        self.get_logger().info(
            f"waiting for the simulator on {self.resolve_topic_name(TOPIC_DELAYS)}"
        )

    # ------------------------------------------------------------------ loop
    def _send(self):
        command = self._tracker.sent(self._ctrl.command(), time.monotonic())
        self._pub_cmd.publish(float_array_msg(command))

    def _on_delays(self, msg: Float32MultiArray):
        delays = np.asarray(msg.data, dtype=np.float64)
        if delays.size == 0 or not np.all(np.isfinite(delays)):
            return
        if self._ctrl is None or self._ctrl.stage != delays.size:
            if self._ctrl is not None:
                self.get_logger().warning(
                    f"simulator now has {delays.size} stages (was {self._ctrl.stage}): restarting"
                )
            self._ctrl = SpgdPid(delays.size, self._params, setpoints_fs=delays, seed=self._seed)
            self.get_logger().info(f"simulator found: {delays.size} stages; closing the loop")
            self._send()
            return
        self._tracker.on_setpoints(delays)

    def _on_power(self, msg: Float32):
        if not self._tracker.matched or not np.isfinite(msg.data):
            return
        self._ctrl.observe(float(msg.data))
        self._tracker.answered()
        now = time.monotonic()
        self._last_reading_at = now
        if now >= self._next_allowed:
            self._next_allowed = now + self._min_period
            self._send()

    def _watchdog(self):
        if self._ctrl is None:
            return
        now = time.monotonic()
        if self._tracker.pending is None:
            if now >= self._next_allowed:  # rate-limited: the next command is due
                self._next_allowed = now + self._min_period
                self._send()
        elif self._tracker.overdue(now):
            self.get_logger().warning(
                "no reading for the last command: re-sending (simulator slow or restarted?)",
                throttle_duration_sec=5.0,
            )
            self._send()

    def _log_progress(self):
        if self._ctrl is None or not self._ctrl.iterations:
            return
        silent_s = time.monotonic() - self._last_reading_at
        if silent_s > max(self._tracker.timeout_s, self._log_period):
            # The simulator (or rig) is gone or stalled: the last power is no longer current.
            self.get_logger().info(
                f"iteration {self._ctrl.iterations}: no reading for {silent_s:.1f} s "
                "(waiting for the simulator)"
            )
            return
        self.get_logger().info(
            f"iteration {self._ctrl.iterations}: P_N/P_max = {self._ctrl.last_power:.4f}"
        )


def main(args=None):
    raise SystemExit(run_node(SpgdNode, args))


if __name__ == "__main__":
    main()
