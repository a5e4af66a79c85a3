"""Gymnasium environment over the simulator's ROS 2 topics (a running ``ops_sim`` in lockstep).

``RosOpsEnv(stage=3, mode="easy")`` has the same observation and action spaces as
``ops_sim_ros.OpsEnv`` for the same stage and configuration, and builds its observations with the
same function (:func:`ops_sim_ros.observation.build_observation`).

Protocol (lockstep, see docs/interfaces.md): ``step`` adds the scaled action to the current
set-points, publishes the absolute set-points on ``ops/delay_cmd`` and waits until it has the
simulator's answer to THAT command on each of ``ops/intensity``, ``ops/power``, ``ops/reward`` and
``ops/delays``. The answer is identified on ``ops/delays``, which must echo the set-points sent;
older messages (left over by an earlier timeout) are skipped by their position in each topic's
queue, so a step never returns an observation that predates its action. ``reset`` calls the
``ops/reset`` service and waits for the four outputs of the new episode.

Isolation: each bridge owns a private rclpy Context (optionally on its own ``domain_id``) and a
node under ``namespace``; no thread is started (the bridge spins its own executor while it
waits), and ``close()`` destroys the node and shuts the context down.

Every wait has a deadline; when it passes, :class:`SimulatorTimeoutError` says what was awaited.
"""

from __future__ import annotations

import itertools
import os
import time
from collections import deque
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from ops_sim_ros.config import make_config
from ops_sim_ros.observation import ObservationSpec, build_observation, pulse_energies_from_trace

ENV_ID = "ops_gym_bridge/RosPulseStacking-v0"
_TOPICS = ("intensity", "power", "reward", "delays")
_COUNTER = itertools.count()
#: Set-points echoed on ops/delays are float32 copies of the command; allow float32 rounding.
_ECHO_TOL_FS = 1e-3


class BridgeError(RuntimeError):
    """Base of the bridge's errors."""


class SimulatorTimeoutError(BridgeError, TimeoutError):
    """The simulator did not answer within the timeout."""


class StageMismatchError(BridgeError):
    """The simulator runs another number of stages than the bridge was asked for."""


class LockstepError(BridgeError):
    """The simulator's outputs do not follow the lockstep protocol."""


class _AttemptTimeout(Exception):
    """One attempt went unanswered (a lost message); the request is sent again."""


