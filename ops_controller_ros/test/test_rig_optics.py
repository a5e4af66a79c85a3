"""The tracker's nominal optics from a rig YAML (``rig_config``): the file's optics where no
parameter was given, the given parameters over the file, and a bad file or key refused with a
message that names the file and the key."""

from __future__ import annotations

import pytest
import yaml
from ops_contract.ros_interface import ParameterError
from ops_controller_ros.rig_optics import hop_every_on_rig, nominal_optics, power_weight_on_rig

DEFAULTS = {"wavelength_nm": 1030.0, "pulse_fwhm_fs": 1000.0, "detector": "polarizer"}


def _rig(tmp_path, **raw):
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"stage": 5, **raw}))
    return str(path)


def test_no_file_keeps_the_parameters():
    assert nominal_optics(DEFAULTS, set(), "") == (DEFAULTS, None, "")


def test_the_file_fills_what_no_parameter_gave(tmp_path):
    path = _rig(
        tmp_path,
        optics={"wavelength_nm": 1064, "pulse_fwhm_fs": 800.0, "detector": "total"},
        calibration={"fs_per_volt": [1.0] * 5},
    )
    values = dict(DEFAULTS, wavelength_nm=1550.0)
    optics, rig, note = nominal_optics(values, {"wavelength_nm"}, path)
    assert optics == {"wavelength_nm": 1550.0, "pulse_fwhm_fs": 800.0, "detector": "total"}
    assert rig.stage == 5
    assert "wavelength_nm given as parameters" in note and "no calibration" not in note


def test_a_file_without_optics_gives_the_defaults(tmp_path):
    optics, rig, note = nominal_optics(DEFAULTS, set(), _rig(tmp_path))
    assert optics == DEFAULTS and rig.stage == 5 and "run ops_rig_ros calibrate" in note


@pytest.mark.parametrize(
    ("raw", "says"),
    [
        ({"optics": {"wavelength_nm": "abc"}}, r"optics\.wavelength_nm must be a number in"),
        ({"optics": {"pulse_fwhm_fs": 0}}, r"optics\.pulse_fwhm_fs must be a number in \[1,"),
        ({"optics": {"detector": "camera"}}, r"optics\.detector must be one of polarizer, total"),
        ({"optics": {"wavelenght_nm": 1030}}, r"optics\.wavelenght_nm is not a key of optics"),
        ({"optics": [1030]}, r"optics must be a mapping"),
        ({"stage": 11}, r"stage must be an integer from 1 to 10 \(got 11\)"),
    ],
)
def test_a_bad_key_names_the_file_and_the_key(tmp_path, raw, says):
    path = _rig(tmp_path, **raw)
    with pytest.raises(ParameterError, match=says) as err:
        nominal_optics(DEFAULTS, set(), path)
    assert str(err.value).startswith(f"rig_config: the rig file {path}: ")


def test_a_missing_file_names_it(tmp_path):
    with pytest.raises(ParameterError, match=r"cannot read the rig file .*nope\.yaml"):
        nominal_optics(DEFAULTS, set(), str(tmp_path / "nope.yaml"))


@pytest.mark.parametrize(
    ("slew", "rate_hz", "given", "hop_every"),
    [
        (200.0, 50.0, set(), 0),  # 4 V x 0.8 fs/V = 3.2 fs per reading < 2 periods (6.9 fs)
        (200.0, 20.0, set(), 10),  # 8 fs per reading: a move fits in one
        ([200.0, 200.0, 200.0, 200.0, 10.0], 20.0, set(), 0),  # the slowest line counts
        (200.0, 50.0, {"hop_every"}, 10),  # given: kept
    ],
)
def test_whole_cycle_moves_are_off_where_a_line_cannot_make_one_in_a_reading(
    tmp_path, slew, rate_hz, given, hop_every
):
    path = _rig(
        tmp_path,
        rate_hz=rate_hz,
        limits={"volts_min": 0, "volts_max": 75, "slew_volts_per_s": slew},
        calibration={"fs_per_volt": [0.8, 1.0, 1.2, 1.4, 1.0]},
    )
    _, rig, _ = nominal_optics(DEFAULTS, set(), path)
    got, note = hop_every_on_rig(10, given, rig, 1030.0, 2)
    assert got == hop_every
    assert ("whole-cycle moves off" in note) == (hop_every == 0)


def test_no_calibration_leaves_the_moves_alone(tmp_path):
    _, rig, _ = nominal_optics(DEFAULTS, set(), _rig(tmp_path, rate_hz=50.0))
    assert rig.reach_fs_per_reading is None
    assert hop_every_on_rig(10, set(), rig, 1030.0, 2) == (10, "")


def test_on_a_rig_the_power_is_weighed_zero_unless_given(tmp_path):
    _, rig, _ = nominal_optics(DEFAULTS, set(), _rig(tmp_path, rate_hz=50.0))
    weight, note = power_weight_on_rig(1.0, set(), rig)
    assert weight == 0.0 and "computed from its trace" in note
    assert power_weight_on_rig(1.0, {"power_weight"}, rig) == (1.0, "")  # given: kept
    assert power_weight_on_rig(1.0, set(), None) == (1.0, "")  # a simulator: its detector


def test_the_file_tells_the_set_points_each_line_can_take(tmp_path):
    path = _rig(
        tmp_path,
        limits={"volts_min": 0, "volts_max": 75, "slew_volts_per_s": 200.0},
        calibration={"fs_per_volt": [0.8, -1.0, 1.0, 1.0, 1.0], "zero_volts": [40.0] * 5},
    )
    _, rig, _ = nominal_optics(DEFAULTS, set(), path)
    low, high = rig.setpoint_range_fs
    assert low[0] == pytest.approx(-32.0) and high[0] == pytest.approx(28.0)
    assert low[1] == pytest.approx(-35.0) and high[1] == pytest.approx(40.0)  # a negative fs/V
    _, bare, _ = nominal_optics(DEFAULTS, set(), _rig(tmp_path, rate_hz=50.0))
    assert bare.setpoint_range_fs is None
