"""policy_io: a model directory (model.zip + metadata.json, its schema ops_contract.policy_meta)
loaded and run.

Real stable-baselines3 models (built, not trained: loading does not care), real files."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from ops_controller_ros.policy_io import (
    METADATA_FILE,
    MODEL_FILE,
    PolicyLoadError,
    check_stage,
    load_policy,
    read_metadata,
    save_metadata,
)

from ops_sim_ros import OpsEnv


def _metadata(env, algo="sac", **extra):
    return {
        "algo": algo,
        "stage": env.stage,
        "mode": env.config.mode,
        "split": env.config.split,
        "action_type": "increment",
        "max_step_fs": env.config.max_step_fs,
        "observation_spec": env.obs_spec.to_dict(),
        "observation_shape": list(env.observation_space.shape),
        "config": env.config.to_dict(),
        "normalization": None,
        "command_line": ["train", "--algo", algo],
        "timesteps": 123,
        "seed": 7,
        **extra,
    }


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    from stable_baselines3 import SAC

    env = OpsEnv(stage=3, mode="easy")
    out = tmp_path_factory.mktemp("policy") / "sac"
    model = SAC("MlpPolicy", env, policy_kwargs={"net_arch": [16, 16]}, seed=0, device="cpu")
    out.mkdir()
    model.save(str(out / MODEL_FILE))
    save_metadata(out, _metadata(env))
    return out


def test_metadata_round_trips(model_dir):
    meta = read_metadata(model_dir)
    env = OpsEnv(stage=3, mode="easy")
    expected = _metadata(env)
    for key, value in expected.items():
        assert meta[key] == pytest.approx(value) if isinstance(value, float) else meta[key] == value
    assert meta["format_version"] == 2
    assert meta["recipe"] == "sac" and meta["recurrent"] is None  # format 2's, by default
    assert set(meta["versions"]) >= {"python", "numpy", "torch", "stable_baselines3", "gymnasium"}
    # Rebuilding the spec and config from the metadata gives the training env's back.
    from ops_contract.config import OpsConfig
    from ops_contract.observation import ObservationSpec

    assert ObservationSpec.from_dict(meta["observation_spec"]) == env.obs_spec
    assert OpsConfig.from_dict(meta["config"]) == env.config


def test_load_by_dir_or_zip_and_predict(model_dir):
    env = OpsEnv(stage=3, mode="easy")
    obs, _ = env.reset(seed=1)
    a = load_policy(model_dir)
    b = load_policy(model_dir / MODEL_FILE)
    assert a.stage == 3 and a.algo == "sac" and a.mode == "easy"
    assert a.max_step_fs == pytest.approx(env.config.max_step_fs)
    assert a.observation_spec == env.obs_spec.to_dict()
    act = a.predict(obs)
    assert act.shape == (3,) and np.all(np.abs(act) <= 1.0)
    np.testing.assert_array_equal(act, b.predict(obs))  # deterministic, same model
    np.testing.assert_array_equal(act, a.predict(obs))
    assert a.predict(np.stack([obs, obs])).shape == (2, 3)  # batches work too
    with pytest.raises(ValueError, match="expects"):
        a.predict(np.zeros(5, np.float32))


def test_saved_normalization_is_applied(model_dir, tmp_path):
    import shutil

    env = OpsEnv(stage=3, mode="easy")
    obs, _ = env.reset(seed=2)
    out = tmp_path / "norm"
    shutil.copytree(model_dir, out)
    mean = np.full(obs.shape, 0.3)
    var = np.full(obs.shape, 4.0)
    meta = read_metadata(out)
    meta["normalization"] = {
        "obs_mean": mean.tolist(),
        "obs_var": var.tolist(),
        "clip_obs": 10.0,
        "epsilon": 1e-8,
    }
    save_metadata(out, meta)
    plain, normed = load_policy(model_dir), load_policy(out)
    expected_input = np.clip((obs - 0.3) / np.sqrt(4.0 + 1e-8), -10, 10).astype(np.float32)
    np.testing.assert_allclose(normed.normalize(obs), expected_input, rtol=1e-6)
    np.testing.assert_array_equal(normed.predict(obs), plain.predict(expected_input))


def test_check_stage_refuses_another_stage(model_dir):
    loaded = load_policy(model_dir)
    check_stage(loaded, 3)
    with pytest.raises(
        PolicyLoadError, match=r"model .*sac was trained for stage 3, the simulator runs stage 5"
    ):
        check_stage(loaded, 5)


def test_missing_paths(tmp_path, model_dir):
    with pytest.raises(PolicyLoadError, match="not found"):
        load_policy(tmp_path / "nowhere")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(PolicyLoadError, match="metadata missing"):
        load_policy(empty)
    only_meta = tmp_path / "only_meta"
    only_meta.mkdir()
    (only_meta / METADATA_FILE).write_text((model_dir / METADATA_FILE).read_text())
    with pytest.raises(PolicyLoadError, match="model file missing"):
        load_policy(only_meta)


@pytest.mark.parametrize("damage", ["not_a_zip", "truncated_zip", "zip_without_model"])
def test_corrupt_model_file(tmp_path, model_dir, damage):
    bad = tmp_path / damage
    bad.mkdir()
    (bad / METADATA_FILE).write_text((model_dir / METADATA_FILE).read_text())
    data = (model_dir / MODEL_FILE).read_bytes()
    if damage == "not_a_zip":
        (bad / MODEL_FILE).write_bytes(b"definitely not a zip")
    elif damage == "truncated_zip":
        (bad / MODEL_FILE).write_bytes(data[: len(data) // 2])
    else:
        with zipfile.ZipFile(bad / MODEL_FILE, "w") as z:
            z.writestr("readme.txt", "nothing useful")
    with pytest.raises(PolicyLoadError, match="corrupt model file"):
        load_policy(bad)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda m: "{not json", "not valid JSON"),
        (lambda m: [1, 2], "JSON object"),
        (lambda m: {k: v for k, v in m.items() if k != "stage"}, "lacks the key 'stage'"),
        (lambda m: {**m, "stage": "three"}, "wrong type"),
        (lambda m: {**m, "max_step_fs": -1.0}, "max_step_fs must be > 0"),
        (lambda m: {**m, "algo": "dqn"}, "unknown algo 'dqn'"),
        (lambda m: {**m, "action_type": "teleport"}, "action_type"),
        (lambda m: {**m, "normalization": {"obs_mean": [0.0]}}, "normalization"),
    ],
)
def test_malformed_metadata(tmp_path, model_dir, edit, message):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / MODEL_FILE).write_bytes((model_dir / MODEL_FILE).read_bytes())
    edited = edit(json.loads((model_dir / METADATA_FILE).read_text()))
    (bad / METADATA_FILE).write_text(edited if isinstance(edited, str) else json.dumps(edited))
    with pytest.raises(PolicyLoadError, match=message):
        load_policy(bad)


def test_metadata_model_mismatch_is_refused(tmp_path, model_dir):
    bad = tmp_path / "mismatch"
    bad.mkdir()
    (bad / MODEL_FILE).write_bytes((model_dir / MODEL_FILE).read_bytes())
    meta = json.loads((model_dir / METADATA_FILE).read_text())
    meta["observation_shape"] = [37]
    (bad / METADATA_FILE).write_text(json.dumps(meta))
    with pytest.raises(PolicyLoadError, match="observation_shape"):
        load_policy(bad)


def test_save_refuses_incomplete_metadata(tmp_path):
    with pytest.raises(PolicyLoadError, match="lacks the key"):
        save_metadata(tmp_path, {"algo": "sac"})
    assert not (tmp_path / METADATA_FILE).exists()


def test_a_model_runs_only_on_its_observation_set(model_dir):
    from ops_contract.policy_meta import PolicyMeta, check_asked, read_meta

    meta = read_meta(model_dir)
    spec = {k: v for k, v in meta.entries["observation_spec"].items() if k != "observation"}
    old = meta.replace(observation_spec=spec)
    assert old.observation.observation == "rig"  # saved before observation sets: the rig's
    check_asked(old, observation="rig")
    with pytest.raises(PolicyLoadError, match=r"trained on the 'rig' observation set.*'authors'"):
        check_asked(meta, observation="authors")
    authors = PolicyMeta.from_dict(
        {**meta.entries, "observation_spec": {**spec, "observation": "authors"}}
    )
    with pytest.raises(PolicyLoadError, match=r"set -p observation:=authors .*ops/delays_actual"):
        check_asked(authors, observation="rig", flag="-p observation:=")
