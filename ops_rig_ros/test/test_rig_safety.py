"""The safety gate: no command outside the limits, non-finite or of the wrong length ever
reaches a piezo, and every move keeps to the slew limit (the simulated piezo records every
voltage it received, through a real pseudo-terminal)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from ops_rig_ros.rig import Rig
from ops_rig_ros.rig_config import Calibration, load_rig_config
from ops_rig_ros.safety import (
    UnsafeVoltage,
    check_volts,
    command_volts,
    fs_for,
    slew_step,
    volts_for,
)
from rig_lab_helpers import write_rig_yaml


def _cal(n):
    return Calibration(
        fs_per_volt=np.full(n, 1.1),
        zero_volts=np.full(n, 37.0),
        slot_positions=np.arange(2**n - 1) * 24.0 + 50.0,
        detector_offset_volts=0.0,
        detector_full_volts=1.0,
    )


def test_fs_volts_round_trip():
    cal = _cal(3)
    c = np.array([-3.0, 0.0, 12.5])
    np.testing.assert_allclose(fs_for(volts_for(c, cal), cal), c, atol=1e-12)


def test_command_volts_refuses_whole(lab, tmp_path):
    cfg = load_rig_config(write_rig_yaml(lab, tmp_path / "rig.yaml"))
    cal = _cal(3)
    ok, problem = command_volts([0.0, 1.0, -1.0], 3, cal, cfg.limits)
    assert problem is None and ok.shape == (3,)
    for bad, says in (
        ([0.0, 1e9, 0.0], "stage 2 set-point 1e\\+09 fs needs"),
        ([0.0, float("nan"), 0.0], "non-finite"),
        ([0.0, 1.0], "expected 3 delays"),
        ([-1e3, 0.0, 0.0], "outside its limits"),
    ):
        volts, problem = command_volts(bad, 3, cal, cfg.limits)
        assert volts is None
        assert re.search(says, problem), problem


def test_nothing_outside_the_limits_reaches_the_piezo(lab, tmp_path):
    cfg = load_rig_config(
        write_rig_yaml(
            lab,
            tmp_path / "rig.yaml",
            limits={"volts_min": [5, 10, 0], "volts_max": [60, 40, 70], "slew_volts_per_s": 500},
        )
    )
    rig = Rig(cfg)
    rig.drive.connect()
    cal = _cal(3)
    rng = np.random.default_rng(0)
    commands = [
        [1e9, 0.0, 0.0],
        [float("nan"), 0.0, 0.0],
        [0.0, float("inf"), 0.0],
        [0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0],
        [-1e9, -1e9, -1e9],
        *rng.normal(0.0, 60.0, (40, 3)).tolist(),
    ]
    try:
        for c in commands:
            volts, _ = command_volts(c, 3, cal, cfg.limits)
            target = volts if volts is not None else rig.drive.last_sent
            rig.drive.move_towards(target)
        for bad in ([np.nan, 1, 1], [1e6, 1, 1]):
            with pytest.raises(UnsafeVoltage):
                rig.drive._send(np.array(bad, dtype=float))  # the last line of defence
        with pytest.raises(UnsafeVoltage):
            rig.drive.move_towards(np.array([np.nan, 1.0, 1.0]))
    finally:
        rig.close()
    received = np.array(lab.received)
    assert received.size, "nothing was sent"
    for ch in range(3):
        v = received[received[:, 0] == ch, 1]
        assert np.all(np.isfinite(v))
        assert v.min() >= cfg.limits.volts_min[ch] and v.max() <= cfg.limits.volts_max[ch]
        # each send is within one slew step (at most max_dt) of the one before
        step = 500.0 * rig.drive.max_dt + 1e-3
        assert np.all(np.abs(np.diff(v)) <= step)


def test_slew_and_check():
    from ops_rig_ros.rig_config import Limits

    lim = Limits(np.zeros(2), np.full(2, 10.0), np.array([1.0, 100.0]), np.zeros(2))
    np.testing.assert_allclose(slew_step(np.zeros(2), np.full(2, 5.0), lim, 0.1), [0.1, 5.0])
    check_volts([1.0, 2.0], lim)
    with pytest.raises(UnsafeVoltage, match="slew"):
        check_volts([1.0, 2.0], lim, last=np.zeros(2), dt=0.1)
    with pytest.raises(UnsafeVoltage, match="outside"):
        check_volts([11.0, 2.0], lim)


def test_drive_needs_one_channel_per_stage(lab, tmp_path):
    from ops_rig_ros.rig_config import RigConfigError

    data = lab.rig_yaml()
    data["actuators"][0]["channels"] = ["x", "y"]
    path = tmp_path / "rig.yaml"
    import yaml

    path.write_text(yaml.safe_dump(data))
    with pytest.raises(RigConfigError, match="one channel per stage"):
        Rig(load_rig_config(path))


def test_drive_failure_marks_it_disconnected_then_reconnects(lab, tmp_path):
    from ops_rig_ros.drivers.base import InstrumentError

    data = lab.rig_yaml()
    data["actuators"][0]["timeout_s"] = 0.2
    path = tmp_path / "rig.yaml"
    path.write_text(__import__("yaml").safe_dump(data))
    rig = Rig(load_rig_config(path))
    rig.drive.connect()
    try:
        lab.piezos[0].silent = True
        with pytest.raises(InstrumentError, match="no prompt"):
            rig.drive.move_towards(rig.drive.last_sent + 0.5)
        assert not rig.drive.connected
        with pytest.raises(InstrumentError, match="not connected"):
            rig.drive.move_towards(rig.drive.last_sent)
        lab.piezos[0].silent = False
        rig.drive.connect()  # what the node does every reconnect_period_s
        assert rig.drive.connected
        rig.drive.move_towards(rig.drive.last_sent + 0.1)
    finally:
        lab.piezos[0].silent = False
        rig.close()
