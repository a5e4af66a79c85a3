"""Configuration of the optical pulse stacking (OPS) simulator.

One frozen dataclass, :class:`OpsConfig`, holds every number the physics, the noise and the
environment use. :func:`make_config` fills mode- and split-dependent defaults, applies overrides and
validates; it is the only supported way to build a configuration.

Units: times and delays in femtoseconds (fs), wavelengths in nanometres; noise, actuator and
initial-state figures are given in *optical cycles* (fractions of the optical period lambda/c), so
they keep their meaning when the wavelength changes. ``*_fs`` properties convert them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from typing import Any

SPEED_OF_LIGHT_NM_PER_FS = 299.792458  # c in nm/fs

MODES = ("easy", "medium", "hard")
SPLITS = ("train", "test")
MAX_STAGE = 10

# Drift defaults per (mode, split): (slope_min, slope_max) in cycles/step, (knot_min, knot_max) in
# steps. Only hard mode drifts; its test split drifts faster and changes direction more often, so a
# policy trained on "train" meets a shifted noise distribution on "test" (paper section 2.2).
_DRIFT_DEFAULTS = {
    ("hard", "train"): dict(
        drift_slope_min_cycles=0.0,
        drift_slope_max_cycles=0.01,
        drift_knot_min_steps=100,
        drift_knot_max_steps=300,
    ),
    ("hard", "test"): dict(
        drift_slope_min_cycles=0.005,
        drift_slope_max_cycles=0.015,
        drift_knot_min_steps=40,
        drift_knot_max_steps=120,
    ),
}
_NO_DRIFT = dict(
    drift_slope_min_cycles=0.0,
    drift_slope_max_cycles=0.0,
    drift_knot_min_steps=100,
    drift_knot_max_steps=300,
)
_INITIAL_RANGE = {"easy": 0.1, "medium": 0.5, "hard": 0.5}


@dataclass(frozen=True)
class OpsConfig:
    """Every parameter of one simulated stacker (see ``docs/physics.md``)."""

    # --- geometry and mode
    stage: int = 5
    mode: str = "medium"
    split: str = "train"
    # --- optics
    wavelength_nm: float = 1030.0
    pulse_fwhm_fs: float = 1000.0  # sech^2 intensity FWHM
    pulse_spacing_fs: float = 12.5e6  # T: 12.5 ns, an 80 MHz oscillator
    quadrature_points: int = 6  # K: time samples per slot for the energy / I^2 integrals
    # --- detection
    samples_per_slot: int = 8  # samples of the detected trace per pulse slot
    detector_noise: float = 0.0  # std of additive noise on detected pulse energies (normalized)
    # --- noise of the delay lines (eq. 2 / 4), in optical cycles
    jitter_sigma_cycles: float = 0.001
    drift_slope_min_cycles: float = 0.0
    drift_slope_max_cycles: float = 0.0
    drift_knot_min_steps: int = 100
    drift_knot_max_steps: int = 300
    drift_bound_cycles: float = 10.0
    # --- initial state and actuator
    initial_range_cycles: float = 0.5  # set-points start uniform in +- this (per stage)
    max_step_cycles: float = 0.02  # actuator: largest set-point change per control step
    actuator_range_cycles: float = 30.0  # set-points are clipped to +- this
    absolute_action_range_cycles: float = 1.0  # absolute actions in [-1, 1] map to +- this
    # --- episodes
    episode_steps: int = 200

    # ----------------------------------------------------------------- derived quantities
    @property
    def optical_period_fs(self) -> float:
        return self.wavelength_nm / SPEED_OF_LIGHT_NM_PER_FS

    def cycles_to_fs(self, cycles: float) -> float:
        return float(cycles) * self.optical_period_fs

    @property
    def jitter_sigma_fs(self) -> float:
        return self.cycles_to_fs(self.jitter_sigma_cycles)

    @property
    def max_step_fs(self) -> float:
        return self.cycles_to_fs(self.max_step_cycles)

    @property
    def actuator_range_fs(self) -> float:
        return self.cycles_to_fs(self.actuator_range_cycles)

    @property
    def initial_range_fs(self) -> float:
        return self.cycles_to_fs(self.initial_range_cycles)

    @property
    def absolute_action_range_fs(self) -> float:
        return self.cycles_to_fs(self.absolute_action_range_cycles)

    @property
    def drift_enabled(self) -> bool:
        return self.drift_slope_max_cycles > 0.0

    @property
    def num_slots(self) -> int:
        """Output slots that can hold light: the odd time slots 1, 3, .., 2^(N+1) - 3."""
        return 2**self.stage - 1

    @property
    def main_slot(self) -> int:
        """Index (in the output slots) of the stacked pulse, time slot 2^N - 1."""
        return 2 ** (self.stage - 1) - 1

    # ----------------------------------------------------------------- (de)serialization
    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OpsConfig:
        data = dict(data)
        stage = data.pop("stage", 5)
        mode = data.pop("mode", "medium")
        split = data.pop("split", "train")
        return make_config(stage=stage, mode=mode, split=split, **data)

    def replace(self, **changes: Any) -> OpsConfig:
        """A validated copy with some fields changed."""
        data = self.to_dict()
        data.update(changes)
        return OpsConfig.from_dict(data)


_FIELD_NAMES = tuple(f.name for f in fields(OpsConfig))
_INT_FIELDS = {
    "stage",
    "quadrature_points",
    "samples_per_slot",
    "drift_knot_min_steps",
    "drift_knot_max_steps",
    "episode_steps",
}


def _check(cond: bool, message: str) -> None:
    if not cond:
        raise ValueError(message)


def make_config(
    stage: int = 5, mode: str = "medium", split: str = "train", **overrides: Any
) -> OpsConfig:
    """Build a validated :class:`OpsConfig`.

    Defaults that depend on the mode (initial range, drift) and the split (hard-mode drift) are
    filled first; ``overrides`` (any field name of :class:`OpsConfig`) then replace them.
    Raises ``ValueError`` naming the offending parameter and what it may be.
    """
    _check(mode in MODES, f"mode must be one of {', '.join(MODES)} (got {mode!r})")
    _check(split in SPLITS, f"split must be one of {', '.join(SPLITS)} (got {split!r})")
    _check(
        isinstance(stage, int | float) and not isinstance(stage, bool) and int(stage) == stage,
        f"stage must be an integer from 1 to {MAX_STAGE} (got {stage!r})",
    )
    stage = int(stage)
    _check(1 <= stage <= MAX_STAGE, f"stage must be an integer from 1 to {MAX_STAGE} (got {stage})")
    unknown = sorted(set(overrides) - set(_FIELD_NAMES))
    _check(
        not unknown,
        f"unknown parameter(s) {', '.join(unknown)}; allowed: {', '.join(_FIELD_NAMES)}",
    )

    values: dict[str, Any] = dict(stage=stage, mode=mode, split=split)
    values["initial_range_cycles"] = _INITIAL_RANGE[mode]
    values.update(_DRIFT_DEFAULTS.get((mode, split), _NO_DRIFT))
    values.update(overrides)

    for name in _FIELD_NAMES:
        if name in ("mode", "split") or name not in values:
            continue
        v = values[name]
        if name in _INT_FIELDS:
            ok = isinstance(v, int | float) and not isinstance(v, bool) and float(v).is_integer()
            _check(ok, f"{name} must be an integer (got {v!r})")
            values[name] = int(v)
        else:
            ok = isinstance(v, int | float) and not isinstance(v, bool)
            _check(ok, f"{name} must be a number (got {v!r})")
            values[name] = float(v)
            _check(
                values[name] == values[name] and abs(values[name]) != float("inf"),
                f"{name} must be finite (got {v!r})",
            )

    cfg = OpsConfig(**values)
    positive = (
        "wavelength_nm",
        "pulse_fwhm_fs",
        "pulse_spacing_fs",
        "max_step_cycles",
        "actuator_range_cycles",
        "absolute_action_range_cycles",
        "drift_bound_cycles",
        "episode_steps",
    )
    for name in positive:
        _check(getattr(cfg, name) > 0, f"{name} must be > 0 (got {getattr(cfg, name)})")
    non_negative = (
        "detector_noise",
        "jitter_sigma_cycles",
        "drift_slope_min_cycles",
        "drift_slope_max_cycles",
        "initial_range_cycles",
    )
    for name in non_negative:
        _check(getattr(cfg, name) >= 0, f"{name} must be >= 0 (got {getattr(cfg, name)})")
    _check(
        2 <= cfg.quadrature_points <= 64,
        f"quadrature_points must be from 2 to 64 (got {cfg.quadrature_points})",
    )
    _check(
        2 <= cfg.samples_per_slot <= 256,
        f"samples_per_slot must be from 2 to 256 (got {cfg.samples_per_slot})",
    )
    _check(
        cfg.drift_slope_min_cycles <= cfg.drift_slope_max_cycles,
        "drift_slope_min_cycles must be <= drift_slope_max_cycles "
        f"(got {cfg.drift_slope_min_cycles} > {cfg.drift_slope_max_cycles})",
    )
    _check(
        1 <= cfg.drift_knot_min_steps <= cfg.drift_knot_max_steps,
        "drift_knot_min_steps must be >= 1 and <= drift_knot_max_steps "
        f"(got {cfg.drift_knot_min_steps}, {cfg.drift_knot_max_steps})",
    )
    _check(
        cfg.initial_range_cycles <= cfg.actuator_range_cycles,
        "initial_range_cycles must be <= actuator_range_cycles "
        f"(got {cfg.initial_range_cycles} > {cfg.actuator_range_cycles})",
    )
    # Walk-off sanity: the quadrature assumes slots are far apart compared with the pulses.
    _check(
        cfg.pulse_spacing_fs >= 20 * cfg.pulse_fwhm_fs,
        "pulse_spacing_fs must be >= 20 * pulse_fwhm_fs so pulses in neighbouring slots do not "
        f"overlap (got {cfg.pulse_spacing_fs} vs fwhm {cfg.pulse_fwhm_fs})",
    )
    return cfg
