"""A simulated MDT693B-style piezo controller on a pseudo-terminal (``os.openpty``): pyserial
opens ``device`` (e.g. ``/dev/pts/7``) as it would a USB serial port.

The protocol of :mod:`ops_rig_ros.drivers.mdt_piezo`: ``\\r``-terminated commands, an echo while
``echo`` is on (``echo=0`` / ``echo=1``), query answers in brackets, a ``>`` prompt after every
answer; ``xvoltage=V`` / ``xvoltage?`` (and y, z), ``vlimit?``, ``id?``, ``xmin?``/``xmax?``;
anything else answers ``CMD_NOT_DEFINED``. Voltages are clamped to ``[0, vlimit]`` as the unit
does, and every voltage received is recorded (``received``: (channel, volts) before clamping),
so tests can prove that nothing outside the rig's limits ever arrived.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
import tty

from .optics import SimOptics

AXES = ("x", "y", "z")


class SimPiezo:
    """``axes`` of ``optics`` channels ``first_channel, ...`` behind one simulated unit."""

    def __init__(
        self,
        optics: SimOptics,
        first_channel: int = 0,
        num_axes: int = 3,
        vlimit: float = 75.0,
        record_path=None,
    ):
        self.optics = optics
        self.first = int(first_channel)
        self.axes = AXES[:num_axes]
        self.vlimit = float(vlimit)
        self.volts = {a: 0.0 for a in self.axes}
        self.received: list[tuple[int, float]] = []
        self.echo = True
        self.silent = False
        self._record = open(record_path, "a") if record_path else None  # noqa: SIM115
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.device = os.ttyname(self._slave)
        for a in self.axes:
            self._apply(a, 0.0)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _apply(self, axis: str, volts: float) -> None:
        v = min(max(volts, 0.0), self.vlimit)
        self.volts[axis] = v
        self.optics.set_voltage(self.first + self.axes.index(axis), v)

    def _serve(self) -> None:
        buf = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.1)
            if not ready:
                continue
            try:
                data = os.read(self._master, 4096)
            except OSError:
                time.sleep(0.05)  # no reader on the other end right now
                continue
            buf += data
            while True:
                cut = min((i for i in (buf.find(b"\r"), buf.find(b"\n")) if i >= 0), default=-1)
                if cut < 0:
                    break
                line, buf = buf[:cut].decode(errors="replace").strip(), buf[cut + 1 :]
                if line and not self.silent:
                    self._write(self._answer(line))

    def _write(self, text: str) -> None:
        with contextlib.suppress(OSError):
            os.write(self._master, text.encode())

    def _answer(self, line: str) -> str:
        echo = line + "\r" if self.echo else ""
        cmd = line.lower()
        if cmd.startswith("echo="):
            self.echo = cmd[5:].strip() not in ("0", "off")
            return ("" if not self.echo else echo) + ">"
        if cmd == "id?":
            return echo + "Model MDT693B Piezo Control Module (simulated)\r>"
        if cmd == "vlimit?":
            return echo + f"[{self.vlimit:5.0f}]\r>"
        if len(cmd) > 1 and cmd[0] in self.axes:
            axis, rest = cmd[0], cmd[1:]
            if rest == "voltage?":
                return echo + f"[{self.volts[axis]:7.2f}]\r>"
            if rest in ("min?", "max?"):
                return echo + f"[{0.0 if rest == 'min?' else self.vlimit:7.2f}]\r>"
            if rest.startswith("voltage="):
                try:
                    v = float(rest[8:])
                except ValueError:
                    return echo + "CMD_ARG_INVALID\r>"
                channel = self.first + self.axes.index(axis)
                self.received.append((channel, v))
                if self._record is not None:
                    self._record.write(f"{time.time():.4f} {channel} {v!r}\n")
                    self._record.flush()
                if v != v:  # NaN: a real unit refuses it
                    return echo + "CMD_ARG_INVALID\r>"
                self._apply(axis, v)
                return echo + ">"
        return echo + "CMD_NOT_DEFINED\r>"

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self._record is not None:
            self._record.close()
