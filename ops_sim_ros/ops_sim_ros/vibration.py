"""Vibration of the delay lines in physical time (``vibration`` of OpsConfig; docs/physics.md,
"Physical time and vibration").

A preset gives acoustic and building *lines* (a frequency and an rms each, fs) and a *floor*
whose power spectral density falls as 1/f^slope over a band (its rms over the whole band, fs).
Each delay line of each environment vibrates as a sum of sinusoids at fixed frequencies with
random phases (the spectral-representation method): one per line, the line's frequency within
``line_spread`` of its nominal one per environment (two labs' fans do not turn at the same
speed), and one per log-spaced band of the floor, at a random frequency inside its band, with
the variance the spectrum puts in that band (equal in every band for slope 1). The offset is a
function of physical time, evaluated at t = steps x ``step_s``: a loop of any rate samples the same
vibration, and a slow loop sees its lines aliased to low frequencies, as a real one does.
Deterministic per generator; pure numpy, batched over (environments, stages).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class VibrationPreset:
    """The figures of one vibration preset (delays in fs rms, frequencies in Hz)."""

    lines: tuple[tuple[float, float], ...]  # (nominal frequency, rms) of each line
    floor_rms_fs: float  # rms of the floor over floor_band_hz
    floor_band_hz: tuple[float, float]
    floor_slope: float = 1.0  # the floor's power spectral density falls as 1/f**floor_slope
    floor_components: int = 24  # sinusoids of the floor: one per log-spaced band
    line_spread: float = 0.01  # each env's line within +- this fraction of its nominal frequency

    @property
    def rms_fs(self) -> float:
        """The total rms of one delay line's vibration."""
        return float(np.sqrt(sum(r * r for _, r in self.lines) + self.floor_rms_fs**2))

    def floor_share(self, low_hz, high_hz):
        """The share of the floor's variance in [low_hz, high_hz) (arrays broadcast): the
        integral of f**-floor_slope over the band's overlap with floor_band_hz, normalized."""
        lo, hi = self.floor_band_hz
        a = np.clip(low_hz, lo, hi)
        b = np.clip(high_hz, lo, hi)
        if self.floor_slope == 1.0:
            return np.maximum(np.log(b / a), 0.0) / np.log(hi / lo)
        e = 1.0 - self.floor_slope  # the antiderivative of f**-slope is f**e / e
        return np.maximum((b**e - a**e) / (hi**e - lo**e), 0.0)

    def band_rms_fs(self, low_hz: float, high_hz: float) -> float:
        """The rms the preset puts in [low_hz, high_hz): the lines whose nominal frequency lies
        there and the floor's share."""
        var = sum(r * r for f, r in self.lines if low_hz <= f < high_hz)
        var += self.floor_rms_fs**2 * float(self.floor_share(low_hz, high_hz))
        return float(np.sqrt(var))


#: The presets by name (``config.VIBRATIONS`` lists them with ``none``); docs/physics.md gives
#: each figure's source.
#:
#: ``lab``: a free-space stacker on a floated optical table under an enclosure, in a building
#: with air handling: 0.026 fs (8 nm of path, 1/130 of the 1030 nm wavelength) rms per delay
#: line. The floated table passes little above its ~1.5 Hz resonance, so the floor falls as
#: 1/f^2 (90 % of its variance below 10 Hz) and the acoustic lines are sub-nm.
#:
#: ``open``: the same table without an enclosure, its mounts driven by the room's sound:
#: 0.066 fs (20 nm, 1/52 of the wavelength), a 1/f floor with a third of its variance above
#: 100 Hz and lines several times louder; what a loop leaves then is set by its bandwidth.
PRESETS = {
    "lab": VibrationPreset(
        lines=(
            (14.6, 0.006),  # the floor's structural mode, left after the isolators
            (29.5, 0.005),  # an air handler's fan or a pump motor (1770 rpm)
            (120.0, 0.002),  # twice the 60 Hz mains (100 Hz on 50 Hz): transformer and motor hum
            (230.0, 0.002),  # a mirror mount's resonance on its post, driven acoustically
            (470.0, 0.001),  # a second mount resonance
        ),
        floor_rms_fs=0.025,
        floor_band_hz=(1.0, 1000.0),
        floor_slope=2.0,
    ),
    "open": VibrationPreset(
        lines=((14.6, 0.015), (29.5, 0.015), (120.0, 0.010), (230.0, 0.012), (470.0, 0.006)),
        floor_rms_fs=0.06,
        floor_band_hz=(1.0, 1000.0),
        floor_slope=1.0,
    ),
}


class Vibration:
    """The vibration of ``num_envs`` x ``stage`` delay lines: :meth:`at` gives it at a time."""

    def __init__(self, preset: VibrationPreset, num_envs: int, stage: int, rng) -> None:
        shape = (int(num_envs), int(stage))
        nominal = np.array([f for f, _ in preset.lines])
        spread = 1.0 + preset.line_spread * rng.uniform(-1.0, 1.0, (shape[0], 1, nominal.size))
        line_hz = np.broadcast_to(nominal * spread, (*shape, nominal.size))  # same in all stages
        k = int(preset.floor_components)
        lo, hi = np.log(preset.floor_band_hz)
        width = (hi - lo) / k
        floor_hz = np.exp(lo + width * (np.arange(k) + rng.random((*shape, k))))
        self.hz = np.concatenate([line_hz, floor_hz], axis=2)  # (B, N, M)
        self.phase = rng.random(self.hz.shape)  # cycles
        edges = np.exp(lo + width * np.arange(k + 1))
        floor_rms = preset.floor_rms_fs * np.sqrt(preset.floor_share(edges[:-1], edges[1:]))
        rms = np.concatenate([[r for _, r in preset.lines], floor_rms])
        self.amplitude = np.sqrt(2.0) * rms  # (M,) fs
        self._amplitude32 = self.amplitude.astype(np.float32)
        self._cycles = np.empty_like(self.hz)
        self._whole = np.empty_like(self.hz)
        self._rad = np.empty(self.hz.shape, np.float32)

    def at(self, t_s: float) -> np.ndarray:
        """The lines' offsets (num_envs, stage) fs at time ``t_s`` (a fresh array).

        Each sinusoid's phase is reduced to [-1/2, 1/2] cycle in float64 (exact to ~1e-7 cycle
        after 10^6 s at 1 kHz), then its sine taken in float32, which numpy vectorizes where its
        float64 sine runs element by element (40-60 ns each on the 2-core test machine); the
        result is good to ~1e-6 of the vibration's amplitude."""
        cycles = np.multiply(self.hz, t_s, out=self._cycles)
        cycles += self.phase
        cycles -= np.rint(cycles, out=self._whole)
        rad = np.multiply(cycles, _TWO_PI, out=self._rad, casting="same_kind")
        np.sin(rad, out=rad)
        return (rad @ self._amplitude32).astype(np.float64)


def make_vibration(name: str, num_envs: int, stage: int, rng: np.random.Generator):
    """The :class:`Vibration` of preset ``name`` drawn from a generator spawned from ``rng``
    (so the random walk's draws stay those without vibration), or None for ``none``."""
    if name == "none":
        return None
    try:
        child = rng.spawn(1)[0]
    except (AttributeError, TypeError, ValueError):  # a generator without a seed sequence
        child = np.random.default_rng(int(rng.integers(2**63)))
    return Vibration(PRESETS[name], num_envs, stage, child)
