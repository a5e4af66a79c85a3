"""The learned agents shipped in models/ (issue 11): each folder loads as `policy` and `evaluate`
load it, and re-evaluating one of its recorded evaluation seeds gives the recorded figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from ops_gym_bridge.evaluate import build_parser, evaluate

MODELS = Path(__file__).resolve().parents[2] / "models"
SHIPPED = sorted(p.parent for p in MODELS.glob("*/model.zip"))


def test_models_are_shipped():
    names = {p.name for p in SHIPPED}
    assert "n3_easy" in names  # the one the README runs
    assert any(name.startswith("n5_") for name in names)


@pytest.mark.parametrize("folder", SHIPPED, ids=[p.name for p in SHIPPED])
def test_shipped_model_reproduces_its_recorded_evaluation(folder):
    recorded = json.loads((folder / "eval" / "evaluation.json").read_text())
    meta = json.loads((folder / "metadata.json").read_text())
    assert (recorded["stage"], recorded["mode"]) == (meta["stage"], meta["mode"])
    seed = recorded["seeds"][0]
    episodes = str(recorded["episodes_per_seed"])
    argv = [str(folder), "--seeds", str(seed), "--episodes", episodes, "--splits", "test"]
    args = build_parser().parse_args([*argv, "--quiet"])
    again = evaluate(args)["splits"]["test"]["final_power_per_seed"][0]
    before = recorded["splits"]["test"]["final_power_per_seed"][0]
    # deterministic policy, seeded episodes: the same up to float differences between CPUs
    assert np.isclose(again, before, atol=0.02), (again, before)
