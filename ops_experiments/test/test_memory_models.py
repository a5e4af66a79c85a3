"""Models with observation memory: trained with ``--obs-history``, saved with their
spec, rebuilt identically by the policy runner's code path, evaluated, refused on a mismatch; and
the ``fast`` hyper-parameter set with sb3-contrib's algorithms."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from ops_contract.observation import ObservationSpec, pulse_energies_from_trace
from ops_controller_ros.policy_io import PolicyLoadError, PolicyRunner, load_policy

from ops_experiments import hyperparams as hp
from ops_experiments import train
from ops_sim_ros import OpsEnv

pytestmark = pytest.mark.timeout(120)

TINY = ["learning_starts=64", "net_arch=[16,16]", "batch_size=32", "gradient_steps=1"]


@pytest.fixture(scope="module")
def memory_model(tmp_path_factory):
    out = tmp_path_factory.mktemp("memory") / "sac_h2"
    code = train.run(
        [
            "--hyperparams-set",
            "fast",
            "--stage",
            "3",
            "--mode",
            "hard",
            "--n-envs",
            "4",
            "--obs-history",
            "2",
            "--timesteps",
            "200",
            "--eval-freq",
            "80",
            "--eval-episodes",
            "2",
            "--out",
            str(out),
            "--no-progress",
            "--hyperparams",
            *TINY,
        ]
    )
    assert code == 0
    return out


def test_metadata_records_the_memory_and_the_set(memory_model):
    meta = json.loads((memory_model / "metadata.json").read_text())
    assert meta["observation_spec"]["history"] == 2 and meta["obs_history"] == 2
    assert meta["hyperparams_set"] == "fast" and meta["algo"] == "sac" and meta["n_envs"] == 4
    assert meta["observation_shape"] == [2 * (7 + 1 + 3 + 3)]
    assert meta["hyperparams"]["buffer_size"] == hp.load("sac", "fast")["buffer_size"]


def test_eval_freq_keeps_the_best_model(memory_model):
    best = memory_model / "best"
    meta = json.loads((best / "metadata.json").read_text())
    assert 0.0 <= meta["eval_final_power"] <= 1.0 and meta["eval_episodes"] == 2
    assert not (best / "replay_buffer.pkl").exists()
    loaded = load_policy(best)
    assert loaded.observation_spec["history"] == 2 and loaded.model.num_timesteps <= 200


def test_policy_runner_builds_the_envs_observations(memory_model):
    """The runner's code path (PolicyRunner, as the ops_policy node runs it) rebuilds, from the
    readings of each step, the very observation the env gave, step after step."""
    loaded = load_policy(memory_model)
    runner = PolicyRunner(loaded)
    # the same readings as they come over DDS: sampled from the float32 trace, float32 values
    wire = PolicyRunner(loaded)
    env = OpsEnv(stage=3, mode="hard", observation_options=runner.spec.options())
    obs, info = env.reset(seed=3)
    for _ in range(30):
        r = env._last
        action = runner.act(r.pulse_energies[0], r.power[0], r.setpoints_fs[0])
        np.testing.assert_array_equal(runner.last_observation, obs)
        energies = pulse_energies_from_trace(env.trace(), env.config.samples_per_slot)
        sp32 = info["setpoints_fs"].astype(np.float32).astype(np.float64)
        wire_action = wire.act(energies, float(np.float32(info["power"])), sp32)
        np.testing.assert_allclose(wire.last_observation, obs, rtol=0, atol=1e-5)
        np.testing.assert_allclose(wire_action, action, atol=1e-4)
        obs, _, _, _, info = env.step(action)
    # restart(): the next reading starts a new history
    runner.restart()
    r = env._last
    runner.act(r.pulse_energies[0], r.power[0], r.setpoints_fs[0])
    f = runner.spec.frame_dim
    np.testing.assert_array_equal(runner.last_observation[f : f + 3], 0.0)


def test_evaluate_runs_a_memory_model(memory_model, tmp_path):
    from ops_experiments import evaluate

    code = evaluate.run(
        [
            *(str(memory_model), "--seeds", "0", "--episodes", "2", "--steps", "20"),
            *("--splits", "test", "--no-plot", "--quiet", "--out", str(tmp_path / "ev")),
        ]
    )
    assert code == 0
    res = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert len(res["splits"]["test"]["curve_mean"]) == 21


def test_spec_and_model_mismatch_is_a_clear_error(memory_model, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(memory_model, bad)
    meta = json.loads((bad / "metadata.json").read_text())
    meta["observation_spec"]["history"] = 3
    meta.pop("observation_shape")
    (bad / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(PolicyLoadError, match=r"disagree.*history=3.*42 values.*\[28\]"):
        load_policy(bad)
    meta["observation_spec"]["history"] = "two"
    (bad / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(PolicyLoadError, match="observation_spec is not valid"):
        load_policy(bad)


def test_resume_keeps_the_memory(memory_model, tmp_path):
    out = tmp_path / "resumed"
    shutil.copytree(memory_model, out)
    assert train.run(["--out", str(out), "--resume", "--timesteps", "40", "--no-progress"]) == 0
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["obs_history"] == 2 and meta["hyperparams_set"] == "fast"
    assert meta["timesteps"] >= 240
    code = train.run(["--out", str(out), "--resume", "--obs-history", "0", "--timesteps", "8"])
    assert code == 2


@pytest.mark.parametrize("algo", ["tqc", "crossq"])
def test_sb3_contrib_algorithms_train_save_and_load(algo, tmp_path):
    out = tmp_path / algo
    code = train.run(
        ["--hyperparams-set", "fast", "--algo", algo, "--stage", "2", "--mode", "easy"]
        + ["--n-envs", "4", "--timesteps", "120", "--out", str(out), "--no-progress"]
        + ["--hyperparams", "learning_starts=64", "batch_size=32"]
        + ([] if algo == "crossq" else ["net_arch=[16,16]"])
    )
    assert code == 0
    loaded = load_policy(out)
    assert loaded.algo == algo and type(loaded.model).__name__.lower() == algo
    spec = ObservationSpec.from_dict(loaded.observation_spec)
    assert spec.history == hp.set_defaults("fast")["obs_history"]  # the set's memory
    obs, _ = OpsEnv(stage=2, mode="easy", observation_options=spec.options()).reset(seed=0)
    assert loaded.predict(obs).shape == (2,)


def test_sets_defaults_and_errors():
    paper = {"algo": "sac", "n_envs": 1, "obs_history": 0, "reward": "paper"}
    assert hp.set_defaults("paper") == paper
    fast = hp.set_defaults("fast")
    assert fast["n_envs"] > 1 and fast["algo"] in hp.ALL_ALGOS
    for algo in ("sac", "tqc", "crossq", "td3"):
        assert hp.load(algo, "fast")["gradient_steps"] < fast["n_envs"]  # UTD below 1
    with pytest.raises(ValueError, match="paper set has no tqc"):
        hp.load("tqc")
    with pytest.raises(ValueError, match="set must be one of"):
        hp.load("sac", "slow")
    assert hp.ALGOS == ("ppo", "td3", "sac")  # the paper's (the Table 1 benchmark runs these)


def test_max_minutes_stops_training_and_saves(tmp_path, capsys):
    out = tmp_path / "limited"
    code = train.run(
        [
            *("--hyperparams-set", "fast", "--stage", "2", "--mode", "easy", "--n-envs", "4"),
            *("--timesteps", "100000000", "--max-minutes", "0.03", "--out", str(out)),
            *("--no-progress", "--hyperparams", *TINY),
        ]
    )
    assert code == 0
    assert "(stopped at --max-minutes 0.03)" in capsys.readouterr().out
    meta = json.loads((out / "metadata.json").read_text())
    assert 0 < meta["timesteps"] < 100000000 and meta["history"][-1]["wall_s"] < 30
    assert load_policy(out).stage == 2
