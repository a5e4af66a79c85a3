"""The simulator node ``ops_sim``: the physics behind ROS 2 topics.

Free-running (default): steps at ``rate_hz`` with the latest commanded set-points, as a rig whose
noise advances with time. Lockstep (``lockstep:=true``): exactly one step per accepted command.
Every step publishes one message on each output in a fixed order: delays (the set-points of this
step) first, then intensity, power and reward, so a subscriber that processes ``ops/delays`` before
the others knows which set-points produced the readings that follow. In lockstep every accepted
command and every reset produces exactly one such group, so a client that waits for all four
before sending the next command gets each command's own outputs (docs/interfaces.md).
"""

from __future__ import annotations

import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from ops_contract.command_inbox import CommandInbox, command_verdict
from ops_contract.config import (
    DETECTORS,
    LIMITS,
    MAX_STAGE,
    MODES,
    SPLITS,
    TIME_BASES,
    VIBRATIONS,
    make_config,
)
from ops_contract.executors import guarded
from ops_contract.node_params import (
    DIAGNOSTICS_PERIOD_SPEC,
    ParamSpec,
    check_change,
    coerce,
    declare_all,
    samples_per_slot_spec,
)
from ops_contract.rig_params import RIG_PARAM_KEYS, RIG_PARAMS
from ops_contract.ros_interface import (
    QOS_RELIABLE,
    QOS_STATE,
    SERVICE_RESET,
    TOPIC_DELAY_CMD,
    TOPIC_DELAYS,
    TOPIC_DELAYS_ACTUAL,
    TOPIC_DIAGNOSTICS,
    TOPIC_INTENSITY,
    TOPIC_POWER,
    TOPIC_REWARD,
    ParameterError,
    check_command,
    float32_bytes,
    float_array_bytes,
    run_node,
    trace_bytes,
)
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from std_msgs.msg import Float32, Float32MultiArray
from std_srvs.srv import Trigger

from .simulation import BatchedSimulation

# Noise and optics figures a user may override; names and units as in OpsConfig (optical cycles).
# A negative value means "the mode's default".
_CONFIG_OVERRIDES = (
    ("jitter_sigma_cycles", "std of each step of the delays' random walk, optical cycles"),
    ("drift_slope_max_cycles", "largest drift, optical cycles per step (hard, extreme)"),
    ("drift_slope_min_cycles", "smallest drift, optical cycles per step (hard, extreme)"),
    ("drift_turn_s", "seconds over which the drift's slope reverses at its bound (0: one step)"),
    ("initial_sigma_cycles", "std of the initial delay errors (clipped at 2 sigma), cycles"),
    ("actuator_range_cycles", "set-points are clipped to +- this, optical cycles"),
    ("detector_noise", "std of additive noise on detected pulse energies (normalized)"),
)

