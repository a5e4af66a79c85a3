"""The rig node ``ops_rig``: a real stacker's instruments on the simulator's topics.

At ``rate_hz`` each tick: (re)connects what is gone (every ``reconnect_period_s``), applies the
newest accepted ``ops/delay_cmd`` (one slew-limited step towards its voltages, only while
traces are fresh), acquires a record and publishes ``ops/delays`` (the set-points of the
voltages now applied, fs), then ``ops/intensity`` and ``ops/power`` of that record, in that
order and one of each per reading (as the simulator: controllers pair them by sequence
number). Nothing only a simulator knows is published (no ``ops/reward``, no
``ops/delays_actual``). Safety (docs/rig.md): commands whose voltages leave the limits are
refused whole; traces older than ``stale_s`` hold the piezos where they are; instrument errors
are logged (throttled) and the instrument reconnected; shutdown parks the piezos at the slew
limit.
"""

from __future__ import annotations

import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from ops_contract.command_inbox import CommandInbox
from ops_contract.executors import guarded
from ops_contract.node_params import declare_all
from ops_contract.ros_interface import (
    QOS_RELIABLE,
    QOS_STATE,
    SERVICE_RESET,
    TOPIC_DELAY_CMD,
    TOPIC_DELAYS,
    TOPIC_DIAGNOSTICS,
    TOPIC_INTENSITY,
    TOPIC_POWER,
    ParameterError,
    float_array_msg,
    run_node,
    trace_msg,
)
from rclpy.node import Node
from std_msgs.msg import Float32, Float32MultiArray
from std_srvs.srv import Trigger

from .drivers.base import InstrumentError
from .params import PARAMS
from .rig import Rig
from .rig_config import RigConfigError, load_rig_config
from .safety import UnsafeVoltage, command_volts, fs_for
from .trace import TraceError

_WARN_PERIOD_S = 2.0


