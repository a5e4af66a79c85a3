"""The ROS side of the bridge: one client of a lockstep simulator (``ops_sim`` with
``lockstep:=true``), as the controllers have :class:`~ops_controller_ros.command_tracker.
CommandTracker`. :class:`LockstepClient` starts a private rclpy context and node, sends a reset or
a command, drains, collects the four outputs that answer it, and resends a request whose answer
went missing; :class:`~.bridge_env.RosOpsEnv` turns those outputs into observations.

Protocol (docs/interfaces.md): a command is answered by one message on each of ``ops/intensity``,
``ops/power``, ``ops/reward`` and ``ops/delays``; the answer is identified on ``ops/delays``, which
must echo the set-points sent; older messages (left over by an earlier timeout) are skipped by
their position in each topic's queue. Isolation: a private Context (optionally on its own
``domain_id``) and a node under ``namespace``; no thread is started (the client spins its own
executor while it waits). With a finite ``timeout_s`` every wait has a deadline; when it passes,
:class:`SimulatorTimeoutError` says what was awaited. With ``timeout_s=None`` (training's
default) a wait has no deadline: through lost messages and outages of any length the client
re-sends its request every ``retry_after_s``, says every few seconds that it is still waiting, and
carries on when the simulator answers again. A request left unanswered for
``reconnect_after_s`` while the simulator's endpoints stayed matched makes the client close its
DDS participant and open a new one, then send the request again (next time after twice as long,
at most :data:`RECONNECT_LIMIT_S`): DDS's state for each link, which a process frozen and resumed
(SIGSTOP, a debugger) may leave unable to carry messages, is built anew on both sides, while the
simulator keeps its state (docs/interfaces.md, "A process frozen"). The default, 30 s, is longer
than Fast DDS's participant lease (20 s), after which a link that is down (a cable, a frozen
process) unmatches the endpoints: an outage of the network alone never replaces the participant,
and discovery finds the simulator again as it would have.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections import deque

import numpy as np
from ops_controller_ros.command_tracker import MATCH_TOLERANCE_FS

_TOPICS = ("intensity", "power", "reward", "delays")
_COUNTER = itertools.count()
#: Set-points echoed on ops/delays are float32 copies of the command (the controllers' rule).
ECHO_TOLERANCE_FS = MATCH_TOLERANCE_FS
#: Waits that are no request's answer (draining, the lockstep check) end after this at most.
HOUSEKEEPING_LIMIT_S = 5.0
#: How often a wait without deadline says that it still waits.
STILL_WAITING_EVERY_S = 10.0
#: Each further reconnection waits for twice the matched silence of the one before, up to this.
RECONNECT_LIMIT_S = 120.0


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


class LockstepClient:
    """Requests to one lockstep simulator and the four outputs that answer each.

    ``stage`` and ``mode`` describe the simulator expected (the stage is checked, the mode only
    named in hints); ``timeout_s`` bounds every wait (None or ``inf``: no bound, for outages of any
    length); a request unanswered for ``retry_after_s`` is sent again (``retries`` counts them);
    one unanswered for ``reconnect_after_s`` with the simulator's endpoints matched all the while
    (None: never) is sent again over a new DDS participant (``reconnects`` counts them).
    """

    def __init__(
        self,
        stage: int,
        mode: str,
        namespace: str = "",
        domain_id: int | None = None,
        timeout_s: float | None = None,
        retry_after_s: float | None = 1.0,
        node_name: str | None = None,
        with_actual: bool = False,
        reconnect_after_s: float | None = 30.0,
    ) -> None:
        if timeout_s is None:
            timeout_s = math.inf
        if not (timeout_s > 0):
            raise ValueError(f"timeout_s must be > 0 or None (no bound); got {timeout_s}")
        self.stage = int(stage)
        self.mode = mode
        self.timeout_s = float(timeout_s)
        # A request unanswered for this long is sent again (DDS may lose a message, e.g. a
        # service response right after discovery); the whole wait is still bounded by timeout_s.
        self.retry_after_s = (
            None if not retry_after_s else min(float(retry_after_s), self.timeout_s / 2)
        )
        if reconnect_after_s is not None and not (reconnect_after_s > 0):
            raise ValueError(
                f"reconnect_after_s must be > 0 or None (never); got {reconnect_after_s}"
            )
        self.reconnect_after_s = None if reconnect_after_s is None else float(reconnect_after_s)
        self.retries = 0  # requests sent again so far
        self.outages = 0  # requests answered only after a resend
        self.reconnects = 0  # DDS participants replaced while no answer came
        self._unanswered_since: float | None = None  # when the current request first went out
        self._matched_silent_since: float | None = None  # matched, unanswered: since when
        self._reconnect_wait = math.inf  # the matched silence that replaces the participant
        self._late_possible = False  # an earlier wait timed out: old answers may still arrive
        self._timed_out = False  # a wait timed out since the last successful reset
        self._lockstep_checked = False
        # with_actual: also wait for the simulator-only ops/delays_actual (the authors' set).
        self._topics = _TOPICS + (("delays_actual",) if with_actual else ())
        self._namespace, self._node_name = namespace, node_name
        self._start_ros(namespace, domain_id, node_name)

    @property
    def context(self):
        """The private rclpy Context (None once closed)."""
        return self._context

    def close(self) -> None:
        self._shutdown_ros()

    def _start_ros(self, namespace: str, domain_id: int | None, node_name: str | None) -> None:
        import rclpy
        from ops_contract.ros_interface import (
            QOS_RELIABLE,
            SERVICE_RESET,
            TOPIC_DELAY_CMD,
            TOPIC_DELAYS,
            TOPIC_DELAYS_ACTUAL,
            TOPIC_INTENSITY,
            TOPIC_POWER,
            TOPIC_REWARD,
            MessageGuard,
            delays_from_msg,
            power_from_msg,
            trace_from_msg,
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
            self._queues: dict[str, deque] = {t: deque() for t in self._topics}
            topics = {
                "intensity": (Float32MultiArray, TOPIC_INTENSITY, trace_from_msg),
                "power": (Float32, TOPIC_POWER, power_from_msg),
                "reward": (Float32, TOPIC_REWARD, power_from_msg),
                "delays": (Float32MultiArray, TOPIC_DELAYS, delays_from_msg),
                "delays_actual": (Float32MultiArray, TOPIC_DELAYS_ACTUAL, delays_from_msg),
            }
            topics = {k: v for k, v in topics.items() if k in self._topics}
            guard = MessageGuard(self._node)

            def receive(msg, key, topic, check):
                # Malformed messages are dropped (warned), as by every node: one rule.
                if guard.take(topic, check, msg) is not None:
                    self._queues[key].append(msg)

            self._subs = [
                self._node.create_subscription(
                    msg_type,
                    topic,
                    lambda m, k=key, t=topic, c=check: receive(m, k, t, c),
                    QOS_RELIABLE,
                )
                for key, (msg_type, topic, check) in topics.items()
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
        ros = [getattr(self, k, None) for k in ("_executor", "_node", "_context")]
        self._executor = self._node = self._context = None
        _close_ros(*ros)

    def _spin_until(self, ready, deadline: float, waiting_for: str | None = None) -> bool:
        """Process callbacks until ``ready()`` or the deadline; returns ready(). With
        ``waiting_for``, a long wait says every few seconds that it still waits."""
        start = said = time.monotonic()
        while not ready():
            now = time.monotonic()
            left = deadline - now
            if left <= 0:
                return ready()
            if waiting_for and now - said >= STILL_WAITING_EVERY_S:
                said = now
                self._node.get_logger().warning(
                    f"still waiting for {waiting_for} ({now - start:.0f} s; {self._where})"
                )
            self._executor.spin_once(timeout_sec=min(left, 0.1))
        return True

    def _drain(self, grace_s: float = 0.0) -> int:
        """Take every message already delivered and drop it; returns how many delays were seen.

        With ``grace_s`` > 0 (after a timeout), also waits until no message came for that long,
        so late answers to an abandoned request cannot be mistaken for the next one's.
        """
        seen = 0
        quiet_since = time.monotonic()
        end = quiet_since + max(min(self.timeout_s, HOUSEKEEPING_LIMIT_S), grace_s)
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
            f"-p mode:={self.mode} -p lockstep:=true"
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
            limit = min(self.timeout_s, HOUSEKEEPING_LIMIT_S)
            if not self._spin_until(future.done, time.monotonic() + limit):
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
                    if np.all(np.abs(echo - command) <= ECHO_TOLERANCE_FS):
                        index[0] = i
                        break
                if index[0] is None:
                    return False
            k = index[0]
            return all(len(q[t]) > k for t in self._topics)

        if not self._spin_until(find, deadline):
            self._late_possible = True
            self._timed_out = True
            if not final:
                raise _AttemptTimeout
            got = {t: len(q[t]) for t in self._topics}
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
        out = tuple(q[t][k] for t in self._topics)
        for t in self._topics:
            for _ in range(k + 1):
                q[t].popleft()
        return out

    # ------------------------------------------------------------------ requests
    def reset(self) -> tuple:
        """Call ``ops/reset`` and return the new episode's four outputs."""
        self._unanswered_since = None
        self._wait_for_simulator()
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
        self._answered("reset")
        return msgs

    def _wait_for_simulator(self) -> None:
        """The reset service answers, the topics are connected, the simulator is in lockstep."""
        start = said = time.monotonic()
        deadline = start + self.timeout_s
        while not self._reset_client.wait_for_service(
            timeout_sec=max(0.0, min(1.0, deadline - time.monotonic()))
        ):
            now = time.monotonic()
            if now < deadline:
                if now - said >= STILL_WAITING_EVERY_S:
                    said = now
                    self._node.get_logger().warning(
                        f"still waiting for a simulator on {self._reset_topic} "
                        f"({now - start:.0f} s; {self._where}); {self._hint()}"
                    )
                continue
            raise SimulatorTimeoutError(
                f"no simulator answered on {self._reset_topic} within {self.timeout_s:g} s "
                f"({self._where}); {self._hint()}"
            )

        # Reliable but volatile topics: a message sent before the endpoints match is lost, so
        # wait until the command reaches a subscriber and every output has a publisher.
        if not self._spin_until(
            self._connected, time.monotonic() + self.timeout_s, "the simulator's topics to connect"
        ):
            raise SimulatorTimeoutError(
                f"the simulator's reset service answers but its topics did not connect within "
                f"{self.timeout_s:g} s ({self._where}); {self._hint()}"
            )
        if not self._lockstep_checked:
            self._check_lockstep_parameter()
            # A simulator publishes its initial state once when it starts: let that settle.
            self._drain(grace_s=0.1)

    def _connected(self) -> bool:
        """The command reaches a subscriber and every output has a publisher."""
        return self._pub.get_subscription_count() > 0 and all(
            s.get_publisher_count() > 0 for s in self._subs
        )

    def _links(self) -> str:
        """What a wait has to go on: messages received per output since the last request, and
        the endpoints matched (the command's subscribers, each output's publishers)."""
        got = ", ".join(f"{t} {len(self._queues[t])}" for t in self._topics)
        publishers = "/".join(str(s.get_publisher_count()) for s in self._subs)
        subscribers = self._pub.get_subscription_count()
        return (
            f"received since the last send: {got}; the command reaches {subscribers} "
            f"subscriber(s), the outputs have {publishers} publisher(s)"
        )

    def _attempt_end(self, deadline: float) -> float:
        if self.retry_after_s is None:
            return deadline
        end = time.monotonic() + self.retry_after_s
        return deadline if end >= deadline - 0.05 else end

    def _retry(self) -> None:
        self.retries += 1
        now = time.monotonic()
        first = self._unanswered_since is None
        if first:  # the first attempt went out retry_after_s ago
            self._unanswered_since = now - (self.retry_after_s or 0.0)
            self._matched_silent_since = None
            self._reconnect_wait = self.reconnect_after_s or math.inf
        self._node.get_logger().warning(
            "no complete answer from the simulator yet: sending the request again "
            f"({self.retries} resend(s) so far; {self._links()})",
            throttle_duration_sec=5.0,
        )
        # A link that is down unmatches the endpoints within the lease: only a silence with the
        # simulator's endpoints matched all along is one that a new participant may end.
        if not self._connected():
            self._matched_silent_since = None
        elif self._matched_silent_since is None:
            self._matched_silent_since = self._unanswered_since if first else now
        elif now - self._matched_silent_since >= self._reconnect_wait:
            self._reconnect(now)
        self._prepare(strict=False)  # waits until late answers stop, drops them

    def _reconnect(self, now: float) -> None:
        """Replace the DDS participant (context, node, endpoints) by a new one, and wait a
        little for it to match the simulator's endpoints; the request is then sent again."""
        away = now - self._unanswered_since
        matched = now - self._matched_silent_since
        doubled = min(2.0 * self._reconnect_wait, RECONNECT_LIMIT_S)
        self._reconnect_wait = max(self._reconnect_wait, doubled)
        self._node.get_logger().warning(
            f"no answer from the simulator for {away:.0f} s, its endpoints matched for the last "
            f"{matched:.0f} s: replacing this bridge's DDS participant by a new one (links left "
            "unable to carry messages, e.g. by a process frozen and resumed, are built anew); "
            f"next time after {self._reconnect_wait:.0f} s more"
        )
        # The new participant first, then the old one closed: the new one takes other ports
        # (participant numbers) than the old, and the bridge is never without a participant.
        old = (self._executor, self._node, self._context)
        self._executor = self._node = self._context = None  # a failed start closes its own
        try:
            self._start_ros(self._namespace, self.domain_id, self._node_name)
        finally:
            _close_ros(*old)
        self.reconnects += 1
        self._matched_silent_since = None
        limit = min(HOUSEKEEPING_LIMIT_S, max(self.retry_after_s or 0.0, 1.0))
        self._spin_until(self._connected, time.monotonic() + limit)

    def command(self, command: np.ndarray, t0: float, what: str) -> tuple:
        """Publish ``command`` and collect its answer; a lost message means the same command is
        sent again (in lockstep the simulator steps again with the same set-points)."""
        self._unanswered_since = None
        self._prepare(strict=True)
        deadline = t0 + self.timeout_s
        msg = self._float_array()
        msg.data = command.tolist()
        while True:
            attempt_end = self._attempt_end(deadline)
            final = attempt_end >= deadline
            self._pub.publish(msg)
            try:
                answer = self._collect(command, attempt_end, what, final=final)
            except _AttemptTimeout:
                self._retry()
                continue
            self._answered(what)
            return answer

    def _answered(self, what: str) -> None:
        """A request got its answer: after resends, say how long the simulator was away."""
        if self._unanswered_since is None:
            return
        away = time.monotonic() - self._unanswered_since
        self._unanswered_since = None
        self._matched_silent_since = None
        self.outages += 1
        if away >= 1.0:
            self._node.get_logger().info(
                f"the simulator answered again ({what}) after {away:.1f} s without an answer; "
                "carrying on"
            )


def _close_ros(executor, node, context) -> None:
    """Shut down an executor, destroy its node and shut down its context (any may be None)."""
    import rclpy

    if executor is not None:
        executor.shutdown(timeout_sec=1.0)
    if node is not None:
        node.destroy_node()
    if context is not None:
        rclpy.try_shutdown(context=context)
