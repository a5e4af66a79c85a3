"""The tracker's nominal optics from a rig YAML (``-p rig_config:=RIG.yaml``, docs/rig.md).

Every controller node reads the file (:func:`read_rig`, in
:class:`~ops_controller_ros.loop_node.ControllerLoopNode`) for the lines' range, which it keeps
its set-points inside (:mod:`ops_controller_ros.setpoint_range`); the tracker also takes its
optics from it.

The rig YAML that ``ops_rig_ros calibrate`` wrote tells the stacker's stage and nominal optics
(``optics.wavelength_nm``, ``optics.pulse_fwhm_fs``, ``optics.detector``), read here with the
rig package's own checks (:mod:`ops_contract.rig_file`, shared: this package does not depend on
``ops_rig_ros``). A parameter given explicitly (command line, launch file, parameter file)
overrides the file; the file overrides the parameters' defaults.

The file also tells how far a delay line moves in one reading at the rig's slew limit. A
whole-cycle move of the tracker (``hop_every``: it measures the wavelength) that takes longer
than one reading leaves readings half-way, far below the stack (simulated lab, N = 5, hard,
50 Hz, 200 V/s: a dip every ~20 readings, docs/rig.md), so on such a rig the moves are off unless
``hop_every`` is given.
"""

from __future__ import annotations

from ops_contract.config import SPEED_OF_LIGHT_NM_PER_FS
from ops_contract.rig_file import RigFileError, RigModel, read_rig_model
from ops_contract.ros_interface import ParameterError
from rclpy.node import Node


def given_parameters(node: Node) -> set[str]:
    """The parameters given to ``node`` from outside (command line, launch, parameter files).

    rclpy keeps them in ``Node._parameter_overrides`` and has no public accessor (Jazzy); a
    parameter declared with its default cannot otherwise be told from one given its default."""
    return set(getattr(node, "_parameter_overrides", {}))


def read_rig(path: str) -> RigModel | None:
    """The rig YAML at ``path`` (the ``rig_config`` parameter; '' : None), read with the rig
    package's checks; ParameterError names the parameter, the file and the key."""
    if not path:
        return None
    try:
        return read_rig_model(path)
    except RigFileError as exc:
        raise ParameterError(f"rig_config: {exc}") from None


def nominal_optics(
    values: dict, given: set[str], path: str, rig: RigModel | None = None
) -> tuple[dict, RigModel | None, str]:
    """The optics (wavelength_nm, pulse_fwhm_fs, detector) of the parameter ``values``, with
    those not ``given`` taken from the rig YAML at ``path`` ('' : none; ``rig``: that file
    already read, :func:`read_rig`); the file's model (None without a file) and a line saying
    where each came from. ParameterError names the file and the key."""
    names = ("wavelength_nm", "pulse_fwhm_fs", "detector")
    optics = {k: values[k] for k in names}
    if not path:
        return optics, None, ""
    if rig is None:
        rig = read_rig(path)
    taken = [k for k in names if k not in given]
    optics.update({k: rig.optics[k] for k in taken})
    source = ", ".join(f"{k}={optics[k]}" for k in names)
    kept = [k for k in names if k in given]
    note = f"nominal model from {path}: stage {rig.stage}, {source}" + (
        f" ({', '.join(kept)} given as parameters)" if kept else ""
    )
    if not rig.calibrated:
        note += "; the file has no calibration yet (run ops_rig_ros calibrate)"
    return optics, rig, note


def power_weight_on_rig(power_weight: float, given: set[str], rig: RigModel | None):
    """``power_weight``, or 0 on a rig (a rig file given, ``power_weight`` not): a rig node's
    ``ops/power`` is the sum of the squared slot energies of the trace it publishes, clipped at
    1, so it repeats the stacked slot's noise and adds the full scale's error squared (N = 5,
    hard, in process, slot energies 4 % high: 39 % of readings >= 0.95 weighed 1, 95 % weighed
    0; docs/rig.md). Returns the weight and a line saying so, or ''."""
    if rig is None or "power_weight" in given or power_weight == 0.0:
        return power_weight, ""
    return 0.0, (
        "power_weight 0: the rig's ops/power is computed from its trace and adds nothing to "
        "the slot energies but their full scale's error; -p power_weight:=W weighs it anyway"
    )


def hop_every_on_rig(
    hop_every: int, given: set[str], rig: RigModel | None, wavelength_nm: float, hop_cycles: int
) -> tuple[int, str]:
    """``hop_every``, or 0 where the rig's lines cannot make a whole-cycle move of ``hop_cycles``
    periods within one reading (and ``hop_every`` was not given); a line saying so, or ''."""
    if rig is None or rig.reach_fs_per_reading is None or "hop_every" in given or not hop_every:
        return hop_every, ""
    move_fs = hop_cycles * wavelength_nm / SPEED_OF_LIGHT_NM_PER_FS
    if move_fs <= rig.reach_fs_per_reading:
        return hop_every, ""
    return 0, (
        f"whole-cycle moves off (hop_every 0): a move of {move_fs:.2f} fs takes more than one "
        f"reading at the rig's slew limit (the slowest line moves {rig.reach_fs_per_reading:.2f} "
        "fs per reading); -p hop_every:=N makes them anyway"
    )