class RigNode(Node):
    def __init__(self):
        super().__init__("ops_rig")
        self.values = v = declare_all(self, PARAMS)
        if not v["config"]:
            raise ParameterError(
                "config must be the path of a rig YAML (-p config:=RIG.yaml; "
                "`ros2 run ops_rig_ros simlab --config-out RIG.yaml` writes one)"
            )
        try:
            self.config = load_rig_config(v["config"])
            self.rig = Rig(self.config)
        except RigConfigError as exc:
            raise ParameterError(f"config {v['config']}: {exc}") from None
        self.cal = self.config.calibration
        if self.cal is None:
            raise ParameterError(
                f"config {v['config']}: no calibration section; run "
                f"`ros2 run ops_rig_ros calibrate --ros-args -p config:={v['config']}` first"
            )
        self.stage = self.config.stage
        self.spp = v["samples_per_slot"]
        self.rate_hz = v["rate_hz"] if v["rate_hz"] > 0 else self.config.rate_hz
        self.limits = self.config.limits
        self.rig.follow_full_scale(v["full_scale_window"])
        self._full_logged = self.rig.detector_full_volts  # the full scale last logged, V

        self._pub_delays = self.create_publisher(Float32MultiArray, TOPIC_DELAYS, QOS_STATE)
        self._pub_intensity = self.create_publisher(
            Float32MultiArray, TOPIC_INTENSITY, QOS_RELIABLE
        )
        self._pub_power = self.create_publisher(Float32, TOPIC_POWER, QOS_RELIABLE)
        self._pub_diag = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self._passed = None  # (bytes, volts) of the last command the inbox's check passed
        self._inbox = CommandInbox(self, TOPIC_DELAY_CMD, self._command_problem)
        self.create_service(Trigger, SERVICE_RESET, self._on_reset)

        self.target: np.ndarray | None = None  # voltages the piezos move towards
        self.readings = 0
        self.power = float("nan")
        self.last_good = float("-inf")  # monotonic time of the last good reading
        self.errors = {"scope": 0, "piezo": 0, "trace": 0}
        self.last_error = ""
        self._retry_at = {"scope": 0.0, "piezo": 0.0}
        self._warned_at: dict[str, float] = {}
        self._parked = False

        self.create_timer(1.0 / self.rate_hz, guarded(self, self._tick))
        self.create_timer(v["diagnostics_period_s"], guarded(self, self._publish_diagnostics))
        self.get_logger().info(
            f"rig stage={self.stage} rate={self.rate_hz:g} Hz config={v['config']} "
            f"scope={self.rig.source.describe()} "
            f"piezos={', '.join(a.describe() for a in self.rig.drive.actuators)} "
            f"trace_baseline={self.rig.config.trace_baseline}"
        )

    # ------------------------------------------------------------------ helpers
    def _warn(self, key: str, text: str, period: float = _WARN_PERIOD_S) -> None:
        """A warning at most every ``period`` s per ``key`` (an instrument, a kind of fault)."""
        now = time.monotonic()
        if now - self._warned_at.get(key, float("-inf")) >= period:
            self._warned_at[key] = now
            self.get_logger().warning(text)
        self.last_error = text

    @property
    def fresh(self) -> bool:
        return time.monotonic() - self.last_good <= self.config.stale_s

    def _command_problem(self, values: np.ndarray) -> str | None:
        """The inbox's check; the voltages of a command it passes are kept for its taking."""
        volts, problem = command_volts(values.tolist(), self.stage, self.cal, self.limits)
        if volts is not None:
            self._passed = (values.tobytes(), volts)
        return problem

    def _volts_of(self, values: np.ndarray):
        """The drive voltages of a command the inbox passed: kept by its check, which the inbox
        runs on every valid command it takes, in order, before it returns the newest of them
        (computed again should another command be given)."""
        if self._passed is not None and self._passed[0] == values.tobytes():
            return self._passed[1]
        return command_volts(values.tolist(), self.stage, self.cal, self.limits)[0]

    # ------------------------------------------------------------------ the loop
    def _connect(self, now: float) -> None:
        period = self.values["reconnect_period_s"]
        if not self.rig.drive.connected and now >= self._retry_at["piezo"]:
            self._retry_at["piezo"] = now + period
            try:
                self.rig.drive.connect()
                self.target = self.rig.drive.last_sent.copy()  # hold where the piezos are
                self.get_logger().info(
                    f"piezo drives connected at {np.round(self.target, 3).tolist()} V"
                )
            except InstrumentError as exc:
                self.errors["piezo"] += 1
                self._warn("piezo", f"piezo drive unavailable: {exc} (retrying)", 10.0)
        if not self.rig.scope_connected and now >= self._retry_at["scope"]:
            self._retry_at["scope"] = now + period
            try:
                self.rig.connect_scope()
                self.get_logger().info(f"scope connected: {self.rig.source.describe()}")
            except InstrumentError as exc:
                self.errors["scope"] += 1
                self._warn("scope", f"scope unavailable: {exc} (retrying)", 10.0)

    def _take_command(self) -> None:
        values = self._inbox.take_latest()
        report = self._inbox.rejections_to_report(_WARN_PERIOD_S)
        if report is not None:
            total, problems = report
            self.get_logger().warning(
                f"refused {total} delay command(s) ({problems}); the piezos hold"
            )
            self.last_error = f"refused delay command: {problems}"
        if values is None:
            return
        if not self.fresh:
            self._warn("stale_cmd", "delay command ignored: no fresh trace (holding the piezos)")
            return
        volts = self._volts_of(values)
        if volts is not None:
            self.target = volts

    def _tick(self) -> None:
        now = time.monotonic()
        self._connect(now)
        self._take_command()
        drive = self.rig.drive
        if drive.connected and self.target is not None and self.fresh:
            try:
                drive.move_towards(self.target)
            except (InstrumentError, UnsafeVoltage) as exc:
                self.errors["piezo"] += 1
                self._warn("piezo", f"piezo drive failed: {exc} (reconnecting; holding)")
        elif not self.fresh and self.readings:
            held = "?" if drive.last_sent is None else np.round(drive.last_sent, 3).tolist()
            self._warn(
                "stale",
                f"no good trace for {now - self.last_good:.1f} s: holding the piezos at {held} V",
                5.0,
            )
        if not (self.rig.scope_connected and drive.connected):
            return
        try:
            trace, power = self.rig.reading(self.spp)
        except (InstrumentError, TraceError) as exc:
            kind = "trace" if isinstance(exc, TraceError) else "scope"
            self.errors[kind] += 1
            self._warn(kind, f"bad reading: {exc}")
            return
        self.last_good = time.monotonic()
        self.readings += 1
        self.power = power
        self._log_full_scale()
        self._pub_delays.publish(float_array_msg(fs_for(drive.last_sent, self.cal)))
        self._pub_intensity.publish(trace_msg(np.clip(trace, -10.0, 10.0), self.spp))
        self._pub_power.publish(Float32(data=power))

    def _log_full_scale(self) -> None:
        """Say when the full scale has grown by 0.5 % or more since it was last said."""
        full = self.rig.detector_full_volts
        if full >= 1.005 * self._full_logged:
            grown = 100.0 * (full / self._full_logged - 1.0)
            self.get_logger().info(
                f"detector full scale raised to {full:.4f} V ({grown:.1f} % since "
                f"{self._full_logged:.4f} V): the trace's slot energies summed above it "
                "(a stack shows no more light than its perfect stack); ops/power follows, "
                "ops/intensity keeps the calibration's units"
            )
            self._full_logged = full

    # ------------------------------------------------------------------ services, status
    def _on_reset(self, request, response):
        if not self.rig.drive.connected or not self.fresh:
            response.success = False
            response.message = "no fresh trace or piezo drive: holding"
            return response
        volts, problem = command_volts(np.zeros(self.stage), self.stage, self.cal, self.limits)
        if volts is None:
            response.success = False
            response.message = f"the calibrated zero is not reachable: {problem}"
            return response
        self.target = volts
        response.success = True
        response.message = "moving to the calibrated zero (set-points 0 fs) at the slew limit"
        return response

    def _publish_diagnostics(self) -> None:
        drive = self.rig.drive
        if not (self.rig.scope_connected and drive.connected):
            level, message = DiagnosticStatus.ERROR, "instrument disconnected: " + self.last_error
        elif not self.fresh:
            level, message = DiagnosticStatus.WARN, "traces stale: holding the piezos"
        else:
            level, message = DiagnosticStatus.OK, "running"
        status = DiagnosticStatus(
            level=level, name="ops_rig", message=message[:200], hardware_id="ops_rig_ros"
        )
        volts = drive.last_sent
        status.values = [
            KeyValue(key=k, value=str(val))
            for k, val in (
                ("stage", self.stage),
                ("rate_hz", self.rate_hz),
                ("readings", self.readings),
                ("power", f"{self.power:.4f}"),
                ("detector_full_volts", f"{self.rig.detector_full_volts:.5f}"),
                ("scope", "connected" if self.rig.scope_connected else "gone"),
                ("piezo", "connected" if drive.connected else "gone"),
                ("volts", "?" if volts is None else np.round(volts, 3).tolist()),
                ("scope_errors", self.errors["scope"]),
                ("trace_errors", self.errors["trace"]),
                ("piezo_errors", self.errors["piezo"]),
            )
        ]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._pub_diag.publish(msg)

    # ------------------------------------------------------------------ shutdown
    def park(self) -> None:
        """Ramp the piezos to ``park_volts`` at the slew limit, then release the instruments."""
        if self._parked:
            return
        self._parked = True
        drive = self.rig.drive
        try:
            if drive.connected:
                drive.ramp_to(self.limits.park_volts, timeout_s=self.values["park_timeout_s"])
                print(
                    f"[ops_rig] parked the piezos at {self.limits.park_volts.tolist()} V",
                    flush=True,
                )
        except (InstrumentError, UnsafeVoltage) as exc:
            print(f"[ops_rig] park failed: {exc}", flush=True)
        finally:
            self.rig.close()

    def destroy_node(self):
        self.park()
        super().destroy_node()


def main(args=None):
    raise SystemExit(run_node(RigNode, args, loops=True))


if __name__ == "__main__":
    main()
