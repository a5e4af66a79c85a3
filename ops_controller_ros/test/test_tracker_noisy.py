"""Any noise the tracker is told of counts as noisy (issue 30): a digitized trace however fine,
the detector's noise, the source's pulse noise; and on a noisy detector the drift estimate moves
slowly, so the noise does not walk it away (docs/tracker.md, "Any told noise is noisy")."""

from __future__ import annotations

import numpy as np
import pytest
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_sim_ros.config import make_config
from ops_sim_ros.simulation import BatchedSimulation

P = TrackerParams()


@pytest.mark.parametrize(
    "rig",
    [
        dict(trace_adc_bits=10, trace_full_scale=1.25),  # rounding alone: 0.0007 rms as told
        dict(trace_adc_bits=12, trace_full_scale=1.25),
        dict(detector_noise=0.0005),
        dict(pulse_amplitude_noise=0.01),
    ],
)
def test_a_told_noise_takes_the_noisy_fit_window(rig):
    tracker = PhaseTracker(make_config(5, "hard", "test", **rig), seed=1)
    assert tracker.window_length == max(P.window, P.noisy_window)


def test_an_ideal_detector_keeps_the_short_window():
    tracker = PhaseTracker(make_config(5, "hard", "test"), seed=1)
    assert tracker.window_length == P.window


def _held(seed: int, steps: int = 700) -> float:
    """Share of readings 150..steps >= 0.95, `lab` rig told, hard, one continuous run."""
    config = make_config(5, "hard", "test", realism="lab")
    sim = BatchedSimulation(config, 1, seed=seed)
    tracker = PhaseTracker(config, seed=seed)
    sim.reset(seed=seed)
    powers = []
    for _ in range(steps):
        res = sim.step_setpoints(next_command(tracker)[None])
        tracker.observe(float(res.power[0]), res.pulse_energies[0])
        powers.append(float(res.power[0]))
    return float(np.mean(np.array(powers[150:]) >= 0.95))


def test_the_lab_rig_is_held_near_the_top():
    """Before the slower drift estimate on a noisy detector (noisy_drift_prior_cycles 0.002),
    3000 readings of seeds 1000 and 1001 held 95.1 % and 95.8 % >= 0.95; now 99.45 % each."""
    held = [_held(seed) for seed in (71, 72)]
    assert min(held) >= 0.97, held
