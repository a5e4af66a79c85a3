"""An open-loop piezo controller over a serial ASCII protocol through pyserial, after the
Thorlabs MDT693B (three channels x, y, z) / MDT694B (one channel, x).

The protocol implemented (115200 baud 8N1 on the real unit; any on a pseudo-terminal): a command
is ASCII terminated by a carriage return; the unit echoes the command when echo is on, answers a
query with its value in brackets (``[  24.80]``), and ends every answer with a prompt character
(``>`` by default; option ``prompt``). On connect the driver sends ``echo=0`` and checks
``id?`` and ``vlimit?`` (the unit's output limit switch: 75, 100 or 150 V). Per channel::

    xvoltage=12.500     set channel x to 12.5 V (millivolt resolution is sent)
    xvoltage?           -> [  12.50]

An answer that does not end in the prompt within ``timeout_s`` (0.5 s), a query without a
bracketed number, or a closed port raise :class:`InstrumentError`. Which axes this unit drives,
in stage order: option ``channels`` (e.g. ``[x, y, z]``).
"""

from __future__ import annotations

import contextlib
import re

import numpy as np

from .base import DelayActuator, InstrumentError

_VALUE = re.compile(r"\[\s*([-+0-9.eE]+)\s*\]")
AXES = ("x", "y", "z")


class MdtPiezo(DelayActuator):
    """Options: ``port`` (required: a serial device path), ``channels`` (default [x, y, z]),
    ``baudrate`` (115200), ``timeout_s`` (0.5), ``prompt`` (``>``)."""

    def __init__(self, options: dict):
        super().__init__(options)
        if "port" not in self.options:
            raise ValueError("actuators[].port is required for mdt69x (a serial device)")
        self.port = str(self.options["port"])
        self.channels = [str(c).lower() for c in self.options.get("channels", AXES)]
        bad = [c for c in self.channels if c not in AXES]
        if bad or not self.channels:
            raise ValueError(f"mdt69x channels must be among {', '.join(AXES)} (got {bad})")
        self.baudrate = int(self.options.get("baudrate", 115200))
        self.timeout_s = float(self.options.get("timeout_s", 0.5))
        self.prompt = str(self.options.get("prompt", ">")).encode()
        self._serial = None
        self.vlimit = None

    @property
    def num_channels(self) -> int:
        return len(self.channels)

    def describe(self) -> str:
        return f"piezo {self.port}"

    def connect(self) -> None:
        import serial

        self.close()
        try:
            self._serial = serial.Serial(
                self.port, self.baudrate, timeout=self.timeout_s, write_timeout=self.timeout_s
            )
            self._serial.reset_input_buffer()
        except Exception as exc:
            self._serial = None
            raise InstrumentError(f"{self.describe()}: cannot open ({exc})") from None
        try:
            self._command("echo=0")
            self._command("id?")
            self.vlimit = self._query("vlimit?")
        except InstrumentError:
            self.close()
            raise

    def _command(self, text: str) -> str:
        """Send one command; the answer before the prompt (echo stripped)."""
        if self._serial is None:
            raise InstrumentError(f"{self.describe()}: not connected")
        try:
            self._serial.write(text.encode() + b"\r")
            answer = self._serial.read_until(self.prompt)
        except Exception as exc:
            raise InstrumentError(f"{self.describe()}: {text!r} failed ({exc})") from None
        if not answer.endswith(self.prompt):
            raise InstrumentError(
                f"{self.describe()}: no prompt after {text!r} within {self.timeout_s:g} s "
                f"(got {answer[-40:]!r})"
            )
        body = answer[: -len(self.prompt)].decode(errors="replace")
        if body.startswith(text):  # echo still on
            body = body[len(text) :]
        return body.strip()

    def _query(self, text: str) -> float:
        body = self._command(text)
        match = _VALUE.search(body)
        if match is None:
            raise InstrumentError(
                f"{self.describe()}: no value in the answer to {text!r}: {body!r}"
            )
        try:
            return float(match.group(1))
        except ValueError:
            raise InstrumentError(f"{self.describe()}: bad value for {text!r}: {body!r}") from None

    def set_voltages(self, volts: np.ndarray) -> None:
        volts = np.asarray(volts, dtype=np.float64)
        if volts.shape != (self.num_channels,) or not np.all(np.isfinite(volts)):
            raise InstrumentError(f"{self.describe()}: refusing voltages {volts!r}")
        for axis, v in zip(self.channels, volts, strict=True):
            body = self._command(f"{axis}voltage={v:.3f}")
            if body:  # a set is answered by the prompt alone; anything else is an error
                raise InstrumentError(f"{self.describe()}: {axis}voltage={v:.3f} -> {body!r}")

    def read_voltages(self) -> np.ndarray:
        return np.array([self._query(f"{axis}voltage?") for axis in self.channels])

    def close(self) -> None:
        if self._serial is not None:
            with contextlib.suppress(Exception):  # closing a dead port: nothing to release
                self._serial.close()
        self._serial = None
