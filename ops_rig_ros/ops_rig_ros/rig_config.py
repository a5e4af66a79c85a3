"""The rig YAML: which instruments, the safety limits and the calibration (docs/rig.md).

Pure Python (no rclpy). :func:`load_rig_config` validates everything a rig needs before any
instrument is touched and raises :class:`RigConfigError` naming the key and what it may be;
:func:`save_calibration` writes a calibration back into the file, keeping the other keys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from ops_contract.rig_file import RigFileError, parse_optics, read_rig_mapping

#: Where a trace's reading of no light comes from (``trace_baseline``; ops_rig_ros.trace).
BASELINES = ("record", "calibrated")

MAX_STAGE = 10
MAX_VOLTS = 1000.0  # no piezo drive of this project's kind goes beyond


class RigConfigError(ValueError):
    """The rig YAML cannot be used (the message names the key)."""


@dataclass
class Limits:
    """Per channel (one per stage): volts_min <= volts <= volts_max, at most slew_volts_per_s,
    park_volts on shutdown."""

    volts_min: np.ndarray
    volts_max: np.ndarray
    slew_volts_per_s: np.ndarray
    park_volts: np.ndarray


@dataclass
class Calibration:
    fs_per_volt: np.ndarray  # (N,) delay per volt of each channel, fs/V (sign included)
    zero_volts: np.ndarray  # (N,) voltage of each channel at the nominal stacking delay
    slot_positions: np.ndarray  # (2^N - 1,) record index of each pulse slot's centre
    detector_offset_volts: float  # detector reading of no light, V
    detector_full_volts: float  # reading of a perfectly stacked pulse above the offset, V


@dataclass
class RigConfig:
    path: Path
    stage: int
    rate_hz: float
    scope: dict
    actuators: list[dict]
    limits: Limits
    calibration: Calibration | None
    stale_s: float = 0.5
    sweep_span_volts: float = 12.0
    settle_reads: int = 1
    trace_baseline: str = "record"
    optics: dict = field(default_factory=dict)
    raw: dict = field(default_factory=dict)

    @property
    def num_slots(self) -> int:
        return 2**self.stage - 1


def _number(value, key: str, low=-math.inf, high=math.inf) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise RigConfigError(f"{key} must be a number (got {value!r})") from None
    if not (low <= x <= high):
        raise RigConfigError(f"{key} must be in [{low:g}, {high:g}] (got {value!r})")
    return x


def _choice(value, key: str, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise RigConfigError(f"{key} must be one of {', '.join(allowed)} (got {value!r})")
    return str(value)


def _per_channel(section: dict, name: str, n: int, where: str, required=True, **bounds):
    key = f"{where}.{name}"
    if name not in section or section[name] is None:
        if required:
            raise RigConfigError(f"{key} is required: one value per stage ({n}) or one for all")
        return None
    value = section[name]
    values = value if isinstance(value, list | tuple) else [value] * n
    if len(values) != n:
        raise RigConfigError(f"{key} must have {n} values (one per stage), got {len(values)}")
    return np.array([_number(v, f"{key}[{i}]", **bounds) for i, v in enumerate(values)])


def parse_limits(raw: dict, n: int) -> Limits:
    section = raw.get("limits")
    if not isinstance(section, dict):
        raise RigConfigError(
            "limits is required: volts_min, volts_max, slew_volts_per_s (per channel); "
            "no instrument is driven without them"
        )
    vmin = _per_channel(section, "volts_min", n, "limits", low=-MAX_VOLTS, high=MAX_VOLTS)
    vmax = _per_channel(section, "volts_max", n, "limits", low=-MAX_VOLTS, high=MAX_VOLTS)
    slew = _per_channel(section, "slew_volts_per_s", n, "limits", low=1e-6, high=1e6)
    if np.any(vmax <= vmin):
        i = int(np.argmax(vmax <= vmin))
        raise RigConfigError(f"limits.volts_max[{i}] must be above limits.volts_min[{i}]")
    park = _per_channel(
        section, "park_volts", n, "limits", required=False, low=-MAX_VOLTS, high=MAX_VOLTS
    )
    if park is None:
        park = vmin.copy()
    if np.any((park < vmin) | (park > vmax)):
        raise RigConfigError("limits.park_volts must lie within volts_min .. volts_max")
    return Limits(vmin, vmax, slew, park)


def parse_calibration(raw: dict, n: int) -> Calibration | None:
    section = raw.get("calibration")
    if not section:
        return None
    if not isinstance(section, dict):
        raise RigConfigError("calibration must be a mapping (written by calibrate)")
    k = _per_channel(section, "fs_per_volt", n, "calibration", low=-1e4, high=1e4)
    if np.any(np.abs(k) < 1e-6):
        raise RigConfigError("calibration.fs_per_volt must not be 0")
    zero = _per_channel(section, "zero_volts", n, "calibration", low=-MAX_VOLTS, high=MAX_VOLTS)
    slots = section.get("slot_positions")
    if not isinstance(slots, list) or len(slots) != 2**n - 1:
        raise RigConfigError(f"calibration.slot_positions must list {2**n - 1} record indices")
    positions = np.array(
        [_number(v, f"calibration.slot_positions[{i}]", low=0.0) for i, v in enumerate(slots)]
    )
    offset = _number(section.get("detector_offset_volts"), "calibration.detector_offset_volts")
    full = _number(section.get("detector_full_volts"), "calibration.detector_full_volts", low=1e-9)
    return Calibration(k, zero, positions, offset, full)


def load_rig_config(path) -> RigConfig:
    """The validated rig YAML at ``path``; RigConfigError naming the key when it is unusable."""
    path = Path(path)
    try:
        raw = read_rig_mapping(path)
    except RigFileError as exc:
        raise RigConfigError(str(exc)) from None
    if "stage" not in raw:
        raise RigConfigError("stage is required (number of stacking stages, 1 to 10)")
    stage = _number(raw["stage"], "stage", 1, MAX_STAGE)
    if stage != int(stage):
        raise RigConfigError(f"stage must be an integer from 1 to {MAX_STAGE}")
    n = int(stage)
    rate = _number(raw.get("rate_hz", 50.0), "rate_hz", 1.0, 1000.0)
    scope = raw.get("scope")
    if not isinstance(scope, dict) or "driver" not in scope:
        raise RigConfigError("scope is required, with its driver (e.g. driver: scpi_scope)")
    actuators = raw.get("actuators")
    if not isinstance(actuators, list) or not actuators:
        raise RigConfigError("actuators is required: a list of drives, e.g. driver: mdt69x")
    for i, a in enumerate(actuators):
        if not isinstance(a, dict) or "driver" not in a:
            raise RigConfigError(f"actuators[{i}] must be a mapping with its driver")
    try:  # the keys the controllers' nominal model reads too (ops_contract.rig_file)
        optics, _ = parse_optics(raw)
    except ValueError as exc:
        raise RigConfigError(str(exc)) from None
    return RigConfig(
        path=path,
        stage=n,
        rate_hz=rate,
        scope=scope,
        actuators=actuators,
        limits=parse_limits(raw, n),
        calibration=parse_calibration(raw, n),
        stale_s=_number(raw.get("stale_s", 0.5), "stale_s", 0.01, 60.0),
        sweep_span_volts=_number(raw.get("sweep_span_volts", 12.0), "sweep_span_volts", 0.1, 1e3),
        settle_reads=int(_number(raw.get("settle_reads", 1), "settle_reads", 1, 100)),
        trace_baseline=_choice(raw.get("trace_baseline", "record"), "trace_baseline", BASELINES),
        optics=optics,
        raw=raw,
    )


def calibration_dict(cal: Calibration) -> dict:
    return {
        "fs_per_volt": [round(float(v), 6) for v in cal.fs_per_volt],
        "zero_volts": [round(float(v), 5) for v in cal.zero_volts],
        "slot_positions": [round(float(v), 3) for v in cal.slot_positions],
        "detector_offset_volts": round(float(cal.detector_offset_volts), 6),
        "detector_full_volts": round(float(cal.detector_full_volts), 6),
    }


def save_calibration(path, cal: Calibration) -> None:
    """Write ``cal`` as the ``calibration`` section of the YAML at ``path`` (other keys kept;
    comments are not)."""
    path = Path(path)
    raw = yaml.safe_load(path.read_text()) or {}
    raw["calibration"] = calibration_dict(cal)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(yaml.safe_dump(raw, sort_keys=False))
    tmp.replace(path)
