"""Instrument drivers behind :class:`~.base.TraceSource` and :class:`~.base.DelayActuator`.

``driver:`` in the rig YAML names one of :data:`TRACE_SOURCES` / :data:`ACTUATORS`, or a class of
a lab's own module as ``package.module:ClassName`` (see docs/rig.md, "Adding a driver").
"""

from __future__ import annotations

import importlib

from .base import DelayActuator, InstrumentError, TraceSource, Waveform

#: Built-in drivers: name -> "module:Class" (imported only when used).
TRACE_SOURCES = {"scpi_scope": "ops_rig_ros.drivers.scpi_scope:ScpiScope"}
ACTUATORS = {
    "mdt69x": "ops_rig_ros.drivers.mdt_piezo:MdtPiezo",
    "nidaq_ao": "ops_rig_ros.drivers.nidaq_ao:NidaqAnalogOut",
}

__all__ = [
    "ACTUATORS",
    "TRACE_SOURCES",
    "DelayActuator",
    "InstrumentError",
    "TraceSource",
    "Waveform",
    "driver_class",
]


def driver_class(name: str, builtin: dict[str, str], base: type) -> type:
    """The driver class ``name`` (a built-in name or ``module:Class``); ValueError if unknown."""
    target = builtin.get(name, name)
    if ":" not in target:
        raise ValueError(
            f"unknown driver {name!r}: use one of {', '.join(builtin)} or module:Class"
        )
    module_name, _, class_name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"driver {name!r} cannot be loaded: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise ValueError(f"driver {name!r} is not a {base.__name__}")
    return cls
