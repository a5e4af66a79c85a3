"""The tracker's online calibration: it estimates a detector gain and offset it is not told of,
while it holds the lock (no calibration phase)."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.calibration import ModelCalibration
from ops_controller_ros.controllers import next_command
from ops_controller_ros.tracker import PhaseTracker, TrackerParams
from ops_sim_ros.env import OpsEnv


def _run(true_overrides, steps, seed, params=None, mode="hard"):
    nominal = make_config(5, mode, "test")
    env = OpsEnv.from_config(nominal.replace(**true_overrides), max_episode_steps=steps)
    _, info = env.reset(seed=seed)
    ctl = PhaseTracker(nominal, params or TrackerParams(), info["setpoints_fs"], seed=seed)
    power = []
    for _ in range(steps):
        r = env.step_setpoints(next_command(ctl))
        ctl.observe(float(r.power[0]), r.pulse_energies[0])
        power.append(float(r.power[0]))
    return ctl, np.array(power)


@pytest.mark.parametrize("seed", [2001, 2002])
def test_detector_gain_and_offset_are_estimated_while_locked(seed):
    ctl, power = _run({"detector_gain": 0.7, "detector_offset": 0.02}, 300, seed)
    est = ctl.calibration.estimates()
    assert est["detector_gain"] == pytest.approx(0.7, rel=0.01), est
    assert est["detector_offset"] == pytest.approx(0.02, abs=0.003), est
    # no calibration phase that costs the lock: held from step 50 on. A glitch of a reading or
    # two is allowed: which trajectory a seed takes hangs on the last bit of the fits' sums
    # (seed 2001 dips to 0.48 for 2 readings at step 85 with the Jacobian stored C-ordered,
    # holds >= 0.98 with it as it comes), and the test must hold on any CPU.
    assert np.sum(power[50:] < 0.95) <= 3, np.flatnonzero(power[50:] < 0.95) + 50
    # the optics are nominal here: the wavelength estimate stays near 1030 nm, the width is not
    # estimated
    assert est["wavelength_nm"] == pytest.approx(1030.0, rel=0.003), est
    assert est["pulse_fwhm_fs"] == 1000.0


@pytest.mark.parametrize(("true_nm", "seed"), [(1050.6, 2001), (1019.7, 2002)])
def test_a_wavelength_it_is_not_told_of_is_estimated_while_locked(true_nm, seed):
    """A rig 2 % or 1 % off the model's 1030 nm: the tracker's whole-cycle moves measure the
    period; the estimate comes within 0.3 % and stays there, and the lock holds meanwhile."""
    ctl, power = _run({"wavelength_nm": true_nm}, 600, seed)
    assert ctl.hops > 20
    assert ctl.calibration.estimates()["wavelength_nm"] == pytest.approx(true_nm, rel=0.003)
    assert np.mean(power[50:] >= 0.95) > 0.98, np.mean(power[50:] >= 0.95)
    # without the moves the model keeps its wavelength (what an unseen period would do)
    ctl, _ = _run({"wavelength_nm": true_nm}, 200, seed, TrackerParams(hop_every=0))
    assert ctl.calibration.estimates()["wavelength_nm"] == 1030.0


def test_without_calibration_a_detector_off_by_thirty_percent_is_not_acquired():
    """The reason for the calibration: with gain x0.7 the uncalibrated fit never explains the
    readings, so the tracker never locks (why the test above would fail without it)."""
    ctl, power = _run({"detector_gain": 0.7}, 80, 2001, TrackerParams(calibrate=False))
    assert not ctl.locked and power[-50:].mean() < 0.9


def test_fit_detector_recovers_a_line_and_refuses_a_flat_window():
    cal = ModelCalibration(make_config(3))
    f = np.linspace(0.0, 1.0, 24).reshape(4, 6)
    assert cal.fit_detector(f, 0.8 * f + 0.05)
    assert cal.gain == pytest.approx(0.8) and cal.offset == pytest.approx(0.05)
    y = cal.correct(0.8 * f + 0.05)
    assert np.allclose(y[:, :-1], f[:, :-1]) and np.allclose(y[:, -1], 0.8 * f[:, -1] + 0.05)
    flat = np.full((4, 6), 0.3)
    assert not cal.fit_detector(flat, flat)
    assert cal.gain == pytest.approx(0.8)  # unchanged


def test_a_detector_fit_that_never_locks_is_forgotten():
    """A gain fitted to readings that did not belong together must not keep the tracker unlocked
    for good: after calibration_reset_after readings without lock it is back to nominal."""
    ctl, _ = _run({}, 60, 2003, TrackerParams(calibration_reset_after=30))
    assert ctl.locked
    ctl.calibration.gain, ctl.calibration.offset = 0.56, 0.005  # a corrupted estimate
    ctl.estimate = None  # lost
    for _ in range(40):
        ctl.command()
        ctl.observe(0.1, np.full(ctl.stacker.num_slots, 0.1))
    assert ctl.calibration_resets >= 1
    assert ctl.calibration.estimates()["detector_gain"] != 0.56
