"""The privileged teacher (oracle) and the DAgger recipe (``distill``)."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from ops_bench.processes import executable
from ops_controller_ros.policy_io import load_policy, read_metadata
from ops_experiments.oracle import (
    oracle_increments,
    probe_pattern,
    teacher_labels,
    true_error_fs,
)
from ops_sim_ros.vec_env import OpsVectorEnv

from ops_experiments import distill

pytestmark = pytest.mark.timeout(120)


@pytest.mark.parametrize(
    ("mode", "rig"),
    [("easy", {}), ("hard", {}), ("extreme", {}), ("hard", {"latency_steps": 2})],
)
def test_oracle_drives_the_true_error_to_zero_without_noise(mode, rig):
    venv = OpsVectorEnv(num_envs=32, mode=mode, seed=3, jitter_sigma_cycles=0.0, **rig)
    venv.reset(seed=3)
    start = np.abs(true_error_fs(venv.sim)).max() / venv.config.optical_period_fs
    assert start > 0.1  # far from the optimum at the start
    for _ in range(80):  # 0.5 cycles at 0.02 a step: 25 steps, and the latency
        _, _, _, _, info = venv.step(oracle_increments(venv.sim))
    # the applied delays are a whole number of periods (drift fed forward, latency waited for)
    applied = venv.sim.last.applied_fs / venv.config.optical_period_fs
    assert np.abs(applied - np.round(applied)).max() < 1e-6
    assert info["power"].min() > 0.9999


def test_oracle_actions_stay_in_the_action_bounds():
    venv = OpsVectorEnv(num_envs=64, mode="hard", seed=0)
    venv.reset(seed=0)
    a = oracle_increments(venv.sim)
    assert np.abs(a).max() <= 1.0
    assert (np.abs(a) == 1.0).any()  # far errors: a full step


def test_teacher_probes_first_then_follows_the_oracle():
    venv = OpsVectorEnv(num_envs=8, mode="medium", seed=1)
    venv.reset(seed=1)
    pattern = probe_pattern(3, 5)
    assert set(np.unique(pattern)) == {-1.0, 1.0}
    assert len({tuple(row) for row in pattern}) == 3  # every probe step differs
    for t in range(5):
        labels = teacher_labels(venv.sim, probe_steps=3)
        expected = pattern[t] if t < 3 else oracle_increments(venv.sim)
        np.testing.assert_array_equal(labels, np.broadcast_to(expected, labels.shape))
        venv.step(labels)


def test_a_run_carried_on_is_probed_at_its_start_only():
    venv = OpsVectorEnv(num_envs=4, mode="hard", seed=2)
    venv.reset(seed=2)
    age = np.array([0, 1, 5, 50])  # steps since each run started afresh; episode step 0 for all
    labels = teacher_labels(venv.sim, probe_steps=3, age=age)
    pattern = probe_pattern(3, 5)
    np.testing.assert_array_equal(labels[:2], pattern[:2])
    np.testing.assert_array_equal(labels[2:], oracle_increments(venv.sim)[2:])


def test_standardizer_folded_into_the_first_layer_gives_the_same_actions():
    from stable_baselines3 import SAC

    from ops_sim_ros import OpsEnv

    model = SAC("MlpPolicy", OpsEnv(stage=3, observation_options={"history": 2}), seed=0)
    rng = np.random.default_rng(0)
    obs = rng.normal(0.3, 0.2, (64, model.observation_space.shape[0])).astype(np.float32)
    norm = distill.Standardizer(obs)
    inside = distill.student_actions(model.actor, obs, norm)
    with norm.folded(model.actor):
        raw = distill.student_actions(model.actor, obs)
    np.testing.assert_allclose(raw, inside, atol=1e-4)
    after = distill.student_actions(model.actor, obs, norm)  # unfolded again
    np.testing.assert_allclose(after, inside, atol=1e-6)


def test_a_tiny_dagger_run_makes_a_model_that_evaluate_runs(tmp_path):
    out = tmp_path / "student"
    code = distill.main(
        ["--stage", "3", "--mode", "easy", "--obs-history", "3", "--probe-steps", "2",
         "--envs", "16", "--rounds", "2", "--grad-steps", "5", "--batch", "64", "--width", "32",
         "--eval-every", "1", "--capacity", "20000", "--out", str(out)]
    )  # fmt: skip
    assert code == 0
    meta = read_metadata(out)
    assert meta["recipe"] == "dagger-oracle"
    assert meta["training_wall_s"] > 0
    assert meta["algo"] == "sac" and meta["observation"] == "rig"
    assert meta["observation_spec"]["history"] == 3
    assert (out / "learning.csv").read_text().count("\n") >= 2
    policy = load_policy(out)
    assert policy.predict(np.zeros(meta["observation_shape"], np.float32)).shape == (3,)
    done = subprocess.run(
        [*executable("ops_gym_bridge", "evaluate"), str(out), "--splits", "test", "--seeds", "7",
         "--episodes", "1", "--steps", "20", "--no-plot", "--quiet", "--out", str(tmp_path / "ev")],
        capture_output=True, text=True, timeout=90, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "ev" / "evaluation.json").exists()


def test_auxiliary_targets_are_fitted_by_a_head_that_is_not_saved(tmp_path):
    import torch
    from stable_baselines3 import SAC

    from ops_sim_ros import OpsEnv

    model = SAC("MlpPolicy", OpsEnv(stage=3), seed=0, policy_kwargs={"net_arch": [32, 32]})
    actor, rng = model.actor, np.random.default_rng(0)
    data = distill.Dataset(512, model.observation_space.shape[0], 3, aux_dim=9)
    obs = rng.normal(size=(512, data.obs_dim)).astype(np.float32)
    data.add(obs, np.zeros((512, 3)), np.tanh(obs[:, :9]))  # targets the input tells
    head = torch.nn.Linear(32, 9)
    opt = torch.optim.Adam([*actor.parameters(), *head.parameters()], lr=1e-2)

    def aux_error() -> float:
        with torch.no_grad():
            latent = actor.latent_pi(torch.as_tensor(data.obs))
            return float(torch.mean((head(latent) - torch.as_tensor(data.aux)) ** 2))

    before = aux_error()
    distill.fit(actor, opt, data, rng, 200, 128, lambda x: x, aux=(head, 1.0))
    assert aux_error() < before / 3
    # a tiny run with the targets: the saved model is the actor alone (a plain SAC model)
    out = tmp_path / "student"
    code = distill.main(
        ["--stage", "3", "--mode", "hard", "--obs-history", "2", "--probe-steps", "2",
         "--envs", "8", "--rounds", "1", "--grad-steps", "5", "--batch", "32", "--width", "32",
         "--capacity", "5000", "--aux-weight", "0.5", "--out", str(out)]
    )  # fmt: skip
    assert code == 0
    meta = read_metadata(out)
    assert meta["dagger"]["aux_weight"] == 0.5 and meta["recipe"] == "dagger-oracle"
    fresh = SAC("MlpPolicy", OpsEnv(stage=3, observation_options={"history": 2}),
                policy_kwargs={"net_arch": [32, 32]})  # fmt: skip
    saved = load_policy(out).model.actor.state_dict()
    assert saved.keys() == fresh.actor.state_dict().keys()
