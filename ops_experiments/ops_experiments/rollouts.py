"""Episodes of a controller against the in-process simulator: the one rollout loop of each kind.

* :func:`controller_episodes` drives any controller of :mod:`ops_controller_ros.controllers`
  (SPGD-PID, the tracker, ...) exactly as its node drives the simulator: absolute set-points, one
  reading (P_N / P_max and the detected slot energies) per command. Used by ``evaluate
  --controller``, ``evaluate --record`` and ``ops-bench spgd-baseline``.
* :func:`rollout_policy` runs a learned policy's batched ``predict`` on a vector env;
  :func:`rollout_runner` the same episodes with a runner that reads the readings itself (a
  model's runner with its layers, :mod:`ops_controller_ros.runner_factory`).
* :func:`policy_episodes` runs a batched ``predict`` on the very episodes of
  :func:`controller_episodes` (one env per episode, reset with :func:`episode_seed`: the same
  initial delay errors and the same noise draws), so agents and controllers compare like with
  like (the benchmark).

The controller is built from a *nominal* configuration; the simulator may run another one
(``evaluate --env KEY=VALUE``): the controller is not told.

Both return ``power`` (episodes, steps + 1): P_N/P_max after reset and after each step, and
``returns`` (episodes,): the sum of rewards.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def episode_seed(seed: int, episode: int) -> int:
    """The seed of episode ``episode`` of evaluation seed ``seed`` (simulator and controller)."""
    return seed * 1000 + episode


def controller_episodes(
    env,
    controller: str,
    params: dict[str, Any],
    nominal,
    episodes: int,
    steps: int,
    seed: int,
    on_step=None,
) -> dict[str, np.ndarray]:
    """``episodes`` episodes of ``controller`` on ``env`` (an OpsEnv, or a wrapper with
    ``reset(seed=)`` and ``step_setpoints(setpoints_fs) -> StepResult``). ``on_step(episode,
    step, ctl, env, result)``, if given, is called after the controller has taken each step's
    reading: the studies of ``ops-bench`` look inside the controller and the simulator there."""
    from ops_controller_ros.controllers import make_controller, next_command

    power = np.empty((episodes, steps + 1))
    returns = np.zeros(episodes)
    for e in range(episodes):
        s = episode_seed(seed, e)
        _, info = env.reset(seed=s)
        ctl = make_controller(
            controller, nominal, params, setpoints_fs=info["setpoints_fs"], seed=s
        )
        power[e, 0] = info["power"]
        for t in range(steps):
            r = env.step_setpoints(next_command(ctl))
            p = float(r.power[0])
            ctl.observe(p, r.pulse_energies[0])
            power[e, t + 1] = p
            returns[e] += float(r.reward[0])
            if on_step is not None:
                on_step(e, t, ctl, env, r)
    return {"power": power, "returns": returns}


def rollout_controller(
    controller: str,
    params: dict[str, Any],
    nominal,
    sim_config,
    episodes: int,
    steps: int,
    seed: int,
) -> dict[str, np.ndarray]:
    """:func:`controller_episodes` on a fresh in-process env running ``sim_config``."""
    from ops_sim_ros.env import OpsEnv

    env = OpsEnv.from_config(sim_config, max_episode_steps=steps)
    try:
        return controller_episodes(env, controller, params, nominal, episodes, steps, seed)
    finally:
        env.close()


def rollout_policy(
    predict,
    sim_config,
    episodes: int,
    steps: int,
    seed: int,
    observation_options: dict[str, Any] | None = None,
    paired: bool = False,
    hold_steps: int = 1,
) -> dict[str, np.ndarray]:
    """``episodes`` parallel episodes on ``sim_config`` with a batched ``predict(obs)``;
    ``observation_options``: the model's observation choices (``ObservationSpec.options()``,
    memory included; None: the default observation). ``paired``: the very episodes
    :func:`controller_episodes` runs (:func:`policy_episodes`) instead of one vector env's.
    ``hold_steps`` k > 1 (resolved): held decisions in the env (``ops_contract.held``, as
    ``train --hold-steps`` trains), ``steps`` simulator steps in ceil(steps / k) decisions;
    ``power`` then holds the reading after reset and after each decision (its last column is
    the reading after the last simulator step, as without a hold)."""
    if paired:
        if hold_steps != 1:
            raise ValueError("paired episodes run every reading: hold_steps must be 1")
        return _paired_episodes(predict, sim_config, episodes, steps, seed, observation_options)
    return _vector_episodes(
        lambda obs, _: predict(obs),
        sim_config,
        episodes,
        steps,
        seed,
        observation_options,
        hold_steps,
    )


def rollout_runner(
    runner, sim_config, episodes: int, steps: int, seed: int
) -> dict[str, np.ndarray]:
    """:func:`rollout_policy` for a runner that builds its own observations from each reading
    (``runner.act(pulse_energies, power, setpoints_fs, applied_fs)`` on (B, ...) arrays: a
    runner of ``episodes`` rigs, ``ModelStack.build`` of
    :mod:`ops_controller_ros.runner_factory`): the same episodes as :func:`rollout_policy` for
    the same ``seed``."""
    runner.restart()

    def act(_, r):
        return runner.act(r.pulse_energies, r.power, r.setpoints_fs, r.applied_fs)

    return _vector_episodes(act, sim_config, episodes, steps, seed)


def _vector_episodes(
    choose,
    sim_config,
    episodes: int,
    steps: int,
    seed: int,
    observation_options=None,
    hold_steps: int = 1,
) -> dict[str, np.ndarray]:
    """The loop of both: ``choose(obs, last StepResult) -> actions`` on a vector env (with
    ``hold_steps`` > 1 one call per decision)."""
    from ops_sim_ros.vec_env import OpsVectorEnv

    env = OpsVectorEnv.from_config(
        sim_config,
        num_envs=episodes,
        max_episode_steps=steps,
        observation_options=observation_options,
        hold_steps=hold_steps,
    )
    decisions = -(-steps // env.hold_steps)
    try:
        obs, info = env.reset(seed=seed)
        power = np.empty((episodes, decisions + 1))
        power[:, 0] = np.asarray(info["power"], dtype=np.float64)
        returns = np.zeros(episodes)
        for t in range(decisions):
            obs, rewards, _, _, info = env.step(choose(obs, env.sim.last))
            returns += rewards
            final = info.get("final_info") if t == decisions - 1 else None
            source = final if final is not None and "power" in final else info
            power[:, t + 1] = np.asarray(source["power"], dtype=np.float64)
        return {"power": power, "returns": returns}
    finally:
        env.close()


def policy_episodes(*args, **kwargs) -> dict[str, np.ndarray]:
    """:func:`rollout_policy` on the episodes :func:`controller_episodes` runs for the same
    ``seed`` (the benchmark's agents and controllers compare like with like)."""
    return rollout_policy(*args, paired=True, **kwargs)


def _paired_episodes(predict, sim_config, episodes: int, steps: int, seed: int, options=None):
    """``episodes`` episodes of a batched deterministic ``predict(obs) -> actions``: episode
    ``e`` is an :class:`~ops_sim_ros.env.OpsEnv` reset with ``episode_seed(seed, e)``, and every
    step draws the simulator's noise exactly as a controller's step does. ``options``: the
    model's observation choices (``ObservationSpec.options()``)."""
    from ops_sim_ros.env import OpsEnv

    envs = [
        OpsEnv.from_config(sim_config, max_episode_steps=steps, observation_options=options)
        for _ in range(episodes)
    ]
    try:
        power = np.empty((episodes, steps + 1))
        returns = np.zeros(episodes)
        first = [env.reset(seed=episode_seed(seed, e)) for e, env in enumerate(envs)]
        obs = np.stack([o for o, _ in first])
        power[:, 0] = [info["power"] for _, info in first]
        for t in range(steps):
            actions = np.asarray(predict(obs), dtype=np.float32).reshape(episodes, -1)
            for e, env in enumerate(envs):
                o, reward, _, _, info = env.step(actions[e])
                obs[e] = o
                power[e, t + 1] = info["power"]
                returns[e] += reward
        return {"power": power, "returns": returns}
    finally:
        for env in envs:
            env.close()
