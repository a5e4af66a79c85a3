"""The one state machine of a batch of simulated stackers (env, vector env and the ROS node use it).

State per environment: the delay set-points (fs, relative to the nominal delays) and the step
count of the current episode; shared: the delay noise (drift + jitter) and the random generator.
Every step: set-points (clipped to the actuator range) + noise sample -> applied delays -> physics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy._core.umath import clip as _clip  # the bare ufunc: much cheaper than np.clip

from .config import OpsConfig
from .noise import DelayNoise
from .physics import stacker_from_config

_isfinite = np.isfinite
_all = np.logical_and.reduce  # ndarray.all() without its Python wrapper


@dataclass
class StepResult:
    """One control step (or the measurement at reset) for a batch of B environments."""

    setpoints_fs: np.ndarray  # (B, N) set-points after clipping
    applied_fs: np.ndarray  # (B, N) delays really applied: set-point + noise
    power: np.ndarray  # (B,) P_N / P_max
    reward: np.ndarray  # (B,) eq. (3), -(1 - power)^2
    pulse_energies: np.ndarray  # (B, S) detected H-port slot energies (normalized, + det. noise)
    main_pulse_energy: np.ndarray  # (B,) true energy of the stacked pulse (normalized)
    rejected_energy: np.ndarray  # (B,) energy lost at the output polarizer (normalized)
    clipped: np.ndarray  # (B, N) bool: the requested set-point was outside the actuator range
    step_count: np.ndarray  # (B,) steps taken in the current episode (0 right after reset)
    truncated: np.ndarray  # (B,) bool: step_count reached episode_steps


def _as_generator(seed) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(seed)


class BatchedSimulation:
    """``num_envs`` independent stackers sharing one batched physics call per step."""

    def __init__(self, config: OpsConfig, num_envs: int = 1, seed=None) -> None:
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1 (got {num_envs})")
        self.config = config
        self.num_envs = int(num_envs)
        self.stage = config.stage
        self.stacker = stacker_from_config(config)
        self._main_slot = self.stacker.main_slot
        self.optical_period_fs = config.optical_period_fs
        self.max_step_fs = config.max_step_fs
        self.range_fs = config.actuator_range_fs
        self.rng = _as_generator(seed)
        self.noise = DelayNoise.from_config(config, self.num_envs, self.rng)
        self.setpoints_fs = np.zeros((self.num_envs, self.stage))
        self.step_count = np.zeros(self.num_envs, dtype=np.int64)
        self.last: StepResult | None = None

    # ------------------------------------------------------------------ episode control
    def reset(self, mask=None, seed=None) -> StepResult:
        """Start new episodes (all, or where ``mask`` is True) and measure the initial state.

        ``seed`` (int or ``np.random.Generator``) restarts the random stream AND the drift process,
        so the same seed gives the same episodes. Without a seed the drift simply continues.
        The returned measurement uses fresh jitter on the current drift; it does not advance the
        drift (only control steps do).
        """
        if seed is not None:
            self.rng = _as_generator(seed)
            self.noise.restart(self.rng)
        if mask is None:
            mask = np.ones(self.num_envs, dtype=bool)
        mask = np.asarray(mask, dtype=bool)
        count = int(mask.sum())
        r = self.config.initial_range_fs
        sp = self.setpoints_fs.copy()  # fresh array: earlier results may still view the old one
        sp[mask] = self.rng.uniform(-r, r, size=(count, self.stage))
        self.setpoints_fs = sp
        self.step_count[mask] = 0
        result = self._measure(
            self.setpoints_fs.copy(), np.zeros_like(self.setpoints_fs, bool), advance=False
        )
        if self.last is not None and not mask.all():
            # Envs that were not reset keep their last measurement (their step did not happen).
            keep = ~mask
            for name in ("applied_fs", "pulse_energies"):
                getattr(result, name)[keep] = getattr(self.last, name)[keep]
            for name in ("power", "reward", "main_pulse_energy", "rejected_energy"):
                getattr(result, name)[keep] = getattr(self.last, name)[keep]
            result.truncated[keep] = self.last.truncated[keep]
        self.last = result
        return result

    # ------------------------------------------------------------------ stepping
    def step_setpoints(self, setpoints_fs) -> StepResult:
        """Apply absolute set-points (B, N) in fs (clipped to +- actuator range) for one step."""
        sp = np.array(setpoints_fs, dtype=np.float64).reshape(self.num_envs, self.stage)
        if not np.isfinite(sp).all():
            raise ValueError("set-points must be finite")
        clipped = np.abs(sp) > self.range_fs
        _clip(sp, -self.range_fs, self.range_fs, out=sp)
        self.setpoints_fs = sp
        self.step_count += 1
        self.last = self._measure(sp, clipped)
        return self.last

    def step_increments(self, actions) -> StepResult:
        """Move set-points by ``actions`` in [-1, 1] (clipped) times the actuator's max step."""
        a = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, self.stage)
        if not _all(_isfinite(a), axis=None):
            raise ValueError("actions must be finite")
        sp = _clip(a, -1.0, 1.0)
        sp *= self.max_step_fs
        sp += self.setpoints_fs
        clipped = np.abs(sp) > self.range_fs
        _clip(sp, -self.range_fs, self.range_fs, out=sp)
        self.setpoints_fs = sp
        self.step_count += 1
        self.last = self._measure(sp, clipped)
        return self.last

    def _measure(self, setpoints: np.ndarray, clipped: np.ndarray, advance=True) -> StepResult:
        applied = self.noise.sample(advance)
        applied += setpoints  # the noise array is fresh: reuse it for the applied delays
        true_energies, power = self.stacker._energies_and_power(applied)
        energies = true_energies
        if self.config.detector_noise > 0.0:
            energies = energies + self.rng.normal(0.0, self.config.detector_noise, energies.shape)
        if self.num_envs == 1:
            # One env: the same arithmetic on Python floats (fewer numpy calls per step).
            x = 1.0 - float(power[0])
            reward = np.array([-(x * x)])
            main = np.array([float(true_energies[0, self._main_slot])])
            rejected = np.array([1.0 - float(np.add.reduce(true_energies, axis=None))])
        else:
            reward = np.subtract(power, 1.0)
            np.multiply(reward, np.subtract(1.0, power), out=reward)  # -(1 - power)^2
            main = true_energies[:, self._main_slot].copy()
            rejected = np.subtract(1.0, np.add.reduce(true_energies, axis=1))
        return StepResult(
            setpoints_fs=setpoints,
            applied_fs=applied,
            power=power,
            reward=reward,
            pulse_energies=energies,
            main_pulse_energy=main,
            rejected_energy=rejected,
            clipped=clipped,
            step_count=self.step_count.copy(),
            truncated=self.step_count >= self.config.episode_steps,
        )

    # ------------------------------------------------------------------ observables
    def trace(self, result: StepResult | None = None) -> np.ndarray:
        """Detected intensity traces (B, S * samples_per_slot) float32 for a step result."""
        result = self.last if result is None else result
        if result is None:
            raise RuntimeError("reset() the simulation before asking for a trace")
        return self.stacker.trace_from_energies(result.pulse_energies)
