"""The learned-policy runner ``ops_policy``: a trained stable-baselines3 model closing the loop.

``ros2 run ops_controller_ros policy --ros-args -p model:=DIR`` loads ``DIR/model.zip`` and the
metadata saved beside it by training, builds each observation with the same builder as the
in-process environment (``ops_sim_ros.observation.ObservationBuilder``, through
``policy_io.PolicyRunner``; a model trained with memory gets its last observations and actions,
the history starting at the node's first reading) from the simulator's trace, power and
set-points, and publishes new set-points: current set-points + action * max step (the only action
type ``ops_controller_ros.policy_io`` loads is "increment"). A switching model (one policy
acquires, another holds: ``ops_controller_ros.policy_switch``) runs both on every reading and
logs which one acts.

A step's readings are used only once the set-points they report equal the last command (the
simulator publishes ``ops/delays`` first), as in the SPGD node. A model trained for another stage
than the simulator runs stops the node with a clear error (exit code 1).
"""

from __future__ import annotations

import time

import numpy as np
from ops_sim_ros.node_params import ParamSpec, declare_all
from ops_sim_ros.observation import OBSERVATION_SETS, pulse_energies_from_trace
from ops_sim_ros.ros_interface import (
    QOS_READINGS,
    QOS_RELIABLE,
    QOS_STATE,
    TOPIC_DELAY_CMD,
    TOPIC_DELAYS,
    TOPIC_DELAYS_ACTUAL,
    TOPIC_INTENSITY,
    TOPIC_POWER,
    MessageGuard,
    NodeFatalError,
    ParameterError,
    delays_from_msg,
    float_array_msg,
    power_from_msg,
    run_node,
    trace_from_msg,
)
from rclpy.node import Node
from std_msgs.msg import Float32, Float32MultiArray

from . import controller_params, loop_status
from .command_tracker import CommandTracker
from .policy_io import PolicyLoadError, check_observation, check_stage, load_policy
from .policy_switch import SwitchingRunner, make_runner

PARAMS = [
    ParamSpec("model", "", "trained model: the training output DIR or DIR/model.zip"),
    ParamSpec(
        "observation",
        "rig",
        "observation set the model was trained on: rig (measurable on a real stacker) or "
        "authors (needs the simulator's ops/delays_actual oracle)",
        choices=OBSERVATION_SETS,
        read_only=True,
    ),
    controller_params.TIMEOUT,
    controller_params.LOG_PERIOD,
    *loop_status.PARAMS,
]


