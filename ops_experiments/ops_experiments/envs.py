"""Environment factories for training and evaluation: in-process or through the ROS 2 bridge.

Every environment is wrapped in SB3's ``Monitor`` with ``info_keywords=("power",)`` so that each
finished episode reports its return, its length and its final P_N / P_max.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

BACKENDS = ("inprocess", "ros")
EPISODE_STEPS = 200  # paper section 3.1


def make_single_env(
    backend: str,
    stage: int,
    mode: str,
    split: str = "train",
    namespace: str = "",
    timeout_s: float | None = None,
    episode_steps: int = EPISODE_STEPS,
    overrides: dict[str, Any] | None = None,
    observation_options: dict[str, Any] | None = None,
    rig_randomize=None,
    hold_steps: int = 1,
    continue_prob: float = 0.0,
):
    """One gymnasium env (not wrapped). ``observation_options``: e.g. ``{"history": 4}``;
    ``rig_randomize``: ranges of the rig's figures drawn per episode (in-process only,
    ``ops_contract.rig_randomization``); ``hold_steps``: simulator steps per decision
    (in-process only, ``ops_contract.held``; 0: the episode's latency_steps + 1);
    ``continue_prob``: the share of episode ends that carry on the same run (in-process only,
    ``OpsEnv``)."""
    if continue_prob and backend != "inprocess":
        raise ValueError(
            f"--continue-prob carries a run on in the simulator: it needs --backend inprocess "
            f"(got {backend})"
        )
    if hold_steps != 1 and backend != "inprocess":
        raise ValueError(
            f"--hold-steps holds each decision in the simulator: it needs --backend inprocess "
            f"(got {backend})"
        )
    common = {
        "stage": stage,
        "mode": mode,
        "split": split,
        "max_episode_steps": episode_steps,
        "observation_options": observation_options,
        **(overrides or {}),
    }
    if backend == "inprocess":
        from ops_sim_ros import OpsEnv

        return OpsEnv(
            rig_randomize=rig_randomize,
            hold_steps=hold_steps,
            continue_prob=continue_prob,
            **common,
        )
    if rig_randomize:
        raise ValueError(
            "--rig-randomize draws the rig in the simulator of each episode: it needs "
            "--backend inprocess"
        )
    if backend == "ros":
        from ops_gym_bridge.bridge.bridge_env import RosOpsEnv

        return RosOpsEnv(namespace=namespace, timeout_s=timeout_s, **common)
    raise ValueError(f"backend must be one of {', '.join(BACKENDS)} (got {backend!r})")


def _batched_vec_env(
    n_envs: int,
    stage: int,
    mode: str,
    split: str,
    episode_steps: int,
    seed,
    overrides: dict,
    observation_options: dict | None = None,
    continue_prob: float = 0.0,
    hold_steps: int = 1,
):
    """ops_sim_ros's batched SB3 VecEnv (one physics call for all envs), if it is available."""
    try:
        from ops_sim_ros import vec_env as ops_vec_env
    except ImportError:
        return None
    factory = getattr(ops_vec_env, "make_sb3_vec_env", None) or getattr(
        ops_vec_env, "OpsSb3VecEnv", None
    )
    if factory is None:
        return None
    return monitored_batched(
        factory,
        num_envs=n_envs,
        stage=stage,
        mode=mode,
        split=split,
        max_episode_steps=episode_steps,
        seed=seed,
        observation_options=observation_options,
        continue_prob=continue_prob,
        hold_steps=hold_steps,
        **overrides,
    )


def monitored_batched(factory, **kwargs):
    """``factory(**kwargs)``, a batched SB3 VecEnv, monitored (episode figures and ``power``)."""
    from stable_baselines3.common.vec_env import VecMonitor

    with warnings.catch_warnings():
        # SB3 warns that the batched env has no render_mode attribute (it renders nothing).
        warnings.filterwarnings("ignore", message="The `render_mode` attribute")
        venv = factory(**kwargs)
    return VecMonitor(venv, info_keywords=("power",))


def make_vec_env(
    backend: str,
    stage: int,
    mode: str,
    split: str = "train",
    n_envs: int = 1,
    seed: int | None = None,
    namespaces: list[str] | None = None,
    timeout_s: float | None = None,
    episode_steps: int = EPISODE_STEPS,
    batched: bool = True,
    overrides: dict[str, Any] | None = None,
    observation_options: dict[str, Any] | None = None,
    continue_prob: float = 0.0,
    rig_randomize=None,
    hold_steps: int = 1,
):
    """An SB3 VecEnv of ``n_envs`` monitored envs.

    In-process with ``n_envs > 1``: the batched vector env of ``ops_sim_ros.vec_env`` (falls back to
    a DummyVecEnv of ``OpsEnv`` if it is missing). ROS backend: one bridge per namespace.
    ``overrides``: OpsConfig fields (e.g. ``detector``) of every env; ``observation_options``:
    the observation's choices (e.g. ``{"history": 4}``) of every env; ``continue_prob``: the
    share of episode ends that carry on the same run (in-process only: ``ops_sim_ros.vec_env``,
    or each ``OpsEnv``); ``rig_randomize``: ranges of the rig's figures that each env draws anew at
    every reset (``ops_contract.rig_randomization``): a DummyVecEnv of ``OpsEnv`` (the batched
    env runs one rig for all its envs); ``hold_steps``: each step one decision of that many
    simulator steps (``ops_contract.held``; 0, auto: each env's rig's latency_steps + 1, per
    episode where the rig is drawn per episode; in-process only). Episodes keep
    ``episode_steps`` simulator steps (so about episode_steps / hold_steps decisions).
    """
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1 (got {n_envs})")
    env_kwargs = {
        "stage": stage,
        "mode": mode,
        "split": split,
        "episode_steps": episode_steps,
        "overrides": overrides,
        "observation_options": observation_options,
        "hold_steps": hold_steps,
    }
    if hold_steps != 1 and backend != "inprocess":
        raise ValueError(
            f"--hold-steps holds each decision in the simulator: it needs --backend inprocess "
            f"(got {backend})"
        )
    if rig_randomize:
        if backend != "inprocess":
            raise ValueError(
                "--rig-randomize draws the rig in the simulator of each episode: it needs "
                f"--backend inprocess (got {backend})"
            )
        env_kwargs["continue_prob"] = continue_prob  # a carried-on run keeps its rig
        return _monitored("inprocess", [{"rig_randomize": rig_randomize}] * n_envs, env_kwargs)
    if backend == "ros":
        namespaces = _ros_namespaces(namespaces, n_envs)
        return _monitored("ros", [{"namespace": ns, "timeout_s": timeout_s} for ns in namespaces],
                          env_kwargs)  # fmt: skip
    if backend != "inprocess":
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)} (got {backend!r})")
    if n_envs > 1 and batched:
        venv = _batched_vec_env(
            n_envs,
            stage,
            mode,
            split,
            episode_steps,
            seed,
            overrides or {},
            observation_options,
            continue_prob,
            hold_steps,
        )
        if venv is not None:
            return venv
    return _monitored("inprocess", [{}] * n_envs, {**env_kwargs, "continue_prob": continue_prob})


