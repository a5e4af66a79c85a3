"""The one state machine of a batch of simulated stackers (env, vector env and the ROS node use it).

State per environment: the delay set-points (fs, relative to the nominal delays; 0 at every
reset), the hidden delay-line offsets (the initial delay error plus its random walk and drift, see
:mod:`ops_sim_ros.noise`) and the step count of the current episode. Every step: set-points
(clipped to the actuator range) + offsets -> applied delays -> physics. On a rig that is not
ideal (:mod:`ops_sim_ros.rig`: latency, DAC, hysteresis, lag) the set-points pass through the
actuator to become delay-line positions first, and the detected energies through the digitizer;
an imperfect source (:mod:`ops_sim_ros.source`) gives unequal or noisy input pulses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ops_contract.arrays import clip as _clip
from ops_contract.config import OpsConfig

from .noise import DelayNoise
from .physics import power_to_reward, stacker_from_config
from .rig import Actuator, Digitizer
from .source import amplitude_noise

_isfinite = np.isfinite
_all = np.logical_and.reduce  # ndarray.all() without its Python wrapper


@dataclass
class StepResult:
    """One control step (or the measurement at reset) for a batch of B environments."""

    setpoints_fs: np.ndarray  # (B, N) set-points after clipping (as commanded)
    applied_fs: np.ndarray  # (B, N) delays really applied: delay-line position + noise
    power: np.ndarray  # (B,) P_N / P_max
    reward: np.ndarray  # (B,) eq. (3), -(1 - power)^2
    pulse_energies: np.ndarray  # (B, S) detected slot energies (normalized, + detector noise)
    main_pulse_energy: np.ndarray  # (B,) true detected energy of the stacked pulse (normalized)
    rejected_energy: np.ndarray  # (B,) energy the detector does not see (polarizer's p port)
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
        self._total = config.detector == "total"
        self.optical_period_fs = config.optical_period_fs
        self.max_step_fs = config.max_step_fs
        self.range_fs = config.actuator_range_fs
        self.rng = _as_generator(seed)
        self.noise = DelayNoise.from_config(config, self.num_envs, self.rng)
        self.setpoints_fs = np.zeros((self.num_envs, self.stage))
        self.step_count = np.zeros(self.num_envs, dtype=np.int64)
        self.last: StepResult | None = None
        # The rig between commands and optics: None where ideal (the exact former arithmetic).
        self.actuator = None if config.ideal_actuator else Actuator(config, self.num_envs)
        self.digitizer = None if config.ideal_digitizer else Digitizer(config)
        self._amplitude_noise = config.pulse_amplitude_noise
        self._pulses_shape = (self.num_envs, 2**self.stage)
        if self.actuator is not None:
            self.actuator.reset(self.setpoints_fs)

    def with_config(self, config: OpsConfig) -> BatchedSimulation:
        """A simulation with other figures that continues this one: same random stream,
        set-points, step counts and delay-line errors (the drift process starts afresh; the
        vibration and its clock go on)."""
        if config.stage != self.stage:
            raise ValueError(f"stage must stay {self.stage} (got {config.stage})")
        sim = BatchedSimulation(config, num_envs=self.num_envs, seed=self.rng)
        sim.setpoints_fs = self.setpoints_fs.copy()
        if sim.actuator is not None:
            sim.actuator.reset(sim.setpoints_fs)
        sim.step_count = self.step_count.copy()
        sim.noise.continue_from(self.noise)
        sim.last = self.last
        return sim

    def use_rig(self, config: OpsConfig) -> None:
        """Run the rig's and the source's figures of ``config`` from now on (``OpsEnv``'s
        ``rig_randomize`` draws one per episode); the optics, noise, drift, random stream,
        set-points and step counts stay. Nothing is in flight on the new actuator: call it
        before :meth:`reset`."""
        if config.stage != self.stage:
            raise ValueError(f"stage must stay {self.stage} (got {config.stage})")
        if config.burst_envelope != self.config.burst_envelope:
            self.stacker = stacker_from_config(config)
        self.config = config
        self.actuator = None if config.ideal_actuator else Actuator(config, self.num_envs)
        self.digitizer = None if config.ideal_digitizer else Digitizer(config)
        self._amplitude_noise = config.pulse_amplitude_noise
        if self.actuator is not None:
            self.actuator.reset(self.setpoints_fs)

    # ------------------------------------------------------------------ episode control
    def reset(self, mask=None, seed=None) -> StepResult:
        """Start new episodes (all, or where ``mask`` is True) and measure the initial state.

        A new episode has its set-points at 0 and a fresh hidden delay error (the mode's initial
        state). ``seed`` (int or ``np.random.Generator``) restarts the random stream AND the
        drift process, so the same seed gives the same episodes; without a seed the knot
        process of the extreme mode's drift simply continues.
        """
        if seed is not None:
            self.rng = _as_generator(seed)
            self.noise.restart(self.rng)
        if mask is None:
            mask = np.ones(self.num_envs, dtype=bool)
        mask = np.asarray(mask, dtype=bool)
        sp = self.setpoints_fs.copy()  # fresh array: earlier results may still view the old one
        sp[mask] = 0.0
        self.setpoints_fs = sp
        if self.actuator is not None:
            self.actuator.reset(sp, mask)
        self.noise.new_episodes(mask)
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

    def continue_episodes(self, mask) -> None:
        """New episodes that carry on where the old ones are (``mask``): only the step count
        restarts; set-points, delay errors and drift go on."""
        mask = np.asarray(mask, dtype=bool).reshape(self.num_envs)
        self.step_count[mask] = 0
        if self.last is not None:  # a fresh array: the caller may still hold the old one
            self.last.truncated = self.last.truncated & ~mask

    def use_rng(self, rng: np.random.Generator) -> None:
        """Draw all further randomness (noise, new episodes) from ``rng``; nothing restarts."""
        self.rng = rng
        self.noise.rng = rng

    def place(self, setpoints_fs=None, delay_errors_fs=None) -> StepResult:
        """Put every env at given set-points and/or hidden delay-line errors (B, N) fs and
        measure there without taking a step (for figures, tests and chosen starts)."""
        shape = (self.num_envs, self.stage)
        if setpoints_fs is not None:
            sp = np.array(setpoints_fs, dtype=np.float64).reshape(shape)
            if not np.isfinite(sp).all():
                raise ValueError("set-points must be finite")
            self.setpoints_fs = _clip(sp, -self.range_fs, self.range_fs)
            if self.actuator is not None:
                self.actuator.reset(self.setpoints_fs)
        if delay_errors_fs is not None:
            err = np.array(delay_errors_fs, dtype=np.float64).reshape(shape)
            if not np.isfinite(err).all():
                raise ValueError("delay errors must be finite")
            self.noise.place(err)
        self.last = self._measure(self.setpoints_fs.copy(), np.zeros(shape, bool), advance=False)
        return self.last

    # ------------------------------------------------------------------ stepping
    def step_setpoints(self, setpoints_fs) -> StepResult:
        """Apply absolute set-points (B, N) in fs (clipped to +- actuator range) for one step."""
        sp = np.array(setpoints_fs, dtype=np.float64).reshape(self.num_envs, self.stage)
        if not np.isfinite(sp).all():
            raise ValueError("set-points must be finite")
        return self._step_to(sp)

    def step_increments(self, actions) -> StepResult:
        """Move set-points by ``actions`` in [-1, 1] (clipped) times the actuator's max step."""
        a = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, self.stage)
        if not _all(_isfinite(a), axis=None):
            raise ValueError("actions must be finite")
        sp = _clip(a, -1.0, 1.0)
        sp *= self.max_step_fs
        sp += self.setpoints_fs
        return self._step_to(sp)

    def _step_to(self, sp: np.ndarray) -> StepResult:
        """One step to the set-points ``sp`` (B, N; clipped in place to +- actuator range)."""
        clipped = np.abs(sp) > self.range_fs
        _clip(sp, -self.range_fs, self.range_fs, out=sp)
        self.setpoints_fs = sp
        self.step_count += 1
        self.last = self._measure(sp, clipped)
        return self.last

    def _measure(self, setpoints: np.ndarray, clipped: np.ndarray, advance=True) -> StepResult:
        """``advance``: a step (the noise and the rig's actuator move on), else a measurement
        where things are (reset, place)."""
        applied = self.noise.sample(advance)
        if self.actuator is None:
            applied += setpoints  # the noise array is fresh: reuse it for the applied delays
        elif advance:
            applied += self.actuator.move(setpoints)
        else:
            applied += self.actuator.position
        if self._amplitude_noise > 0.0:  # the source's pulses differ from step to step
            factors = amplitude_noise(self.rng, self._pulses_shape, self._amplitude_noise)
            true_energies, power = self.stacker.energies_and_power_of_pulses(applied, factors)
        else:
            true_energies, power = self.stacker.energies_and_power(applied)
        energies = true_energies
        gain, offset = self.config.detector_gain, self.config.detector_offset
        if gain != 1.0 or offset != 0.0:  # a detector off its calibration (power stays exact)
            energies = energies * gain + offset
        if self.digitizer is not None:
            energies = self.digitizer.read(energies, self.config.detector_noise, self.rng)
        elif self.config.detector_noise > 0.0:
            energies = energies + self.rng.normal(0.0, self.config.detector_noise, energies.shape)
        reward = power_to_reward(power)
        if self.num_envs == 1:
            # One env: the same arithmetic on Python floats (fewer numpy calls per step).
            main = np.array([float(true_energies[0, self._main_slot])])
            rejected = np.array([0.0 if self._total else 1.0 - float(true_energies.sum())])
        else:
            main = true_energies[:, self._main_slot].copy()
            if self._total:  # both polarizations are detected: nothing is rejected
                rejected = np.zeros(self.num_envs)
            else:
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
