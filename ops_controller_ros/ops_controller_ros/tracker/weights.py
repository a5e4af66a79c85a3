"""Per-entry weights of a reading: the source's pulse-to-pulse noise moves the
stacked pulse's energy and the power, not the other slots.

A reading is 2^N - 1 slot energies and the power. Near a lock the light is in the stacked slot,
and a pulse energy noise of rms s moves that slot's energy by about s / sqrt(2^N) and the power
by twice that, while the other slots, dark by interference, hardly move. Weighing every entry
alike, the tracker would have to treat the whole reading as noisy (a longer window, a slower
drift prior), which costs power. Weighing the two noisy entries down by their
extra variance keeps the dark slots' information at its own noise.
"""

from __future__ import annotations

import numpy as np


class WeightedStacker:
    """A stacker whose predicted readings are scaled by ``weights`` (slot energies, power),
    for fits that compare them with readings scaled alike."""

    def __init__(self, stacker, weights: np.ndarray):
        self.inner = stacker
        self.weights = weights
        self.num_slots = stacker.num_slots

    def evaluate(self, delays_fs):
        out = self.inner.evaluate(delays_fs)
        return Readings(out.slot_energies * self.weights[:-1], out.power * self.weights[-1])

    def energies_and_power(self, d: np.ndarray):
        """Weighed slot energies (B, S) and power (B,) of a checked (B, N) float64 array of
        delays, fs (:meth:`~ops_sim_ros.physics.PulseStacker.energies_and_power`)."""
        energies, power = self.inner.energies_and_power(d)
        return energies * self.weights[:-1], power * self.weights[-1]


class Readings:
    """What the fits read of a wrapped stacker's ``evaluate``: slot energies and power."""

    __slots__ = ("power", "slot_energies")

    def __init__(self, slot_energies, power):
        self.slot_energies = slot_energies
        self.power = power


def source_noise_weights(stage: int, energy_noise: float, floor_sd: float) -> np.ndarray | None:
    """Weights (2^N,) of the slot energies and the power for readings whose other noise has
    std ``floor_sd``: 1 where the source adds nothing, floor / sqrt(floor^2 + its variance) on
    the stacked slot and the power; None without source noise."""
    if energy_noise <= 0.0:
        return None
    slots = 2**stage - 1
    w = np.ones(slots + 1)
    var = energy_noise**2 / 2**stage  # the stacked pulse's energy, as rig.reading_noise_std
    floor = max(floor_sd, 1e-12) ** 2
    w[slots // 2] = (floor / (floor + var)) ** 0.5
    w[-1] = (floor / (floor + 4.0 * var)) ** 0.5
    return w
