"""A detector noise the tracker was not told of is found by its tracking fits (the changes of
their residuals from one reading to the next), and the detector is then taken as noisy. Taken as
clean, an untold noise of 1e-3 (normalized slot energies) was read as knots: the first test's
seeds took 59 / 72 / 47 false knots in 300 readings (hard mode has none) and held 79.5 / 81.6 /
87.0 % of the readings >= 0.95 (docs/results/tracker/notes.md)."""

from __future__ import annotations

import numpy as np
from ops_contract.config import make_config
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_sim_ros.simulation import BatchedSimulation


def _run(seed: int, mode: str = "hard", noise: float = 0.0, steps: int = 300, **params):
    """(tracker, share of the readings after the first lock whose true P_N/P_max >= 0.95):
    N = 5, testing split, the slot energies read with Gaussian noise of std ``noise`` and the
    power computed from them, as a rig node does (``power_weight`` 0 unless given)."""
    config = make_config(5, mode, "test")
    sim = BatchedSimulation(config, 1, seed=seed)
    tracker = PhaseTracker(config, TrackerParams(**{"power_weight": 0.0, **params}), seed=seed)
    sim.reset(seed=seed)
    rng = np.random.default_rng(seed + 1000)
    held = []
    for _ in range(steps):
        locked = tracker.estimate is not None
        res = sim.step_setpoints(next_command(tracker)[None])
        energies = res.pulse_energies[0] + rng.normal(0.0, noise, res.pulse_energies[0].shape)
        power = min(float(np.sum(np.maximum(energies, 0.0) ** 2)), 1.0)
        tracker.observe(power, energies)
        tracker.think()
        if locked:
            held.append(float(res.power[0]) >= 0.95)
    return tracker, float(np.mean(held))


def test_an_untold_noise_is_found_by_the_fits_and_the_lock_holds():
    runs = [_run(seed, noise=1e-3) for seed in (1, 2, 3)]
    for tracker, _ in runs:
        assert tracker.noisy and tracker.window_length == tracker.params.noisy_window
        assert tracker.measured_noise < tracker.params.noisy_threshold  # not by the first reading
        assert 0.7e-3 < tracker.fit_noise < 1.3e-3, tracker.fit_noise
    held = [h for _, h in runs]
    knots = sum(t.knots for t, _ in runs)
    assert np.mean(held) >= 0.95 and min(held) >= 0.9, held
    assert knots <= 40, knots


def test_the_switch_can_be_turned_off():
    tracker, _ = _run(1, noise=1e-3, steps=120, fit_noisy_threshold=0.0)
    assert not tracker.noisy


def test_a_clean_detector_stays_clean():
    """In process (the power weighed in), extreme seeds 3 and 6 misfit by 1-2e-4 (std) for
    hundreds of readings, more in a knot's wake: the residuals' level would have taken them as
    noisy, their changes do not."""
    for mode, seed, weight in (
        ("hard", 1, 0.0),
        ("hard", 2, 0.0),
        ("extreme", 3, 1.0),
        ("extreme", 6, 1.0),
    ):
        tracker, _ = _run(seed, mode=mode, power_weight=weight)
        assert not tracker.noisy, (mode, seed)
        assert tracker.fit_noise < 1e-4, (mode, seed, tracker.fit_noise)
        assert tracker.window_length == tracker.params.window
