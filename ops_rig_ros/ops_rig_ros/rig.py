"""A rig's instruments behind one object (no rclpy): the trace source, the piezo drives behind
the safety gate (:class:`~.safety.SafeDrive`) and the trace extraction. The node
(:mod:`.rig_node`) and the calibration (:mod:`.calibration`) both use it.
"""

from __future__ import annotations

import numpy as np

from .drivers import ACTUATORS, TRACE_SOURCES, DelayActuator, TraceSource, driver_class
from .rig_config import RigConfig, RigConfigError
from .safety import SafeDrive
from .trace import estimate_power, extract_trace


def _make(section: dict, key: str, builtin: dict, base: type):
    try:
        return driver_class(str(section["driver"]), builtin, base)(section)
    except ValueError as exc:
        raise RigConfigError(f"{key}: {exc}") from None


class Rig:
    def __init__(self, config: RigConfig):
        self.config = config
        self.source: TraceSource = _make(config.scope, "scope", TRACE_SOURCES, TraceSource)
        actuators = [
            _make(a, f"actuators[{i}]", ACTUATORS, DelayActuator)
            for i, a in enumerate(config.actuators)
        ]
        try:
            self.drive = SafeDrive(actuators, config.limits, max_dt=2.0 / config.rate_hz)
        except ValueError as exc:
            raise RigConfigError(f"actuators: {exc}") from None
        self.scope_connected = False

    def connect_scope(self) -> None:
        self.source.close()
        self.scope_connected = False
        self.source.connect()
        self.scope_connected = True

    def read_record(self) -> np.ndarray:
        """One record (volts); on InstrumentError the scope is marked disconnected."""
        try:
            return self.source.read().volts
        except Exception:
            self.scope_connected = False
            self.source.close()
            raise

    def reading(self, samples_per_slot: int) -> tuple[np.ndarray, float]:
        """(normalized trace, estimated power) of a fresh record; needs the calibration."""
        trace = extract_trace(self.read_record(), self.config.calibration, samples_per_slot)
        return trace, estimate_power(trace, samples_per_slot)

    def close(self) -> None:
        self.source.close()
        self.drive.close()
