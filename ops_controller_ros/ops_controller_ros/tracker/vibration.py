"""The delay lines' vibration as the tracker's fits see it: a part the path follows and a part
that is noise of each reading, split by how much of it one loop step keeps.

A reading at step t sees each line's error X_t = S_t + V_t: S the random walk and drift the path
fits model, V the vibration (:mod:`ops_sim_ros.vibration`: lines and a floor, sinusoids at random
phases). Each of V's components keeps, from one reading to the next (``step_s`` apart), the
correlation cos(2 pi f step_s) (for a line, averaged over the spread of its frequency between
rigs: times a sinc). A component that keeps at least ``vibration_follow`` of it moves little
between readings and is followed as part of the path: its variance per step, 2 sigma^2 (1 - rho),
adds to the walk's. One that does not is new in every reading: it is noise of the reading,
not of the path. Taken as a move of the path, a 10 Hz loop's vibration (a correlation of 0.2
from one reading to the next, 0.017 cycles over five lines) lets every reading's path point
land on its own mirror image (x and -x read alike) wherever it exceeds the known excursion.
Taken as noise of the readings, every reading speaks of the same slow path, and the excursions'
pattern over the window fixes the sign.

That noise, a jitter of std sigma_fast per line about the path, moves each entry of a reading
(slot energies, power) about the model's value at the path by a variance and a mean that follow
from the stacker: both are measured once by draws at a tracking excursion off the stacking point
(:meth:`VibrationModel.reading_moments`); the mean (the stacked slot and power read lower, the
dark slots brighter, to second order in the jitter) is added to the model's readings
(:class:`ShakenStacker`), the variance weighs each entry down (:mod:`.weights`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .weights import Readings

#: Points of the floor's integral over its band (log-spaced).
FLOOR_POINTS = 2001
#: Draws of the fast vibration that give a reading's mean and variance under it.
READING_DRAWS = 4096


def told_vibration(params, config, build: bool = True):
    """The vibration the fits allow for (a :class:`VibrationModel`) or None: ``params.vibration``
    names a preset, ``none``, or ``model`` (the rig model's ``vibration``, at its ``step_s``
    when its ``time_base`` is seconds; a step-based model has no physical time to read one at).
    ``build`` False: only whether there is one (True or None)."""
    name = params.vibration
    step_s = float(getattr(config, "step_s", 0.1))
    if name == "model":
        name = str(getattr(config, "vibration", "none"))
        if getattr(config, "time_base", "step") != "seconds":
            name = "none"
    if name == "none":
        return None
    if not build:
        return True
    from ops_sim_ros.vibration import PRESETS

    return VibrationModel(PRESETS[name], step_s, float(config.optical_period_fs), params)


def under_vibration(params, config):
    """The parameters the tracker runs with under the vibration it is told of (``vibration``,
    :func:`told_vibration`): the ``vibration_*`` settings in place of the ones they stand for,
    the walk and the drift prior per step of the loop (``config.time_scale`` reference steps);
    ``params`` as they are without one."""
    if told_vibration(params, config, build=False) is None:
        return params
    scale = float(getattr(config, "time_scale", 1.0))
    walk = params.walk_cycles
    if walk is None:
        jitter = float(config.jitter_sigma_cycles) * scale**0.5
        walk = max(params.vibration_walk_factor * jitter, 1e-6)
    drift = params.vibration_drift_prior_cycles * scale
    window = max(params.window, params.vibration_window)
    sigmas = params.vibration_knot_walk_sigmas
    return replace(
        params,
        walk_cycles=walk,
        drift_prior_cycles=drift,
        noisy_drift_prior_cycles=drift,
        quiet_drift_prior_cycles=min(params.quiet_drift_prior_cycles, drift),
        window=window,
        noisy_window=window,
        recover_readings=min(params.recover_readings, window),
        noisy_dither_factor=params.vibration_dither_factor,
        knot_walk_sigmas=sigmas,
        noisy_knot_walk_sigmas=sigmas,
    )


class VibrationModel:
    """A vibration preset (:class:`ops_sim_ros.vibration.VibrationPreset`) read every ``step_s``
    seconds, in cycles of an optical period of ``period_fs``, split by ``vibration_follow`` of
    ``params`` into the walk it adds per step (:attr:`walk_var`) and the jitter per reading
    (:attr:`fast_var`), both cycles^2 per line."""

    def __init__(self, preset, step_s: float, period_fs: float, params) -> None:
        self.preset = preset
        self.step_s = float(step_s)
        self.period_fs = float(period_fs)
        variance, rho = self._components()
        follow = rho >= params.vibration_follow
        self.walk_var = float(np.sum(2.0 * variance[follow] * (1.0 - rho[follow])))
        self.fast_var = float(np.sum(variance[~follow]))
        self.var = float(np.sum(variance))

    def _components(self) -> tuple[np.ndarray, np.ndarray]:
        """Each component's variance (cycles^2) and its correlation over one step: the lines,
        then the floor on a fine log grid."""
        p, dt = self.preset, self.step_s
        hz = np.array([f for f, _ in p.lines])
        var = np.array([r * r for _, r in p.lines])
        rho = np.cos(2.0 * np.pi * hz * dt) * np.sinc(2.0 * hz * p.line_spread * dt)
        lo, hi = np.log(p.floor_band_hz)
        edges = np.exp(np.linspace(lo, hi, FLOOR_POINTS + 1))
        mid = np.sqrt(edges[:-1] * edges[1:])
        floor_var = p.floor_rms_fs**2 * p.floor_share(edges[:-1], edges[1:])
        floor_rho = np.cos(2.0 * np.pi * mid * dt)
        variance = np.concatenate([var, floor_var]) / self.period_fs**2
        return variance, np.concatenate([rho, floor_rho])

    def reading_moments(self, stacker, excursion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean shift, variance) (S + 1,) each that the fast jitter adds to the entries of a
        reading (slot energies, power) taken ``excursion`` (N,) cycles off the stacking point:
        over a fixed set of ``READING_DRAWS`` draws (a deterministic figure of the model)."""
        n = excursion.size
        draws = np.random.default_rng(0).standard_normal((READING_DRAWS, n))
        draws = np.concatenate([draws, -draws])  # antithetic: the mean's odd terms cancel
        points = excursion[None] + self.fast_var**0.5 * draws
        f = _readings(stacker, points * self.period_fs)
        f0 = _readings(stacker, excursion[None] * self.period_fs)[0]
        return f.mean(axis=0) - f0, f.var(axis=0)


def _readings(stacker, delays_fs: np.ndarray) -> np.ndarray:
    energies, power = stacker.energies_and_power(np.ascontiguousarray(delays_fs))
    return np.concatenate([energies, power[:, None]], axis=1).astype(np.float64)


class ShakenStacker:
    """A stacker whose readings are those expected under a fast jitter: its own plus ``bias``
    (slot energies (S,), power) (:meth:`VibrationModel.reading_moments`)."""

    def __init__(self, stacker, bias: np.ndarray):
        self.inner = stacker
        self.bias = bias
        self.num_slots = stacker.num_slots

    def evaluate(self, delays_fs):
        out = self.inner.evaluate(delays_fs)
        return Readings(out.slot_energies + self.bias[:-1], out.power + self.bias[-1])

    def energies_and_power(self, d: np.ndarray):
        energies, power = self.inner.energies_and_power(d)
        return energies + self.bias[:-1], power + self.bias[-1]