def _ros_namespaces(namespaces: list[str] | None, n_envs: int) -> list[str]:
    """One simulator's namespace per env of the ROS backend."""
    namespaces = list(namespaces or [""])
    if len(namespaces) == 1 and n_envs > 1:
        raise ValueError(
            f"--backend ros with --n-envs {n_envs} needs {n_envs} simulators: give one "
            "--namespace per simulator (e.g. --namespace /rig1 --namespace /rig2)"
        )
    if n_envs not in (1, len(namespaces)):
        raise ValueError(f"--n-envs {n_envs} but {len(namespaces)} namespaces were given")
    return namespaces


def _monitored(backend: str, per_env: list[dict], env_kwargs: dict):
    """A DummyVecEnv of one monitored :func:`make_single_env` per entry of ``per_env`` (that
    env's own arguments on top of ``env_kwargs``)."""
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv

    def factory(own: dict):
        return lambda: Monitor(
            make_single_env(backend, **env_kwargs, **own), info_keywords=("power",)
        )

    return DummyVecEnv([factory(own) for own in per_env])


def final_powers(ep_info_buffer) -> np.ndarray:
    """Final P_N / P_max of the episodes in an SB3 ep_info_buffer."""
    return np.array([ep["power"] for ep in ep_info_buffer if "power" in ep], dtype=np.float64)
