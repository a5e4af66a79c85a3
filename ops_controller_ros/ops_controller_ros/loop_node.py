"""The closed loop every controller node runs: a Node that drives a controller of
:mod:`ops_controller_ros.controllers` against a simulator (or rig) over the ``ops/`` topics.

Pairing of readings with set-points: the simulator publishes ``ops/delays`` (the set-points of a
step), then ``ops/intensity`` and ``ops/power``. After sending a command the node waits for a
delays message equal to it (:class:`CommandTracker`); a power reading is used only when its step
(by DDS sequence number, :class:`StepPairing`) is not before the first step reported on the
command's set-points, with the trace of that same step (a controller that reads the power alone,
:attr:`ControllerLoopNode.reads_trace` False, takes no trace), so a reading never predates its
command and never mixes two steps (without sequence numbers: the latest set-points must equal
the command, and the latest trace is taken). The stage count (and the trace's samples per slot)
come from the messages. If no matching reading arrives within ``timeout_s`` (simulator slow,
restarted or gone) the command is sent again; a simulator that comes back with another stage
restarts the controller from its set-points. A lockstep simulator whose first trace was missed is
asked for a step at its present set-points.

The set-points stay inside a rig's range (``rig_config``: a rig YAML with a calibration,
docs/rig.md): a rig refuses a command beyond a line's limits, and the drift carries a lock
towards one. A command within two optical cycles of a limit is moved whole cycles inwards and the
controller told (``move_setpoints``, :class:`~ops_controller_ros.setpoint_range.RangeKeeper`); a
controller that keeps the range itself (the tracker, :attr:`ControllerLoopNode.keeps_own_range`)
moves its own; and whatever is still beyond the range is clipped, so no such command goes out.

Subclasses declare their own parameters and build the controller (:meth:`build_controller`).
Only ``rate_hz`` and ``timeout_s`` change live; every other parameter is fixed after start (a
change is refused with the reason).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from ops_contract.config import SPEED_OF_LIGHT_NM_PER_FS
from ops_contract.executors import guarded, subscribe_with_info
from ops_contract.node_params import ParamSpec, declare_all
from ops_contract.observation import pulse_energies_from_trace
from ops_contract.rig_params import RIG_PARAMS, rig_config, rig_values
from ops_contract.ros_interface import (
    QOS_READINGS,
    QOS_RELIABLE,
    QOS_STATE,
    TOPIC_DELAY_CMD,
    TOPIC_DELAYS,
    TOPIC_DELAYS_ACTUAL,
    TOPIC_INTENSITY,
    TOPIC_POWER,
    MessageGuard,
    ParameterError,
    delays_from_msg,
    float_array_bytes,
    power_from_msg,
    trace_from_msg,
)
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from std_msgs.msg import Float32, Float32MultiArray

from . import controller_params, loop_status
from .command_tracker import CommandTracker, StepPairing, sequence_number, steps_between
from .reading_gaps import MAX_GAP_TICKS, TickClock, source_stamp
from .rig_optics import read_rig
from .setpoint_range import MARGIN_CYCLES, RangeKeeper

LOOP_PARAMS = [
    ParamSpec(
        "rate_hz",
        0.0,
        "largest command rate; 0: as fast as readings arrive",
        low=0.1,
        high=10000.0,
        special=(0.0,),
    ),
    controller_params.TIMEOUT,
    ParamSpec("seed", -1, "random seed of the controller; -1 draws one", low=-1, high=2**31 - 1),
    controller_params.LOG_PERIOD,
    *loop_status.PARAMS,
    # the rig YAML: the lines' range every controller keeps (and the tracker's optics)
    controller_params.RIG_CONFIG,
    # the rig the controller is told of, as the simulator node takes it
    *RIG_PARAMS,
]
#: The parameters a running loop applies at once; the others are fixed after start.
LIVE_PARAMS = ("rate_hz", "timeout_s")
#: The default of every controller node's ``executor`` parameter (declared by run_node,
#: ops_contract.executors): the events executor, with which each controller node missed fewer of
#: the simulator's steps (``ops-bench loop-rate``, docs/benchmarks.md)
EXECUTOR = "events"


class ControllerLoopNode(Node):
    """Closes the loop with the controller a subclass builds (see the module docstring)."""

    #: True: the controller keeps the rig's range itself (built with it, as the tracker is); the
    #: node then only clips. False: the node moves the commands and tells the controller.
    keeps_own_range = False
    #: False: the controller reads the power alone (SPGD-PID): the node does not subscribe to
    #: ops/intensity, so a simulator with no other reader of it does not build or send the
    #: trace (a step of the loop then moves one message less each way).
    reads_trace = True

    def __init__(self, node_name: str, params: list[ParamSpec]):
        super().__init__(node_name)
        specs = [
            p if p.name in LIVE_PARAMS else replace(p, read_only=True)
            for p in [*params, *LOOP_PARAMS]
        ]
        v = declare_all(self, specs, on_change=self._on_set_parameters)
        self.values = v
        rig_config(v)  # a rig make_config refuses stops the node before it spins
        self.rig = rig_values(v)  # the rig told (realism and the figures given)
        self.rig_model = read_rig(v["rig_config"])  # the rig YAML's model (None: no file)
        self._range = self._range_keeper()
        self._range_moves = 0  # moves off a limit logged so far
        self.seed = None if v["seed"] < 0 else v["seed"]
        self._min_period = 1.0 / v["rate_hz"] if v["rate_hz"] > 0 else 0.0
        self._log_period = v["log_period_s"]
        self.ctrl = None
        self.readings = 0
        self._commands = CommandTracker(v["timeout_s"])
        self._pairing = StepPairing()
        # Sequence number of the first step seen on the pending command's set-points: a reading
        # of that step or a later one is the command's (docs/interfaces.md, "Pairing").
        self._command_step = None
        self._guard = MessageGuard(self)
        self._status = loop_status.StatusReporter(self, v)
        self._trace = None  # (flat trace, samples per slot) of the latest ops/intensity
        self._delays = None  # the latest ops/delays
        self._next_allowed = 0.0
        self._last_reading_at = float("-inf")
        self._last_power_at = float("-inf")  # any ops/power, a reading of ours or not
        self._last_power_seq = None  # DDS sequence number of the last ops/power reading used
        self._last_power_stamp = None  # ... and its source timestamp (s)
        # a rig's tick period, for the steps of gaps in its readings (a simulator: none)
        self._ticks = None if self.rig_model is None else TickClock()
        self.late_steps = 0  # simulator steps that ran on old set-points (the command was late)
        self.revised_commands = 0  # commands replaced once the controller had thought further
        self._logged_counts: dict[str, int] = {}  # each counter at the last progress line

        # Delays first: when several are ready the executor takes them in creation order. The
        # latched subscription gives the set-points at start (a lockstep simulator publishes
        # only when commanded); the best-effort ones carry the running loop: a lost message
        # is not waited for (a reliable one costs seconds per loss on a lossy link).
        # (each callback takes the message info: its sequence number pairs a step's messages;
        # and the message serialized, read by ops_contract.cdr without building its objects)
        self._latched = None  # the latched subscription while it is needed (_keep_latched)
        self._keep_latched(True)
        self._subscribe(Float32MultiArray, TOPIC_DELAYS, self._on_delays, QOS_READINGS)
        if self.reads_trace:
            self._subscribe(Float32MultiArray, TOPIC_INTENSITY, self._on_intensity, QOS_READINGS)
        self._applied_delays = False  # see use_applied_delays
        self._subscribe(Float32, TOPIC_POWER, self._on_power, QOS_READINGS)
        self._pub_cmd = self.create_publisher(Float32MultiArray, TOPIC_DELAY_CMD, QOS_RELIABLE)
        # Re-sends are due a few sample periods after a command (CommandTracker.resend_after).
        self.create_timer(0.01, guarded(self, self._watchdog))
        self.create_timer(self._log_period, guarded(self, self._log_progress))
        told = " ".join(f"{k}={val}" for k, val in self.rig.items())
        self.get_logger().info(
            f"waiting for the simulator on {self.resolve_topic_name(TOPIC_DELAYS)} (rig: {told})"
        )

    def _subscribe(self, msg_type, topic: str, callback, qos):
        """``callback(raw, info)`` for each message on ``topic``: its bytes and MessageInfo."""
        return subscribe_with_info(self, msg_type, topic, callback, qos, raw=True)

    def _keep_latched(self, wanted: bool) -> None:
        """Hold the latched subscription of ``ops/delays`` or drop it. It is wanted until the
        loop closes and again while the simulator is silent (a restarted lockstep simulator of
        another stage publishes its set-points only there). While the loop runs it would only
        deliver every step's set-points a second time: over DDS that copy cost each process
        about a fifth of a step's CPU, and SPGD-PID at 1 kHz missed two to four times more of
        the simulator's steps (``ops-bench loop-rate``, docs/loop_rate.md)."""
        if wanted and self._latched is None:
            self._latched = self._subscribe(
                Float32MultiArray, TOPIC_DELAYS, self._on_delays, QOS_STATE
            )
        elif not wanted and self._latched is not None:
            self.destroy_subscription(self._latched)
            self._latched = None

    def _range_keeper(self) -> RangeKeeper | None:
        """The keeper of the rig file's set-point range (None without one), said on the log."""
        rig = self.rig_model
        if rig is None:
            return None
        if rig.setpoint_range_fs is None:
            self.get_logger().warning(
                f"rig_config: {rig.path} has no calibration, so no set-point range: a rig "
                "refuses set-points beyond its limits, and the drift carries a lock there "
                "(run ops_rig_ros calibrate)"
            )
            return None
        low, high = rig.setpoint_range_fs
        period = rig.optics["wavelength_nm"] / SPEED_OF_LIGHT_NM_PER_FS
        keeper = RangeKeeper(low, high, period, MARGIN_CYCLES, rig.reach_fs_per_reading)
        if self.keeps_own_range:
            ranges = ", ".join(f"[{a:.1f}, {b:.1f}]" for a, b in zip(low, high, strict=True))
            line = (
                f"set-point range in force (from {rig.path}), fs: {ranges}; the controller "
                f"moves a set-point within {MARGIN_CYCLES:g} cycles of a limit whole cycles "
                "inwards, and a command beyond the range is clipped"
            )
        else:
            line = f"{keeper.describe()} (from {rig.path})"
        self.get_logger().info(line)
        return keeper

    def _actuator_range_keeper(self, stage: int) -> RangeKeeper | None:
        """Without a rig file: the keeper of the nominal model's actuator range (the
        simulator's ``actuator_range_cycles``, +-30 cycles by default). A free-running simulator
        clips a set-point beyond it, and the loop would then wait for a command it never takes
        (seen: a policy whose blind stage walked to +30 cycles stalled after 45 s)."""
        try:
            model = self.nominal_model(stage=stage)
        except ParameterError:
            return None
        reach, period = model.actuator_range_fs, model.optical_period_fs
        keeper = RangeKeeper(np.full(stage, -reach), np.full(stage, reach), period, MARGIN_CYCLES)
        if self._range is None:  # said once, at the first start
            self.get_logger().info(
                f"set-points kept inside the simulator's actuator range +-{reach:.1f} fs "
                f"(+-{model.actuator_range_cycles:g} cycles; a rig: -p rig_config:=RIG.yaml)"
            )
        return keeper

    def _in_range(self, command: np.ndarray) -> np.ndarray:
        """``command`` kept inside the rig's range (see the module docstring), the moves and
        clips said on the log (throttled)."""
        keeper = self._range
        clipped = keeper.clipped
        if self.keeps_own_range:
            command = keeper.clip(command)
            moves = int(getattr(self.ctrl, "range_moves", 0))
            how = "moved by the controller"
        else:
            command = keeper.keep(self.ctrl, command)
            moves = keeper.moves
            periods = " ".join(f"{k:+d}" for k in keeper.last_move) if moves else ""
            how = f"moved by {periods} periods of {keeper.period_fs:.3f} fs"
        if moves > self._range_moves:
            self._range_moves = moves
            self.get_logger().info(
                f"set-points near a limit of the rig's range {how} (the same interference; "
                f"{moves} stage moves so far)",
                throttle_duration_sec=5.0,
            )
        if keeper.clipped > clipped:
            self.get_logger().warning(
                f"a command beyond the rig's set-point range was clipped into it "
                f"({keeper.clipped} so far)",
                throttle_duration_sec=5.0,
            )
        return command

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Apply a validated change of rate_hz or timeout_s (declare_all refused the rest)."""
        for p in params:
            if p.name == "rate_hz":
                self._min_period = 1.0 / p.value if p.value > 0 else 0.0
                self._next_allowed = min(self._next_allowed, time.monotonic() + self._min_period)
            elif p.name == "timeout_s":
                self._commands.timeout_s = float(p.value)
        return SetParametersResult(successful=True)

    def use_applied_delays(self) -> None:
        """The controller also observes the simulator's applied delays of each reading's own
        step (``ops/delays_actual``, an oracle no rig has: the authors' observation set), as
        ``observe(..., applied=)``; a reading waits for them."""
        self._applied_delays = True
        self._subscribe(Float32MultiArray, TOPIC_DELAYS_ACTUAL, self._on_actual, QOS_READINGS)

    # ------------------------------------------------------------------ subclass hooks
    def build_controller(self, delays: np.ndarray, samples_per_slot: int):
        """The controller for a simulator with these set-points (its stage) and trace layout,
        or None when it cannot be built (say why in the log)."""
        raise NotImplementedError

    def nominal_model(self, **model):
        """The nominal model (an OpsConfig) of ``model`` (stage, wavelength, ...) on the rig
        the node was told of (``realism`` and the rig's figures); ParameterError if refused."""
        return rig_config(self.values, **model)

    def progress(self) -> str:
        """The start of the progress log line (before ``: P_N/P_max = ...``)."""
        return f"reading {self.readings}"

    def after_reading(self) -> None:
        """Called after the controller took each reading (e.g. to report what it found)."""

    def progress_note(self) -> str:
        """What the progress log line says after the power (e.g. which policy acts)."""
        return ""

    # ------------------------------------------------------------------ loop
    def _send(self):
        command = self.ctrl.command()
        if self._range is not None:
            command = self._in_range(command)
        command = self._commands.sent(command, time.monotonic())
        if not self._commands.resent:
            self._command_step = None
        self._pub_cmd.publish(float_array_bytes(command))

    def _start(self):
        stage = self._delays.size
        if self.ctrl is not None:
            self.get_logger().warning(
                f"simulator now has {stage} stages (was {self.ctrl.stage}): restarting"
            )
        self.ctrl = self._build(self._delays, self._trace[1] if self.reads_trace else None)
        if self.ctrl is None:
            return
        self._range_moves = 0  # the new controller's moves
        if self.rig_model is None:
            self._range = self._actuator_range_keeper(stage)
        if self._range is not None:
            self._range.moves = 0
        self.get_logger().info(f"simulator found: {stage} stages; closing the loop")
        self._send()

    def _build(self, delays: np.ndarray, samples_per_slot: int):
        """The subclass's controller, unless the rig file says another stage (its range is per
        stage: the node does not control such a rig)."""
        rig = self.rig_model
        if rig is not None and delays.size != rig.stage:
            self.get_logger().error(
                f"the rig publishes {delays.size} stages, its file "
                f"({self.values['rig_config']}) says {rig.stage}: not controlling it",
                throttle_duration_sec=5.0,
            )
            return None
        return self.build_controller(delays, samples_per_slot)

    def _start_if_found(self) -> bool:
        """(Re)start when set-points and trace agree on a stage other than the controller's
        (the trace tells the samples per slot); True when the controller runs that stage."""
        if self._delays is None or (self.reads_trace and self._trace is None):
            return False
        stage = self._delays.size
        if self.reads_trace and self._trace[0].size != (2**stage - 1) * self._trace[1]:
            return False  # one of them is from another stage: wait for both
        if self.ctrl is None or self.ctrl.stage != stage:
            self._start()
            return False
        return True

    def _on_delays(self, msg: bytes, info):
        seq = sequence_number(info)
        if self._pairing.is_copy("delays", seq):
            return  # (every step's comes twice: a copy is not read again)
        delays = self._guard.take(TOPIC_DELAYS, delays_from_msg, msg)
        if delays is None or not self._pairing.take("delays", seq):
            return
        self._delays = delays
        if self.ctrl is None or self.ctrl.stage != delays.size:
            self._start_if_found()
            return
        # (True: these are the pending command's set-points)
        if self._commands.on_setpoints(delays, now=time.monotonic()) and seq is not None:
            first = self._command_step
            self._command_step = seq if first is None else min(first, seq)

    def _on_intensity(self, msg: bytes, info):
        trace = self._guard.take(TOPIC_INTENSITY, trace_from_msg, msg)
        if trace is None or not self._pairing.take("trace", sequence_number(info), trace):
            return
        self._trace = trace
        if self.ctrl is None or self.ctrl.stage != self._delays.size:
            self._start_if_found()

    def _on_actual(self, msg: bytes, info):
        actual = self._guard.take(TOPIC_DELAYS_ACTUAL, delays_from_msg, msg)
        if actual is None:
            return
        if self._delays is not None and actual.size != self._delays.size:
            self._guard.drop(
                TOPIC_DELAYS_ACTUAL,
                f"{actual.size} delays; the set-points have {self._delays.size}",
            )
            return
        self._pairing.take("actual", sequence_number(info), actual)

    def _on_power(self, msg: bytes, info):
        # The MessageInfo comes through subscribe_with_info (rclpy passes it only to a callback
        # it takes for one that needs it: with a plain ``info=None`` default it never did, so
        # the steps between readings were always taken as 1 over DDS).
        power = self._guard.take(TOPIC_POWER, power_from_msg, msg)
        seq, stamp = sequence_number(info), source_stamp(info)
        self._pairing.on_power(seq)
        if self._ticks is not None:
            self._ticks.on_message(seq, stamp)
        self._last_power_at = time.monotonic()
        if power is None or self.ctrl is None or not self._is_reading(seq):
            return
        energies = None
        if self.reads_trace:
            energies = pulse_energies_from_trace(*self._pairing.kept_for("trace", seq))
            if energies.size != 2**self.ctrl.stage - 1:
                return  # a trace of another stage (the simulator is restarting)
        # Steps of a free-running simulator that ran before our command came (docs/interfaces.md)
        steps = steps_between(self._last_power_seq, seq)
        self.late_steps += steps - 1
        if self._ticks is not None:  # a rig's outage: the ticks its clock says (reading_gaps)
            ticks = self._ticks.steps(self._last_power_stamp, stamp, steps)
            if ticks > steps:
                steps = min(ticks, MAX_GAP_TICKS)
                self.get_logger().info(
                    f"the rig published no reading for {ticks} of its ticks "
                    f"({stamp - self._last_power_stamp:.2f} s): the controller takes "
                    f"{steps} steps of drift",
                    throttle_duration_sec=1.0,
                )
        self._last_power_seq, self._last_power_stamp = seq, stamp
        # Steps since the step that took the command (its set-points came back on ops/delays):
        # under a latency a command acts that many steps after it was taken
        age = None
        if seq is not None and self._command_step is not None:
            age = max(self._pairing.step_of(seq, "delays") - self._command_step, 0)
        if self._applied_delays:
            actual = self._pairing.kept_for("actual", seq)
            self.ctrl.observe(power, energies, steps=steps, applied=actual, command_age=age)
        else:
            self.ctrl.observe(power, energies, steps=steps, command_age=age)
        self._commands.answered()
        self.readings += 1
        self.after_reading()
        now = time.monotonic()
        self._last_reading_at = now
        self._status.observe(power, now)
        if now >= self._next_allowed:
            self._next_allowed = now + self._min_period
            self._send()
        self._think()

    def _is_reading(self, seq) -> bool:
        """Whether the power message numbered ``seq`` is a reading of the pending command: its
        step is not before the first step seen on the command's set-points, and its own trace
        came. Without sequence numbers: the latest set-points equal the command."""
        if seq is None:
            return self._commands.matched
        first = self._command_step
        if self._commands.pending is None or first is None:
            return False
        if self._pairing.step_of(seq, "delays") < first:
            return False
        kept = [
            t for t, used in (("trace", self.reads_trace), ("actual", self._applied_delays)) if used
        ]
        return all(self._pairing.kept_for(t, seq) is not None for t in kept)

    def _think(self):
        """The controller's work that can wait until the command is out (``think()``, see
        :mod:`ops_controller_ros.controllers`), in the time before the next step; the revised
        command at once if that changed it."""
        think = getattr(self.ctrl, "think", None)
        if think is not None and think() and self._commands.pending is not None:
            self.revised_commands += 1
            self._send()

    def _watchdog(self):
        now = time.monotonic()
        self._status.check(now)
        # (here, not in a callback of the subscription itself)
        self._keep_latched(
            self.ctrl is None or now - self._last_reading_at > self._commands.timeout_s
        )
        if self.ctrl is None:
            waiting = self._delays is not None and self._trace is None and self.reads_trace
            if waiting and now >= self._next_allowed:
                # A lockstep simulator published its trace before we listened: ask for a step
                # at the present set-points (a command that moves nothing).
                self._next_allowed = now + self._commands.timeout_s
                self._pub_cmd.publish(float_array_bytes(self._delays))
            return
        if self._commands.pending is None:
            if now >= self._next_allowed:  # rate-limited: the next command is due
                self._next_allowed = now + self._min_period
                self._send()
        elif self._commands.overdue(now):
            if now - self._last_reading_at > self._commands.timeout_s:
                # Longer than timeout_s: more than a lost message (quick re-sends are silent).
                self.get_logger().warning(
                    "no reading for the last command: re-sending (simulator slow or restarted?)",
                    throttle_duration_sec=5.0,
                )
            self._send()

    def _why_silent(self) -> str:
        if time.monotonic() - self._last_power_at > self._commands.timeout_s:
            return " (waiting for the simulator)"
        return (
            " (the simulator or rig publishes but has not taken the last command: a rig "
            "refuses set-points outside its limits, see its log)"
        )

    def _log_progress(self):
        if self.ctrl is None or not self.readings:
            return
        silent_s = time.monotonic() - self._last_reading_at
        if silent_s > max(self._commands.timeout_s, self._log_period):
            # The simulator (or rig) is gone or stalled, or it runs on without taking our
            # command: the last power is no longer current.
            self.get_logger().info(
                f"{self.progress()}: no reading for {silent_s:.1f} s{self._why_silent()}"
            )
            return
        power = f"P_N/P_max = {self.ctrl.last_power:.4f}"
        counts = self._counters_note()
        self.get_logger().info(f"{self.progress()}: {power}{self.progress_note()}{counts}")

    def _counters_note(self) -> str:
        """The progress line's counters, each over the last log period and since the start:
        simulator steps that ran on old set-points (their command came late) and commands
        revised after the controller thought further."""
        note = ""
        period = f"{self._log_period:g} s"
        for what, total in (
            ("simulator steps ran before their command came", self.late_steps),
            ("commands revised", self.revised_commands),
        ):
            if total:
                recent = total - self._logged_counts.get(what, 0)
                self._logged_counts[what] = total
                note += f" ({what}: {recent} in the last {period}, {total} since start)"
        return note
