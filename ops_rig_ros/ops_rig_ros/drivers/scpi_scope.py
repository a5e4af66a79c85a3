"""An oscilloscope over SCPI through pyvisa (pyvisa-py backend, ``@py``), Keysight style.

Resource: ``TCPIP::HOST::PORT::SOCKET`` (raw SCPI socket, e.g. port 5025) or
``TCPIP::HOST::INSTR`` (VXI-11). Set-up on connect::

    *IDN?                                  (logged; any answer)
    :WAVeform:SOURce CHANnel<channel>
    :WAVeform:FORMat BYTE|WORD             (option ``format``, default BYTE)
    :WAVeform:UNSigned ON
    :WAVeform:BYTeorder LSBFirst|MSBFirst  (option ``byte_order``, WORD only)
    :WAVeform:POINts <points>              (option ``points``, when given)
    :WAVeform:PREamble?                    format, type, points, count, xincrement, xorigin,
                                           xreference, yincrement, yorigin, yreference

Per record: ``:DIGitize CHANnel<channel>`` (option ``digitize``, default true: one fresh
acquisition per record) with ``:WAVeform:PREamble?`` in the same message (the scale of this
very record, even after someone turned a knob), then ``:WAVeform:DATA?``, an IEEE 488.2
definite-length block (``#<n><length><data>``) read by pyvisa's ``query_binary_values``; volts:
``(code - yreference) * yincrement + yorigin``. A record whose length differs from the
preamble's, a bad block header, a non-finite scale or value, a timeout or a dropped connection
raise :class:`InstrumentError`; the rig then closes the session and connects again.
"""

from __future__ import annotations

import contextlib
import math

import numpy as np

from .base import InstrumentError, TraceSource, Waveform

PREAMBLE_FIELDS = (
    "format",
    "type",
    "points",
    "count",
    "xincrement",
    "xorigin",
    "xreference",
    "yincrement",
    "yorigin",
    "yreference",
)
FORMATS = {"BYTE": ("B", 0), "WORD": ("H", 1)}  # name -> (struct code, preamble format number)


def parse_preamble(text: str) -> dict:
    """The ten fields of a ``:WAVeform:PREamble?`` answer; InstrumentError when malformed."""
    fields = text.strip().split(",")
    if len(fields) != 10:
        raise InstrumentError(f"bad waveform preamble ({len(fields)} fields): {text[:80]!r}")
    try:
        values = [float(f) for f in fields]
    except ValueError:
        raise InstrumentError(f"bad waveform preamble (not numbers): {text[:80]!r}") from None
    names = PREAMBLE_FIELDS
    pre = dict(zip(names, values, strict=True))
    for key in ("xincrement", "yincrement", "yorigin", "yreference"):
        if not math.isfinite(pre[key]):
            raise InstrumentError(f"bad waveform preamble: {key} is {pre[key]}")
    if pre["points"] < 1 or pre["yincrement"] == 0.0:
        raise InstrumentError(f"bad waveform preamble: {text[:80]!r}")
    return pre


def scale_codes(codes: np.ndarray, pre: dict) -> np.ndarray:
    """Volts from the scope's integer codes and its preamble."""
    return (codes.astype(np.float64) - pre["yreference"]) * pre["yincrement"] + pre["yorigin"]


