"""Batched vector environments against their libraries' conventions."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from ops_sim_ros.vec_env import OpsVectorEnv

from ops_sim_ros import OpsEnv


def test_gymnasium_vector_env_matches_sync_vector_env_layout():
    n, steps = 3, 5
    ours = OpsVectorEnv(num_envs=n, stage=2, max_episode_steps=steps, seed=0)
    ref = SyncVectorEnv(
        [lambda: OpsEnv(stage=2, max_episode_steps=steps) for _ in range(n)],
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    assert ours.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert ours.single_observation_space == ref.single_observation_space
    assert ours.observation_space == ref.observation_space
    assert ours.action_space == ref.action_space
    o1, i1 = ours.reset(seed=1)
    o2, i2 = ref.reset(seed=1)
    assert o1.shape == o2.shape and o1.dtype == o2.dtype
    assert set(i1) == set(i2)
    act = np.zeros((n, 2), dtype=np.float32)
    for k in range(steps):
        r1 = ours.step(act)
        r2 = ref.step(act)
        for a, b in zip(r1[:4], r2[:4], strict=True):
            assert np.shape(a) == np.shape(b) and np.asarray(a).dtype == np.asarray(b).dtype
        assert set(r1[4]) == set(r2[4]), k
    obs, _rew, term, trunc, info = r1
    assert trunc.all() and not term.any()
    assert info["_final_obs"].all()
    assert all(o in ours.single_observation_space for o in info["final_obs"])
    assert set(info["final_info"]) == set(r2[4]["final_info"])
    assert obs in ours.observation_space
    # after the autoreset the observations are new episodes: set-points back at zero
    assert np.all(info["setpoints_fs"] == 0.0)
    ref.close()


def test_vector_env_seeding_and_batched_equals_single():
    a = OpsVectorEnv(num_envs=4, stage=3, mode="hard")
    b = OpsVectorEnv(num_envs=4, stage=3, mode="hard")
    oa, _ = a.reset(seed=3)
    ob, _ = b.reset(seed=3)
    np.testing.assert_array_equal(oa, ob)
    act = np.random.default_rng(0).uniform(-1, 1, (4, 3)).astype(np.float32)
    ra, rb = a.step(act), b.step(act)
    np.testing.assert_array_equal(ra[0], rb[0])
    # the batch's physics equals a one-env evaluation of the same applied delays
    from ops_sim_ros.physics import PulseStacker

    ps = PulseStacker(3)
    for i in range(4):
        assert ra[4]["power"][i] == pytest.approx(ps.power(ra[4]["delays_fs"][i]), abs=1e-5)


def test_sb3_vec_env_contract_and_ppo_learns_without_error():
    from ops_sim_ros.vec_env import OpsSb3VecEnv
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecEnv

    venv = OpsSb3VecEnv(num_envs=4, stage=2, max_episode_steps=6)
    assert isinstance(venv, VecEnv)
    venv.seed(3)
    obs = venv.reset()
    assert obs.shape == (4, 3 + 1 + 2)
    for _ in range(6):
        obs, rew, dones, infos = venv.step(np.zeros((4, 2), dtype=np.float32))
        assert rew.shape == (4,) and dones.dtype == bool and len(infos) == 4
    assert dones.all()
    for info in infos:
        assert info["TimeLimit.truncated"] is True
        assert info["terminal_observation"].shape == (6,)
    assert venv.get_attr("stage") == [2] * 4
    assert venv.env_is_wrapped(gym.Wrapper) == [False] * 4
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)
    assert model.num_timesteps >= 256


def test_sb3_seed_reproducible():
    from ops_sim_ros.vec_env import OpsSb3VecEnv

    def run():
        v = OpsSb3VecEnv(num_envs=2, stage=3, mode="hard")
        v.seed(9)
        v.reset()
        return v.step(np.full((2, 3), 0.2, dtype=np.float32))[0]

    np.testing.assert_array_equal(run(), run())


def test_memory_observation_is_the_same_in_the_env_and_both_vector_envs():
    """history=3: OpsEnv, OpsVectorEnv and OpsSb3VecEnv build the same numbers for the same
    seed and actions, across an episode end (the vector envs' autoreset refills the history)."""
    from ops_sim_ros.vec_env import OpsSb3VecEnv

    kw = dict(stage=3, mode="hard", max_episode_steps=5, observation_options={"history": 3})
    env = OpsEnv(**kw)
    vec = OpsVectorEnv(num_envs=1, **kw)
    sb3 = OpsSb3VecEnv(num_envs=1, seed=4, **kw)
    spec = env.obs_spec
    width = spec.frame_dim + spec.stage
    o_env, _ = env.reset(seed=4)
    o_vec, _ = vec.reset(seed=4)
    o_sb3 = sb3.reset()
    actions = np.random.default_rng(1).uniform(-1.2, 1.2, (12, 3)).astype(np.float32)
    for t, a in enumerate(actions):
        np.testing.assert_array_equal(o_vec[0], o_env)
        np.testing.assert_array_equal(o_sb3[0], o_env)
        assert o_env in env.observation_space
        prev = o_env
        o_env, _, _, truncated, _ = env.step(a)
        o_vec, _, _, trunc_vec, info = vec.step(a[None])
        o_sb3, _, dones, infos = sb3.step(a[None])
        assert truncated == trunc_vec[0] == dones[0] == ((t + 1) % 5 == 0)
        # newest frame first, followed by the (clipped) action that produced it
        np.testing.assert_array_equal(o_env[spec.frame_dim : width], np.clip(a, -1, 1))
        np.testing.assert_array_equal(o_env[width:], prev[:-width])
        if truncated:
            np.testing.assert_array_equal(info["final_obs"][0], o_env)
            np.testing.assert_array_equal(infos[0]["terminal_observation"], o_env)
            o_env, _ = env.reset()
            for k in range(3):  # a new episode: the first frame everywhere, zero actions
                block = o_env[k * width : (k + 1) * width]
                np.testing.assert_array_equal(block[: spec.frame_dim], o_env[: spec.frame_dim])
                np.testing.assert_array_equal(block[spec.frame_dim :], 0.0)


@pytest.mark.parametrize("kind", ["gymnasium", "sb3"])
def test_continue_prob_carries_some_episodes_on_and_restarts_the_rest(kind):
    """An ending episode either starts afresh (set-points 0, a new delay error) or carries on
    from where it is (set-points and delays unchanged, only the step count restarts)."""
    n, steps = 16, 4
    kwargs = dict(num_envs=n, stage=3, mode="hard", max_episode_steps=steps, continue_prob=0.5)
    if kind == "sb3":
        from ops_sim_ros.vec_env import OpsSb3VecEnv

        venv = OpsSb3VecEnv(seed=3, **kwargs)
        venv.reset()
    else:
        venv = OpsVectorEnv(**kwargs)
        venv.reset(seed=3)
    action = np.full((n, 3), 0.7, dtype=np.float32)
    carried = fresh = 0
    for _ in range(3):  # episodes
        for t in range(steps):
            before = venv.sim.setpoints_fs.copy(), venv.sim.step_count.copy()
            if kind == "sb3":
                venv.step_async(action)
                _, _, dones, _ = venv.step_wait()
            else:
                _, _, _, dones, _ = venv.step(action)
            assert dones.all() == (t == steps - 1) and (dones.any() == dones.all())
        after = venv.sim.setpoints_fs
        moved = before[0] + action * venv.sim.max_step_fs  # where the last step took them
        restarted = np.all(after == 0.0, axis=1)
        kept = np.all(np.isclose(after, moved), axis=1)
        assert np.all(restarted ^ kept)  # each env one or the other
        assert np.all(venv.sim.step_count == 0) and not venv.sim.last.truncated.any()
        carried, fresh = carried + kept.sum(), fresh + restarted.sum()
    assert carried > 5 and fresh > 5  # about half each of 48 episode ends
    # the episodes that carried on are longer runs: their set-points went on moving
    assert np.abs(venv.sim.setpoints_fs).max() > 2 * steps * venv.sim.max_step_fs * 0.7


def test_continue_prob_is_checked():
    for bad in (-0.1, 1.0, True):
        with pytest.raises(ValueError, match="continue_prob"):
            OpsVectorEnv(num_envs=2, stage=3, continue_prob=bad)
