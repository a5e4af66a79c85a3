"""The tracker node ``ops_tracker``: model-based phase retrieval closing the loop on a simulator
(or rig), with the same topics and the same robustness as ``ops_spgd``.

Pairing of readings with set-points as in the SPGD node (:class:`CommandTracker`): a command is
answered by the first power reading that arrives while the latest ``ops/delays`` equals it; the
trace of that step (``ops/intensity``, published between them) gives the slot energies. The stage
count and the trace's samples per slot come from the messages; a simulator that comes back with
another stage restarts the controller. The model parameters (wavelength, pulse width, detector)
are node parameters with the simulator's defaults: the controller is told the nominal rig, never
the simulator's state.
"""

from __future__ import annotations

import time

import numpy as np
from ops_sim_ros.config import DETECTORS, make_config
from ops_sim_ros.node_params import ParamSpec, declare_all
from ops_sim_ros.observation import pulse_energies_from_trace
from ops_sim_ros.ros_interface import (
    QOS_RELIABLE,
    QOS_STATE,
    TOPIC_DELAY_CMD,
    TOPIC_DELAYS,
    TOPIC_INTENSITY,
    TOPIC_POWER,
    ParameterError,
    float_array_msg,
    run_node,
    trace_from_msg,
)
from rclpy.node import Node
from std_msgs.msg import Float32, Float32MultiArray

from . import controller_params
from .command_tracker import CommandTracker
from .tracker import PhaseTracker, TrackerParams

_D = TrackerParams()
PARAMS = [
    ParamSpec("wavelength_nm", 1030.0, "nominal carrier wavelength, nm", low=100.0, high=20000.0),
    ParamSpec("pulse_fwhm_fs", 1000.0, "nominal sech^2 pulse FWHM, fs", low=1.0, high=1e6),
    ParamSpec("detector", "polarizer", "what the detector sees", choices=DETECTORS),
    ParamSpec("window", _D.window, "readings per fit", low=2, high=64),
    ParamSpec(
        "hold_dither_cycles", _D.hold_dither_cycles, "excursion while tracking", low=0.0, high=0.25
    ),
    ParamSpec("detector_noise", _D.detector_noise, "assumed detector noise std", low=0.0, high=1.0),
    ParamSpec(
        "rate_hz", 0.0, "largest command rate; 0: as fast as readings arrive", low=0.0, high=1e6
    ),
    controller_params.TIMEOUT,
    ParamSpec("seed", -1, "random seed of the excursions; -1 draws one", low=-1, high=2**31 - 1),
    controller_params.LOG_PERIOD,
]
_TRACKER_FIELDS = ("window", "hold_dither_cycles", "detector_noise")


