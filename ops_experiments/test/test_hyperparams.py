"""The paper's selected hyper-parameters (appendix B.1, Tables 2-4) and their SB3 mapping."""

from __future__ import annotations

import numpy as np
import pytest

from ops_experiments import hyperparams as hp

# (algo, key, value as in the paper's tables)
PAPER = [
    ("td3", "buffer_size", 10000),
    ("td3", "learning_starts", 1000),
    ("td3", "train_freq", 100),
    ("td3", "gradient_steps", 100),
    ("td3", "gamma", 0.98),
    ("td3", "action_noise", "normal"),
    ("td3", "action_noise_sigma", 0.7),
    ("td3", "learning_rate", 0.001),
    ("td3", "net_arch", [256, 256]),
    ("sac", "buffer_size", 10000),
    ("sac", "learning_starts", 1000),
    ("sac", "train_freq", 1),
    ("sac", "gradient_steps", 1),
    ("sac", "gamma", 0.98),
    ("sac", "use_sde", True),
    ("sac", "tau", 0.005),
    ("sac", "learning_rate", 0.001),
    ("sac", "net_arch", [256, 256]),
    ("ppo", "n_steps", 1024),
    ("ppo", "n_epochs", 10),
    ("ppo", "clip_range", 0.2),
    ("ppo", "gamma", 0.98),
    ("ppo", "ent_coef", 0.01),
    ("ppo", "gae_lambda", 0.95),
    ("ppo", "vf_coef", 0.5),
    ("ppo", "learning_rate", 0.001),
    ("ppo", "max_grad_norm", 0.5),
    ("ppo", "net_arch", [256, 256]),
]


@pytest.mark.parametrize("algo, key, value", PAPER)
def test_defaults_are_the_papers(algo, key, value):
    assert hp.load(algo)[key] == value


@pytest.mark.parametrize("algo", hp.ALGOS)
def test_defaults_build_the_sb3_model(algo):
    from ops_controller_ros.policy_io import algo_class

    from ops_sim_ros import OpsEnv

    env = OpsEnv(stage=2, mode="easy")
    kwargs = hp.sb3_kwargs(algo, hp.load(algo), action_dim=2)
    model = algo_class(algo)(env=env, device="cpu", **kwargs)
    assert model.gamma == 0.98 and model.learning_rate == 0.001
    if algo == "td3":
        np.testing.assert_allclose(model.action_noise._sigma, [0.7, 0.7])
        assert model.train_freq.frequency == 100 and model.gradient_steps == 100
    if algo == "sac":
        assert model.use_sde and model.train_freq.frequency == 1
    if algo == "ppo":
        assert model.n_steps == 1024 and model.n_epochs == 10


def test_overrides_are_parsed_as_yaml_and_checked():
    params = hp.apply_overrides(
        hp.load("sac"),
        ["learning_starts=200", "net_arch=[64, 64]", "use_sde=false", "ent_coef=auto_0.1"],
        "sac",
    )
    assert params["learning_starts"] == 200 and params["net_arch"] == [64, 64]
    assert params["use_sde"] is False and params["ent_coef"] == "auto_0.1"
    assert hp.sb3_kwargs("sac", params, 3)["policy_kwargs"] == {"net_arch": [64, 64]}
    with pytest.raises(ValueError, match="unknown hyper-parameter 'n_step'"):
        hp.apply_overrides(hp.load("ppo"), ["n_step=5"], "ppo")
    with pytest.raises(ValueError, match="key=value"):
        hp.apply_overrides(hp.load("ppo"), ["n_steps"], "ppo")
    with pytest.raises(ValueError, match="algo must be one of"):
        hp.load("dqn")
