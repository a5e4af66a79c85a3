"""A rig drawn anew for every episode (domain randomization: training on the rig).

:class:`RigRanges` holds, for some of the rig's figures (``config.RIG_KEYS``: latency, actuator,
digitizer, source, detector noise), an inclusive range ``(low, high)``. At each episode reset an
environment built with it (``OpsEnv(rig_randomize=...)``, ``train --rig-randomize``) draws one
value per figure from its own random stream: integers (``latency_steps``, ``dac_bits``,
``trace_adc_bits``, ``trace_averages``) uniformly from low..high inclusive, the others uniformly
in [low, high]. The figures not randomized stay those of the environment's configuration (its
``realism`` preset and ``--rig`` values). Ranges are checked against ``config.LIMITS``.

Written on the command line as ``KEY=LOW:HIGH`` (``latency_steps=0:2``), a fixed value as
``KEY=VALUE``, or a named set of ranges (:data:`RANGE_PRESETS`, e.g. ``lab``) that later items
override key by key. Pure: numpy only.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .config import IDEAL_ZERO, INT_FIELDS, LIMITS, RIG_KEYS

#: Named sets of ranges. ``lab``: the issue's "latency 0-2 steps and the other imperfections over
#: their ranges" around the ``lab`` preset (docs/physics.md, "Rig imperfections"): each range
#: holds the preset's value and reaches the realism sweep's harder figures (6-bit trace, 15 %
#: hysteresis, 3 % pulse noise). The digitizer's full scale and averaging are settings of the
#: scope, not imperfections: they stay the preset's.
RANGE_PRESETS: dict[str, dict[str, tuple[float, float]]] = {
    "lab": {
        "latency_steps": (0, 2),
        "actuator_lag_steps": (0.0, 0.5),
        "actuator_hysteresis": (0.0, 0.15),
        "dac_bits": (12, 16),
        "trace_adc_bits": (6, 12),
        "pulse_amplitude_noise": (0.0, 0.03),
        "burst_envelope": (0.0, 0.3),
        "detector_noise": (0.0, 0.004),
    },
}

OPTION = "--rig-randomize"


def _allowed(key: str) -> str:
    low, high = LIMITS[key]
    if key in IDEAL_ZERO:
        return f"0 ({IDEAL_ZERO[key]}) or from 1 to {high}"
    return f"from {low} to {high}"


def check_range(key: str, low: float, high: float) -> tuple[float, float]:
    """``(low, high)`` of one figure, checked (ValueError naming the key and its allowed
    range); integers for the integer figures."""
    where = f"{OPTION} {key}={low:g}:{high:g}"
    if key not in RIG_KEYS:
        raise ValueError(f"{OPTION} {key}: not a figure of the rig; allowed: {', '.join(RIG_KEYS)}")
    if not (np.isfinite(low) and np.isfinite(high)):
        raise ValueError(f"{where}: the bounds must be finite numbers")
    if low > high:
        raise ValueError(f"{where}: the low bound must not exceed the high bound")
    lo_lim, hi_lim = LIMITS[key]
    if key in IDEAL_ZERO:
        lo_lim = 0  # 0 (ideal) and 1..high: every integer in [0, high] is allowed
    if not (lo_lim <= low and high <= hi_lim):
        raise ValueError(f"{where}: {key} must be {_allowed(key)}")
    if key in INT_FIELDS:
        if not (float(low).is_integer() and float(high).is_integer()):
            raise ValueError(f"{where}: {key} is an integer: give whole numbers")
        return int(low), int(high)
    return float(low), float(high)


def _number(text: str, item: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ValueError(
            f"{OPTION} {item}: {text!r} is not a number (write KEY=LOW:HIGH, e.g. "
            "latency_steps=0:2)"
        ) from None


@dataclass(frozen=True)
class RigRanges:
    """Inclusive ranges of some of the rig's figures, drawn per episode (see the module)."""

    ranges: Mapping[str, tuple[float, float]]

    def __post_init__(self) -> None:
        checked = {k: check_range(k, *self.ranges[k]) for k in sorted(self.ranges)}
        object.__setattr__(self, "ranges", checked)

    def __bool__(self) -> bool:
        return bool(self.ranges)

    @classmethod
    def parse(cls, items: Iterable[str] | None) -> RigRanges:
        """From the command line's items: ``KEY=LOW:HIGH``, ``KEY=VALUE`` (fixed) or the name of
        a set of :data:`RANGE_PRESETS`; later items win key by key."""
        ranges: dict[str, tuple[float, float]] = {}
        for item in items or []:
            if item in RANGE_PRESETS:
                ranges.update(RANGE_PRESETS[item])
                continue
            if "=" not in item:
                raise ValueError(
                    f"{OPTION} {item!r}: write KEY=LOW:HIGH (e.g. latency_steps=0:2) or a named "
                    f"set: {', '.join(RANGE_PRESETS)}"
                )
            key, text = (s.strip() for s in item.split("=", 1))
            low, sep, high = text.partition(":")
            lo = _number(low, item)
            ranges[key] = (lo, _number(high, item) if sep else lo)
        return cls(ranges)

    @classmethod
    def from_value(cls, value: Any) -> RigRanges:
        """From a RigRanges, a mapping ``{key: (low, high)}`` (a model's metadata) or None."""
        if isinstance(value, RigRanges):
            return value
        return cls({k: tuple(v) for k, v in (value or {}).items()})

    def to_dict(self) -> dict[str, list[float]]:
        """``{key: [low, high]}`` (JSON; a model's metadata ``rig_randomize``)."""
        return {k: [lo, hi] for k, (lo, hi) in self.ranges.items()}

    def draw(self, rng: np.random.Generator) -> dict[str, float | int]:
        """One rig: a value per figure, drawn from ``rng`` in a fixed (sorted) order."""
        out: dict[str, float | int] = {}
        for key, (lo, hi) in self.ranges.items():
            if key in INT_FIELDS:
                out[key] = int(rng.integers(lo, hi + 1))
            else:
                out[key] = float(rng.uniform(lo, hi)) if hi > lo else float(lo)
        return out

    def bounds(self) -> tuple[dict[str, float], dict[str, float]]:
        """The rigs at every low and at every high bound (to check them against a config)."""
        return (
            {k: lo for k, (lo, _) in self.ranges.items()},
            {k: hi for k, (_, hi) in self.ranges.items()},
        )

    def max_latency(self, default: int = 0) -> int:
        """The largest latency the ranges draw (``default`` when latency is not drawn)."""
        return int(self.ranges.get("latency_steps", (default, default))[1])

    def describe(self) -> str:
        """``key=low:high ...`` as typed on the command line."""
        return " ".join(f"{k}={lo:g}:{hi:g}" for k, (lo, hi) in self.ranges.items())
