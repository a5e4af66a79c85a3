"""Trace extraction, the power estimate, and the calibration against the simulated lab's hidden
truth (fs per volt within 2 %, the zero within 0.05 optical cycle)."""

from __future__ import annotations

import numpy as np
import pytest
from ops_rig_ros.calibration import calibrate
from ops_rig_ros.fringe import find_slots, fit_fringe, indicator_weights, optical_period_fs
from ops_rig_ros.rig import Rig
from ops_rig_ros.rig_config import Calibration, load_rig_config
from ops_rig_ros.simlab.main import Lab
from ops_rig_ros.trace import estimate_power, extract_trace
from ops_sim_ros.physics import PulseStacker
from rig_lab_helpers import write_rig_yaml


def test_power_is_the_sum_of_squared_slot_energies():
    ps = PulseStacker(stage=4, dtype=np.float64)
    d = np.random.default_rng(0).normal(0.0, 0.5, (200, 4))
    out = ps.evaluate(d)
    trace = ps.trace_from_energies(out.slot_energies)
    est = np.array([estimate_power(t, ps.samples_per_slot) for t in trace])
    np.testing.assert_allclose(est, out.power, atol=1e-5)


def test_extract_trace_normalizes_and_centres():
    positions = 40.0 + 24.0 * np.arange(7)
    cal = Calibration(np.ones(3), np.zeros(3), positions, 0.05, 0.5)
    x = np.arange(250)
    energies = np.array([0.0, 0.1, 0.0, 0.8, 0.0, 0.1, 0.0])
    record = 0.05 + 0.5 * (np.exp(-0.5 * ((x[:, None] - positions) / 2.4) ** 2) @ energies)
    trace = extract_trace(record, cal, 8, "calibrated")
    np.testing.assert_allclose(trace[4::8], energies, atol=1e-9)
    # the record's own baseline: the pulses' tails half-way between slots (5 sigma) only
    np.testing.assert_allclose(extract_trace(record, cal, 8)[4::8], energies, atol=1e-5)
    with pytest.raises(ValueError, match="does not reach"):
        extract_trace(record[:100], cal, 8)
    with pytest.raises(ValueError, match="baseline must be one of record, calibrated"):
        extract_trace(record, cal, 8, "dark")


def test_the_records_own_baseline_takes_out_an_offset_the_calibration_missed():
    """A calibrated offset 0.5 mV off (1e-3 of the full scale; calibrate was seen up to 1.1e-3
    off on the simulated lab) reads as light in every empty slot; the record's baseline, half-way
    between the slots, does not, and moves with a detector's offset after the calibration."""
    positions = 40.0 + 24.0 * np.arange(7)
    x = np.arange(250)
    energies = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    bumps = np.exp(-0.5 * ((x[:, None] - positions) / 2.4) ** 2) @ energies
    for true_offset in (0.0495, 0.0512):
        record = true_offset + 0.5 * bumps
        cal = Calibration(np.ones(3), np.zeros(3), positions, 0.05, 0.5)
        told = extract_trace(record, cal, 8, "calibrated")[4::8]
        assert np.max(np.abs(told - energies)) > 9e-4  # every slot off by the offset's error
        np.testing.assert_allclose(extract_trace(record, cal, 8)[4::8], energies, atol=1e-5)


def test_fit_fringe_recovers_a_sinusoid():
    v = np.linspace(30, 42, 60)
    s = 0.2 + 0.1 * np.cos(2 * np.pi * 0.31 * v + 1.0)
    f, a, b, phi, rms = fit_fringe(v, s, 0.1, 2.0)
    assert f == pytest.approx(0.31, rel=1e-4) and b == pytest.approx(0.1, rel=1e-3)
    assert a == pytest.approx(0.2, abs=1e-6)
    assert np.cos(phi - 1.0) == pytest.approx(1.0, abs=1e-6)
    assert rms < 1e-6


def test_indicator_weights_of_the_last_stage_is_the_stacked_slot():
    w = indicator_weights(3, 2)
    assert np.flatnonzero(w).tolist() == [3] and w[3] == 1.0
    assert np.count_nonzero(indicator_weights(3, 0)) > 1


