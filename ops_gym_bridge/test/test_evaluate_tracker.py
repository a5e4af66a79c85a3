"""`evaluate --controller tracker`: the model-based controller through the evaluation CLI."""

from __future__ import annotations

import json

from ops_gym_bridge import evaluate


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
