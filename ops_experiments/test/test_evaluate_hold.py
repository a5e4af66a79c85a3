"""``evaluate --hold-steps``: a model trained without latency, acting on one reading in
latency + 1 and holding its command in between (ops_controller_ros.policy_hold), on a rig with
latency. Ten episodes each (seeds 8301-8302, the realism sweep's), a few seconds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ops_experiments import evaluate

MODEL = Path(__file__).resolve().parents[2] / "models" / "n5_hard"
BASE = ["--mode", "hard", "--splits", "test", "--seeds", "8301", "8302", "--episodes", "5"]
BASE += ["--no-plot", "--quiet"]


def _run(tmp_path, name: str, *extra: str) -> dict:
    out = tmp_path / name
    assert evaluate.run([str(MODEL), *BASE, "--out", str(out), *extra]) == 0
    return json.loads((out / "evaluation.json").read_text())


def _finals(results: dict) -> np.ndarray:
    return np.asarray(results["splits"]["test"]["final_power_mean"])


def test_held_decisions_bring_a_latency_free_model_back_under_latency(tmp_path):
    bare = _run(tmp_path, "bare", "--rig", "latency_steps=1")
    held = _run(tmp_path, "held", "--rig", "latency_steps=1", "--hold-steps", "auto")
    assert "hold_steps" not in bare and held["hold_steps"] == 2  # auto: latency 1 + 1
    assert _finals(bare) < 0.4  # measured 0.20 over 100 episodes
    assert _finals(held) > 0.7 and _finals(held) > _finals(bare) + 0.4  # measured 0.83
    # To the policy the rig looks latency-free: the same hold on the ideal rig gives the very
    # same decisions' readings, so the same finals.
    ideal = _run(tmp_path, "ideal", "--hold-steps", "2")
    assert _finals(ideal) == pytest.approx(_finals(held), abs=1e-12)


def test_auto_on_an_ideal_rig_acts_on_every_reading(tmp_path):
    bare = _run(tmp_path, "bare")
    auto = _run(tmp_path, "auto", "--hold-steps", "0")
    assert auto["hold_steps"] == 1
    assert _finals(auto) == _finals(bare)


def test_bad_hold_steps_are_refused_with_the_allowed_range(tmp_path, capsys):
    for bad in ("-1", "1002", "1.5", "some"):
        with pytest.raises(SystemExit) as exc:
            evaluate.run([str(MODEL), "--hold-steps", bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "--hold-steps must be auto (or 0" in err and "from 1 to 1001" in err
    code = evaluate.run(["--controller", "tracker", "--hold-steps", "2", "--out", str(tmp_path)])
    assert code == 2
    assert "--hold-steps holds a learned policy's decisions" in capsys.readouterr().err