class TrackerNode(Node):
    def __init__(self):
        super().__init__("ops_tracker")
        v = declare_all(self, PARAMS)
        try:
            self._params = TrackerParams(**{k: v[k] for k in _TRACKER_FIELDS})
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self._model = {k: v[k] for k in ("wavelength_nm", "pulse_fwhm_fs", "detector")}
        self._seed = None if v["seed"] < 0 else v["seed"]
        self._min_period = 1.0 / v["rate_hz"] if v["rate_hz"] > 0 else 0.0
        self._log_period = v["log_period_s"]
        self._ctrl: PhaseTracker | None = None
        self._commands = CommandTracker(v["timeout_s"])
        self._trace = None  # (flat trace, samples per slot) of the latest ops/intensity
        self._delays = None  # the latest ops/delays
        self._next_allowed = 0.0
        self._last_reading_at = float("-inf")
        self._readings = 0

        # Delays first, then the trace, then the power: the simulator's order within a step.
        self.create_subscription(Float32MultiArray, TOPIC_DELAYS, self._on_delays, QOS_STATE)
        self.create_subscription(
            Float32MultiArray, TOPIC_INTENSITY, self._on_intensity, QOS_RELIABLE
        )
        self.create_subscription(Float32, TOPIC_POWER, self._on_power, QOS_RELIABLE)
        self._pub_cmd = self.create_publisher(Float32MultiArray, TOPIC_DELAY_CMD, QOS_RELIABLE)
        self.create_timer(0.05, self._watchdog)
        self.create_timer(self._log_period, self._log_progress)
        self.get_logger().info(
            f"waiting for the simulator on {self.resolve_topic_name(TOPIC_DELAYS)}"
        )

    # ------------------------------------------------------------------ loop
    def _send(self):
        command = self._commands.sent(self._ctrl.command(), time.monotonic())
        self._pub_cmd.publish(float_array_msg(command))

    def _start(self, delays: np.ndarray, samples_per_slot: int):
        try:
            model = make_config(stage=delays.size, samples_per_slot=samples_per_slot, **self._model)
        except ValueError as exc:
            self.get_logger().error(f"cannot model this simulator: {exc}")
            return
        self._ctrl = PhaseTracker(model, self._params, setpoints_fs=delays, seed=self._seed)
        self.get_logger().info(f"simulator found: {delays.size} stages; closing the loop")
        self._send()

    def _on_delays(self, msg: Float32MultiArray):
        delays = np.asarray(msg.data, dtype=np.float64)
        if delays.size == 0 or not np.all(np.isfinite(delays)):
            return
        self._delays = delays
        if self._ctrl is None or self._ctrl.stage != delays.size:
            if self._trace is None:
                return  # wait for the trace: it tells the samples per slot
            if self._ctrl is not None:
                self.get_logger().warning(
                    f"simulator now has {delays.size} stages (was {self._ctrl.stage}): restarting"
                )
            self._start(delays, self._trace[1])
            return
        self._commands.on_setpoints(delays)

    def _on_intensity(self, msg: Float32MultiArray):
        self._trace = trace_from_msg(msg)
        if self._ctrl is None and self._delays is not None:
            self._start(self._delays, self._trace[1])

    def _on_power(self, msg: Float32):
        if self._ctrl is None or not self._commands.matched or not np.isfinite(msg.data):
            return
        trace, samples = self._trace
        energies = pulse_energies_from_trace(trace, samples)
        if energies.size != self._ctrl.stacker.num_slots:
            return  # a trace of another stage (the simulator is restarting)
        self._ctrl.observe(float(msg.data), energies)
        self._commands.answered()
        self._readings += 1
        now = time.monotonic()
        self._last_reading_at = now
        if now >= self._next_allowed:
            self._next_allowed = now + self._min_period
            self._send()

    def _watchdog(self):
        if self._ctrl is None:
            if self._delays is not None and self._trace is None:
                # A lockstep simulator published its trace before we listened: ask for a step
                # at the present set-points (a command that moves nothing).
                now = time.monotonic()
                if now >= self._next_allowed:
                    self._next_allowed = now + self._commands.timeout_s
                    self._pub_cmd.publish(float_array_msg(self._delays))
            return
        now = time.monotonic()
        if self._commands.pending is None:
            if now >= self._next_allowed:
                self._next_allowed = now + self._min_period
                self._send()
        elif self._commands.overdue(now):
            self.get_logger().warning(
                "no reading for the last command: re-sending (simulator slow or restarted?)",
                throttle_duration_sec=5.0,
            )
            self._send()

    def _log_progress(self):
        if self._ctrl is None or not self._readings:
            return
        silent_s = time.monotonic() - self._last_reading_at
        if silent_s > max(self._commands.timeout_s, self._log_period):
            self.get_logger().info(
                f"reading {self._readings}: no reading for {silent_s:.1f} s "
                "(waiting for the simulator)"
            )
            return
        state = "locked" if self._ctrl.locked else "acquiring"
        self.get_logger().info(
            f"reading {self._readings}: P_N/P_max = {self._ctrl.last_power:.4f} ({state})"
        )


def main(args=None):
    raise SystemExit(run_node(TrackerNode, args))


if __name__ == "__main__":
    main()
