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

MODES = ("easy", "medium", "hard", "extreme")
SPLITS = ("train", "test")
DETECTORS = ("polarizer", "total")
REALISMS = ("ideal", "lab")
#: What a control step is (docs/physics.md, "Physical time"): ``step``, the paper's noise per
#: step whatever the step lasts; ``seconds``, the noise of ``step_s`` seconds of physical time.
TIME_BASES = ("step", "seconds")
#: The delay lines' vibration (ops_sim_ros.vibration): none, or a preset of lines and a floor.
VIBRATIONS = ("none", "lab", "open")
#: The paper's control step (appendix C: ~0.1 s per interaction of a real stacker): under
#: ``time_base`` seconds, the figures counted per step are per this much physical time.
REFERENCE_STEP_S = 0.1
MAX_STAGE = 10
#: Inclusive (low, high) of the fields a user sets most (node parameters, ``--env``): the one
#: rule that make_config, the simulator node's parameter descriptors and the docs follow.
LIMITS = {
    "samples_per_slot": (1, 64),
    "quadrature_points": (2, 64),
    "detector_noise": (0.0, 1.0),
    "detector_gain": (0.01, 100.0),
    "detector_offset": (-1.0, 1.0),
    "jitter_sigma_cycles": (0.0, 1.0),
    "drift_slope_min_cycles": (0.0, 1.0),
    "drift_slope_max_cycles": (0.0, 1.0),
    "drift_turn_s": (0.0, 3600.0),
    "initial_sigma_cycles": (0.0, 10.0),
    "actuator_range_cycles": (0.0, 1000.0),
    # the rig between controller and optics (ops_sim_ros.rig, docs/physics.md)
    "latency_steps": (0, 1000),
    "actuator_lag_steps": (0.0, 1000.0),
    "actuator_hysteresis": (0.0, 0.99),
    "dac_bits": (0, 32),
    "trace_adc_bits": (0, 32),
    "trace_full_scale": (1e-6, 1e6),
    "trace_averages": (1, 10000),
    # the source (ops_sim_ros.source): pulse-to-pulse energy noise and the burst's droop
    "pulse_amplitude_noise": (0.0, 0.3),
    "burst_envelope": (0.0, 0.9),
    # the control period (physical time): 10 us to 10 s
    "step_s": (1e-5, 10.0),
}
#: What a value of 0 means where it is allowed below the usual range (the error messages say it).
IDEAL_ZERO = {"dac_bits": "an ideal DAC", "trace_adc_bits": "an ideal trace"}

# The rig presets (``realism``): each fills these fields unless they are given. ``ideal`` is the
# ideal stacker (no rig between controller and optics); ``lab`` a typical lab's rig
# (docs/physics.md, "Rig imperfections", gives each value's source).
REALISM_PRESETS = {
    "ideal": dict(
        latency_steps=0,
        actuator_lag_steps=0.0,
        actuator_hysteresis=0.0,
        dac_bits=0,
        trace_adc_bits=0,
        trace_full_scale=1.0,
        trace_averages=1,
        pulse_amplitude_noise=0.0,
        burst_envelope=0.0,
    ),
    "lab": dict(
        latency_steps=1,
        actuator_lag_steps=0.3,
        actuator_hysteresis=0.12,
        dac_bits=16,
        trace_adc_bits=8,
        trace_full_scale=1.25,
        trace_averages=1,
        pulse_amplitude_noise=0.01,
        burst_envelope=0.2,
        detector_noise=0.002,
    ),
}
#: The figures of the rig between controller and optics (``evaluate --rig``, docs/physics.md):
#: the presets' keys.
RIG_KEYS = (*REALISM_PRESETS["ideal"], "detector_noise")
#: The keys of physical time (time base, control period, vibration): OpsConfig fields that
#: ``--env`` and ``--rig`` take besides the rig's figures (not drawn by rig randomization).
TIME_KEYS = ("time_base", "step_s", "vibration")

