"""What stands between a controller and the optics on a real rig, for a batch of B
simulated stackers: the command's latency, the delay-line actuator (DAC, open-loop piezo
hysteresis, finite response) and the trace's digitizer (averaging, ADC). docs/physics.md, "Rig
imperfections", gives each figure's meaning, unit, range and typical lab value.

Pure array functions (:func:`quantize`, :func:`play`, :func:`digitize`) under two small
stateful parts that :class:`~ops_sim_ros.simulation.BatchedSimulation` holds when the rig is not
ideal: :class:`Actuator` (commanded set-points in, delay-line positions out) and
:class:`Digitizer` (detected pulse energies in, what the scope reports out). With every figure
at its ideal value neither exists, and the simulation is exactly what it was without them.
"""

from __future__ import annotations

from collections import deque

import numpy as np

#: Play operators of the hysteresis model (Prandtl-Ishlinskii): enough for a smooth loop down
#: to excursions of a hundredth of the travel.
HYSTERESIS_OPERATORS = 64


def lag_gain(lag_steps: float) -> float:
    """The share of the way to its drive that a first-order delay line of time constant
    ``lag_steps`` covers in one step (1: no lag)."""
    return 1.0 - float(np.exp(-1.0 / lag_steps)) if lag_steps > 0.0 else 1.0


def quantize(x: np.ndarray, low: float, high: float, bits: int) -> np.ndarray:
    """``x`` rounded to the nearest of 2^bits levels spanning [low, high], clipped to it."""
    step = (high - low) / (2**bits - 1)
    return np.clip(np.round((x - low) / step) * step + low, low, high)


def play(x: np.ndarray, state: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """One step of play (backlash) operators: each output follows the input only once the
    input has moved more than its ``radius`` away (state and radius broadcast against x)."""
    return np.clip(state, x - radius, x + radius)


def hysteresis_radii(half_travel: float) -> np.ndarray:
    """Radii of the play operators, evenly spread over (0, half the travel]."""
    k = np.arange(1, HYSTERESIS_OPERATORS + 1)
    return (k - 0.5) / HYSTERESIS_OPERATORS * half_travel


def hysteresis_weight(fraction: float) -> float:
    """The play operators' weight w in :func:`hysteresis` that opens a loop ``fraction`` of the
    travel wide."""
    return 4.0 * fraction / (1.0 + 4.0 * fraction)


def hysteresis(x: np.ndarray, plays: np.ndarray, radii: np.ndarray, fraction: float):
    """An open-loop piezo's position for drive ``x`` (fs), and the operators' new states.

    The position lags the drive by the weighted mean lag of play operators of radii spread
    evenly up to half the travel (a Prandtl-Ishlinskii model), scaled so that small moves go as
    far as commanded (a rig calibrates its fs per volt over a fringe or two). A sweep of the
    whole travel and back opens a loop ``fraction`` of the travel wide at mid-travel and goes
    further than commanded at its ends (a piezo's response grows with its excursion); a sweep of
    amplitude A opens one about (A / half travel)^2 as wide (the Rayleigh law of
    piezoceramics). Monotonic for every fraction in [0, 1)."""
    weight = hysteresis_weight(fraction)
    plays = play(x[None], plays, radii[:, None, None])
    return (x - weight * np.mean(x[None] - plays, axis=0)) / (1.0 - weight), plays


def digitize(
    energies: np.ndarray,
    noise_std: float,
    averages: int,
    bits: int,
    full_scale: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """What a digitizer reports of detected energies (B, S): the mean of ``averages``
    acquisitions, each with the detector's noise and (``bits`` > 0) rounded to 2^bits levels
    over [0, full_scale] and clipped there."""
    reads = energies[None] + (
        rng.normal(0.0, noise_std, (averages, *energies.shape)) if noise_std > 0.0 else 0.0
    )
    if bits > 0:
        reads = quantize(reads, 0.0, full_scale, bits)
    return np.mean(reads, axis=0)


def reading_noise_std(config, quantization_steps: float) -> float:
    """The std of the error of a detected pulse energy that a controller told of this rig
    should expect: the detector's noise (averaged), the digitizer's rounding weighed as
    ``quantization_steps`` of its step (the controller's choice: the tracker's
    ``quantization_noise_steps``) and the source's pulse-to-pulse noise (the stacked pulse's
    energy, the largest, moves by about its rms over the square root of the pulse count)."""
    var = config.detector_noise**2 / config.trace_averages
    var += config.pulse_amplitude_noise**2 / 2**config.stage
    if config.trace_adc_bits > 0:
        step = config.trace_full_scale / (2**config.trace_adc_bits - 1)
        var += (quantization_steps * step) ** 2
    return float(var**0.5)


class Actuator:
    """The delay lines between the commands and the optics: set-points act ``latency_steps``
    steps late, through a DAC of ``dac_bits`` over the actuator range, an open-loop piezo's
    hysteresis and a first-order response of ``lag_steps`` steps."""

    def __init__(self, config, num_envs: int):
        self.latency = int(config.latency_steps)
        self.half_travel = config.actuator_range_fs
        self.dac_bits = int(config.dac_bits)
        self.gain = lag_gain(config.actuator_lag_steps)
        self.hysteresis = float(config.actuator_hysteresis)
        self.radii = hysteresis_radii(self.half_travel)
        shape = (num_envs, config.stage)
        self._queue: deque[np.ndarray] = deque()
        self._plays = np.zeros((HYSTERESIS_OPERATORS, *shape))
        self.position = np.zeros(shape)  # delay-line positions, fs

    def reset(self, setpoints: np.ndarray, mask: np.ndarray | None = None) -> None:
        """The delay lines at rest on ``setpoints`` (B, N) where ``mask`` (all by default),
        with nothing in flight there."""
        mask = np.ones(setpoints.shape[0], bool) if mask is None else np.asarray(mask, bool)
        target = self._drive(setpoints)
        self._plays[:, mask] = target[mask]
        self.position = self.position.copy()
        self.position[mask] = target[mask]
        if not self._queue:
            self._queue.extend(setpoints.copy() for _ in range(self.latency))
        for queued in self._queue:
            queued[mask] = setpoints[mask]

    def _drive(self, setpoints: np.ndarray) -> np.ndarray:
        """The DAC's output for set-points (fs)."""
        if self.dac_bits > 0:
            return quantize(setpoints, -self.half_travel, self.half_travel, self.dac_bits)
        return setpoints

    def move(self, setpoints: np.ndarray) -> np.ndarray:
        """One step with these commanded set-points (B, N) fs; the positions (B, N) fs."""
        self._queue.append(np.array(setpoints, dtype=np.float64))
        acting = self._queue.popleft()
        target = self._drive(acting)
        if self.hysteresis > 0.0:
            target, self._plays = hysteresis(target, self._plays, self.radii, self.hysteresis)
        self.position = self.position + self.gain * (target - self.position)
        return self.position.copy()


class Digitizer:
    """The trace's digitizer: :func:`digitize` with the rig's figures."""

    def __init__(self, config):
        self.bits = int(config.trace_adc_bits)
        self.full_scale = float(config.trace_full_scale)
        self.averages = int(config.trace_averages)

    def read(self, energies: np.ndarray, noise_std: float, rng: np.random.Generator):
        return digitize(energies, noise_std, self.averages, self.bits, self.full_scale, rng)
