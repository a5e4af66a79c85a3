"""One summary and one schema for every evaluation.json (evaluate's and the benchmark's runs),
read back also from benchmark runs stored before it; the YAML profiles and candidates; the one
model-building path."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ops_experiments.build import build_model
from ops_experiments.summary import (
    SUMMARY_KEYS,
    read_evaluation,
    read_summary,
    summarize,
)
from ops_experiments.table1 import benchmark, report

from ops_experiments import hyperparams as hp

pytestmark = pytest.mark.timeout(120)


def _seed(finals, start=0.2):
    """One seed's rollout result: episodes rising linearly from ``start`` to ``finals``."""
    finals = np.asarray(finals, dtype=float)
    power = np.linspace(start, finals, 11).T  # (episodes, steps + 1)
    return {"power": power, "returns": power[:, 1:].sum(axis=1)}


def test_summarize_keeps_the_worst_episode_beside_the_mean():
    s = summarize([_seed([0.9, 0.95]), _seed([0.5, 0.99])])
    assert tuple(s) == SUMMARY_KEYS
    assert s["final_power_per_seed"] == [0.925, 0.745]
    assert s["final_power_mean"] == pytest.approx(0.835)
    assert s["final_power_min_episode"] == pytest.approx(0.5)  # not the worst seed's mean
    assert s["final_power_per_episode"] == [0.9, 0.95, 0.5, 0.99]
    assert s["initial_power_mean"] == pytest.approx(0.2)
    assert len(s["curve_mean"]) == 11 and s["curve_mean"][-1] == pytest.approx(0.835)
    json.dumps(s)  # plain JSON


# What a benchmark run wrote before the one schema (docs/results/*/runs/*/evaluation.json).
OLD_BENCHMARK_SPLIT = {
    "final_power_mean": 0.8,
    "final_power_std": 0.1,
    "final_power_per_seed": [0.7, 0.9],
    "curve_mean": [0.3, 0.6, 0.8],
    "curve_std": [0.01, 0.02, 0.03],
}


def test_a_summary_of_the_old_benchmark_schema_reads_in_the_one_schema():
    s = read_summary(OLD_BENCHMARK_SPLIT)
    assert tuple(s) == SUMMARY_KEYS
    assert s["final_power_per_seed"] == [0.7, 0.9] and s["curve_mean"] == [0.3, 0.6, 0.8]
    assert s["initial_power_mean"] == 0.3  # from the curve
    assert s["final_power_min_episode"] is None  # not measured then: not made up
    assert s["final_power_per_episode"] is None and s["episode_return_mean"] is None
    new = summarize([_seed([0.9, 0.95])])
    assert read_summary(new) == new


def test_report_reads_old_and_new_runs_alike(tmp_path):
    """A folder with a run in the old schema and one in the new gives the same Table 1 cells as
    if both were old (the report reads what both hold)."""
    new = summarize([_seed([0.7, 0.7]), _seed([0.9, 0.9])])
    for rid, split in (("n5_easy_td3_s0", OLD_BENCHMARK_SPLIT), ("n5_easy_td3_s1", new)):
        d = tmp_path / "runs" / rid
        d.mkdir(parents=True)
        spec = {"id": rid, "kind": "train", "algo": "td3", "stage": 5, "mode": "easy",
                "seed": int(rid[-1]), "detector": "total", "observation": "authors"}  # fmt: skip
        (d / "run.json").write_text(json.dumps({"spec": spec, "timesteps": 100}))
        ev = {"splits": {"train": split, "test": split}, "transfer": {}}
        (d / "evaluation.json").write_text(json.dumps(ev))
    ev = read_evaluation(tmp_path / "runs" / "n5_easy_td3_s0" / "evaluation.json")
    assert ev["splits"]["test"]["initial_power_mean"] == 0.3
    rows = report.table1_rows(report.load_runs(tmp_path))
    test_row = next(r for r in rows if r["environment"] == "testing")
    assert test_row["n"] == 2 and test_row["mean"] == pytest.approx(0.8)
    assert read_evaluation(tmp_path / "missing.json") is None


def test_profiles_and_candidates_load_from_yaml_beside_the_hyperparameters():
    profiles = hp.profiles()
    assert set(profiles) >= {"paper", "quick", "smoke"}
    assert profiles == benchmark.PROFILES
    paper = profiles["paper"]
    assert paper["stage"] == 5 and paper["seeds"] == list(range(10))
    assert paper["timesteps"] == {"ppo": 300_000, "td3": 300_000, "sac": 300_000}
    assert [tuple(t) for t in paper["traces"]] == [("td3", "hard")]
    assert profiles["smoke"]["hyperparams"]["td3"][-1] == "net_arch=[16,16]"
    for name in ("profiles.yaml", "candidates.yaml"):  # installed with the package
        assert (hp.HYPERPARAMS_DIR / name).is_file()
    cands = hp.candidates()
    assert cands["fast-sac-64env"] == {
        "algo": "sac", "hyperparams_set": "fast", "n_envs": 64, "obs_history": 0,
        "overrides": ["gradient_steps=8"],
    }  # fmt: skip
    for c in cands.values():
        hp.apply_overrides(hp.load(c["algo"], c["hyperparams_set"]), c["overrides"])


def test_a_profile_missing_a_key_is_refused(monkeypatch, tmp_path):
    (tmp_path / "profiles.yaml").write_text("tiny: {stage: 2}\n")
    monkeypatch.setattr(hp, "HYPERPARAMS_DIR", tmp_path)
    with pytest.raises(ValueError, match="tiny must have the keys"):
        hp.profiles()


def test_build_model_builds_as_train_does(tmp_path):
    """The one model-building path: train's options in, the run (env, model, params) out."""
    run = build_model(
        ["--algo", "td3", "--stage", "2", "--mode", "easy", "--timesteps", "0",
         "--hyperparams", "net_arch=[8,8]", "learning_starts=10"],
        out=tmp_path / "m",
    )  # fmt: skip
    try:
        assert run.args.algo == "td3" and run.args.n_envs == 1 and run.args.observation == "rig"
        assert run.params["learning_starts"] == 10
        assert run.model.policy.actor.mu[0].out_features == 8
        assert run.venv.num_envs == 1 and run.model.num_timesteps == 0
    finally:
        run.venv.close()
