"""``ros2 run ops_rig_ros calibrate --ros-args -p config:=RIG.yaml``: run the calibration
(:mod:`.calibration`) on the rig's instruments and write it into the rig YAML.

Refuses to run without limits (the YAML's ``limits``: every sweep stays within them, at the
slew limit). Ends with the piezos at the calibrated zero (set-points 0 fs), where the rig node
takes over; Ctrl-C or SIGTERM parks them at ``park_volts`` and writes nothing.
"""

from __future__ import annotations

import signal
import sys

import rclpy
from ops_contract.node_params import ParamSpec, declare_all
from ops_contract.ros_interface import ParameterError

from .drivers.base import InstrumentError
from .fringe import CalibrationError
from .rig import Rig
from .rig_config import RigConfigError, calibration_dict, load_rig_config, save_calibration
from .safety import UnsafeVoltage, volts_for

PARAMS = [
    ParamSpec("config", "", "path of the rig YAML to calibrate (written back)", read_only=True),
]


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def run(config_path: str) -> int:
    try:
        config = load_rig_config(config_path)
        rig = Rig(config)
    except RigConfigError as exc:
        print(f"[ERROR] invalid parameter: config {config_path}: {exc}", file=sys.stderr)
        return 2
    from .calibration import calibrate

    def say(text: str) -> None:
        print(f"[calibrate] {text}", flush=True)

    try:
        rig.drive.connect()
        rig.connect_scope()
        say(f"sweeping {config.stage} stages within the limits of {config_path}")
        cal = calibrate(rig, log=say)
        save_calibration(config_path, cal)
        rig.drive.ramp_to(volts_for([0.0] * config.stage, cal))
        say(f"wrote calibration {calibration_dict(cal)} into {config_path}")
        return 0
    except KeyboardInterrupt:
        say("interrupted: parking the piezos; nothing written")
        _park(rig)
        return 130
    except (InstrumentError, CalibrationError, UnsafeVoltage) as exc:
        print(f"[ERROR] calibration failed: {exc}", file=sys.stderr, flush=True)
        _park(rig)
        return 1
    finally:
        rig.close()


def _park(rig: Rig) -> None:
    try:
        if rig.drive.connected:
            rig.drive.ramp_to(rig.config.limits.park_volts, timeout_s=30.0)
    except (InstrumentError, UnsafeVoltage) as exc:
        print(f"[ERROR] park failed: {exc}", file=sys.stderr, flush=True)


def main(args=None) -> None:
    rclpy.init(args=args)
    try:
        node = rclpy.create_node("ops_rig_calibrate")
        try:
            values = declare_all(node, PARAMS)
            if not values["config"]:
                raise ParameterError("config must be the path of a rig YAML (-p config:=RIG.yaml)")
        except ParameterError as exc:
            print(f"[ERROR] invalid parameter: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    # rclpy's handlers are gone with its context: Ctrl-C and SIGTERM interrupt the sweep here.
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    raise SystemExit(run(values["config"]))


if __name__ == "__main__":
    main()
