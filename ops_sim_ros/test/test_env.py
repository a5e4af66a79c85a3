"""The in-process Gymnasium environment (ops_sim_ros.env.OpsEnv)."""

import gymnasium as gym
import numpy as np
import pytest

import ops_sim_ros
from ops_sim_ros import OpsEnv


def test_gymnasium_env_checker():
    from gymnasium.utils.env_checker import check_env

    check_env(gym.make("ops_sim_ros/PulseStacking-v0", stage=3).unwrapped, skip_render_check=True)
    check_env(OpsEnv(stage=2, mode="hard", action_type="absolute"), skip_render_check=True)


def test_sb3_env_checker():
    from stable_baselines3.common.env_checker import check_env

    check_env(OpsEnv(stage=3, mode="easy"), warn=True)


def test_registered_once_and_figure5_example_runs():
    ops_sim_ros._register()  # a second registration must be harmless
    env = gym.make("ops_sim_ros/PulseStacking-v0", stage=5, mode="medium")
    env.reset(seed=0)
    done, steps = False, 0
    while not done:
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        done = terminated or truncated
        steps += 1
        assert not terminated
        assert reward == pytest.approx(-((1 - info["power"]) ** 2))
    assert steps == 200
    assert obs in env.observation_space
    assert set(info) >= {"power", "delays_fs", "setpoints_fs"}


def test_spaces_and_info():
    env = OpsEnv(stage=4)
    assert env.action_space.shape == (4,) and env.action_space.low.min() == -1.0
    assert env.observation_space.shape == (15 + 1 + 4,)
    obs, info = env.reset(seed=1)
    assert 0.0 <= info["power"] <= 1.0
    assert obs[15] == pytest.approx(info["power"], abs=1e-6)
    _, _, _, _, info2 = env.step(np.ones(4, dtype=np.float32))
    step = info2["setpoints_fs"] - info["setpoints_fs"]
    np.testing.assert_allclose(step, env.config.max_step_fs)
    # the hidden delay errors moved by one step of the random walk (clipped at 3 sigma)
    walk = (info2["delays_fs"] - info2["setpoints_fs"]) - (info["delays_fs"] - info["setpoints_fs"])
    assert 0 < np.abs(walk).max() <= 3 * env.config.jitter_sigma_fs + 1e-9
    assert np.all(info["setpoints_fs"] == 0.0)  # a new episode starts from zero set-points


def test_same_seed_same_episode_and_different_seed_differs():
    def episode(seed):
        env = OpsEnv(stage=3, mode="hard")
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for _ in range(20):
            out.append(env.step(np.full(3, 0.3, dtype=np.float32))[0])
        return np.stack(out)

    np.testing.assert_array_equal(episode(11), episode(11))
    assert not np.array_equal(episode(11), episode(12))


def test_episode_truncation_length_and_absolute_actions():
    env = OpsEnv(stage=2, max_episode_steps=7, action_type="absolute")
    env.reset(seed=0)
    for i in range(7):
        _, _, term, trunc, info = env.step(np.array([0.5, -1.0], dtype=np.float32))
        assert not term and trunc == (i == 6)
    np.testing.assert_allclose(
        info["setpoints_fs"], np.array([0.5, -1.0]) * env.config.optical_period_fs
    )


def test_easy_start_is_better_than_medium_on_average():
    powers = {}
    for mode in ("easy", "medium"):
        env = OpsEnv(stage=3, mode=mode)
        powers[mode] = np.mean([env.reset(seed=s)[1]["power"] for s in range(100)])
    assert powers["easy"] > powers["medium"] + 0.1


