"""The model metadata schema (ops_contract.policy_meta): every shipped model's metadata.json reads
with the defaults of the fields format 1 lacks, round-trips through write_meta, and what a runner
does not know or was not trained for is refused with a message that names it. Real files; no
torch (the networks are not loaded here)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from ops_contract.observation import ObservationSpec
from ops_contract.policy_layers import SwitchParams, WatchdogParams
from ops_contract.policy_meta import (
    FORMAT_VERSION,
    PolicyLoadError,
    PolicyMeta,
    check_asked,
    read_meta,
    recipe_known,
    write_meta,
)

MODELS = Path(__file__).resolve().parents[2] / "models"
SHIPPED = sorted(p.parent for p in MODELS.glob("**/metadata.json"))


def _format(folder: Path) -> int:
    return json.loads((folder / "metadata.json").read_text()).get("format_version", 1)


#: The shipped models written before format 2 (no recipe, recurrent, training_wall_s) and after.
LEGACY = [p for p in SHIPPED if _format(p) == 1]
CURRENT = [p for p in SHIPPED if _format(p) >= 2]


def _entries(**extra) -> dict:
    return {
        "algo": "sac",
        "stage": 3,
        "mode": "easy",
        "action_type": "increment",
        "max_step_fs": 0.07,
        "observation_spec": ObservationSpec(stage=3, history=2).to_dict(),
        "config": {"detector": "polarizer"},
        **extra,
    }


@pytest.mark.parametrize("folder", LEGACY, ids=[str(p.relative_to(MODELS)) for p in LEGACY])
def test_a_shipped_model_reads_with_the_new_fields_defaults_and_round_trips(folder, tmp_path):
    raw = json.loads((folder / "metadata.json").read_text())
    assert "recipe" not in raw and raw["format_version"] == 1  # written before format 2
    meta = read_meta(folder)
    assert meta.path == folder and meta.model_file == folder / "model.zip"
    assert (meta.algo, meta.stage, meta.mode) == (raw["algo"], raw["stage"], raw["mode"])
    assert meta.recipe == raw["algo"] and meta.recurrent is None
    runs = [h["wall_s"] for h in raw["history"] if isinstance(h.get("wall_s"), int | float)]
    assert meta.training_wall_s == pytest.approx(sum(runs))
    assert meta.hold_steps == raw.get("hold_steps", 1)
    assert meta.detector == raw["config"]["detector"]
    assert (meta.switch is None) == ("switch" not in raw)
    assert (meta.reacquire is None) == ("reacquire" not in raw)
    write_meta(tmp_path, meta)
    again = read_meta(tmp_path)
    written = json.loads((tmp_path / "metadata.json").read_text())
    assert written["format_version"] == FORMAT_VERSION == 2
    assert {k: v for k, v in written.items() if k != "format_version"} == {
        k: v for k, v in meta.entries.items() if k != "format_version"
    }
    assert (again.recipe, again.training_wall_s, again.switch) == (
        meta.recipe,
        meta.training_wall_s,
        meta.switch,
    )


def test_written_metadata_keeps_the_new_fields(tmp_path):
    rec = {"kind": "lstm", "hidden": 64}
    write_meta(tmp_path, _entries(algo="recurrent_ppo", recipe="dagger-oracle", recurrent=rec))
    meta = read_meta(tmp_path)
    assert meta.recipe == "dagger-oracle" and meta.training_wall_s is None  # no history
    assert meta.recurrent.to_dict() == {"kind": "lstm", "hidden": 64, "layers": 1}
    assert set(meta.entries["versions"]) >= {"python", "numpy", "torch", "stable_baselines3"}
    write_meta(tmp_path, _entries(training_wall_s=1234.5, history=[{"wall_s": 10.0}]))
    assert read_meta(tmp_path).training_wall_s == 1234.5  # given: not the lineage's 10 s


@pytest.mark.parametrize(
    "entries, message",
    [
        ({"recipe": "evolution"}, r"model metadata was trained with the recipe 'evolution'"),
        ({"recipe": "dagger-Oracle!"}, r"recipe 'dagger-Oracle!'"),
        ({"recipe": 3}, r"recipe 3"),
        ({"recurrent": {"kind": "gru", "hidden": 64}}, r"recurrent state of kind 'gru'"),
        ({"recurrent": {"kind": "lstm", "hidden": 0}}, r"recurrent hidden must be an integer"),
        ({"recurrent": "lstm"}, r"'recurrent' must be null or an object"),
        ({"recurrent": {"kind": "lstm", "hidden": 8}}, r"algo 'sac' carries no recurrent state"),
        ({"algo": "recurrent_ppo"}, r"'recurrent' is null"),
        ({"critic_observation": "camera"}, r"critic that saw 'camera', which this runner"),
        ({"critic_observation": "privileged"}, r"'privileged' needs a recipe of the 'asymmetric'"),
        ({"training_wall_s": "long"}, r"training_wall_s must be null or seconds"),
        ({"detector": "eye"}, r"detector 'eye' is not one of polarizer, total"),
        ({"stage": 5}, r"observation_spec is for stage 3, the model for stage 5"),
        ({"hold_steps": -3}, r"hold_steps must be 0 \(auto"),
        ({"switch": {"lock_power": 0.9}}, r"'switch' needs 'acquire_model'"),
        ({"switch": {"acquire_model": "a", "lock_power": 2}}, r"switch lock_power must be"),
        ({"reacquire": {"patience": 0}}, r"reacquire patience must be >= 1"),
        ({"reacquire": [1]}, r"'reacquire' entry must be an object"),
        ({"format_version": 3}, r"format_version 3 in metadata is not supported"),
        ({"algo": "dqn"}, r"unknown algo 'dqn'"),
        ({"normalization": {"obs_mean": [0.0]}}, r"normalization needs obs_mean and obs_var"),
    ],
)
def test_what_the_runner_does_not_know_is_refused_naming_it(entries, message):
    with pytest.raises(PolicyLoadError, match=message):
        PolicyMeta.from_dict(_entries(**entries))


def test_an_unknown_observation_set_is_refused_naming_it():
    spec = {**ObservationSpec(stage=3).to_dict(), "observation": "camera"}
    with pytest.raises(PolicyLoadError, match=r"observation set 'camera', which this runner"):
        PolicyMeta.from_dict(_entries(observation_spec=spec))


def test_an_asymmetric_model_says_what_its_critic_saw():
    assert PolicyMeta.from_dict(_entries()).critic_observation == "rig"  # absent: rig
    meta = PolicyMeta.from_dict(_entries(recipe="asymmetric-sac", critic_observation="privileged"))
    assert (meta.recipe, meta.critic_observation) == ("asymmetric-sac", "privileged")


def test_recipes_and_their_variants():
    for good in ("sac", "td3", "ppo", "recurrent_ppo", "dagger", "dagger-oracle", "asymmetric"):
        assert recipe_known(good), good
    for bad in ("", "dagger-", "-oracle", "evolution", "evolution-oracle", None, "DAgger"):
        assert not recipe_known(bad), bad


def test_check_asked_names_what_differs_and_who_asks():
    meta = PolicyMeta.from_dict(_entries(), path="models/x")
    check_asked(meta, stage=3, detector="polarizer", observation="rig")
    with pytest.raises(
        PolicyLoadError,
        match=r"^model models/x was trained for stage 3, the simulator runs stage 5$",
    ):
        check_asked(meta, stage=5)
    with pytest.raises(PolicyLoadError, match=r"'polarizer' detector, the rig file r.yaml has"):
        check_asked(meta, detector="total", source="the rig file r.yaml")
    with pytest.raises(PolicyLoadError, match=r"set --observation rig \(the authors' set"):
        check_asked(meta, observation="authors")


def test_missing_and_malformed_files_say_what(tmp_path):
    with pytest.raises(PolicyLoadError, match=r"model not found: .*nowhere"):
        read_meta(tmp_path / "nowhere")
    with pytest.raises(PolicyLoadError, match=r"metadata missing: .*metadata.json not found"):
        read_meta(tmp_path)
    (tmp_path / "metadata.json").write_text("{not json")
    with pytest.raises(PolicyLoadError, match=r"metadata malformed: .* is not valid JSON"):
        read_meta(tmp_path)
    with pytest.raises(PolicyLoadError, match="lacks the key"):
        write_meta(tmp_path / "out", {"algo": "sac"})
    assert not (tmp_path / "out" / "metadata.json").exists()


def test_a_checkpoint_reads_its_own_step_count(tmp_path):
    write_meta(tmp_path, _entries(checkpoint=True, timesteps=0))
    (tmp_path / "model_500_steps.zip").write_bytes(b"")
    meta = read_meta(tmp_path / "model_500_steps.zip")
    assert meta.entries["timesteps"] == 500 and meta.model_file.name == "model_500_steps.zip"


def test_layer_settings_are_checked_with_their_names():
    assert SwitchParams.from_dict({"acquire_model": "acquire", "note": "kept"}) == SwitchParams()
    with pytest.raises(ValueError, match=r"switch release_power must be in \[0, lock_power\)"):
        SwitchParams(release_power=0.96)
    assert WatchdogParams.from_dict({}) == WatchdogParams()
    with pytest.raises(ValueError, match=r"reacquire seed must be an integer"):
        WatchdogParams(seed=1.5)


@pytest.mark.parametrize("folder", CURRENT, ids=[p.name for p in CURRENT])
def test_a_shipped_model_of_format_2_reads_its_recipe_and_wall_time_as_written(folder):
    raw = json.loads((folder / "metadata.json").read_text())
    meta = read_meta(folder)
    assert meta.recipe == raw["recipe"] and meta.recurrent == raw["recurrent"]
    assert meta.training_wall_s == pytest.approx(raw["training_wall_s"])
    assert meta.training_wall_s > 0
