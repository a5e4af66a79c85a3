"""The one gate between commands and piezos: limits, slew rate and the fs <-> volts map.

Pure numpy (no rclpy). :class:`SafeDrive` is the only object that calls an actuator's
``set_voltages``; every voltage passes :func:`check_volts` there (finite, within each channel's
limits, within one slew step of the last sent), so a bug elsewhere cannot reach a piezo.
"""

from __future__ import annotations

import time

import numpy as np

from .drivers.base import DelayActuator, InstrumentError
from .rig_config import Calibration, Limits


class UnsafeVoltage(RuntimeError):
    """A voltage vector broke the limits (never sent)."""


def command_problem(values, stage: int) -> str | None:
    """Why a delay command (fs) cannot be used, or None."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (stage,):
        return f"expected {stage} delays (one per stage), got {arr.size}"
    if not np.all(np.isfinite(arr)):
        return f"non-finite delay at index {int(np.argmax(~np.isfinite(arr)))}"
    return None


def volts_for(command_fs, cal: Calibration) -> np.ndarray:
    """Drive voltages of delay set-points (fs, relative to nominal)."""
    return cal.zero_volts + np.asarray(command_fs, dtype=np.float64) / cal.fs_per_volt


def command_volts(values, stage: int, cal: Calibration, limits: Limits):
    """(drive voltages, None) of a delay command (fs), or (None, why it is refused): wrong
    length, non-finite, or a voltage outside a channel's limits (refused whole, never clipped:
    a set-point the rig cannot reach is a controller's error to hear about)."""
    problem = command_problem(values, stage)
    if problem:
        return None, problem
    volts = volts_for(values, cal)
    outside = np.flatnonzero((volts < limits.volts_min) | (volts > limits.volts_max))
    if outside.size:
        i = int(outside[0])
        return None, (
            f"stage {i + 1} set-point {float(np.asarray(values)[i]):.6g} fs needs "
            f"{volts[i]:.6g} V, outside its limits [{limits.volts_min[i]:g}, "
            f"{limits.volts_max[i]:g}] V"
        )
    return volts, None


def fs_for(volts, cal: Calibration) -> np.ndarray:
    """Delay set-points (fs) of drive voltages."""
    return (np.asarray(volts, dtype=np.float64) - cal.zero_volts) * cal.fs_per_volt


def clip_to_limits(volts, limits: Limits) -> tuple[np.ndarray, bool]:
    """``volts`` within the limits; and whether anything was clipped."""
    v = np.asarray(volts, dtype=np.float64)
    out = np.clip(v, limits.volts_min, limits.volts_max)
    return out, bool(np.any(out != v))


def slew_step(current, target, limits: Limits, dt: float) -> np.ndarray:
    """From ``current`` towards ``target`` by at most the slew rate times ``dt``."""
    max_step = limits.slew_volts_per_s * max(dt, 0.0)
    return current + np.clip(target - current, -max_step, max_step)


def check_volts(volts, limits: Limits, last=None, dt: float | None = None) -> None:
    """UnsafeVoltage unless finite, within limits and (given ``last``, ``dt``) within a slew
    step of ``last`` (plus a nanovolt of rounding)."""
    v = np.asarray(volts, dtype=np.float64)
    if v.shape != limits.volts_min.shape:
        raise UnsafeVoltage(f"{v.size} voltages for {limits.volts_min.size} channels")
    if not np.all(np.isfinite(v)):
        raise UnsafeVoltage(f"non-finite voltage {v}")
    if np.any(v < limits.volts_min) or np.any(v > limits.volts_max):
        raise UnsafeVoltage(f"voltage {v} outside the limits")
    if last is not None and dt is not None:
        allowed = limits.slew_volts_per_s * dt + 1e-9
        if np.any(np.abs(v - last) > allowed):
            raise UnsafeVoltage(f"step {v - last} V beyond the slew limit")


class SafeDrive:
    """The actuators of a rig (channels in stage order) behind the limits.

    ``move_towards(target)`` clips the target into the limits, takes one slew-limited step from
    the last voltages sent (time since the last step, at most ``max_dt``) and sends it. Until
    the voltages are known (after a connect: read back), nothing is sent.
    """

    def __init__(self, actuators: list[DelayActuator], limits: Limits, max_dt: float = 0.1):
        self.actuators = actuators
        self.limits = limits
        self.max_dt = float(max_dt)
        self.last_sent: np.ndarray | None = None
        self._last_time: float | None = None
        self.connected = False
        n = sum(a.num_channels for a in actuators)
        if n != limits.volts_min.size:
            raise ValueError(
                f"the actuators have {n} channels in all; the rig has {limits.volts_min.size} "
                "stages (one channel per stage)"
            )

    def connect(self) -> None:
        """Connect every drive and read the present voltages (InstrumentError on failure)."""
        try:
            for a in self.actuators:
                a.connect()
            present = np.concatenate([a.read_voltages() for a in self.actuators])
        except InstrumentError:
            self.close()
            raise
        # Outside the limits (the drive was left there by someone else): plan from the nearest
        # limit; the first step goes there.
        self.last_sent, _ = clip_to_limits(present, self.limits)
        self._last_time = time.monotonic()
        self.connected = True

    def _send(self, volts: np.ndarray) -> None:
        check_volts(volts, self.limits)
        i = 0
        try:
            for a in self.actuators:
                a.set_voltages(volts[i : i + a.num_channels])
                i += a.num_channels
        except InstrumentError:
            self.connected = False
            raise
        self.last_sent = volts.copy()

    def move_towards(self, target, now: float | None = None) -> np.ndarray:
        """One slew-limited step towards ``target`` (clipped into the limits); the voltages
        now applied. UnsafeVoltage for a non-finite target (nothing sent)."""
        if not self.connected or self.last_sent is None:
            raise InstrumentError("piezo drives not connected")
        target = np.asarray(target, dtype=np.float64)
        if target.shape != self.last_sent.shape or not np.all(np.isfinite(target)):
            raise UnsafeVoltage(f"bad target voltages {target}")
        now = time.monotonic() if now is None else now
        dt = min(now - self._last_time, self.max_dt)
        self._last_time = now
        target, _ = clip_to_limits(target, self.limits)
        step = slew_step(self.last_sent, target, self.limits, dt)
        if np.array_equal(step, self.last_sent):
            return self.last_sent.copy()
        self._send(step)
        return step.copy()

    def ramp_to(self, target, timeout_s: float = 30.0, period_s: float = 0.01) -> np.ndarray:
        """Slew to ``target`` and wait there (blocking; for calibration and parking)."""
        target, _ = clip_to_limits(target, self.limits)
        deadline = time.monotonic() + timeout_s
        while True:
            applied = self.move_towards(target)
            if np.allclose(applied, target, rtol=0.0, atol=1e-9):
                return applied
            if time.monotonic() > deadline:
                raise InstrumentError(f"ramp to {target} V did not finish in {timeout_s:g} s")
            time.sleep(period_s)

    def close(self) -> None:
        for a in self.actuators:
            a.close()
        self.connected = False