PARAMS = [
    ParamSpec(
        "stage",
        3,
        "number of stacking stages N (2^N pulses)",
        low=1,
        high=MAX_STAGE,
        read_only=True,
    ),
    ParamSpec(
        "mode", "medium", "difficulty: initial state and drift (paper Fig. 4)", choices=MODES
    ),
    ParamSpec("split", "train", "drift variant (train or shifted test)", choices=SPLITS),
    ParamSpec(
        "detector",
        "polarizer",
        "what the detector sees: the s port behind a polarizer, or the total intensity",
        choices=DETECTORS,
    ),
    ParamSpec(
        "seed",
        -1,
        "random seed; -1 draws one from the OS (logged at start, in diagnostics)",
        low=-1,
        high=2**31 - 1,
        read_only=True,
    ),
    ParamSpec(
        "rate_hz",
        100.0,
        "free-running step rate (a rig's: 1 Hz to 1 kHz; beyond, the loop's headroom)",
        low=1.0,
        high=10000.0,
    ),
    ParamSpec("lockstep", False, "true: one step per command instead of a timer"),
    samples_per_slot_spec("trace samples per pulse slot"),
    DIAGNOSTICS_PERIOD_SPEC,
    # -1 means "the mode's default"; otherwise the config's range (LIMITS) applies.
    *[
        ParamSpec(
            name, -1.0, desc + " (-1: mode default)", low=0.0, high=LIMITS[name][1], special=(-1.0,)
        )
        for name, desc in _CONFIG_OVERRIDES
    ],
    # The rig between controller and optics (docs/physics.md "Rig imperfections"),
    # declared once for the simulator and every controller node: -1 means "the realism
    # preset's value".
    *RIG_PARAMS,
    ParamSpec(
        "latency_ms",
        -1.0,
        "latency of a command in ms, as steps of the loop (rate_hz; time_base seconds: "
        "step_s) rounded; overrides latency_steps; -1: latency_steps",
        low=0.0,
        high=60000.0,
        special=(-1.0,),
    ),
    ParamSpec(
        "actuator_lag_ms",
        -1.0,
        "the delay lines' response time in ms, as steps of the loop (as latency_ms); "
        "overrides actuator_lag_steps; -1: actuator_lag_steps",
        low=0.0,
        high=60000.0,
        special=(-1.0,),
    ),
    # Physical time (docs/physics.md, "Physical time and vibration").
    ParamSpec(
        "time_base",
        "step",
        "step: the paper's noise per step at any rate; seconds: the noise of step_s seconds "
        "per step (a simulated second the same at any rate)",
        choices=TIME_BASES,
    ),
    ParamSpec(
        "step_s",
        -1.0,
        "the control period in s (-1: 1 / rate_hz under time_base seconds, the paper's 0.1 "
        "under step)",
        low=LIMITS["step_s"][0],
        high=LIMITS["step_s"][1],
        special=(-1.0,),
    ),
    ParamSpec(
        "vibration",
        "none",
        "the delay lines' vibration in physical time: none, lab (a floated table under an "
        "enclosure) or open (the same table open to the room)",
        choices=VIBRATIONS,
    ),
]
_SPECS = {p.name: p for p in PARAMS}
#: The default of the node's ``executor`` parameter (run_node declares it, ops_contract.executors):
#: the events executor, whose steps cost less CPU and whose controllers miss fewer of them
#: (``ops-bench loop-rate``, docs/benchmarks.md)
EXECUTOR = "events"
_WARN_PERIOD_S = 2.0
#: Warn when the steps of the last RATE_WINDOW_S seconds ran below this share of rate_hz.
RATE_WINDOW_S = 2.0
RATE_TOLERANCE = 0.9


def _time_overrides(values: dict) -> dict:
    """time_base, step_s and vibration, and the latency and lag given in ms as loop steps:
    under time_base seconds a step lasts step_s (1 / rate_hz unless given), under step
    1 / rate_hz of wall time."""
    out = {"time_base": values["time_base"], "vibration": values["vibration"]}
    step_s = values["step_s"]
    if values["time_base"] == "seconds":
        period = step_s if step_s != -1.0 else 1.0 / values["rate_hz"]
        low, high = LIMITS["step_s"]
        if not low <= period <= high:
            raise ParameterError(
                f"step_s must be from {low:g} to {high:g} s under time_base seconds (got "
                f"{period:g}" + (f" from rate_hz {values['rate_hz']:g})" if step_s == -1.0 else ")")
            )
        out["step_s"] = period
    elif step_s != -1.0:
        out["step_s"] = step_s
    if values["latency_ms"] >= 0.0:
        if values["time_base"] == "seconds":
            out["latency_steps"] = round(values["latency_ms"] / 1000.0 / out["step_s"])
        else:
            out["latency_steps"] = round(values["latency_ms"] * values["rate_hz"] / 1000.0)
    if values["actuator_lag_ms"] >= 0.0:
        period = out["step_s"] if values["time_base"] == "seconds" else 1.0 / values["rate_hz"]
        out["actuator_lag_steps"] = values["actuator_lag_ms"] / 1000.0 / period
    return out


def config_from_params(values: dict):
    """The validated OpsConfig for a set of parameter values (ParameterError if impossible)."""
    overrides = {name: values[name] for name, _ in _CONFIG_OVERRIDES if values[name] >= 0.0}
    overrides.update({name: values[name] for name in RIG_PARAM_KEYS if values[name] != -1})
    overrides.update(_time_overrides(values))
    try:
        return make_config(
            stage=values["stage"],
            mode=values["mode"],
            split=values["split"],
            detector=values["detector"],
            samples_per_slot=values["samples_per_slot"],
            realism=values["realism"],
            **overrides,
        )
    except ValueError as exc:
        raise ParameterError(str(exc)) from None


