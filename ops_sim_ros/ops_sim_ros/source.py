"""The laser source's imperfections: unequal pulses in a burst and pulse-to-pulse
energy noise. docs/physics.md, "Rig imperfections", gives their meaning and typical values.

Both act on the input pulses' field amplitudes. Amplitudes are normalized so that the mean pulse
energy of the burst is 1: an imperfect source redistributes energy between the pulses, it does
not change the input energy the detected energies are normalized by.
"""

from __future__ import annotations

import numpy as np


def burst_amplitudes(stage: int, droop: float) -> np.ndarray | None:
    """Field amplitudes (2^N,) of a burst whose pulse energy falls exponentially from its first
    pulse to its last by ``droop`` (0.2: the last pulse has 80 % of the first's energy), as a
    gain-saturated amplifier leaves it; mean energy 1. None for an even burst (droop 0)."""
    if droop <= 0.0:
        return None
    count = 2 ** int(stage)
    energies = (1.0 - float(droop)) ** (np.arange(count) / max(count - 1, 1))
    energies /= energies.mean()
    return np.sqrt(energies)


def amplitude_noise(
    rng: np.random.Generator, shape: tuple[int, int], energy_noise: float
) -> np.ndarray:
    """Field factors (B, 2^N) of pulses whose energies carry independent relative noise of rms
    ``energy_noise`` (a pulse's energy never goes below zero)."""
    energy = 1.0 + energy_noise * rng.standard_normal(shape)
    return np.sqrt(np.maximum(energy, 0.0))
