"""The full scale raised while the rig runs (ops_rig_ros.full_scale): a stack shows no more light
than its perfect stack, so summed slot energies above 1 say the calibration's full scale is low;
dark slots that a digitizer's clipped noise lifts above zero are not taken for light."""

from __future__ import annotations

import numpy as np
import pytest
from ops_rig_ros.calibration import calibrate
from ops_rig_ros.fringe import optical_period_fs
from ops_rig_ros.full_scale import FullScaleFollower, dark_floor
from ops_rig_ros.rig import Rig
from ops_rig_ros.rig_config import load_rig_config
from ops_rig_ros.simlab.main import Lab
from ops_rig_ros.trace import slot_readings_volts
from ops_sim_ros.physics import PulseStacker
from ops_sim_ros.rig import digitize
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


def test_the_slot_readings_stand_on_the_records_own_baseline():
    """An offset the calibration got wrong leaves the readings as they are (over 31 slots, 1 mV
    of offset error would be 31 mV of their sum)."""
    positions = 40.0 + 24.0 * np.arange(31)
    x = np.arange(800)
    pulses = np.exp(-0.5 * ((x[:, None] - positions) / 2.4) ** 2)
    energies = np.full(31, 0.002)
    energies[15] = 0.9
    for offset in (0.0, 0.02, -0.013):
        record = offset + 0.75 * (pulses @ energies)
        readings = slot_readings_volts(record, positions)
        np.testing.assert_allclose(readings, 0.75 * energies, atol=1e-6)
        assert readings.sum() == pytest.approx(0.75 * energies.sum(), rel=1e-4)


def _stacked(energy: float, slots: int = 31) -> np.ndarray:
    """Slot energies of a stack: ``energy`` in the middle slot, the others dark."""
    energies = np.zeros(slots)
    energies[slots // 2] = energy
    return energies


def test_dark_slots_lifted_by_a_clipping_digitizer_are_not_taken_for_light():
    """A lock on an 8-bit trace, the calibration's full scale 10 % low: every dark slot reads
    ~5e-4 high on average (the noise below code 0 is clipped), 1.5 % over 30 slots. The plain
    sum raises the full scale that much past the truth, and the power then reads 3 % low; less
    the dark floor it lands within 0.3 %."""
    rng = np.random.default_rng(5)
    truth = 1.0 / 0.9  # the stacked slot's reading with the full scale 10 % low
    stack = np.full(31, 1e-4)  # a good lock: a little light leaks into every slot ...
    stack[[3, 11, 20]] = 0.004  # ... and more into a few
    stack[15] = 1.0 - stack.sum() + stack[15]
    followers = [FullScaleFollower(250), FullScaleFollower(250, subtract_dark_floor=False)]
    for _ in range(3000):
        # the simulator's digitizer: noise 0.002, 8 bits over [0, 1.25], clipped at code 0
        reading = digitize(truth * stack, 0.002, 1, 8, 1.25, rng)
        for follower in followers:
            follower.observe(reading)
    with_floor, plain = (f.gain for f in followers)
    assert plain > truth * 1.01  # what the floor is for: the plain sum runs 1.5 % high
    assert with_floor == pytest.approx(truth, rel=0.003)
    assert followers[0].floor == pytest.approx(5e-4, abs=3e-4)


def test_the_dark_floor_is_a_dark_slots_mean_and_none_for_two_slots():
    readings = np.zeros((10, 7))
    readings[:, 3] = 0.9  # the stack
    readings[:, 1] = 0.05  # light leaking into one slot
    readings[::2, [0, 2, 4, 5, 6]] = 0.002  # the dark ones: 0.001 on average
    assert dark_floor(readings) == pytest.approx(0.001)
    assert dark_floor(readings[:, 2:4]) == 0.0


def test_a_low_full_scale_is_raised_to_the_windows_median_and_no_further():
    rng = np.random.default_rng(0)
    follower = FullScaleFollower(window=50)
    truth = 1.0 / 0.87  # the sums a full scale 13 % low reads at a lock
    sums = truth * (1.0 - np.abs(rng.normal(0.0, 0.005, 2000))) + rng.normal(0.0, 0.02, 2000)
    raised = [i for i, s in enumerate(sums) if follower.observe(_stacked(s))]
    assert raised and raised[0] == 49  # at the first full window
    assert follower.gain == pytest.approx(truth, rel=0.01)  # not run away with the noise
    assert follower.gain <= truth * 1.01


def test_sums_at_or_below_one_and_single_outliers_raise_nothing():
    follower = FullScaleFollower(window=20)
    rng = np.random.default_rng(1)
    for i in range(200):  # an unlocked stack, with a glitch now and then
        s = 0.6 + 0.1 * rng.random() if i % 7 else 3.0
        assert not follower.observe(_stacked(s))
    assert not follower.observe(_stacked(float("nan"))) and follower.gain == 1.0
    assert not follower.observe(np.ones(4))  # another slot count than the first: ignored
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
