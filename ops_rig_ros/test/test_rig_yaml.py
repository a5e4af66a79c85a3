"""The rig YAML: every key a rig needs is checked before an instrument is touched, and the
message names the key."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from ops_rig_ros.rig_config import (
    Calibration,
    RigConfigError,
    load_rig_config,
    save_calibration,
)
from rig_lab_helpers import write_rig_yaml


def test_simlab_yaml_loads(lab, tmp_path):
    cfg = load_rig_config(write_rig_yaml(lab, tmp_path / "rig.yaml"))
    assert cfg.stage == 3 and cfg.calibration is None
    assert cfg.trace_baseline == "record"  # the default
    np.testing.assert_allclose(cfg.limits.volts_max, 75.0)
    np.testing.assert_allclose(cfg.limits.park_volts, 0.0)


@pytest.mark.parametrize(
    ("limits", "says"),
    [
        (None, "limits is required"),
        ({"volts_min": 0, "volts_max": 75}, "limits.slew_volts_per_s is required"),
        ({"volts_max": 75, "slew_volts_per_s": 10}, "limits.volts_min is required"),
        ({"volts_min": 0, "volts_max": [75, 75], "slew_volts_per_s": 9}, "3 values"),
        ({"volts_min": 10, "volts_max": 5, "slew_volts_per_s": 9}, "above limits.volts_min"),
        ({"volts_min": 0, "volts_max": 75, "slew_volts_per_s": 0}, "slew_volts_per_s\\[0\\]"),
        (
            {"volts_min": 0, "volts_max": 75, "slew_volts_per_s": 9, "park_volts": 80},
            "park_volts",
        ),
        ({"volts_min": "x", "volts_max": 75, "slew_volts_per_s": 9}, "must be a number"),
    ],
)
def test_limits_are_required_and_checked(lab, tmp_path, limits, says):
    data = lab.rig_yaml()
    if limits is None:
        del data["limits"]
    else:
        data["limits"] = limits
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(RigConfigError, match=says):
        load_rig_config(path)


def test_other_keys(lab, tmp_path):
    path = tmp_path / "rig.yaml"
    for change, says in (
        ({"stage": 11}, "stage must be in"),
        ({"scope": None}, "scope is required"),
        ({"actuators": []}, "actuators is required"),
        ({"rate_hz": 0}, "rate_hz"),
        ({"trace_baseline": "dark"}, "trace_baseline must be one of record, calibrated"),
    ):
        write_rig_yaml(lab, path, **change)
        with pytest.raises(RigConfigError, match=says):
            load_rig_config(path)
    with pytest.raises(RigConfigError, match="cannot read"):
        load_rig_config(tmp_path / "missing.yaml")


def test_calibration_round_trip(lab, tmp_path):
    path = write_rig_yaml(lab, tmp_path / "rig.yaml")
    cal = Calibration(
        np.array([1.0, 1.1, 1.2]), np.array([30.0, 31.0, 32.0]), 50 + 24.0 * np.arange(7), 0.02, 0.8
    )
    save_calibration(path, cal)
    back = load_rig_config(path).calibration
    np.testing.assert_allclose(back.fs_per_volt, cal.fs_per_volt)
    np.testing.assert_allclose(back.slot_positions, cal.slot_positions)
    assert back.detector_full_volts == 0.8
    assert load_rig_config(path).scope["driver"] == "scpi_scope"  # the rest kept


def test_the_optics_are_checked_as_the_tracker_checks_them(lab, tmp_path):
    """optics.* is the key set the tracker's ``rig_config`` reads (ops_contract.rig_file)."""
    cfg = load_rig_config(write_rig_yaml(lab, tmp_path / "rig.yaml", optics={"detector": "total"}))
    assert cfg.optics == {"wavelength_nm": 1030.0, "pulse_fwhm_fs": 1000.0, "detector": "total"}
    bad = write_rig_yaml(lab, tmp_path / "bad.yaml", optics={"wavelength_nm": -5})
    with pytest.raises(RigConfigError, match=r"optics\.wavelength_nm must be a number in"):
        load_rig_config(bad)
