"""Piezo drive voltages from an NI-DAQmx analog-output card through ``nidaqmx`` (optional).

Options: ``channels`` (physical channels in stage order, e.g. ``[Dev1/ao0, Dev1/ao1]``),
``min_volts`` / ``max_volts`` (the task's range, default -10 / 10; an amplifier after the card
is the lab's business: the rig's limits are in the card's volts). Read-back is the last written
value (analog outputs have no read-back). Needs NI's driver (NI-DAQmx runtime); without it
``connect`` raises :class:`InstrumentError` saying so.
"""

from __future__ import annotations

import contextlib

import numpy as np

from .base import DelayActuator, InstrumentError


def driver_missing_reason() -> str | None:
    """Why nidaqmx cannot drive a card here, or None when it can."""
    try:
        import nidaqmx.system
    except ImportError as exc:
        return f"the nidaqmx package is not installed ({exc})"
    try:
        nidaqmx.system.System.local().driver_version  # noqa: B018 - loads the NI library
    except Exception as exc:
        return f"the NI-DAQmx driver is not installed ({str(exc).splitlines()[0][:120]})"
    return None


class NidaqAnalogOut(DelayActuator):
    def __init__(self, options: dict):
        super().__init__(options)
        channels = self.options.get("channels")
        if not channels:
            raise ValueError("nidaq_ao needs channels (e.g. [Dev1/ao0, Dev1/ao1])")
        self.channels = [str(c) for c in channels]
        self.min_volts = float(self.options.get("min_volts", -10.0))
        self.max_volts = float(self.options.get("max_volts", 10.0))
        self._task = None
        self._last = None

    @property
    def num_channels(self) -> int:
        return len(self.channels)

    def describe(self) -> str:
        return f"NI-DAQmx {','.join(self.channels)}"

    def connect(self) -> None:
        reason = driver_missing_reason()
        if reason:
            raise InstrumentError(f"{self.describe()}: {reason}")
        import nidaqmx

        self.close()
        try:
            task = nidaqmx.Task()
            for ch in self.channels:
                task.ao_channels.add_ao_voltage_chan(
                    ch, min_val=self.min_volts, max_val=self.max_volts
                )
            self._task = task
        except Exception as exc:
            self.close()
            raise InstrumentError(f"{self.describe()}: cannot open ({exc})") from None

    def set_voltages(self, volts: np.ndarray) -> None:
        volts = np.asarray(volts, dtype=np.float64)
        if self._task is None:
            raise InstrumentError(f"{self.describe()}: not connected")
        if volts.shape != (self.num_channels,) or not np.all(np.isfinite(volts)):
            raise InstrumentError(f"{self.describe()}: refusing voltages {volts!r}")
        try:
            data = volts.tolist() if self.num_channels > 1 else float(volts[0])
            self._task.write(data, auto_start=True)
        except Exception as exc:
            raise InstrumentError(f"{self.describe()}: write failed ({exc})") from None
        self._last = volts.copy()

    def read_voltages(self) -> np.ndarray:
        if self._last is None:
            raise InstrumentError(f"{self.describe()}: nothing written yet")
        return self._last.copy()

    def close(self) -> None:
        if self._task is not None:
            with contextlib.suppress(Exception):  # closing a dead port: nothing to release
                self._task.close()
        self._task = None