class ScpiScope(TraceSource):
    """Options: ``resource`` (required), ``channel`` (1), ``format`` (BYTE or WORD),
    ``byte_order`` (LSBFirst or MSBFirst), ``points`` (leave the scope's), ``timeout_ms``
    (1000), ``digitize`` (true)."""

    def __init__(self, options: dict):
        super().__init__(options)
        if "resource" not in self.options:
            raise ValueError("scope.resource is required (e.g. TCPIP::127.0.0.1::5025::SOCKET)")
        self.resource = str(self.options["resource"])
        self.channel = int(self.options.get("channel", 1))
        self.format = str(self.options.get("format", "BYTE")).upper()
        if self.format not in FORMATS:
            raise ValueError(f"scope.format must be one of {', '.join(FORMATS)}")
        self.byte_order = str(self.options.get("byte_order", "LSBFirst"))
        if self.byte_order not in ("LSBFirst", "MSBFirst"):
            raise ValueError("scope.byte_order must be LSBFirst or MSBFirst")
        self.timeout_ms = int(self.options.get("timeout_ms", 1000))
        self.digitize = bool(self.options.get("digitize", True))
        self.points = self.options.get("points")
        self._inst = None
        self._rm = None
        self.preamble: dict | None = None
        self.idn = ""

    def describe(self) -> str:
        return f"scope {self.resource}"

    def connect(self) -> None:
        import pyvisa

        self.close()
        try:
            self._rm = pyvisa.ResourceManager("@py")
            inst = self._rm.open_resource(self.resource, open_timeout=self.timeout_ms)
            inst.timeout = self.timeout_ms
            inst.read_termination = "\n"
            inst.write_termination = "\n"
            self._inst = inst
            self.idn = inst.query("*IDN?").strip()
            inst.write(f":WAVeform:SOURce CHANnel{self.channel}")
            inst.write(f":WAVeform:FORMat {self.format}")
            inst.write(":WAVeform:UNSigned ON")
            if self.format == "WORD":
                inst.write(f":WAVeform:BYTeorder {self.byte_order}")
            if self.points is not None:
                inst.write(f":WAVeform:POINts {int(self.points)}")
            self.preamble = parse_preamble(inst.query(":WAVeform:PREamble?"))
        except InstrumentError:
            self.close()
            raise
        except Exception as exc:  # pyvisa's VisaIOError, OSError, ... : the scope is not there
            self.close()
            raise InstrumentError(f"{self.describe()}: cannot connect ({_why(exc)})") from None
        if int(self.preamble["format"]) != FORMATS[self.format][1]:
            self.close()
            raise InstrumentError(f"{self.describe()}: scope did not take format {self.format}")

    def read(self) -> Waveform:
        if self._inst is None or self.preamble is None:
            raise InstrumentError(f"{self.describe()}: not connected")
        code, _ = FORMATS[self.format]
        try:
            # One message (SCPI compound command): a write alone followed by a query waits
            # out the peer's delayed ACK (Nagle) on TCP, ~40 ms.
            digitize = f":DIGitize CHANnel{self.channel};" if self.digitize else ""
            preamble_text = self._inst.query(digitize + ":WAVeform:PREamble?")
            codes = self._inst.query_binary_values(
                ":WAVeform:DATA?",
                datatype=code,
                is_big_endian=self.format == "WORD" and self.byte_order == "MSBFirst",
                container=np.array,
                header_fmt="ieee",
                expect_termination=True,
            )
        except Exception as exc:
            raise InstrumentError(
                f"{self.describe()}: waveform read failed ({_why(exc)})"
            ) from None
        try:
            self.preamble = parse_preamble(preamble_text)
        except InstrumentError as exc:
            raise InstrumentError(f"{self.describe()}: {exc}") from None
        expected = int(self.preamble["points"])
        if codes.size != expected:
            raise InstrumentError(
                f"{self.describe()}: short waveform ({codes.size} points, preamble says {expected})"
            )
        volts = scale_codes(codes, self.preamble)
        if not np.all(np.isfinite(volts)):
            raise InstrumentError(f"{self.describe()}: non-finite values in the waveform")
        return Waveform(volts=volts, x_increment_s=float(self.preamble["xincrement"]))

    def close(self) -> None:
        for thing in (self._inst, self._rm):
            if thing is not None:
                with contextlib.suppress(Exception):  # a dead session: nothing to release
                    thing.close()
        self._inst = None
        self._rm = None


def _why(exc: Exception) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0][:160]