class RosOpsEnv(gym.Env):
    """N-stage optical pulse stacking through a running simulator's topics.

    Arguments: ``stage``, ``mode``, ``split`` and config ``overrides`` (as ``OpsEnv``; they must
    describe the simulator that runs: the bridge cannot set them, but it checks the stage),
    ``namespace`` (e.g. ``"/rig2"`` for a sim started with ``-r __ns:=/rig2``), ``domain_id``
    (None: ``ROS_DOMAIN_ID``), ``timeout_s`` (deadline of every wait), ``max_episode_steps``.

    ``info``: ``power`` (P_N/P_max), ``setpoints_fs`` (set-points now applied, as echoed by the
    simulator), ``reward``, ``step_time_s`` (wall time of the round trip), ``retries`` (requests
    sent again so far because an answer went missing for ``retry_after_s``; in lockstep a resent
    command makes the simulator step once more with the same set-points).
    """

    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(
        self,
        stage: int = 5,
        mode: str = "medium",
        split: str = "train",
        namespace: str = "",
        domain_id: int | None = None,
        timeout_s: float = 5.0,
        max_episode_steps: int = 200,
        action_type: str = "increment",
        observation_options: dict[str, Any] | None = None,
        node_name: str | None = None,
        retry_after_s: float | None = 1.0,
        **overrides: Any,
    ) -> None:
        super().__init__()
        if action_type != "increment":
            raise ValueError("the bridge supports action_type 'increment' only")
        if not (timeout_s > 0):
            raise ValueError(f"timeout_s must be > 0 (got {timeout_s})")
        self.config = make_config(
            stage=stage, mode=mode, split=split, episode_steps=max_episode_steps, **overrides
        )
        self.stage = self.config.stage
        self.action_type = action_type
        self.obs_spec = ObservationSpec.from_config(self.config, **(observation_options or {}))
        self.observation_space = self.obs_spec.space()
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.stage,), dtype=np.float32)
        self.max_step_fs = self.config.max_step_fs
        self.range_fs = self.config.actuator_range_fs
        self.timeout_s = float(timeout_s)
        # A request unanswered for this long is sent again (DDS may lose a message, e.g. a
        # service response right after discovery); the whole wait is still bounded by timeout_s.
        self.retry_after_s = (
            None if not retry_after_s else min(float(retry_after_s), self.timeout_s / 2)
        )
        self.retries = 0  # requests sent again so far
        self.max_episode_steps = int(max_episode_steps)
        self.namespace = namespace
        self._setpoints: np.ndarray | None = None
        self._steps = 0
        self._late_possible = False  # an earlier wait timed out: old answers may still arrive
        self._timed_out = False  # a wait timed out since the last successful reset
        self._lockstep_checked = False
        self._closed = False
        if self.spec is None:  # direct construction: declare the nondeterminism gym.make would
            from gymnasium.envs.registration import EnvSpec

            self.spec = EnvSpec(
                ENV_ID,
                entry_point="ops_gym_bridge.bridge_env:RosOpsEnv",
                nondeterministic=True,
                max_episode_steps=None,
            )
        self._start_ros(namespace, domain_id, node_name)

    # ------------------------------------------------------------------ ROS plumbing
    def _start_ros(self, namespace: str, domain_id: int | None, node_name: str | None) -> None:
        import rclpy
        from ops_sim_ros.ros_interface import (
            QOS_RELIABLE,
            SERVICE_RESET,
            TOPIC_DELAY_CMD,
            TOPIC_DELAYS,
            TOPIC_INTENSITY,
            TOPIC_POWER,
            TOPIC_REWARD,
        )
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import Float32, Float32MultiArray
        from std_srvs.srv import Trigger

        if domain_id is None:
            domain_id = int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
        self.domain_id = int(domain_id)
        self._context = Context()
        # A private context installs no signal handlers: Ctrl-C stays a KeyboardInterrupt.
        rclpy.init(context=self._context, domain_id=self.domain_id)
        try:
            name = node_name or f"ops_gym_bridge_{os.getpid()}_{next(_COUNTER)}"
            self._node = rclpy.create_node(name, namespace=namespace or "", context=self._context)
            self._executor = SingleThreadedExecutor(context=self._context)
            self._executor.add_node(self._node)
            self._queues: dict[str, deque] = {t: deque() for t in _TOPICS}
            topics = {
                "intensity": (Float32MultiArray, TOPIC_INTENSITY),
                "power": (Float32, TOPIC_POWER),
                "reward": (Float32, TOPIC_REWARD),
                "delays": (Float32MultiArray, TOPIC_DELAYS),
            }
            self._subs = [
                self._node.create_subscription(
                    msg_type, topic, lambda m, q=self._queues[key]: q.append(m), QOS_RELIABLE
                )
                for key, (msg_type, topic) in topics.items()
            ]
            self._pub = self._node.create_publisher(
                Float32MultiArray, TOPIC_DELAY_CMD, QOS_RELIABLE
            )
            self._reset_client = self._node.create_client(Trigger, SERVICE_RESET)
            self._trigger = Trigger
            self._float_array = Float32MultiArray
            self._where = (
                f"namespace '{self._node.get_namespace()}', ROS_DOMAIN_ID {self.domain_id}"
            )
            self._reset_topic = self._node.resolve_service_name(SERVICE_RESET)
            self._delays_topic = self._node.resolve_topic_name(TOPIC_DELAYS)
        except BaseException:
            self._shutdown_ros()
            raise

    def _shutdown_ros(self) -> None:
        import rclpy

        executor = getattr(self, "_executor", None)
        node = getattr(self, "_node", None)
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
            self._executor = None
        if node is not None:
            node.destroy_node()
            self._node = None
        context = getattr(self, "_context", None)
        if context is not None:
            rclpy.try_shutdown(context=context)
            self._context = None

    def _check_open(self) -> None:
        if self._closed:
            raise BridgeError("the bridge is closed")

    def _spin_until(self, ready, deadline: float) -> bool:
        """Process callbacks until ``ready()`` or the deadline; returns ready()."""
        while not ready():
            left = deadline - time.monotonic()
            if left <= 0:
                return ready()
            self._executor.spin_once(timeout_sec=min(left, 0.1))
        return True

    def _drain(self, grace_s: float = 0.0) -> int:
        """Take every message already delivered and drop it; returns how many delays were seen.

        With ``grace_s`` > 0 (after a timeout), also waits until no message came for that long,
        so late answers to an abandoned request cannot be mistaken for the next one's.
        """
        seen = 0
        quiet_since = time.monotonic()
        end = quiet_since + max(self.timeout_s, grace_s)
        while True:
            before = sum(len(q) for q in self._queues.values())
            self._executor.spin_once(timeout_sec=min(grace_s, 0.02) if grace_s > 0 else 0.0)
            seen += len(self._queues["delays"])
            got = sum(len(q) for q in self._queues.values()) > before
            for q in self._queues.values():
                q.clear()
            now = time.monotonic()
            if now >= end:  # a flood never goes quiet: stop at the deadline all the same
                return seen
            if got:
                quiet_since = now
            elif grace_s <= 0 or now - quiet_since >= grace_s:
                return seen

    def _prepare(self, strict: bool) -> None:
        """Before a request: drop old messages. ``strict`` (a step): in lockstep nothing may have
        been published since the last answer, so anything found means crossed wires."""
        if self._late_possible:
            self._drain(grace_s=0.2)
            self._late_possible = False
            return
        unsolicited = self._drain()
        if strict and unsolicited and not self._timed_out:
            raise LockstepError(
                f"the simulator published {unsolicited} output set(s) that no command of this "
                f"bridge caused ({self._where}); it is free-running (start it with "
                "-p lockstep:=true) or another node is commanding it"
            )

    def _hint(self) -> str:
        return (
            f"start one with: ros2 run ops_sim_ros sim --ros-args -p stage:={self.stage} "
            f"-p mode:={self.config.mode} -p lockstep:=true"
            + (
                f" -r __ns:={self._node.get_namespace()}"
                if self._node.get_namespace() != "/"
                else ""
            )
        )

    def _check_lockstep_parameter(self) -> None:
        """Ask the simulator node (``ops_sim`` in our namespace) whether it runs in lockstep.

        A simulator that does not expose the parameter (another node name, a real rig) is
        trusted; the protocol checks in ``step`` still catch unsolicited outputs.
        """
        from rcl_interfaces.srv import GetParameters

        client = self._node.create_client(GetParameters, "ops_sim/get_parameters")
        try:
            if not client.wait_for_service(timeout_sec=min(self.timeout_s, 1.0)):
                self._lockstep_checked = True
                return
            future = client.call_async(GetParameters.Request(names=["lockstep"]))
            if not self._spin_until(future.done, time.monotonic() + self.timeout_s):
                client.remove_pending_request(future)
                return
            values = future.result().values if future.result() is not None else []
            self._lockstep_checked = True
            # ParameterType.PARAMETER_BOOL == 1
            if values and values[0].type == 1 and not values[0].bool_value:
                raise LockstepError(
                    f"the simulator runs free (parameter lockstep is false; {self._where}): the "
                    "bridge needs one step per command; start it with -p lockstep:=true or set "
                    f"it live: ros2 param set {self._node.get_namespace().rstrip('/')}/ops_sim "
                    "lockstep true"
                )
        finally:
            self._node.destroy_client(client)

    # ------------------------------------------------------------------ waiting for answers
    def _check_stage(self, delays_msg) -> None:
        n = len(delays_msg.data)
        if n != self.stage:
            raise StageMismatchError(
                f"the simulator runs stage {n} (its {self._delays_topic} has {n} values) but the "
                f"bridge was asked for stage {self.stage}; start the bridge with stage={n} or the "
                f"simulator with -p stage:={self.stage}"
            )

    def _collect(
        self, command: np.ndarray | None, deadline: float, what: str, final: bool = True
    ) -> tuple:
        """Wait for one answer on each output; for a command, the answer on ops/delays that
        echoes it (older answers before it in every queue are dropped). With ``final`` False a
        missed deadline raises :class:`_AttemptTimeout` (the caller retries)."""
        q = self._queues
        index: list[int | None] = [None]

        def find() -> bool:
            if index[0] is None:
                for i, msg in enumerate(q["delays"]):
                    self._check_stage(msg)
                    if command is None:
                        index[0] = i
                        break
                    echo = np.asarray(msg.data, dtype=np.float64)
                    if np.all(np.abs(echo - command) <= _ECHO_TOL_FS):
                        index[0] = i
                        break
                if index[0] is None:
                    return False
            k = index[0]
            return all(len(q[t]) > k for t in _TOPICS)

        if not self._spin_until(find, deadline):
            self._late_possible = True
            self._timed_out = True
            if not final:
                raise _AttemptTimeout
            got = {t: len(q[t]) for t in _TOPICS}
            if index[0] is not None:
                raise SimulatorTimeoutError(
                    f"{what}: the simulator echoed the command on ops/delays but its other "
                    f"outputs did not all arrive within {self.timeout_s:g} s ({self._where}; "
                    f"messages received per output: {got})"
                )
            if command is not None and q["delays"]:
                echo = np.asarray(q["delays"][-1].data)
                raise LockstepError(
                    f"{what}: the simulator answered with set-points {np.round(echo, 3)} instead "
                    f"of the commanded {np.round(command, 3)} ({self._where}); another node may "
                    "be commanding it, or it was not started with -p lockstep:=true"
                )
            raise SimulatorTimeoutError(
                f"{what}: no answer from the simulator within {self.timeout_s:g} s ({self._where};"
                f" messages received per output: {got}). Is it running in lockstep mode, or has it "
                f"died? {self._hint()}"
            )
        k = index[0]
        if command is not None and k > 0 and not self._timed_out:
            # In lockstep nothing is published between our drain and our command's answer.
            raise LockstepError(
                f"{what}: the simulator published {k} output set(s) that no command of this "
                f"bridge caused ({self._where}); it is free-running (start it with "
                "-p lockstep:=true) or another node is commanding it"
            )
        out = tuple(q[t][k] for t in _TOPICS)
        for t in _TOPICS:
            for _ in range(k + 1):
                q[t].popleft()
        return out

    def _observe(self, msgs) -> tuple[np.ndarray, dict[str, Any]]:
        from ops_sim_ros.ros_interface import trace_from_msg

        intensity, power_msg, reward_msg, delays_msg = msgs
        trace, samples = trace_from_msg(intensity)
        energies = pulse_energies_from_trace(trace, samples)
        if energies.shape[-1] != self.obs_spec.num_slots:
            raise StageMismatchError(
                f"the simulator's intensity trace has {energies.shape[-1]} slots, stage "
                f"{self.stage} has {self.obs_spec.num_slots}"
            )
        setpoints = np.asarray(delays_msg.data, dtype=np.float64)
        power = float(power_msg.data)
        obs = build_observation(self.obs_spec, energies, power, setpoints)
        self._setpoints = setpoints
        info = {
            "power": power,
            "setpoints_fs": setpoints.copy(),
            "reward": float(reward_msg.data),
            "retries": self.retries,
        }
        return obs, info

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start a new episode on the simulator. ``seed`` seeds only the bridge's own generator
        (the simulator's noise is seeded by its ``seed`` parameter)."""
        self._check_open()
        super().reset(seed=seed)
        t0 = time.monotonic()
        if not self._reset_client.wait_for_service(timeout_sec=self.timeout_s):
            raise SimulatorTimeoutError(
                f"no simulator answered on {self._reset_topic} within {self.timeout_s:g} s "
                f"({self._where}); {self._hint()}"
            )

        # Reliable but volatile topics: a message sent before the endpoints match is lost, so
        # wait until the command reaches a subscriber and every output has a publisher.
        def connected() -> bool:
            return self._pub.get_subscription_count() > 0 and all(
                s.get_publisher_count() > 0 for s in self._subs
            )

        if not self._spin_until(connected, time.monotonic() + self.timeout_s):
            raise SimulatorTimeoutError(
                f"the simulator's reset service answers but its topics did not connect within "
                f"{self.timeout_s:g} s ({self._where}); {self._hint()}"
            )
        if not self._lockstep_checked:
            self._check_lockstep_parameter()
            # A simulator publishes its initial state once when it starts: let that settle.
            self._drain(grace_s=0.1)
        self._prepare(strict=False)
        deadline = time.monotonic() + self.timeout_s
        while True:
            attempt_end = self._attempt_end(deadline)
            final = attempt_end >= deadline
            future = self._reset_client.call_async(self._trigger.Request())
            if not self._spin_until(future.done, attempt_end):
                self._late_possible = True
                self._timed_out = True
                self._reset_client.remove_pending_request(future)
                if final:
                    raise SimulatorTimeoutError(
                        f"the simulator did not answer the reset request on {self._reset_topic} "
                        f"within {self.timeout_s:g} s ({self._where})"
                    )
                self._retry()
                continue
            response = future.result()
            if response is None or not response.success:
                raise BridgeError(
                    f"the simulator refused the reset: {getattr(response, 'message', '')}"
                )
            try:
                msgs = self._collect(
                    None, attempt_end if not final else deadline, "reset", final=final
                )
                break
            except _AttemptTimeout:
                self._retry()
        self._timed_out = False
        self._steps = 0
        obs, info = self._observe(msgs)
        info["step_time_s"] = time.monotonic() - t0
        return obs, info

    def _attempt_end(self, deadline: float) -> float:
        if self.retry_after_s is None:
            return deadline
        end = time.monotonic() + self.retry_after_s
        return deadline if end >= deadline - 0.05 else end

    def _retry(self) -> None:
        self.retries += 1
        self._node.get_logger().warning(
            "no complete answer from the simulator yet: sending the request again "
            f"({self.retries} resend(s) so far)",
            throttle_duration_sec=5.0,
        )
        self._prepare(strict=False)  # waits until late answers stop, drops them

    def _command_step(self, command: np.ndarray, t0: float, what: str) -> tuple:
        """Publish ``command`` and collect its answer; a lost message means the same command is
        sent again (in lockstep the simulator steps again with the same set-points)."""
        self._prepare(strict=True)
        deadline = t0 + self.timeout_s
        msg = self._float_array()
        msg.data = command.tolist()
        while True:
            attempt_end = self._attempt_end(deadline)
            final = attempt_end >= deadline
            self._pub.publish(msg)
            try:
                return self._collect(command, attempt_end, what, final=final)
            except _AttemptTimeout:
                self._retry()

    def step(self, action):
        self._check_open()
        if self._setpoints is None:
            raise RuntimeError("call reset() before step()")
        t0 = time.monotonic()
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(self.stage), -1.0, 1.0)
        command = np.clip(self._setpoints + a * self.max_step_fs, -self.range_fs, self.range_fs)
        command = command.astype(np.float32).astype(np.float64)  # what the message carries
        msgs = self._command_step(command, t0, f"step {self._steps + 1}")
        self._steps += 1
        obs, info = self._observe(msgs)
        info["step_time_s"] = time.monotonic() - t0
        truncated = self._steps >= self.max_episode_steps
        return obs, float(info["reward"]), False, truncated, info

    def set_setpoints(self, setpoints_fs) -> tuple[np.ndarray, dict[str, Any]]:
        """Command absolute set-points (fs) for one step; returns (observation, info)."""
        self._check_open()
        command = (
            np.clip(
                np.asarray(setpoints_fs, dtype=np.float64).reshape(self.stage),
                -self.range_fs,
                self.range_fs,
            )
            .astype(np.float32)
            .astype(np.float64)
        )
        t0 = time.monotonic()
        msgs = self._command_step(command, t0, "set_setpoints")
        obs, info = self._observe(msgs)
        info["step_time_s"] = time.monotonic() - t0
        return obs, info

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._shutdown_ros()


def make_bridge_env(**kwargs) -> RosOpsEnv:
    return RosOpsEnv(**kwargs)
