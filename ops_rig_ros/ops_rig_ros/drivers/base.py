"""The two instrument roles of a rig, as small abstract classes: a :class:`TraceSource` (the
oscilloscope or digitizer behind the output photodiode) and a :class:`DelayActuator` (the drive
of the delay lines' piezos). A driver implements one of them in one module; the rig finds it by
name (:mod:`ops_rig_ros.drivers`) or as ``package.module:Class``.

Every failure of an instrument (timeout, garbage, disconnect) is raised as
:class:`InstrumentError` with a message that says what happened; the rig logs it, holds the
piezos and reconnects. A driver never clips or checks voltages itself beyond its own hardware
range: the safety layer (:mod:`ops_rig_ros.safety`) does that before ``set_voltages``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np


class InstrumentError(RuntimeError):
    """An instrument did not answer, answered garbage or went away (the message says which)."""


@dataclass
class Waveform:
    """One acquired record: ``volts`` (float64, one value per point) and the time between
    points, s."""

    volts: np.ndarray
    x_increment_s: float = 1.0


class TraceSource(ABC):
    """A digitizer of the detector signal. ``options``: the driver's section of the rig YAML."""

    def __init__(self, options: dict):
        self.options = dict(options)

    @abstractmethod
    def connect(self) -> None:
        """Open the instrument and set it up; InstrumentError when it is not there."""

    @abstractmethod
    def read(self) -> Waveform:
        """Acquire one record and return it scaled to volts; InstrumentError on any failure."""

    @abstractmethod
    def close(self) -> None:
        """Release the instrument (never raises)."""

    def describe(self) -> str:
        """A short name for logs (e.g. the resource string)."""
        return type(self).__name__


class DelayActuator(ABC):
    """A drive of ``len(self.channels)`` piezo channels, in volts."""

    def __init__(self, options: dict):
        self.options = dict(options)

    @property
    @abstractmethod
    def num_channels(self) -> int:
        """How many channels this drive has (the rig uses them in order)."""

    @abstractmethod
    def connect(self) -> None:
        """Open the drive; InstrumentError when it is not there."""

    @abstractmethod
    def set_voltages(self, volts: np.ndarray) -> None:
        """Apply one voltage per channel (already checked by the safety layer)."""

    @abstractmethod
    def read_voltages(self) -> np.ndarray:
        """The voltages the drive reports, one per channel."""

    @abstractmethod
    def close(self) -> None:
        """Release the drive (never raises)."""

    def describe(self) -> str:
        return type(self).__name__
