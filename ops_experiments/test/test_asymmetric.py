"""The asymmetric actor-critic (``train --critic-observation privileged``): its env appends the
simulator's true state to the rig's observation, a tiny real training saves the actor alone on
the rig's observation, which ``evaluate`` and the policy runner run from readings, and what does
not fit is refused."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from ops_contract.policy_meta import PolicyLoadError, read_meta
from ops_controller_ros.policy_io import PolicyRunner, load_policy
from ops_controller_ros.runner_factory import build_runner
from ops_experiments.asymmetric import PrivilegedVecEnv, privileged_features
from ops_experiments.build import build_model
from ops_experiments.learn import learn_and_save
from ops_experiments.oracle import true_error_fs
from ops_experiments.training_run import TrainError
from ops_sim_ros.vec_env import OpsSb3VecEnv

from ops_experiments import evaluate
from ops_sim_ros import OpsEnv

pytestmark = pytest.mark.timeout(120)

TINY = ["--algo", "sac", "--critic-observation", "privileged", "--stage", "3", "--mode", "easy",
        "--obs-history", "2", "--n-envs", "4", "--timesteps", "600", "--eval-freq", "300",
        "--eval-episodes", "2", "--no-progress", "--seed", "3", "--hyperparams",
        "learning_starts=100", "net_arch=[32,32]", "batch_size=64",
        "checkpoint_freq=400"]  # fmt: skip


@pytest.mark.filterwarnings("ignore:The `render_mode` attribute")
def test_the_env_appends_the_true_state_to_the_rig_observation():
    kwargs = dict(stage=3, mode="hard", observation_options={"history": 2}, max_episode_steps=5)
    rig, priv = OpsSb3VecEnv(4, seed=1, **kwargs), PrivilegedVecEnv(4, seed=1, **kwargs)
    dim = rig.observation_space.shape[0]
    assert priv.rig_dim == dim and priv.observation_space.shape == (dim + 9,)
    a, b = rig.reset(), priv.reset()
    rng = np.random.default_rng(0)
    for _ in range(7):  # past the episodes' end (5 steps): terminal observations too
        np.testing.assert_array_equal(b[:, :dim], a)
        np.testing.assert_allclose(b[:, dim:], privileged_features(priv.sim), atol=1e-6)
        act = rng.uniform(-1, 1, (4, 3))
        a, _, done_a, info_a = rig.step(act)
        b, _, done_b, info_b = priv.step(act)
        assert (done_a == done_b).all()
        if done_b.any():  # the terminal observation's true state is the one before the reset
            terminal = info_b[0]["terminal_observation"]
            np.testing.assert_array_equal(terminal[:dim], info_a[0]["terminal_observation"])
            assert not np.allclose(terminal[dim:], b[0, dim:])
    phase = 2 * np.pi * true_error_fs(priv.sim) / priv.config.optical_period_fs
    np.testing.assert_allclose(b[:, dim : dim + 3], np.cos(phase), atol=1e-6)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny asymmetric run, built and trained in this process (its training model kept)."""
    out = tmp_path_factory.mktemp("asym") / "run"
    run = build_model(TINY, out)
    interrupted, error, _ = learn_and_save(run)
    assert not interrupted and error is None
    return run


def test_the_saved_model_is_the_actor_alone_on_the_rig_observation(trained):
    out, model = trained.out, trained.model
    meta = read_meta(out)
    rig_dim = meta.observation.dim
    assert meta.recipe == "asymmetric-sac" and meta.critic_observation == "privileged"
    assert meta.algo == "sac" and meta.observation.observation == "rig"
    assert model.observation_space.shape == (rig_dim + 9,)  # the critic's input, in training
    assert meta.entries["observation_shape"] == [rig_dim]
    policy = load_policy(out)
    assert policy.model.observation_space.shape == (rig_dim,)
    # the saved actor acts as the trained one, which never read the privileged part
    obs = np.random.default_rng(1).normal(size=(16, rig_dim + 9)).astype(np.float32)
    trained_actions, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(policy.predict(obs[:, :rig_dim]), trained_actions, atol=1e-6)
    obs[:, rig_dim:] = 0.0
    blind, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(blind, trained_actions, atol=1e-6)
    for extra in ("best", "checkpoints"):  # the in-loop best and the checkpoints likewise
        assert read_meta(out / extra).critic_observation == "privileged"
    ckpt = load_policy(out / "checkpoints" / "model_400_steps.zip")
    assert ckpt.model.observation_space.shape == (rig_dim,)
    assert load_policy(out / "best").model.observation_space.shape == (rig_dim,)


def test_the_runner_and_evaluate_run_it_from_the_rig_readings(trained, tmp_path):
    out = trained.out
    runner = build_runner(out, stage=3, observation="rig")
    env = OpsEnv(stage=3, mode="easy", split="test", observation_options={"history": 2})
    env.reset(seed=5)
    reading = env.sim.last
    for _ in range(5):  # what the policy node gives it: energies, P_N/P_max, set-points
        action = runner.act(reading.pulse_energies[0], reading.power[0], reading.setpoints_fs[0])
        assert action.shape == (3,) and np.abs(action).max() <= 1.0
        reading = env.sim.step_increments(action[None, :])
    assert isinstance(PolicyRunner(load_policy(out)).policy.predict(np.zeros(runner.spec.dim)),
                      np.ndarray)  # fmt: skip
    argv = [str(out), "--splits", "test", "--seeds", "7", "--episodes", "2", "--steps", "20"]
    assert evaluate.run([*argv, "--no-plot", "--quiet", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "evaluation.json").read_text())
    assert 0.0 <= result["splits"]["test"]["final_power_mean"] <= 1.0


def test_a_model_whose_metadata_does_not_fit_is_refused(trained, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(trained.out, bad, ignore=shutil.ignore_patterns("checkpoints", "best", "logs"))
    meta = json.loads((bad / "metadata.json").read_text())
    cases = [
        ({"critic_observation": "oracle"}, r"critic that saw 'oracle', which this runner does"),
        ({"recipe": "sac"}, r"'privileged' needs a recipe of the 'asymmetric' family"),
        ({"recipe": "asymmetrical"}, r"recipe 'asymmetrical', which this runner does not know"),
    ]
    for change, message in cases:
        (bad / "metadata.json").write_text(json.dumps({**meta, **change}))
        with pytest.raises(PolicyLoadError, match=message):
            load_policy(bad)
    # the training model itself (its input the rig's and the privileged values) is not runnable
    (bad / "metadata.json").write_text(json.dumps(meta))
    trained.model.save(str(bad / "model.zip"))
    shape = meta["observation_shape"][0]
    with pytest.raises(PolicyLoadError, match=rf"observation_shape \[{shape}\] does not match"):
        load_policy(bad)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--algo", "td3"], r"is an asymmetric SAC: --algo sac \(got td3\)"),
        (["--rig-randomize", "latency_steps=0:1"], r"one rig \(no --rig-randomize\)"),
        (["--observation", "authors"], r"rig's observation \(got --observation authors\)"),
    ],
)
def test_runs_it_cannot_make_are_refused(tmp_path, extra, message):
    with pytest.raises(TrainError, match=message):
        build_model([*TINY, *extra], tmp_path / "x")


def test_it_cannot_be_resumed(trained):
    with pytest.raises(TrainError, match=r"cannot --resume or --init-from"):
        build_model([*TINY, "--resume"], trained.out)
