"""The observation vector: built by ONE function that the env, the ROS bridge and the policy
runner all call, described by an :class:`ObservationSpec` that is saved beside trained models.

Default layout for N stages (S = 2^N - 1 output slots), float32:

    [0 : S)        detected pulse energies of the output slots (time slots 1, 3, ..,
                   2^(N+1) - 3), normalized by the input energy, clipped to [0, 1];
                   the stacked pulse is index 2^(N-1) - 1 (the centre)
    [S]            P_N / P_max, the normalized second-order detector signal, clipped to [0, 1]
    [S+1 : S+1+N)  delay set-points in optical periods (set-point_fs / optical_period_fs), not
                   wrapped, clipped to +- actuator range (so the policy knows where the actuator
                   limits are)

Each block can be switched off in the spec.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import cached_property
from typing import Any

import numpy as np

from .arrays import clip as _clip
from .config import OpsConfig


@dataclass(frozen=True)
class ObservationSpec:
    stage: int
    optical_period_fs: float = 1030.0 / 299.792458
    setpoint_limit_cycles: float = 30.0  # set-points are clipped to +- this (actuator range)
    include_energies: bool = True
    include_power: bool = True
    include_setpoints: bool = True

    @classmethod
    def from_config(cls, config: OpsConfig, **options: Any) -> ObservationSpec:
        return cls(
            stage=config.stage,
            optical_period_fs=config.optical_period_fs,
            setpoint_limit_cycles=config.actuator_range_cycles,
            **options,
        )

    @property
    def num_slots(self) -> int:
        return 2**self.stage - 1

    @property
    def dim(self) -> int:
        return (
            self.num_slots * self.include_energies
            + 1 * self.include_power
            + self.stage * self.include_setpoints
        )

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of the observation, float32 arrays of length ``dim``."""
        return self._bounds[0].copy(), self._bounds[1].copy()

    @cached_property
    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        low, high = [], []
        if self.include_energies:
            low.append(np.zeros(self.num_slots))
            high.append(np.ones(self.num_slots))
        if self.include_power:
            low.append(np.zeros(1))
            high.append(np.ones(1))
        if self.include_setpoints:
            low.append(np.full(self.stage, -self.setpoint_limit_cycles))
            high.append(np.full(self.stage, self.setpoint_limit_cycles))
        return (
            np.concatenate(low).astype(np.float32),
            np.concatenate(high).astype(np.float32),
        )

    def space(self):
        """The gymnasium Box of this observation."""
        from gymnasium import spaces

        low, high = self.bounds()
        return spaces.Box(low=low, high=high, dtype=np.float32)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ObservationSpec:
        return cls(**data)


def build_observation(spec: ObservationSpec, pulse_energies, power, setpoints_fs) -> np.ndarray:
    """Observation(s) for a batch (B, dim) or a single env (dim,), float32, inside spec.bounds().

    ``pulse_energies`` (B, S) or (S,), ``power`` (B,) or scalar, ``setpoints_fs`` (B, N) or (N,).
    """
    e = np.asarray(pulse_energies, dtype=np.float64)
    single = e.ndim == 1
    slots = 2**spec.stage - 1
    e2 = e.reshape(-1, slots)
    batch = e2.shape[0]
    low, high = spec._bounds
    obs = np.empty((batch, low.shape[0]), dtype=np.float32)
    col = 0
    # Each block is written straight into the float32 array (float64 values rounded once).
    if spec.include_energies:
        obs[:, :slots] = e2
        col = slots
    if spec.include_power:
        obs[:, col] = np.asarray(power, dtype=np.float64).reshape(batch)
        col += 1
    if spec.include_setpoints:
        sp = np.asarray(setpoints_fs, dtype=np.float64).reshape(batch, spec.stage)
        np.multiply(sp, 1.0 / spec.optical_period_fs, out=obs[:, col:])
    _clip(obs, low, high, out=obs)
    return obs[0] if single else obs


def pulse_energies_from_trace(trace, samples_per_slot: int) -> np.ndarray:
    """Sample a detected trace (..., S * samples_per_slot) at the slot centres -> (..., S)."""
    tr = np.asarray(trace, dtype=np.float32)
    spp = int(samples_per_slot)
    if tr.shape[-1] % spp:
        raise ValueError(f"trace length {tr.shape[-1]} is not a multiple of samples_per_slot {spp}")
    return tr[..., spp // 2 :: spp].copy()
