"""The optics behind the simulated instruments: a :class:`BatchedSimulation` of the project
(its noise, drift and rig realism) driven by piezo voltages through a hidden fs-per-volt and
zero per channel, seen by a simulated scope as a record of pulses (volts).

The optics run in real time: the simulation steps at ``step_rate_hz`` (the simulator's 100 Hz by
default; its drift and noise figures are per step), so an acquisition (the scope's trigger) takes
the steps due since the last one at the delays the piezo voltages imply, or, when none is due,
measures the present state at those delays. With a non-ideal rig (``realism`` lab: latency,
actuator lag and hysteresis) every acquisition takes at least one step, as every reading of the
simulator is one step, so the actuator's dynamics act per acquisition. Thread-safe (the scope
and the drives run in threads).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
from ops_contract.config import make_config
from ops_sim_ros.simulation import BatchedSimulation


@dataclass
class HiddenTruth:
    fs_per_volt: np.ndarray
    zero_volts: np.ndarray
    slot_positions: np.ndarray
    detector_offset_volts: float
    detector_full_volts: float

    def as_dict(self) -> dict:
        return {
            "fs_per_volt": self.fs_per_volt.tolist(),
            "zero_volts": self.zero_volts.tolist(),
            "slot_positions": self.slot_positions.tolist(),
            "detector_offset_volts": self.detector_offset_volts,
            "detector_full_volts": self.detector_full_volts,
        }


class SimOptics:
    """``stage`` stages in ``mode`` (and ``realism``), seeded; the truth drawn from the seed."""

    def __init__(
        self,
        stage: int = 5,
        mode: str = "medium",
        seed: int = 0,
        realism: str = "ideal",
        slot_spacing: float = 24.0,
        electronic_noise_volts: float = 0.0,
        quiet: bool = False,
        step_rate_hz: float = 100.0,
    ):
        overrides = {}
        if quiet:  # no drift, jitter or detector noise: calibration checks against the truth
            overrides = dict(
                jitter_sigma_cycles=0.0,
                detector_noise=0.0,
                drift_slope_max_cycles=0.0,
                drift_slope_min_cycles=0.0,
            )
        config = make_config(stage=stage, mode=mode, realism=realism, **overrides)
        self.config = config
        self.stage = stage
        rng = np.random.default_rng(seed)
        self.sim = BatchedSimulation(config, num_envs=1, seed=int(rng.integers(2**31)))
        self.sim.reset()
        self.sim.place(setpoints_fs=np.zeros((1, stage)), delay_errors_fs=np.zeros((1, stage)))
        num_slots = 2**stage - 1
        first = 2.0 * slot_spacing + rng.uniform(0.0, slot_spacing)
        self.truth = HiddenTruth(
            fs_per_volt=rng.uniform(0.7, 1.4, stage),
            zero_volts=rng.uniform(25.0, 50.0, stage),
            slot_positions=first + slot_spacing * np.arange(num_slots),
            detector_offset_volts=float(rng.uniform(0.01, 0.05)),
            detector_full_volts=float(rng.uniform(0.6, 0.9)),
        )
        self.points = int(np.ceil(first + slot_spacing * (num_slots + 1)))
        self.pulse_sigma = slot_spacing / 10.0
        self.noise_volts = float(electronic_noise_volts)
        self.rng = rng
        self.volts = np.zeros(stage)  # what the piezo drives hold
        self.lock = threading.Lock()
        self.acquisitions = 0
        self.last_power = 0.0
        self.step_rate_hz = float(step_rate_hz)
        self._t0 = time.monotonic()
        self.steps = 0

    def set_voltage(self, channel: int, volts: float) -> None:
        with self.lock:
            self.volts[channel] = volts

    def setpoints_fs(self) -> np.ndarray:
        return (self.volts - self.truth.zero_volts) * self.truth.fs_per_volt

    def acquire(self) -> np.ndarray:
        """One step of the optics at the present voltages; the scope's record (volts)."""
        with self.lock:
            sp = self.setpoints_fs()[None, :]
            due = int((time.monotonic() - self._t0) * self.step_rate_hz) - self.steps
            if self.sim.actuator is not None:
                due = max(due, 1)
            if due >= 1:
                for _ in range(min(due, 100)):  # a long pause: the drift of 100 steps at most
                    result = self.sim.step_setpoints(sp)
                self.steps += due
            else:
                result = self.sim.place(setpoints_fs=sp)
            energies = result.pulse_energies[0]
            self.last_power = float(result.power[0])
            self.acquisitions += 1
        x = np.arange(self.points)[:, None]
        bumps = np.exp(-0.5 * ((x - self.truth.slot_positions[None, :]) / self.pulse_sigma) ** 2)
        record = self.truth.detector_offset_volts + self.truth.detector_full_volts * (
            bumps @ energies
        )
        if self.noise_volts > 0:
            record = record + self.rng.normal(0.0, self.noise_volts, record.shape)
        return record
