"""``train --reward``: what the learner is paid (ops_gym_bridge.rewards), stored with the model,
kept on resume; the monitor and every evaluation still measure the paper's quantities."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
from ops_experiments.envs import make_vec_env
from ops_experiments.rewards import nines_reward, wrap_training_reward

from ops_experiments import train

pytestmark = pytest.mark.timeout(120)

TINY = ["learning_starts=64", "net_arch=[16,16]", "batch_size=32", "gradient_steps=1"]


def test_nines_counts_the_nines_of_the_power():
    p = np.array([0.0, 0.9, 0.99, 0.999, 0.9999, 1.2, -0.5])
    np.testing.assert_allclose(nines_reward(p), [0, 1 / 3, 2 / 3, 1, 1, 1, 0], atol=1e-12)
    # Steep near the optimum, where eq. (3) is flat: 0.99 vs 0.8 differ by 0.04 there.
    assert nines_reward(0.99) - nines_reward(0.8) > 0.4


@pytest.mark.parametrize("n_envs", [1, 4])
def test_wrapper_pays_nines_of_each_step_and_leaves_the_monitor_on_eq3(n_envs):
    venv = wrap_training_reward(
        make_vec_env("inprocess", 3, "medium", n_envs=n_envs, seed=3, episode_steps=5), "nines"
    )
    venv.reset()
    rng = np.random.default_rng(0)
    for _ in range(5):  # the fifth step ends the episodes (autoreset)
        actions = rng.uniform(-1, 1, (n_envs, *venv.action_space.shape)).astype(np.float32)
        _, rewards, dones, infos = venv.step(actions)
        power = np.array([info["power"] for info in infos])
        np.testing.assert_allclose(rewards, nines_reward(power), rtol=1e-6)
    assert dones.all()
    episode_return = infos[0]["episode"]["r"]  # VecMonitor underneath: the paper's eq. (3)
    assert episode_return < 0
    with pytest.raises(ValueError, match="reward must be one of paper, nines"):
        wrap_training_reward(venv, "linear")


def test_train_with_nines_stores_it_and_resume_keeps_it(tmp_path, capsys):
    out = tmp_path / "nines"
    common = ["--out", str(out), "--no-progress"]
    code = train.run(
        [
            *("--hyperparams-set", "fast", "--stage", "2", "--mode", "easy", "--n-envs", "4"),
            *("--reward", "nines", "--timesteps", "300", *common, "--hyperparams", *TINY),
        ]
    )
    assert code == 0
    assert json.loads((out / "metadata.json").read_text())["reward"] == "nines"
    rb = pickle.loads((out / "replay_buffer.pkl").read_bytes())
    paid = rb.rewards[: rb.pos]
    assert paid.size and paid.min() >= 0 and paid.max() <= 1  # nines, not eq. (3) (<= 0)
    capsys.readouterr()
    assert train.run(["--resume", "--timesteps", "100", *common]) == 0
    assert "reward=nines" in capsys.readouterr().out
    assert train.run(["--resume", "--reward", "paper", "--timesteps", "10", *common]) == 2
    assert "--reward paper differs from the model's nines" in capsys.readouterr().err
