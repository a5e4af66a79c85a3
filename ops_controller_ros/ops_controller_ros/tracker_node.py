"""The tracker node ``ops_tracker``: model-based phase retrieval closing the loop on a simulator
(or rig), with the same topics, pairing and robustness as ``ops_spgd``
(:class:`~ops_controller_ros.loop_node.ControllerLoopNode`).

The model parameters (wavelength, pulse width, detector) are node parameters with the simulator's
defaults, or a rig YAML's ``optics.*`` (``rig_config``, :mod:`.rig_optics`), and the rig
(``realism`` and its figures, ``ops_contract.rig_params``) as the simulator node takes it: the
controller is told the nominal rig, never the simulator's state; the stage and the trace's
samples per slot come from the messages. The tracker's own parameters are
:class:`~ops_controller_ros.tracker.TrackerParams`' declared node fields, with its defaults
(``evaluate --controller tracker`` runs the same), plus real-time caps on the compute per reading.
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from ops_contract.config import DETECTORS, LIMITS, VIBRATIONS
from ops_contract.node_params import ParamSpec
from ops_contract.rig_file import OPTICS_DEFAULTS, OPTICS_LIMITS
from ops_contract.ros_interface import QOS_RELIABLE, TOPIC_DIAGNOSTICS, ParameterError, run_node
from std_msgs.msg import Float32MultiArray

from .loop_node import EXECUTOR, ControllerLoopNode
from .rig_optics import (
    given_parameters,
    hop_every_on_rig,
    nominal_optics,
    power_weight_on_rig,
)
from .tracker import NODE_FIELDS, PhaseTracker, TrackerParams, node_param_specs

#: The calibration's estimates [wavelength_nm, pulse_fwhm_fs, detector_gain, detector_offset].
TOPIC_CALIBRATION = "ops/tracker/calibration"
#: The nominal model's optics and detector (the simulator's defaults, and a rig YAML's keys).
MODEL_PARAMS = [
    ParamSpec(
        "wavelength_nm",
        OPTICS_DEFAULTS["wavelength_nm"],
        "nominal carrier wavelength, nm",
        *OPTICS_LIMITS["wavelength_nm"],
    ),
    ParamSpec(
        "pulse_fwhm_fs",
        OPTICS_DEFAULTS["pulse_fwhm_fs"],
        "nominal sech^2 pulse FWHM, fs",
        *OPTICS_LIMITS["pulse_fwhm_fs"],
    ),
    ParamSpec("detector", OPTICS_DEFAULTS["detector"], "what the detector sees", choices=DETECTORS),
]
#: The lines' vibration the fits allow for, in the physical time of the loop's period: a
#: simulator under time_base seconds (its rate_hz) or a rig has one; the node cannot read it
#: from the messages, so it is told (docs/loop_rate.md, "The tracker under vibration").
STEP_S = ParamSpec(
    "step_s",
    -1.0,
    "the loop's period in s, which a vibration is read at (the simulator's 1 / rate_hz "
    "under time_base seconds); -1: none told (a vibration then stops the node)",
    low=LIMITS["step_s"][0],
    high=LIMITS["step_s"][1],
    special=(-1.0,),
)
VIBRATION_PARAMS = [
    ParamSpec(
        "vibration",
        "none",
        "the delay lines' vibration the fits allow for: none, or a preset of the simulator's "
        "(lab, open), read at step_s",
        choices=VIBRATIONS,
    ),
    STEP_S,
]
# The tracker's own parameters are generated from TrackerParams' declarations (one default set
# with evaluate; the node adds only real-time caps, docs/tracker.md); the rig's are every
# controller node's (ControllerLoopNode, ops_contract.rig_params), and so is rig_config.
PARAMS = [*MODEL_PARAMS, *VIBRATION_PARAMS, *node_param_specs()]


def physical_time(values: dict) -> dict:
    """The model's time base for a told vibration (``make_config`` keywords): the vibration at
    step_s seconds a step, the walk and drift per second; nothing without one. ParameterError
    when a vibration comes without its step_s."""
    if values["vibration"] == "none":
        return {}
    if values["step_s"] == -1:
        raise ParameterError(
            f"vibration {values['vibration']} needs step_s, the loop's period in s "
            f"({STEP_S.allowed.removeprefix('-1 or ')})"
        )
    return {"time_base": "seconds", "step_s": values["step_s"], "vibration": values["vibration"]}


class TrackerNode(ControllerLoopNode):
    # built with the rig's range: the tracker moves its set-points off a limit itself
    # (tracker/period.py, in its model's cycles, with the hops' bookkeeping)
    keeps_own_range = True

    def __init__(self):
        super().__init__("ops_tracker", PARAMS)
        # The optics: parameters given explicitly, else the rig YAML's, else the defaults.
        given = given_parameters(self)
        path = self.values["rig_config"]
        self._model, rig, note = nominal_optics(self.values, given, path, self.rig_model)
        node_values = {k: self.values[k] for k in NODE_FIELDS}
        node_values["hop_every"], hop_note = hop_every_on_rig(
            node_values["hop_every"],
            given,
            rig,
            self._model["wavelength_nm"],
            TrackerParams.hop_cycles,
        )
        node_values["power_weight"], power_note = power_weight_on_rig(
            node_values["power_weight"], given, rig
        )
        try:
            self._params = TrackerParams(**node_values)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self.nominal_model(**self._model)  # checked before the node spins
        told = physical_time(self.values)
        vibration_note = told and (
            f"vibration {told['vibration']} told, read at step_s {told['step_s']:g} s: the fits "
            "follow what one step keeps and take the rest as noise of each reading"
        )
        for line in (note, hop_note, power_note, vibration_note):
            if line:
                self.get_logger().info(line)
        # What the online calibration estimates (wavelength_nm, pulse_fwhm_fs, detector_gain,
        # detector_offset), published with each progress line.
        self._pub_calibration = self.create_publisher(
            Float32MultiArray, TOPIC_CALIBRATION, QOS_RELIABLE
        )
        self._pub_diag = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self._latency_changes = 0
        self._false_locks = 0

    def nominal_model(self, **model):
        """The rig's nominal model, in physical time when a vibration is told (physical_time)."""
        return super().nominal_model(**model, **physical_time(self.values))

    def after_reading(self) -> None:
        """A latency the readings fit better than the told one: said on the log
        and on /diagnostics (WARN, told and measured steps) as soon as the tracker takes it,
        and on /diagnostics again with every progress line while it stands. A lock dropped as
        false: said on the log."""
        dropped = self.ctrl.false_locks > self._false_locks  # (a new controller counts from 0)
        self._false_locks = self.ctrl.false_locks
        if dropped:
            p = self._params
            self.get_logger().warning(
                f"lock dropped: more than half of its last {p.false_lock_readings} readings "
                f"below {p.false_lock_power:g} (a wrong estimate); the detector calibration is "
                f"back to nominal and the tracker acquires again ({self._false_locks} so far)"
            )
        if self.ctrl.latency_changes == self._latency_changes:
            return
        self._latency_changes = self.ctrl.latency_changes
        self.get_logger().warning(f"latency mismatch: {self.ctrl.latency_note}")
        self._publish_latency()

    def _publish_latency(self) -> None:
        note = self.ctrl.latency_note
        values = {"told_steps": self.ctrl.latency_told, "measured_steps": self.ctrl.latency}
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN,
            name=f"{self.get_name()}: latency",
            message=note,
            hardware_id="ops_tracker",
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._pub_diag.publish(msg)

    def build_controller(self, delays, samples_per_slot):
        # (a rig file's other stage is refused by the loop, ControllerLoopNode._build)
        try:
            model = self.nominal_model(
                stage=delays.size, samples_per_slot=samples_per_slot, **self._model
            )
        except ParameterError as exc:
            self.get_logger().error(f"cannot model this simulator: {exc}")
            return None
        rig = self.rig_model
        return PhaseTracker(
            model,
            self._params,
            setpoints_fs=delays,
            seed=self.seed,
            setpoint_range_fs=None if rig is None else rig.setpoint_range_fs,
            reach_fs=None if rig is None else rig.reach_fs_per_reading,
        )

    def progress(self) -> str:
        if self.ctrl.latency_changes:
            self._publish_latency()
        est = self.ctrl.calibration.estimates()
        self._pub_calibration.publish(Float32MultiArray(data=[float(v) for v in est.values()]))
        return (
            f"reading {self.readings} ({'locked' if self.ctrl.locked else 'acquiring'}; "
            f"model {est['wavelength_nm']:.1f} nm, {est['pulse_fwhm_fs']:.0f} fs, detector "
            f"gain {est['detector_gain']:.3f} offset {est['detector_offset']:+.4f}"
            + self._detector_note()
            + self._knot_note()
            + (
                f"; latency {self.ctrl.latency} steps, told {self.ctrl.latency_told})"
                if self.ctrl.latency_changes
                else ")"
            )
        )

    def _knot_note(self) -> str:
        """The knots taken so far, and the knot tests the budget spread over readings or cut
        short (a machine too slow for them shows here first)."""
        c = self.ctrl
        if not (c.knots or c.knot_tests_spread or c.knot_tests_cut):
            return ""
        # (no parentheses inside the line's own: readers match "(locked; ...): P_N/P_max")
        return (
            f", since start: knots {c.knots}, knot tests spread {c.knot_tests_spread} / cut "
            f"{c.knot_tests_cut}"
        )

    def _detector_note(self) -> str:
        """The noise measured from the repeated first reading, the one the tracking fits find,
        and whether the tracker took the detector as noisy (longer fits, stiffer drift, larger
        excursions): a rig whose first two readings saw its delay lines still moving reads
        noisier there than it is; the fits read the detector's own."""
        noise, fits = self.ctrl.measured_noise, self.ctrl.fit_noise
        if noise is None and fits is None:
            return ""
        note = "" if noise is None else f", noise {noise:.4f}"
        note += "" if fits is None else f", fits {fits:.4f}"
        # (no parentheses: they would end the line's "(locked; ...)" early, see _knot_note)
        return note + (", noisy" if self.ctrl.noisy else "")


def main(args=None):
    raise SystemExit(run_node(TrackerNode, args, executor=EXECUTOR))


if __name__ == "__main__":
    main()
