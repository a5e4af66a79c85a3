"""`evaluate --controller tracker`: the model-based controller through the evaluation CLI."""

from __future__ import annotations

import json

from ops_experiments import evaluate


def test_evaluate_controller_tracker_with_a_model_mismatch(tmp_path):
    """`evaluate --controller tracker` at N = 4 with a pulse width the tracker is not told of."""
    out = tmp_path / "eval"
    argv = ["--controller", "tracker", "--stage", "4", "--mode", "medium", "--episodes", "2"]
    argv += ["--seeds", "0", "--steps", "40", "--env", "pulse_fwhm_fs=1200", "--out", str(out)]
    assert evaluate.run([*argv, "--no-plot", "--quiet"]) == 0
    result = json.loads((out / "evaluation.json").read_text())
    assert result["controller"] == "tracker"
    for split in result["splits"].values():
        assert split["curve_mean"][-1] > 0.97, split["curve_mean"][-5:]


def test_a_rig_the_tracker_is_told_of_and_one_it_is_not(tmp_path, capsys):
    """`--rig latency_steps=2`: the simulator's commands act two steps late and the tracker
    knows it (told nothing, one step of latency takes it to 0.10). The summary prints
    the worst episode beside the mean; a figure that is not the rig's is refused by name."""
    out = tmp_path / "eval"
    argv = ["--controller", "tracker", "--stage", "3", "--mode", "medium", "--episodes", "2"]
    argv += ["--seeds", "0", "--steps", "60", "--splits", "test", "--out", str(out)]
    assert evaluate.run([*argv, "--rig", "latency_steps=2", "--no-plot"]) == 0
    result = json.loads((out / "evaluation.json").read_text())
    assert result["rig"] == {"latency_steps": 2}
    assert result["splits"]["test"]["final_power_min_episode"] > 0.95
    assert "worst episode" in capsys.readouterr().out
    assert evaluate.run([*argv, "--rig", "wavelength_nm=1000", "--no-plot", "--quiet"]) == 2
    assert "--rig wavelength_nm: not a figure of the rig" in capsys.readouterr().err
    assert evaluate.run([*argv, "--rig", "latency_steps=-1", "--no-plot", "--quiet"]) == 2
    assert "latency_steps must be from 0 to 1000" in capsys.readouterr().err


def test_the_default_output_folder_names_the_cell_once(tmp_path):
    """A model folder named for its cell (models/n5_easy) is not named twice
    (not runs/eval/n5_easy_n5_easy); a controller's folder gets the cell."""
    from types import SimpleNamespace

    model = tmp_path / "n5_easy"
    model.mkdir()
    (model / "model.zip").write_bytes(b"")
    cell = SimpleNamespace(name="sac", stage=5, mode="easy")
    assert evaluate.default_out(SimpleNamespace(model=str(model)), cell).name == "n5_easy"
    other = SimpleNamespace(name="sac", stage=5, mode="hard")
    assert evaluate.default_out(SimpleNamespace(model=str(model)), other).name == "n5_easy_n5_hard"
    tracker = SimpleNamespace(name="tracker", stage=5, mode="hard")
    assert evaluate.default_out(SimpleNamespace(model=None), tracker).name == "tracker_n5_hard"
