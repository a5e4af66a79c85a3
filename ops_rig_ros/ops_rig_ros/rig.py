"""A rig's instruments behind one object (no rclpy): the trace source, the piezo drives behind
the safety gate (:class:`~.safety.SafeDrive`) and the trace extraction. The node
(:mod:`.rig_node`) and the calibration (:mod:`.calibration`) both use it.
"""

from __future__ import annotations

import numpy as np

from .drivers import ACTUATORS, TRACE_SOURCES, DelayActuator, TraceSource, driver_class
from .full_scale import FullScaleFollower
from .rig_config import RigConfig, RigConfigError
from .safety import SafeDrive
from .trace import estimate_power, extract_trace, slot_readings_volts


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
        self.full_scale: FullScaleFollower | None = None

    def follow_full_scale(self, window: int) -> None:
        """Raise the full scale of ``ops/power`` while running when the median of the summed
        slot energies over ``window`` readings exceeds it (:mod:`.full_scale`); 0: never. The
        trace stays in the calibration's units."""
        self.full_scale = FullScaleFollower(window) if window > 0 else None

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
        cal = self.config.calibration
        record = self.read_record()
        trace = extract_trace(record, cal, samples_per_slot, self.config.trace_baseline)
        if self.full_scale is None:
            return trace, estimate_power(trace, samples_per_slot)
        # The trace keeps the calibration's units: a controller that fits its gain (the
        # tracker) saw a step of the full scale as a phase error and lost the lock. The power
        # is computed with the full scale followed.
        readings = slot_readings_volts(record, cal.slot_positions) / cal.detector_full_volts
        self.full_scale.observe(readings)
        return trace, estimate_power(trace / self.full_scale.gain, samples_per_slot)

    @property
    def detector_full_volts(self) -> float:
        """The full scale ``ops/power`` is computed with: the calibration's, raised while
        running (:meth:`follow_full_scale`)."""
        gain = 1.0 if self.full_scale is None else self.full_scale.gain
        return self.config.calibration.detector_full_volts * gain

    def close(self) -> None:
        self.source.close()
        self.drive.close()
