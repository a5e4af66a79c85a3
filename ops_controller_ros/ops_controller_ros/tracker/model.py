"""The rig as the tracker models it: the stacker and optical period it fits with (replaced when the
calibration moves the optics), the per-entry weights of a reading, the set-point range, the delay
lines' lag, and the random walk and vibration the path fits assume (:mod:`.vibration`).
"""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
from ops_contract.config import SPEED_OF_LIGHT_NM_PER_FS

from . import fit
from .hysteresis import HysteresisCompensation
from .params import TrackerParams
from .vibration import ShakenStacker, told_vibration
from .weights import WeightedStacker, source_noise_weights
from .work import scaled


def at_wavelength(stacker, wavelength_nm: float):
    """``stacker`` (a :class:`~ops_sim_ros.physics.PulseStacker`) at another carrier wavelength:
    the same pulses, geometry and detector, so only the carrier's period and frequency change.
    Building a stacker anew (``stacker_from_config``) takes about a millisecond, and the period
    correction moves the wavelength after most readings of a window with a whole-cycle move;
    this copy takes microseconds and evaluates exactly as the new one would (the tracker's tests
    compare the two)."""
    out = copy.copy(stacker)
    out.wavelength_nm = float(wavelength_nm)
    out.optical_period_fs = out.wavelength_nm / SPEED_OF_LIGHT_NM_PER_FS
    out.omega0 = 2.0 * np.pi / out.optical_period_fs
    out._bits_t_complex = out._bits_t * (1j * out.omega0)
    out._buffers = {}  # scratch arrays of its own
    return out


def told_noise(params: TrackerParams, model) -> TrackerParams:
    """The parameters with the detector noise the rig's model implies (its detector noise and
    digitizer, :func:`ops_sim_ros.rig.reading_noise_std`, the digitizer's rounding weighed as
    ``quantization_noise_steps``) when that is more than assumed."""
    from ops_sim_ros.rig import reading_noise_std

    noise = 0.0
    if hasattr(model, "trace_adc_bits"):  # the source's noise is weighed per entry (.weights)
        quiet = replace(model, pulse_amplitude_noise=0.0)
        noise = reading_noise_std(quiet, params.quantization_noise_steps)
    return replace(params, detector_noise=noise) if noise > params.detector_noise else params