class PolicyNode(Node):
    def __init__(self):
        super().__init__("ops_policy")
        v = declare_all(self, PARAMS)
        if not v["model"]:
            raise ParameterError(
                "model must be the path of a trained model (the training output directory or "
                "its model.zip), e.g. --ros-args -p model:=runs/sac_n3_easy"
            )
        try:
            self._policy = load_policy(v["model"])
            self._runner = make_runner(self._policy)
            check_observation(self._policy.metadata, v["observation"], "-p observation:=")
        except PolicyLoadError as exc:
            raise ParameterError(f"model: {exc}") from None
        self._spec = self._runner.spec
        self._max_step_fs = self._policy.max_step_fs  # policy_io loads increment models only

        self._tracker = CommandTracker(v["timeout_s"])
        self._guard = MessageGuard(self)
        self._status = loop_status.StatusReporter(self, v)
        self._delays: np.ndarray | None = None
        self._trace: tuple[np.ndarray, int] | None = None
        self._steps = 0
        self._last_power = float("nan")

        self.create_subscription(Float32MultiArray, TOPIC_DELAYS, self._on_delays, QOS_STATE)
        # Readings best effort: a lost one is not waited for (docs/interfaces.md, lossy links).
        self.create_subscription(Float32MultiArray, TOPIC_INTENSITY, self._on_trace, QOS_READINGS)
        self.create_subscription(Float32, TOPIC_POWER, self._on_power, QOS_READINGS)
        self._actual: np.ndarray | None = None  # applied delays (authors' observation set)
        self._waiting: Float32 | None = None  # a reading that waits for its applied delays
        if self._spec.needs_applied_delays:
            self.create_subscription(
                Float32MultiArray, TOPIC_DELAYS_ACTUAL, self._on_actual, QOS_RELIABLE
            )
        self._pub_cmd = self.create_publisher(Float32MultiArray, TOPIC_DELAY_CMD, QOS_RELIABLE)
        self.create_timer(0.01, self._watchdog)  # re-sends after the measured round trip
        self.create_timer(v["log_period_s"], self._log_progress)
        if isinstance(self._runner, SwitchingRunner):
            self.get_logger().info(
                f"switching model: {self._runner.acquire.policy.path} acquires, the model in "
                f"{self._policy.path} holds ({self._runner.params})"
            )
        self.get_logger().info(
            f"loaded {self._policy.algo.upper()} model for stage {self._policy.stage} "
            f"({self._policy.mode} mode, observation {self._spec.describe()}) from "
            f"{self._policy.path}; waiting for the simulator"
        )

    def _on_delays(self, msg: Float32MultiArray):
        delays = self._guard.take(TOPIC_DELAYS, delays_from_msg, msg)
        if delays is None:
            return
        if self._delays is not None and delays.size != self._delays.size:
            self._guard.drop(
                TOPIC_DELAYS, f"{delays.size} delays from a simulator of {self._delays.size} stages"
            )
            return
        if self._delays is None:
            try:
                check_stage(self._policy, delays.size)
            except PolicyLoadError as exc:
                raise NodeFatalError(str(exc)) from None
            self.get_logger().info("simulator found: running the policy")
        self._delays = delays
        self._trace = None
        self._actual = self._waiting = None
        self._tracker.on_setpoints(delays, accept_without_command=True, now=time.monotonic())

    def _on_actual(self, msg: Float32MultiArray):
        """The simulator-only oracle of the applied delays (published right after ops/delays)."""
        actual = self._guard.take(TOPIC_DELAYS_ACTUAL, delays_from_msg, msg)
        if actual is None:
            return
        if actual.size != self._spec.stage:
            self._guard.drop(
                TOPIC_DELAYS_ACTUAL, f"{actual.size} delays; the model drives {self._spec.stage}"
            )
            return
        if self._tracker.matched:
            self._actual = actual
            waiting, self._waiting = self._waiting, None
            if waiting is not None:
                self._on_power(waiting)

    def _on_trace(self, msg: Float32MultiArray):
        trace = self._guard.take(TOPIC_INTENSITY, trace_from_msg, msg)
        if trace is None or not self._tracker.matched:
            return
        slots = trace[0].size // trace[1]
        if slots != self._spec.num_slots:
            # The stage was checked on ops/delays: a trace of another size is not this rig's.
            self._guard.drop(
                TOPIC_INTENSITY,
                f"a trace of {slots} pulse slots; the model expects {self._spec.num_slots}",
            )
            return
        self._trace = trace

    def _on_power(self, msg: Float32):
        power = self._guard.take(TOPIC_POWER, power_from_msg, msg)
        if power is None or not self._tracker.matched or self._trace is None:
            return
        if self._spec.needs_applied_delays and self._actual is None:
            self._waiting = msg  # acted on when this step's applied delays arrive
            return
        trace, samples = self._trace
        energies = pulse_energies_from_trace(trace, samples)
        action = self._runner.act(energies, power, self._delays, self._actual).astype(np.float64)
        command = self._delays + action * self._max_step_fs
        self._last_power = power
        self._steps += 1
        self._status.observe(power, time.monotonic())
        self._trace = None
        self._send(command)

    def _send(self, command: np.ndarray):
        self._pub_cmd.publish(float_array_msg(self._tracker.sent(command, time.monotonic())))

    def _watchdog(self):
        now = time.monotonic()
        self._status.check(now)
        if self._tracker.overdue(now):
            self.get_logger().warning(
                "no reading for the last command: re-sending (simulator slow or restarted?)",
                throttle_duration_sec=5.0,
            )
            self._send(self._tracker.pending)
        elif (
            self._tracker.pending is None
            and self._delays is not None
            and self._steps == 0
            and now - self._tracker.sent_at > self._tracker.timeout_s
        ):
            # Set-points known (latched) but no reading: a lockstep simulator waits for a
            # command. Commanding the current set-points changes nothing and makes it step.
            self._send(self._delays.copy())

    def _log_progress(self):
        if self._steps:
            part = ""
            if isinstance(self._runner, SwitchingRunner):
                r = self._runner
                acting = "holding policy acts" if r.holding else "acquiring policy acts"
                if r.holder_acts and not r.holding:
                    acting = "holding policy searches in turn"
                part = f" ({acting}; {r.switches} hand-overs)"
            self.get_logger().info(f"step {self._steps}: P_N/P_max = {self._last_power:.4f}{part}")


def main(args=None):
    raise SystemExit(run_node(PolicyNode, args))


if __name__ == "__main__":
    main()
