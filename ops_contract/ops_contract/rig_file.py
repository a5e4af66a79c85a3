"""What a controller's nominal model takes from a rig YAML (docs/rig.md): the stage count, the
stacker's nominal optics (``optics.wavelength_nm``, ``optics.pulse_fwhm_fs``,
``optics.detector``) and how far a delay line can move in one reading (``rate_hz``,
``limits.slew_volts_per_s`` and the calibration's ``fs_per_volt``).

Here, in the package every other one depends on, so that ``ops_rig_ros`` (which writes and checks
the whole file) and the controller nodes (which must not depend on ``ops_rig_ros``) check these
keys alike. Pure Python; errors are :class:`RigFileError` naming the file and the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import yaml

from .config import DETECTORS, MAX_STAGE

#: The optics a rig YAML may leave out, and their values then (the simulator's defaults).
OPTICS_DEFAULTS = {"wavelength_nm": 1030.0, "pulse_fwhm_fs": 1000.0, "detector": "polarizer"}
#: Allowed ranges of the numeric optics (inclusive), as the tracker node's parameters.
OPTICS_LIMITS = {"wavelength_nm": (100.0, 20000.0), "pulse_fwhm_fs": (1.0, 1e6)}


class RigFileError(ValueError):
    """The rig YAML cannot be used (the message names the file and the key)."""


@dataclass(frozen=True)
class RigModel:
    """The nominal model's part of a rig YAML."""

    path: Path
    stage: int
    optics: dict  # wavelength_nm, pulse_fwhm_fs, detector: each given or its default
    given: tuple[str, ...]  # the optics keys the file gives
    calibrated: bool  # whether the file has a calibration section (calibrate has run)
    # The least delay, fs, that any stage's line moves in one reading at the slew limit
    # (slew / rate x |fs per volt|); None without a calibration.
    reach_fs_per_reading: float | None = None
    # The set-points (fs) each stage's line can take within its channel's voltage limits,
    # (low (N,), high (N,)); None without a calibration.
    setpoint_range_fs: tuple | None = None


def parse_optics(raw: dict) -> tuple[dict, tuple[str, ...]]:
    """The optics of a rig YAML's mapping ``raw``, checked, with defaults for the keys it leaves
    out; and the keys it gives. ValueError names the key and what it may be."""
    section = raw.get("optics")
    if section is None:
        return dict(OPTICS_DEFAULTS), ()
    if not isinstance(section, dict):
        raise ValueError("optics must be a mapping (wavelength_nm, pulse_fwhm_fs, detector)")
    unknown = sorted(set(section) - set(OPTICS_DEFAULTS))
    if unknown:
        raise ValueError(
            f"optics.{unknown[0]} is not a key of optics (allowed: {', '.join(OPTICS_DEFAULTS)})"
        )
    optics = dict(OPTICS_DEFAULTS)
    for key, (low, high) in OPTICS_LIMITS.items():
        if key not in section:
            continue
        value = section[key]
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if not ok or not low <= value <= high:
            allowed = f"a number in [{low:g}, {high:g}]"
            raise ValueError(f"optics.{key} must be {allowed} (got {value!r})")
        optics[key] = float(value)
    if "detector" in section:
        if section["detector"] not in DETECTORS:
            raise ValueError(
                f"optics.detector must be one of {', '.join(DETECTORS)} "
                f"(got {section['detector']!r})"
            )
        optics["detector"] = section["detector"]
    return optics, tuple(k for k in OPTICS_DEFAULTS if k in section)


def read_rig_mapping(path) -> dict:
    """The keys of the rig YAML at ``path``; RigFileError when it cannot be read, is not YAML
    or is not a mapping (the rig package's loader reads its files through this too)."""
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise RigFileError(f"cannot read the rig file {path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise RigFileError(f"the rig file {path} is not valid YAML: {exc}") from None
    if not isinstance(raw, dict):
        raise RigFileError(f"the rig file {path}: expected a mapping of keys")
    return raw


def read_rig_model(path) -> RigModel:
    """The stage and optics of the rig YAML at ``path``; RigFileError naming file and key."""
    path = Path(path)
    raw = read_rig_mapping(path)
    stage = raw.get("stage")
    if not isinstance(stage, int) or isinstance(stage, bool) or not 1 <= stage <= MAX_STAGE:
        raise RigFileError(
            f"the rig file {path}: stage must be an integer from 1 to {MAX_STAGE} (got {stage!r})"
        )
    try:
        optics, given = parse_optics(raw)
    except ValueError as exc:
        raise RigFileError(f"the rig file {path}: {exc}") from None
    try:
        reach, span = _line_reach_and_range(raw, stage)
    except ValueError as exc:
        raise RigFileError(f"the rig file {path}: {exc}") from None
    return RigModel(path, stage, optics, given, bool(raw.get("calibration")), reach, span)


def _numbers(value, key: str, n: int) -> list[float]:
    values = value if isinstance(value, list | tuple) else [value] * n
    if len(values) != n:
        raise ValueError(f"{key} must have {n} values (one per stage), got {len(values)}")
    for i, v in enumerate(values):
        if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
            raise ValueError(f"{key}[{i}] must be a number (got {v!r})")
    return [float(v) for v in values]


def _line_reach_and_range(raw: dict, n: int) -> tuple[float | None, tuple | None]:
    """What the calibration and the limits give the nominal model, each section read once:

    - the reach: slew / rate x |fs per volt|, least over the stages (fs per reading), None
      without ``fs_per_volt`` and ``slew_volts_per_s``;
    - the set-point range: (low, high) set-points per stage, fs, that the channels' limits allow
      through the calibration (fs = (volts - zero_volts) x fs_per_volt), None without
      ``fs_per_volt``, ``zero_volts``, ``volts_min`` and ``volts_max``.
    """
    calibration, limits = raw.get("calibration"), raw.get("limits")
    if not isinstance(calibration, dict) or not isinstance(limits, dict):
        return None, None
    given, limited = set(calibration), set(limits)
    has_reach = "fs_per_volt" in given and "slew_volts_per_s" in limited
    has_range = {"fs_per_volt", "zero_volts"} <= given and {"volts_min", "volts_max"} <= limited
    if not (has_reach or has_range):
        return None, None
    rate = _rate_hz(raw) if has_reach else None
    k = _numbers(calibration["fs_per_volt"], "calibration.fs_per_volt", n)
    reach = span = None
    if has_reach:
        slew = _numbers(limits["slew_volts_per_s"], "limits.slew_volts_per_s", n)
        reach = min(abs(a) * b for a, b in zip(k, slew, strict=True)) / rate
    if has_range:
        zero = _numbers(calibration["zero_volts"], "calibration.zero_volts", n)
        vmin = _numbers(limits["volts_min"], "limits.volts_min", n)
        vmax = _numbers(limits["volts_max"], "limits.volts_max", n)
        ends = [
            sorted(((a - z) * g, (b - z) * g))
            for a, b, z, g in zip(vmin, vmax, zero, k, strict=True)
        ]
        span = tuple(e[0] for e in ends), tuple(e[1] for e in ends)
    return reach, span


def _rate_hz(raw: dict) -> float:
    rate = raw.get("rate_hz", 50.0)
    if not isinstance(rate, int | float) or isinstance(rate, bool) or not 1.0 <= rate <= 1000.0:
        raise ValueError(f"rate_hz must be a number in [1, 1000] (got {rate!r})")
    return float(rate)
