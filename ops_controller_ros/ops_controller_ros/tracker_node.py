"""The tracker node ``ops_tracker``: model-based phase retrieval closing the loop on a simulator
(or rig), with the same topics, pairing and robustness as ``ops_spgd``
(:class:`~ops_controller_ros.loop_node.ControllerLoopNode`).

The model parameters (wavelength, pulse width, detector) are node parameters with the simulator's
defaults: the controller is told the nominal rig, never the simulator's state; the stage and the
trace's samples per slot come from the messages.
"""

from __future__ import annotations

from ops_sim_ros.config import DETECTORS, make_config
from ops_sim_ros.node_params import ParamSpec
from ops_sim_ros.ros_interface import QOS_RELIABLE, ParameterError, run_node
from std_msgs.msg import Float32MultiArray

from .loop_node import ControllerLoopNode
from .tracker import PhaseTracker, TrackerParams

#: The calibration's estimates [wavelength_nm, pulse_fwhm_fs, detector_gain, detector_offset].
TOPIC_CALIBRATION = "ops/tracker/calibration"
_D = TrackerParams()
PARAMS = [
    ParamSpec("wavelength_nm", 1030.0, "nominal carrier wavelength, nm", low=100.0, high=20000.0),
    ParamSpec("pulse_fwhm_fs", 1000.0, "nominal sech^2 pulse FWHM, fs", low=1.0, high=1e6),
    ParamSpec("detector", "polarizer", "what the detector sees", choices=DETECTORS),
    ParamSpec("window", _D.window, "readings per fit", low=2, high=64),
    ParamSpec(
        "noisy_window",
        _D.noisy_window,
        "readings per fit once the detector is found noisy (the longer of the two is used)",
        low=2,
        high=64,
    ),
    ParamSpec(
        "hold_dither_cycles", _D.hold_dither_cycles, "excursion while tracking", low=0.0, high=0.25
    ),
    ParamSpec(
        "hold_pattern",
        _D.hold_pattern,
        "tracking excursion: all stages at once (Hadamard signs) or one at a time",
        choices=("all", "one"),
    ),
    ParamSpec("detector_noise", _D.detector_noise, "assumed detector noise std", low=0.0, high=1.0),
    ParamSpec(
        "hop_every",
        _D.hop_every,
        "readings between whole-cycle moves that measure the wavelength (0: none)",
        low=0,
        high=100000,
    ),
    # A rig runs in real time: the global search is spread over readings (the in-process
    # evaluation's default, 0, does it in one reading and locks a few steps sooner).
    # A rig steps whether or not the command came: the knot test (5-15 ms) runs after the
    # command is out and a revised command follows if it changed the estimate (the in-process
    # evaluation, which has no clock, tests first: the same controller with instant compute).
    ParamSpec(
        "defer_knot_test",
        True,
        "true: answer a reading first and test it for a knot of the drift after",
    ),
    # 4 ms at 100 Hz: 6 ms let half the revised commands miss their step (measured over DDS,
    # docs/tracker.md); about 40 % of the rig's step period.
    ParamSpec(
        "knot_budget_ms",
        4.0,
        "compute of the knot test and the fits after it per reading, ms (0: no limit)",
        low=0.0,
        high=1000.0,
    ),
    ParamSpec(
        "step_budget_ms",
        4.0,
        "compute of the global search per reading, ms (0: all in one reading)",
        low=0.0,
        high=1000.0,
    ),
]
_TRACKER_FIELDS = (
    "window",
    "noisy_window",
    "hold_dither_cycles",
    "hold_pattern",
    "detector_noise",
    "hop_every",
    "defer_knot_test",
    "knot_budget_ms",
    "step_budget_ms",
)
_MODEL_FIELDS = ("wavelength_nm", "pulse_fwhm_fs", "detector")


class TrackerNode(ControllerLoopNode):
    def __init__(self):
        super().__init__("ops_tracker", PARAMS)
        try:
            self._params = TrackerParams(**{k: self.values[k] for k in _TRACKER_FIELDS})
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self._model = {k: self.values[k] for k in _MODEL_FIELDS}
        # What the online calibration estimates (wavelength_nm, pulse_fwhm_fs, detector_gain,
        # detector_offset), published with each progress line.
        self._pub_calibration = self.create_publisher(
            Float32MultiArray, TOPIC_CALIBRATION, QOS_RELIABLE
        )

    def build_controller(self, delays, samples_per_slot):
        try:
            model = make_config(stage=delays.size, samples_per_slot=samples_per_slot, **self._model)
        except ValueError as exc:
            self.get_logger().error(f"cannot model this simulator: {exc}")
            return None
        return PhaseTracker(model, self._params, setpoints_fs=delays, seed=self.seed)

    def progress(self) -> str:
        est = self.ctrl.calibration.estimates()
        self._pub_calibration.publish(Float32MultiArray(data=[float(v) for v in est.values()]))
        return (
            f"reading {self.readings} ({'locked' if self.ctrl.locked else 'acquiring'}; "
            f"model {est['wavelength_nm']:.1f} nm, {est['pulse_fwhm_fs']:.0f} fs, detector "
            f"gain {est['detector_gain']:.3f} offset {est['detector_offset']:+.4f})"
        )


def main(args=None):
    raise SystemExit(run_node(TrackerNode, args))


if __name__ == "__main__":
    main()