def test_find_slots_from_a_partly_lit_pattern():
    true = 60.3 + 24.0 * np.arange(15)
    lit = np.array([0, 0, 0.05, 0.1, 0.2, 0.3, 0.4, 1.0, 0.4, 0.3, 0.2, 0.1, 0.05, 0, 0])
    x = np.arange(500)
    rec = np.exp(-0.5 * ((x[:, None] - true) / 2.4) ** 2) @ lit
    np.testing.assert_allclose(find_slots(rec, 15), true, atol=0.2)


def test_find_slots_centres_an_unevenly_lit_pattern_by_its_mean():
    """The slots seen in the maximum lie off centre (the last two never lit): the maximum alone
    puts the grid one slot off; the mean records' mirror symmetry puts it right."""
    true = 60.3 + 24.0 * np.arange(15)
    x = np.arange(500)
    pulses = np.exp(-0.5 * ((x[:, None] - true) / 2.4) ** 2)
    lit = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 1.0, 0.6, 0.5, 0.4, 0.3, 0.2, 0, 0])
    mean = np.array([1, 2, 4, 7, 11, 15, 19, 30, 19, 15, 11, 7, 4, 2, 1]) / 30.0
    assert abs(find_slots(pulses @ lit, 15)[0] - true[0]) > 20.0
    np.testing.assert_allclose(
        find_slots(pulses @ lit, 15, mean_record=pulses @ mean), true, atol=0.2
    )


def _calibrate_on(lab, tmp_path):
    """``calibrate`` on ``lab``'s instruments through a rig YAML written for them."""
    rig = Rig(load_rig_config(write_rig_yaml(lab, tmp_path / "rig.yaml")))
    rig.drive.connect()
    rig.connect_scope()
    cal = calibrate(rig, log=lambda _: None)
    rig.close()
    return cal


@pytest.mark.parametrize(("stage", "mode", "quiet"), [(5, "easy", True), (3, "medium", False)])
def test_calibration_recovers_the_hidden_truth(tmp_path, stage, mode, quiet):
    lab = Lab(stage=stage, mode=mode, seed=11, quiet=quiet, scope_format="WORD")
    try:
        cal = _calibrate_on(lab, tmp_path)
        truth = lab.optics.truth
        np.testing.assert_allclose(cal.fs_per_volt, truth.fs_per_volt, rtol=0.02)
        period_v = optical_period_fs() / truth.fs_per_volt
        cycles = (cal.zero_volts - truth.zero_volts) / period_v
        assert np.all(np.abs(cycles - np.round(cycles)) < 0.05), cycles
        np.testing.assert_allclose(cal.slot_positions, truth.slot_positions, atol=0.5)
        assert cal.detector_full_volts == pytest.approx(truth.detector_full_volts, rel=0.05)
        received = np.array(lab.received)[:, 1]
        assert received.min() >= 0.0 and received.max() <= 75.0
    finally:
        lab.close()


@pytest.mark.parametrize("seed", [1, 5])
def test_calibration_survives_hard_drift_on_a_lab_rig(tmp_path, seed):
    """``--realism lab`` with ``hard`` drift: every record is a step of the drift, and the
    sweeps take ~1000 of them. Before each stage's sweep the earlier stages are peaked up again
    on their own fringes, and each stage is swept up and down (a steady drift's shift of the
    fringe frequency cancels): seeds 1 and 5 failed with "no clear fringe" without the first,
    and fs per volt came out 4-5.6 % high on seeds 4 and 5 without the second."""
    lab = Lab(stage=5, mode="hard", realism="lab", seed=seed, scope_format="WORD")
    try:
        cal = _calibrate_on(lab, tmp_path)
        np.testing.assert_allclose(cal.fs_per_volt, lab.optics.truth.fs_per_volt, rtol=0.025)
        np.testing.assert_allclose(cal.slot_positions, lab.optics.truth.slot_positions, atol=0.5)
        received = np.array(lab.received)[:, 1]
        assert received.min() >= 0.0 and received.max() <= 75.0
    finally:
        lab.close()