def test_render_rgb_array_draws_the_trace():
    env = OpsEnv(stage=3, render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert img.std() > 10  # something was drawn
    assert env.trace().shape == (7 * env.config.samples_per_slot,)
    assert OpsEnv(stage=3).render() is None


def test_invalid_arguments():
    with pytest.raises(ValueError, match="action_type"):
        OpsEnv(action_type="delta")
    with pytest.raises(ValueError, match="mode must be one of"):
        OpsEnv(mode="impossible")
    with pytest.raises(ValueError, match="render_mode"):
        OpsEnv(render_mode="ascii")


def test_human_render_draws_a_figure_and_close_removes_it():
    """render_mode="human" on matplotlib's off-screen backend (no display here): one figure is
    drawn and updated by render(), and close() removes it."""
    import os
    import subprocess
    import sys

    code = (
        "from ops_sim_ros import OpsEnv\n"
        "import matplotlib.pyplot as plt\n"
        "env = OpsEnv(stage=3, mode='medium', render_mode='human')\n"
        "env.reset(seed=0)\n"
        "for _ in range(3):\n"
        "    env.step(env.action_space.sample())\n"
        "    env.render()\n"
        "assert len(plt.get_fignums()) == 1, plt.get_fignums()\n"
        "env.close()\n"
        "assert plt.get_fignums() == [], plt.get_fignums()\n"
        "print('ok')\n"
    )
    env = dict(os.environ, MPLBACKEND="Agg")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def _run_episode(env, steps, action):
    for t in range(steps):
        obs, _, terminated, truncated, _ = env.step(action)
        assert not terminated and truncated == (t == steps - 1)
    return obs


def test_continue_prob_carries_some_runs_on_and_restarts_the_rest():
    """A reset after a truncated episode either starts afresh (set-points 0) or, with
    continue_prob, carries on: the same set-points and observation, only the step count
    restarts, and the next episode is again max_episode_steps long."""
    steps = 4
    env = OpsEnv(
        stage=3, mode="hard", max_episode_steps=steps, continue_prob=0.5,
        observation_options={"history": 2},
    )  # fmt: skip
    env.reset(seed=3)
    action = np.full(3, 0.7, dtype=np.float32)
    carried = fresh = 0
    for _ in range(40):
        last = _run_episode(env, steps, action)
        setpoints = env.sim.setpoints_fs.copy()
        obs, info = env.reset()
        if np.all(env.sim.setpoints_fs == 0.0):
            fresh += 1
        else:
            carried += 1
            np.testing.assert_array_equal(env.sim.setpoints_fs, setpoints)
            np.testing.assert_array_equal(obs, last)  # the run's memory goes on
            np.testing.assert_array_equal(info["setpoints_fs"], setpoints[0])
        assert env.sim.step_count[0] == 0
    assert carried > 8 and fresh > 8  # about half each of 40 episode ends


def test_continue_prob_never_carries_a_seeded_or_mid_episode_reset_on():
    env = OpsEnv(stage=3, mode="hard", max_episode_steps=3, continue_prob=0.95)
    action = np.full(3, 0.7, dtype=np.float32)
    for seed in range(5):
        env.reset(seed=seed)
        _run_episode(env, 3, action)
        env.reset(seed=seed)  # a seed asks for that episode
        assert np.all(env.sim.setpoints_fs == 0.0)
    env.step(action)
    env.reset()  # in mid-episode: a new one
    assert np.all(env.sim.setpoints_fs == 0.0)


def test_a_carried_on_run_keeps_its_drawn_rig():
    env = OpsEnv(
        stage=2, mode="hard", realism="lab", max_episode_steps=3, continue_prob=0.5,
        rig_randomize={"latency_steps": (0, 2), "pulse_amplitude_noise": (0.0, 0.03)},
        hold_steps=0,
    )  # fmt: skip
    env.reset(seed=1)
    action = np.full(2, 0.5, dtype=np.float32)
    carried = redrawn = 0
    for _ in range(30):
        while not env.step(action)[3]:  # held decisions: 3 simulator steps, 1-3 decisions
            pass
        rig = dict(env.rig)
        env.reset()
        if np.any(env.sim.setpoints_fs != 0.0):
            carried += 1
            assert env.rig == rig and env.hold_steps == rig["latency_steps"] + 1
        else:
            redrawn += env.rig != rig
    assert carried > 5 and redrawn > 5


def test_continue_prob_is_checked():
    for bad in (-0.1, 1.0, True, "0.5"):
        with pytest.raises(ValueError, match="continue_prob"):
            OpsEnv(stage=2, continue_prob=bad)
