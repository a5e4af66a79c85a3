"""The full scale raised while the rig runs (ops_rig_ros.full_scale): a stack shows no more light
than its perfect stack, so summed slot energies above 1 say the calibration's full scale is low."""

from __future__ import annotations

import numpy as np
import pytest
from ops_rig_ros.calibration import calibrate
from ops_rig_ros.fringe import optical_period_fs
from ops_rig_ros.full_scale import FullScaleFollower
from ops_rig_ros.rig import Rig
from ops_rig_ros.rig_config import load_rig_config
from ops_rig_ros.simlab.main import Lab
from ops_rig_ros.trace import summed_slots_volts
from ops_sim_ros.physics import PulseStacker
from rig_lab_helpers import write_rig_yaml


def test_slot_energies_never_sum_above_the_perfect_stack():
    """The physics the follower rests on, for the polarizer port and both ports together."""
    rng = np.random.default_rng(3)
    for detector in ("polarizer", "total"):
        stacker = PulseStacker(stage=5, dtype=np.float64, detector=detector)
        delays = rng.normal(0.0, 2.0, (500, 5))  # fs: from near the lock to anywhere
        sums = stacker.slot_energies(delays).sum(-1)
        assert sums.max() <= 1.0 + 1e-9
        assert stacker.slot_energies(np.zeros((1, 5))).sum() == pytest.approx(1.0, abs=1e-9)


def test_the_summed_slots_stand_on_the_records_own_baseline():
    """An offset the calibration got wrong leaves the sum as it is (over 31 slots, 1 mV of
    offset error would be 31 mV of sum)."""
    positions = 40.0 + 24.0 * np.arange(31)
    x = np.arange(800)
    pulses = np.exp(-0.5 * ((x[:, None] - positions) / 2.4) ** 2)
    energies = np.full(31, 0.002)
    energies[15] = 0.9
    for offset in (0.0, 0.02, -0.013):
        record = offset + 0.75 * (pulses @ energies)
        assert summed_slots_volts(record, positions) == pytest.approx(
            0.75 * energies.sum(), rel=1e-4
        )


def test_a_low_full_scale_is_raised_to_the_windows_median_and_no_further():
    rng = np.random.default_rng(0)
    follower = FullScaleFollower(window=50)
    truth = 1.0 / 0.87  # the sums a full scale 13 % low reads at a lock
    sums = truth * (1.0 - np.abs(rng.normal(0.0, 0.005, 2000))) + rng.normal(0.0, 0.02, 2000)
    raised = [i for i, s in enumerate(sums) if follower.observe(s)]
    assert raised and raised[0] == 49  # at the first full window
    assert follower.gain == pytest.approx(truth, rel=0.01)  # not run away with the noise
    assert follower.gain <= truth * 1.01


def test_sums_at_or_below_one_and_single_outliers_raise_nothing():
    follower = FullScaleFollower(window=20)
    rng = np.random.default_rng(1)
    for i in range(200):  # an unlocked stack, with a glitch now and then
        s = 0.6 + 0.1 * rng.random() if i % 7 else 3.0
        assert not follower.observe(s)
    assert not follower.observe(float("nan")) and follower.gain == 1.0
    with pytest.raises(ValueError, match="at least 1"):
        FullScaleFollower(0)


def test_the_rig_raises_a_full_scale_set_low_and_its_power_reads_the_stack(tmp_path):
    """The simulated lab at the calibrated zeros (medium, a stack near its lock), the rig's full
    scale set 15 % low: the power read 1 (clipped); after one window the power's full scale is
    within 3 % of the lab's hidden truth, the trace keeps the calibration's units (a controller
    fitting its gain sees no step) and, off the lock, the power reads the lab's true power."""
    lab = Lab(stage=3, mode="medium", seed=4, quiet=False, scope_format="WORD")
    try:
        rig = Rig(load_rig_config(write_rig_yaml(lab, tmp_path / "rig.yaml")))
        rig.drive.connect()
        rig.connect_scope()
        rig.config.calibration = calibrate(rig, log=lambda _: None)
        truth = lab.optics.truth.detector_full_volts
        rig.config.calibration.detector_full_volts = 0.85 * truth
        assert rig.reading(8)[1] == 1.0  # clipped: the stack reads above its perfect stack
        rig.follow_full_scale(40)
        readings = [(*rig.reading(8), lab.optics.last_power) for _ in range(60)]
        assert rig.detector_full_volts == pytest.approx(truth, rel=0.03)
        assert rig.config.calibration.detector_full_volts == 0.85 * truth  # the file's, kept
        stacked = [trace[8 * 3 + 4] for trace, _, _ in readings]  # stage 3: slot 3 is the stack
        assert min(stacked[45:]) > 1.05  # the trace still reads the calibration's 15 % high
        # Off the lock (stage 1 a tenth of a cycle off), the power reads the lab's true power;
        # with the calibration's low full scale it read 1.38 times that (clipped at 1).
        cal = rig.config.calibration
        off = cal.zero_volts.copy()
        off[0] += 0.1 * optical_period_fs() / cal.fs_per_volt[0]
        rig.drive.ramp_to(off)
        readings = [(*rig.reading(8), lab.optics.last_power) for _ in range(12)]
        power, true_power = (np.median([r[i] for r in readings[2:]]) for i in (1, 2))
        assert true_power < 0.85 and power == pytest.approx(true_power, abs=0.03)
        rig.close()
    finally:
        lab.close()