class SimNode(Node):
    def __init__(self):
        super().__init__("ops_sim")
        self._values = declare_all(self, PARAMS, on_change=self._on_set_parameters)
        self._config = config_from_params(self._values)
        # The seed in use, drawn from the OS when -1: logged and in the diagnostics, so that any
        # run can be replayed with -p seed:=SEED.
        self.seed = self._values["seed"]
        if self.seed < 0:
            self.seed = int(np.random.SeedSequence().entropy % 2**31)
        self._sim = BatchedSimulation(self._config, num_envs=1, seed=self.seed)

        self._pub_intensity = self.create_publisher(
            Float32MultiArray, TOPIC_INTENSITY, QOS_RELIABLE
        )
        self._pub_power = self.create_publisher(Float32, TOPIC_POWER, QOS_RELIABLE)
        self._pub_reward = self.create_publisher(Float32, TOPIC_REWARD, QOS_RELIABLE)
        self._pub_delays = self.create_publisher(Float32MultiArray, TOPIC_DELAYS, QOS_STATE)
        # Simulator-only oracle (docs/interfaces.md): for policies of the authors' observation set.
        self._pub_actual = self.create_publisher(
            Float32MultiArray, TOPIC_DELAYS_ACTUAL, QOS_RELIABLE
        )
        self._pub_diag = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self._cmd_sub = None  # lockstep: a callback per command
        self._inbox = None  # free-running: commands taken at each step (command_inbox)
        self.create_service(Trigger, SERVICE_RESET, self._on_reset)

        self._result = self._sim.reset()
        self._command = self._sim.setpoints_fs[0].copy()  # latest accepted set-points
        self._steps = 0
        # Free-running steps at which no new valid command had come since the step before (a
        # controller that keeps up commands every step: docs/interfaces.md, diagnostics)
        self._steps_without_command = 0
        self._episodes = 1
        self._timer = None
        self._diag_timer = None
        self._restart_timers()
        self._set_command_intake()
        self.get_logger().info(
            f"stage={self._config.stage} mode={self._config.mode} split={self._config.split} "
            f"detector={self._config.detector} realism={self._config.realism} seed={self.seed} "
            f"time_base={self._config.time_base} step_s={self._config.step_s:g} "
            f"vibration={self._config.vibration} "
            + ("lockstep" if self._values["lockstep"] else f"rate={self._values['rate_hz']} Hz")
        )
        self._publish()

    # ------------------------------------------------------------------ stepping and publishing
    def _restart_timers(self):
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        self._rate_window = None  # (monotonic time, steps) at the start of the rate window
        if not self._values["lockstep"]:
            self._timer = self.create_timer(
                1.0 / self._values["rate_hz"], guarded(self, self._step)
            )
        if self._diag_timer is not None:
            self.destroy_timer(self._diag_timer)
        self._diag_timer = self.create_timer(
            self._values["diagnostics_period_s"], guarded(self, self._publish_diagnostics)
        )

    def _step(self):
        if self._inbox is not None and not self._take_commands():
            self._steps_without_command += 1
        self._result = self._sim.step_setpoints(self._command[None, :])
        self._steps += 1
        self._publish()
        if self._timer is not None:
            self._check_rate()

    def _check_rate(self):
        """Warn (throttled) when the free-running steps fall behind ``rate_hz``."""
        now = time.monotonic()
        if self._rate_window is None:
            self._rate_window = (now, self._steps)
            return
        t0, n0 = self._rate_window
        if now - t0 < RATE_WINDOW_S:
            return
        reached = (self._steps - n0) / (now - t0)
        self._rate_window = (now, self._steps)
        wanted = self._values["rate_hz"]
        if reached < RATE_TOLERANCE * wanted:
            self.get_logger().warning(
                f"cannot keep rate_hz {wanted:g}: {reached:.0f} steps/s reached over the last "
                f"{now - t0:.1f} s (each step computes and publishes; lower rate_hz or stage)",
                throttle_duration_sec=10.0,
            )

    def _publish(self):
        """A step's messages. The set-points always (latched: a later subscriber gets the last);
        the volatile topics only where someone subscribes (each message costs tens of µs to
        build and publish, at every step)."""
        r = self._result
        # (serialized here: the same bytes as the messages', without building them)
        self._pub_delays.publish(float_array_bytes(r.setpoints_fs[0]))
        if self._pub_actual.get_subscription_count():
            self._pub_actual.publish(float_array_bytes(r.applied_fs[0]))
        if self._pub_intensity.get_subscription_count():
            trace = self._sim.trace(r)[0]
            self._pub_intensity.publish(trace_bytes(trace, self._config.samples_per_slot))
        if self._pub_power.get_subscription_count():
            self._pub_power.publish(float32_bytes(r.power[0]))
        if self._pub_reward.get_subscription_count():
            self._pub_reward.publish(float32_bytes(r.reward[0]))

    def _publish_diagnostics(self):
        status = DiagnosticStatus(
            level=DiagnosticStatus.OK,
            name="ops_sim",
            message="running",
            hardware_id="ops_sim_ros",
        )
        status.values = [
            KeyValue(key=k, value=str(v))
            for k, v in (
                ("stage", self._config.stage),
                ("seed", self.seed),
                ("mode", self._config.mode),
                ("split", self._config.split),
                ("detector", self._config.detector),
                ("time_base", self._config.time_base),
                ("step_s", f"{self._config.step_s:g}"),
                ("vibration", self._config.vibration),
                ("lockstep", self._values["lockstep"]),
                ("step", self._steps),
                ("steps_without_command", self._steps_without_command),
                ("episode", self._episodes),
                ("power", f"{float(self._result.power[0]):.4f}"),
            )
        ]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._pub_diag.publish(msg)

    # ------------------------------------------------------------------ inputs
    def _set_command_intake(self):
        """Lockstep: a callback per command, each one steps. Free-running: the commands that
        queued since the last step are taken at the next one (CommandInbox), so a flood of
        messages costs the loop next to nothing."""
        lockstep = self._values["lockstep"]
        if lockstep and self._cmd_sub is None:
            if self._inbox is not None:
                self._take_commands()
                self._inbox.destroy()
                self._inbox = None
            self._cmd_sub = self.create_subscription(
                Float32MultiArray, TOPIC_DELAY_CMD, self._on_command, QOS_RELIABLE, raw=True
            )
        elif not lockstep and self._inbox is None:
            if self._cmd_sub is not None:
                self.destroy_subscription(self._cmd_sub)
                self._cmd_sub = None
            self._inbox = CommandInbox(self, TOPIC_DELAY_CMD, self._command_problem)

    def _command_problem(self, values: np.ndarray) -> str | None:
        return check_command(values, self._config.stage)

    def _take_commands(self) -> bool:
        """Apply the newest valid command queued since the last step; True if there was one."""
        values = self._inbox.take_latest()
        report = self._inbox.rejections_to_report(_WARN_PERIOD_S)
        if report is not None:
            total, problems = report
            self.get_logger().warning(
                f"rejected {total} delay command(s) in the last {_WARN_PERIOD_S:g} s or so "
                f"({problems}); set-points unchanged"
            )
        if values is None:
            return False
        self._apply_command(values)
        return True

    def _on_command(self, raw: bytes):
        problem, values = command_verdict(raw, self._command_problem)
        if problem:
            self.get_logger().warning(
                f"rejected delay command: {problem}; set-points unchanged",
                throttle_duration_sec=_WARN_PERIOD_S,
            )
            return
        self._apply_command(values)
        if self._values["lockstep"]:
            self._step()

    def _apply_command(self, values: np.ndarray):
        command = values.astype(np.float64)
        limit = self._config.actuator_range_fs
        if np.abs(command).max() > limit:
            self.get_logger().warning(
                f"delay command beyond the actuator range +-{limit:.1f} fs: clipped",
                throttle_duration_sec=_WARN_PERIOD_S,
            )
            command = np.clip(command, -limit, limit)
        self._command = command

    def _on_reset(self, request, response):
        self._result = self._sim.reset()
        self._command = self._sim.setpoints_fs[0].copy()
        self._episodes += 1
        if self._values["lockstep"]:
            self._publish()
        response.success = True
        response.message = f"episode {self._episodes} started"
        return response

    def _on_set_parameters(self, params):
        new = dict(self._values)
        for p in params:
            if p.name not in _SPECS:
                continue
            value = coerce(_SPECS[p.name], p.value)
            problem = check_change(_SPECS, p.name, value)
            if problem:
                return SetParametersResult(successful=False, reason=problem)
            new[p.name] = value
        try:
            config = config_from_params(new)
        except ParameterError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        timers_changed = any(
            new[k] != self._values[k] for k in ("rate_hz", "lockstep", "diagnostics_period_s")
        )
        self._values = new
        if config != self._config:
            # Noise figures, mode and detector apply from now on; the set-points and the delay
            # lines' present errors carry over (the drift restarts with the new figures).
            self._config = config
            self._sim = self._sim.with_config(config)
        if timers_changed:
            self._restart_timers()
            self._set_command_intake()
        return SetParametersResult(successful=True)


def main(args=None):
    raise SystemExit(run_node(SimNode, args, executor=EXECUTOR))


if __name__ == "__main__":
    main()
