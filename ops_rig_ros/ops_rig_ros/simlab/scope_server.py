"""A simulated oscilloscope: SCPI over a TCP socket (a raw SCPI port, as port 5025 of a lab
scope), Keysight-style waveform commands, records from :class:`~.optics.SimOptics`.

Understood (long or short forms, any case; one command per line, ``\\n``-terminated):
``*IDN?``, ``*RST``, ``:WAVeform:SOURce``, ``:WAVeform:FORMat BYTE|WORD``, ``:WAVeform:UNSigned``,
``:WAVeform:BYTeorder LSBFirst|MSBFirst``, ``:WAVeform:POINts``, ``:WAVeform:PREamble?``,
``:DIGitize`` (one acquisition), ``:WAVeform:DATA?`` (IEEE 488.2 definite-length block of the
last acquisition, then ``\\n``). For tests, faults on the next ``:WAVeform:DATA?`` answers:
``:SIMulate:FAULt SHORT|HEADER|NAN|SILENT|DROP [COUNT]`` (a short record, a bad block header,
a NaN y-increment in the preamble, no answer, a dropped connection) and
``:SIMulate:PAUSe SECONDS`` (the scope is gone: connections are dropped and refused).
"""

from __future__ import annotations

import socket
import socketserver
import threading
import time

import numpy as np

from .optics import SimOptics

_SHORT = {
    "WAVEFORM": "WAV",
    "SOURCE": "SOUR",
    "FORMAT": "FORM",
    "UNSIGNED": "UNS",
    "BYTEORDER": "BYT",
    "POINTS": "POIN",
    "PREAMBLE": "PRE",
    "DIGITIZE": "DIG",
    "SIMULATE": "SIM",
    "FAULT": "FAUL",
    "PAUSE": "PAUS",
}


def normalize(header: str) -> str:
    """The short form of a SCPI header (``:WAVeform:DATA?`` -> ``:WAV:DATA?``)."""
    up = header.upper()
    query = up.endswith("?")
    parts = up.rstrip("?").split(":")
    return ":".join(_SHORT.get(p, p) for p in parts) + ("?" if query else "")


def ieee_block(payload: bytes) -> bytes:
    n = str(len(payload))
    return b"#" + str(len(n)).encode() + n.encode() + payload


class ScopeState:
    """Settings and the last record of the simulated scope (shared by its connections)."""

    def __init__(self, optics: SimOptics, volts_range=(-0.1, 1.1)):
        self.optics = optics
        self.format = "BYTE"
        self.msb_first = False
        self.low, self.high = volts_range
        self.record = optics.acquire()
        self.faults: list[str] = []
        self.paused_until = 0.0
        self.lock = threading.Lock()
        self.data_queries = 0

    def preamble(self, nan: bool = False) -> str:
        levels = 256 if self.format == "BYTE" else 65536
        yinc = (self.high - self.low) / (levels - 1)
        yref = 0.0
        fmt = 0 if self.format == "BYTE" else 1
        yinc_text = "nan" if nan else f"{yinc:.9e}"
        return f"{fmt},2,{self.optics.points},1,1.0e-10,0.0,0,{yinc_text},{self.low:.6e},{yref:.1f}"

    def codes(self) -> bytes:
        levels = 256 if self.format == "BYTE" else 65536
        yinc = (self.high - self.low) / (levels - 1)
        codes = np.clip(np.round((self.record - self.low) / yinc), 0, levels - 1)
        if self.format == "BYTE":
            return codes.astype(np.uint8).tobytes()
        return codes.astype(">u2" if self.msb_first else "<u2").tobytes()


class _Handler(socketserver.StreamRequestHandler):
    def setup(self):
        super().setup()
        # As a scope's network stack: answers go out at once (no Nagle wait for an ACK).
        self.request.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def handle(self):
        state: ScopeState = self.server.state
        while True:
            if time.monotonic() < state.paused_until:
                return
            try:
                line = self.rfile.readline()
            except OSError:
                return
            if not line:
                return
            if time.monotonic() < state.paused_until:
                return
            for command in line.decode(errors="replace").strip().split(";"):
                if command.strip() and not self._command(state, command.strip()):
                    return

    def _send(self, data: bytes) -> bool:
        try:
            self.wfile.write(data)
            self.wfile.flush()
        except OSError:
            return False
        return True

    def _command(self, state: ScopeState, command: str) -> bool:
        header, _, arg = command.partition(" ")
        key = normalize(header.lstrip(":") if header.startswith("*") else header)
        arg = arg.strip().upper()
        with state.lock:
            if key == "*IDN?":
                return self._send(b"OPS,SimScope,0,1.0\n")
            if key == ":WAV:FORM":
                state.format = "WORD" if arg.startswith("WORD") else "BYTE"
            elif key == ":WAV:BYT":
                state.msb_first = arg.startswith("MSBF")
            elif key == ":DIG":
                state.record = state.optics.acquire()
            elif key == ":WAV:PRE?":
                nan = bool(state.faults) and state.faults[0] == "NAN"
                if nan:
                    state.faults.pop(0)
                return self._send((state.preamble(nan=nan) + "\n").encode())
            elif key == ":WAV:DATA?":
                state.data_queries += 1
                fault = state.faults.pop(0) if state.faults else None
                payload = state.codes()
                if fault == "SILENT":
                    return True
                if fault == "DROP":
                    return False
                if fault == "SHORT":
                    payload = payload[: len(payload) // 3]
                if fault == "HEADER":
                    return self._send(b"#9x1" + payload + b"\n")
                return self._send(ieee_block(payload) + b"\n")
            elif key == ":SIM:FAUL":
                kind, _, count = arg.partition(" ")
                state.faults = [kind] * int(count or 1)
            elif key == ":SIM:PAUS":
                state.paused_until = time.monotonic() + float(arg or 1.0)
                return False
            # Other settings (:WAV:SOUR, :WAV:UNS, :WAV:POIN, *RST, ...) are taken silently.
        return True


class _Server(socketserver.ThreadingTCPServer):
    allow_reuse_address = True
    daemon_threads = True

    def verify_request(self, request, client_address) -> bool:
        return time.monotonic() >= self.state.paused_until


class SimScope:
    """The simulated scope on 127.0.0.1:``port`` (0: a free one); ``resource`` for pyvisa."""

    def __init__(self, optics: SimOptics, port: int = 0, host: str = "127.0.0.1"):
        self.state = ScopeState(optics)
        self.server = _Server((host, port), _Handler)
        self.server.state = self.state
        self.host, self.port = self.server.server_address[:2]
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()

    @property
    def resource(self) -> str:
        return f"TCPIP::{self.host}::{self.port}::SOCKET"

    def fault(self, kind: str, count: int = 1) -> None:
        with self.state.lock:
            self.state.faults = [kind.upper()] * count

    def pause(self, seconds: float) -> None:
        with self.state.lock:
            self.state.paused_until = time.monotonic() + seconds

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def send_scpi(port: int, command: str, host: str = "127.0.0.1") -> None:
    """Send one command to a scope (e.g. a simlab's fault injection from a test)."""
    with socket.create_connection((host, port), timeout=5) as s:
        s.sendall(command.encode() + b"\n")