class RigModel:
    """The nominal ``config`` (an OpsConfig) as the fits see it. ``setpoint_range_fs``: (low (N,),
    high (N,)) the set-points each line can take (default: the model's +- actuator range);
    ``reach_fs``: how far the slowest line moves in one reading (None: any distance)."""

    def __init__(self, config, params: TrackerParams, setpoint_range_fs=None, reach_fs=None):
        from ops_sim_ros.physics import stacker_from_config
        from ops_sim_ros.rig import lag_gain

        self.config = config
        self.stage = int(config.stage)
        self.stacker = stacker_from_config(config)
        source_noise = float(getattr(config, "pulse_amplitude_noise", 0.0))
        floor = max(params.detector_noise, params.fit_noise_floor)
        self.weights = source_noise_weights(self.stage, source_noise, floor)
        # ... and the delay lines' vibration: the part a step does not keep is noise of every
        # reading, most of the stacked slot and the power, and shifts their mean (.vibration)
        self.vibration = told_vibration(params, config)
        self._shaken = None  # expected's, for the stacker now
        if self.vibration is not None and self.vibration.fast_var > 0.0:
            self._excursion = _tracking_excursion(params, self.stage)
            _, var = self.vibration.reading_moments(self.stacker, self._excursion)
            if self.weights is None:
                self.weights = np.ones(self.stacker.num_slots + 1)
            self.weights = self.weights * (floor**2 / (floor**2 + var)) ** 0.5
        if params.power_weight < 1.0:
            if self.weights is None:
                self.weights = np.ones(self.stacker.num_slots + 1)
            self.weights[-1] *= params.power_weight
        self._weighted = None  # fit_stacker's, for the stacker now
        self.period_fs = config.optical_period_fs
        self.range_cycles = config.actuator_range_cycles
        if setpoint_range_fs is None:
            reach = self.range_cycles * self.period_fs
            setpoint_range_fs = (np.full(self.stage, -reach), np.full(self.stage, reach))
        self.range_fs = tuple(
            np.asarray(r, dtype=np.float64).reshape(-1) for r in setpoint_range_fs
        )
        self.reach_fs = reach_fs
        self._bounds = (None, None, None)  # (period, low, high): the range in cycles
        # A command acts this many steps late: a reading is matched to the command in effect
        # then, and a command aims that far ahead.
        self.latency = int(getattr(config, "latency_steps", 0))
        # ... and the delay lines follow it at first order: a reading is matched to where they are
        lag = float(getattr(config, "actuator_lag_steps", 0.0))
        self.lag_gain = lag_gain(lag) if lag > 0.0 else None
        # ... through an open-loop piezo's hysteresis, which the commands undo (.hysteresis)
        self.compensation = HysteresisCompensation.told(config, params)
        w = params.walk_cycles
        # the path fits' random walk per step: by default six times the model's jitter, so that
        # a rig noisier than nominal is still followed; and the vibration the path follows
        self.walk_sigma = max(6.0 * config.jitter_sigma_cycles, 1e-4) if w is None else w
        if self.vibration is not None:
            self.walk_sigma = (self.walk_sigma**2 + self.vibration.walk_var) ** 0.5
        # One row (delay vector) the physics evaluates, in the work budget's unit (a row at
        # N = 5): its matrix product grows with the square of the patterns (2^N).
        self.work_scale = (self.stacker.num_patterns / 32.0) ** 2
        # A source told noisy moves the stacked slot, which the fits lean on: it counts as a
        # noisy detector, as does a detector noise told of at least told_noisy_threshold.
        source = source_noise > 0.0
        self.told_noisy = source or params.detector_noise >= params.told_noisy_threshold

    def arrival_sd(self, params: TrackerParams) -> float:
        """The std of the path fits' prior on a window's first errors (0: none): under a told
        vibration, ``vibration_arrival_cycles``."""
        return params.vibration_arrival_cycles if self.vibration is not None else 0.0

    @property
    def expected(self):
        """The model's expected reading: the stacker's, and under a vibration with a fast part,
        plus the mean that part's jitter adds (:class:`.vibration.ShakenStacker`); built once
        per stacker."""
        if self.vibration is None or self.vibration.fast_var <= 0.0:
            return self.stacker
        cached = self._shaken
        if cached is None or cached.inner is not self.stacker:
            bias, _ = self.vibration.reading_moments(self.stacker, self._excursion)
            cached = self._shaken = ShakenStacker(self.stacker, bias)
        return cached

    @property
    def fit_stacker(self):
        """The model as the fits see it: the expected readings (:attr:`expected`) weighed per
        entry (.weights); built once per stacker (the calibration replaces ``stacker`` when it
        adopts new optics)."""
        inner = self.expected
        if self.weights is None:
            return inner
        cached = self._weighted
        if cached is None or cached.inner is not inner:
            cached = self._weighted = WeightedStacker(inner, self.weights)
        return cached

    def weighed(self, y):
        """Readings scaled as :attr:`fit_stacker` scales its predictions."""
        return y if self.weights is None else y * self.weights

    def adopt(self, calibration) -> float:
        """Take the calibration's optics; returns the old period over the new (the same fs are
        this many new cycles per old one). A new wavelength alone (every period correction)
        retunes the stacker (:func:`at_wavelength`) instead of building it anew."""
        old_period = self.period_fs
        if calibration.pulse_fwhm_fs == self.stacker.pulse_fwhm_fs:
            self.stacker = at_wavelength(self.stacker, calibration.wavelength_nm)
        else:
            self.stacker = calibration.stacker()
        self.period_fs = self.stacker.optical_period_fs
        return old_period / self.period_fs

    def reading(self, power, pulse_energies) -> np.ndarray:
        """A reading as the fits take it: slot energies and power (S + 1,), checked."""
        if pulse_energies is None:
            raise ValueError("the tracker needs the detected pulse energies, not only the power")
        y = np.append(np.asarray(pulse_energies, dtype=np.float64).ravel(), float(power))
        if y.size != self.stacker.num_slots + 1 or not np.all(np.isfinite(y)):
            raise ValueError(
                f"expected {self.stacker.num_slots} finite pulse energies and a finite power"
            )
        return y

    def reachable(self, u: np.ndarray, position: np.ndarray) -> np.ndarray:
        """A command (cycles) that brings lines lagging at ``position`` to ``u`` in a step,
        within their range."""
        if self.lag_gain is not None:
            u = position + (u - position) / self.lag_gain
        if self._bounds[0] != self.period_fs:  # the range in cycles of the period now
            period = self.period_fs
            self._bounds = (period, self.range_fs[0] / period, self.range_fs[1] / period)
        return np.minimum(np.maximum(u, self._bounds[1]), self._bounds[2])  # (np.clip)

    def rest(self, setpoints_fs) -> np.ndarray:
        """The lines at rest on ``setpoints_fs``, where the hysteresis compensation starts; the
        set-points in cycles."""
        if self.compensation is not None:
            self.compensation.reset(setpoints_fs)
        return self.cycles(setpoints_fs)

    def wire(self, u: np.ndarray) -> np.ndarray:
        """The command ``u`` (cycles) as sent: fs, through the hysteresis compensation."""
        fs = u * self.period_fs
        return fs if self.compensation is None else self.compensation.drive(fs)

    def cycles(self, fs) -> np.ndarray:
        """Set-points in cycles of the model."""
        return np.asarray(fs, dtype=np.float64).reshape(self.stage) / self.period_fs

    def predict(self, x, u, age, drift) -> np.ndarray:
        """Readings (M, K, S + 1) for candidate present errors x (M, N) cycles, unweighed."""
        return fit.predict(self.expected, self.period_fs, x, u, age, drift)

    def cost(self, x, u, y, age, drift) -> np.ndarray:
        """Mean squared weighed residual (M,) of the readings for candidates x (M, N)."""
        return fit.cost(self.fit_stacker, self.period_fs, x, u, self.weighed(y), age, drift)

    def refine(self, x, u, y, age, drift, iterations: int):
        """:func:`.fit.refine` on the model now (a generator; its rows weighed, .work)."""
        y = self.weighed(y)
        job = fit.refine(self.fit_stacker, self.period_fs, x, u, y, age, drift, iterations)
        return scaled(job, self.work_scale)

    def slot_residuals(self, u, path, y) -> np.ndarray:
        """The slot energies predicted at the path (K, N) minus those read (K, S)."""
        energies, _ = self.expected.energies_and_power((u + path) * self.period_fs)
        return energies - y[:, :-1]


def _tracking_excursion(params: TrackerParams, n: int) -> np.ndarray:
    """A tracking excursion (N,) of the length the told noise sizes (:func:`.commands.
    hold_dither`), in the pattern's first direction: where the vibration's moments are taken."""
    from .commands import excursion, hold_dither

    return hold_dither(params, params.detector_noise**2, np.zeros(n)) * excursion(params, n, 0)