# Each mode's initial delay errors and drift, after the authors' code (docs/physics.md, "Modes").
# Initial error per stage: normal(0, initial_sigma_cycles) clipped at +- initial_clip_sigmas sigma,
# plus (hard, extreme) one per-episode offset shared by all stages, uniform in
# +- initial_offset_sigmas sigma. Drift: the mean mu of each step's delay increment, in cycles per
# step; |mu| uniform in [drift_slope_min_cycles, drift_slope_max_cycles] with a random sign.
_MODE_DEFAULTS = {
    "easy": dict(initial_sigma_cycles=0.16, initial_offset_sigmas=0.0),
    "medium": dict(initial_sigma_cycles=0.26, initial_offset_sigmas=0.0),
    "hard": dict(initial_sigma_cycles=0.30, initial_offset_sigmas=1.0),
    "extreme": dict(initial_sigma_cycles=0.30, initial_offset_sigmas=1.0),
}
# Drift per (mode, split). hard: the paper's slow drift, one mu per episode shared by all stages
# and constant within the episode (drift_knot_*_steps = 0); its test split draws |mu| from a range
# shifted upwards (mean |mu| twice the training one, a third of the test episodes drift faster
# than any training episode: the train/test shift of section 2.2). extreme (beyond the paper):
# a slope per stage, redrawn every drift_knot_min..max steps, 10-15x the paper's drift.
_DRIFT_DEFAULTS = {
    ("hard", "train"): dict(drift_slope_min_cycles=0.0, drift_slope_max_cycles=0.001),
    ("hard", "test"): dict(drift_slope_min_cycles=0.0005, drift_slope_max_cycles=0.0015),
    ("extreme", "train"): dict(
        drift_slope_min_cycles=0.0,
        drift_slope_max_cycles=0.01,
        drift_per_stage=True,
        drift_knot_min_steps=100,
        drift_knot_max_steps=300,
    ),
    ("extreme", "test"): dict(
        drift_slope_min_cycles=0.005,
        drift_slope_max_cycles=0.015,
        drift_per_stage=True,
        drift_knot_min_steps=40,
        drift_knot_max_steps=120,
    ),
}


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
    detector: str = "polarizer"  # "polarizer" (s port) or "total" (both polarizations)
    samples_per_slot: int = 8  # samples of the detected trace per pulse slot
    detector_noise: float = 0.0  # std of additive noise on detected pulse energies (normalized)
    detector_gain: float = 1.0  # detected energies = gain * true + offset (+ noise); power exact
    detector_offset: float = 0.0
    # --- noise of the delay lines (eq. 2 / 4), in optical cycles: a random walk whose step is
    # N(mu, jitter_sigma) (the zero-mean part clipped at +- jitter_clip_sigmas sigma)
    jitter_sigma_cycles: float = 0.001
    jitter_clip_sigmas: float = 3.0
    drift_slope_min_cycles: float = 0.0  # |mu| range, cycles per step
    drift_slope_max_cycles: float = 0.0
    drift_per_stage: bool = False  # False: one mu shared by all stages
    drift_knot_min_steps: int = 0  # 0: mu drawn at each reset, constant within the episode
    drift_knot_max_steps: int = 0  # > 0: mu redrawn every knot_min..knot_max steps
    drift_bound_cycles: float = 10.0  # the accumulated drift turns back at +- this
    # 0: the drift turns back at the bound in one step; > 0: its slope reverses smoothly over
    # this many seconds (0.1 s a step under time_base step), as a lab's thermal drift turns
    drift_turn_s: float = 0.0
    # --- initial state (the hidden delay errors at reset; set-points start at 0) and actuator
    initial_sigma_cycles: float = 0.26
    initial_clip_sigmas: float = 2.0
    initial_offset_sigmas: float = 0.0
    max_step_cycles: float = 0.02  # actuator: largest set-point change per control step
    actuator_range_cycles: float = 30.0  # set-points are clipped to +- this
    absolute_action_range_cycles: float = 1.0  # absolute actions in [-1, 1] map to +- this
    # --- episodes
    episode_steps: int = 200
    # --- the rig between controller and optics (ops_sim_ros.rig); ideal by default
    realism: str = "ideal"  # the preset the fields below start from (REALISM_PRESETS)
    latency_steps: int = 0  # a command acts this many steps after the reading it answered
    actuator_lag_steps: float = 0.0  # first-order response of the delay line, steps
    actuator_hysteresis: float = 0.0  # open-loop piezo: loop width, fraction of the travel
    dac_bits: int = 0  # the drive's DAC over the actuator range (0: ideal)
    trace_adc_bits: int = 0  # the trace's digitizer (0: ideal)
    trace_full_scale: float = 1.0  # the digitizer's full scale, normalized energy (clipped)
    trace_averages: int = 1  # acquisitions averaged per reading
    # --- the source (ops_sim_ros.source); ideal by default
    pulse_amplitude_noise: float = 0.0  # rms pulse-to-pulse energy noise, fraction (per step)
    burst_envelope: float = 0.0  # droop of pulse energy from the burst's first to its last pulse
    # --- physical time (docs/physics.md, "Physical time and vibration")
    time_base: str = "step"  # "step": noise per step (the paper's); "seconds": per step_s of time
    step_s: float = REFERENCE_STEP_S  # the control period, s (drift knots, vibration's clock)
    vibration: str = "none"  # "none", or a preset of ops_sim_ros.vibration: "lab", "open"

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
    def initial_sigma_fs(self) -> float:
        return self.cycles_to_fs(self.initial_sigma_cycles)

    @property
    def initial_bound_cycles(self) -> float:
        """Largest initial delay error per stage (clip plus offset), optical cycles."""
        return self.initial_sigma_cycles * (self.initial_clip_sigmas + self.initial_offset_sigmas)

    @property
    def absolute_action_range_fs(self) -> float:
        return self.cycles_to_fs(self.absolute_action_range_cycles)

    @property
    def ideal_actuator(self) -> bool:
        """Commands act at once, exactly, on the delay lines."""
        return (
            self.latency_steps == 0
            and self.actuator_lag_steps == 0.0
            and self.actuator_hysteresis == 0.0
            and self.dac_bits == 0
        )

    @property
    def ideal_digitizer(self) -> bool:
        """The detected energies are reported as they are (with the detector's noise)."""
        return self.trace_adc_bits == 0 and self.trace_averages == 1

    @property
    def time_scale(self) -> float:
        """Physical time of a step over the paper's (``REFERENCE_STEP_S``) under ``time_base``
        seconds; 1 under ``step``. The random walk's variance per step and the drift per step
        scale with it, the steps between drift knots with its inverse."""
        return self.step_s / REFERENCE_STEP_S if self.time_base == "seconds" else 1.0

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
        if "initial_range_cycles" in data:
            raise ValueError(
                "this configuration is from before the seed's stacker architecture and modes "
                "(it has initial_range_cycles): a model trained on it does not apply to this "
                "physics; train it again"
            )
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
    "latency_steps",
    "dac_bits",
    "trace_adc_bits",
    "trace_averages",
}
#: The integer fields (public: :mod:`ops_contract.rig_randomization` draws integers for them).
INT_FIELDS = frozenset(_INT_FIELDS)
_BOOL_FIELDS = {"drift_per_stage"}
_STR_FIELDS = {
    "mode": MODES,
    "split": SPLITS,
    "detector": DETECTORS,
    "realism": REALISMS,
    "time_base": TIME_BASES,
    "vibration": VIBRATIONS,
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

    realism = overrides.get("realism", "ideal")
    _check(realism in REALISMS, f"realism must be one of {', '.join(REALISMS)} (got {realism!r})")
    values: dict[str, Any] = dict(stage=stage, mode=mode, split=split)
    values.update(_MODE_DEFAULTS[mode])
    values.update(_DRIFT_DEFAULTS.get((mode, split), {}))
    values.update(REALISM_PRESETS[realism])
    values.update(overrides)

    _check_types(values)
    cfg = OpsConfig(**values)
    _check_ranges(cfg)
    return cfg


def _check_types(values: dict[str, Any]) -> None:
    """Check each field's type in place (ints and floats normalized)."""
    for name in _FIELD_NAMES:
        if name not in values:
            continue
        v = values[name]
        if name in _STR_FIELDS:
            allowed = _STR_FIELDS[name]
            _check(v in allowed, f"{name} must be one of {', '.join(allowed)} (got {v!r})")
        elif name in _BOOL_FIELDS:
            _check(isinstance(v, bool), f"{name} must be true or false (got {v!r})")
        elif name in _INT_FIELDS:
            ok = isinstance(v, int | float) and not isinstance(v, bool) and float(v).is_integer()
            _check(ok, f"{name} must be an integer (got {v!r})")
            values[name] = int(v)
        else:
            ok = isinstance(v, int | float) and not isinstance(v, bool)
            _check(ok, f"{name} must be a number (got {v!r})")
            values[name] = float(v)
            limits = f" from {LIMITS[name][0]} to {LIMITS[name][1]}" if name in LIMITS else ""
            _check(
                values[name] == values[name] and abs(values[name]) != float("inf"),
                f"{name} must be a finite number{limits} (got {v!r})",
            )


def _check_ranges(cfg: OpsConfig) -> None:
    """Check ranges and relations between fields."""
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
        "jitter_clip_sigmas",
        "drift_slope_min_cycles",
        "drift_slope_max_cycles",
        "initial_sigma_cycles",
        "initial_clip_sigmas",
        "initial_offset_sigmas",
    )
    for name in non_negative:
        _check(getattr(cfg, name) >= 0, f"{name} must be >= 0 (got {getattr(cfg, name)})")
    for name, (low, high) in LIMITS.items():
        value = getattr(cfg, name)
        if name in IDEAL_ZERO:
            _check(
                value == 0 or 1 <= value <= high,
                f"{name} must be 0 ({IDEAL_ZERO[name]}) or from 1 to {high} (got {value})",
            )
            continue
        _check(low <= value <= high, f"{name} must be from {low} to {high} (got {value})")
    _check(
        cfg.drift_slope_min_cycles <= cfg.drift_slope_max_cycles,
        "drift_slope_min_cycles must be <= drift_slope_max_cycles "
        f"(got {cfg.drift_slope_min_cycles} > {cfg.drift_slope_max_cycles})",
    )
    _check(
        cfg.drift_knot_min_steps == cfg.drift_knot_max_steps == 0
        or 1 <= cfg.drift_knot_min_steps <= cfg.drift_knot_max_steps,
        "drift_knot_min_steps and drift_knot_max_steps must both be 0 (one drift per episode) or "
        "1 <= drift_knot_min_steps <= drift_knot_max_steps "
        f"(got {cfg.drift_knot_min_steps}, {cfg.drift_knot_max_steps})",
    )
    # Walk-off sanity: the quadrature assumes slots are far apart compared with the pulses.
    _check(
        cfg.pulse_spacing_fs >= 20 * cfg.pulse_fwhm_fs,
        "pulse_spacing_fs must be >= 20 * pulse_fwhm_fs so pulses in neighbouring slots do not "
        f"overlap (got {cfg.pulse_spacing_fs} vs fwhm {cfg.pulse_fwhm_fs})",
    )
