"""Hyper-parameters: named sets of defaults and ``key=value`` overrides.

Sets (``train --hyperparams-set NAME``):

* ``paper`` (default): the paper's selected values, ``yaml/<algo>.yaml`` (PPO, TD3, SAC).
* ``authors``: ``yaml/authors.yaml``, the values of the authors' code (the code behind
  the paper's figures), where they differ from the paper's tables (PPO, TD3, SAC).
* ``fast``: ``yaml/fast.yaml``, for the batched simulator on a small CPU: many
  environments, fewer gradient steps per environment step (SAC, TD3, and sb3-contrib's TQC and
  CrossQ); its ``defaults`` block names the algorithm, the number of environments and the
  observation memory that ``train`` uses unless the command line says otherwise (chosen by
  measurement: ``ops-bench training``, docs/results.md).

Beside the sets, in the same folder: ``profiles.yaml``, the benchmark's profiles (``benchmark
--profile``: :func:`profiles`), and ``candidates.yaml``, the training bench's candidate set-ups
(:func:`candidates`).

Pure: no rclpy, no torch at import. :func:`load` reads the defaults, :func:`apply_overrides`
applies ``key=value`` strings (values parsed as YAML), :func:`sb3_kwargs` turns the flat dict
into stable-baselines3 constructor arguments.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from ops_controller_ros.policy_io import ALGOS as ALL_ALGOS

from .cli_args import parse_key_value

__all__ = [
    "ALGOS",
    "ALL_ALGOS",
    "CLI_KEYS",
    "SETS",
    "apply_overrides",
    "candidates",
    "load",
    "parse_override",
    "profiles",
    "sb3_kwargs",
    "set_defaults",
]
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "yaml"
#: The paper's algorithms (a ``paper`` yaml each; the Table 1 benchmark runs these).
ALGOS = ("ppo", "td3", "sac")
#: Named hyper-parameter sets: ``paper`` (one yaml per algorithm), others one yaml each.
SETS = ("paper", "fast", "authors")
#: The sets the benchmark may train with (one environment, the paper's protocol).
BENCHMARK_SETS = ("paper", "authors")
#: Keys of a set's ``defaults`` block (train options, not SB3 arguments).
SET_DEFAULT_KEYS = ("algo", "n_envs", "obs_history", "reward")
#: Keys the CLI handles itself; everything else goes to the SB3 constructor.
CLI_KEYS = (
    "normalize_obs",
    "checkpoint_freq",
    "policy",
    "net_arch",
    "action_noise",
    "action_noise_sigma",
    "critic_warmup",  # a fine-tune: steps after learning_starts with the actor kept as it is
    "actor_frozen_until",  # ... the step that ends it (stored, so that --resume keeps it)
)


def load(algo: str, hp_set: str = "paper") -> dict[str, Any]:
    """The default hyper-parameters of ``algo`` in the set ``hp_set`` (a fresh dict)."""
    if algo not in ALL_ALGOS:
        raise ValueError(f"algo must be one of {', '.join(ALL_ALGOS)} (got {algo!r})")
    if hp_set == "paper":
        if algo not in ALGOS:
            raise ValueError(
                f"the paper set has no {algo} (the paper trained {', '.join(ALGOS)}); "
                f"use --hyperparams-set {' or '.join(s for s in SETS if s != 'paper')}"
            )
        path = HYPERPARAMS_DIR / f"{algo}.yaml"
        data = yaml.safe_load(path.read_text())
        if not isinstance(data, dict):
            raise ValueError(f"{path} must hold a mapping")
        return data
    data = _load_set(hp_set)
    if algo not in data or not isinstance(data[algo], dict):
        have = [a for a in ALL_ALGOS if isinstance(data.get(a), dict)]
        raise ValueError(f"hyper-parameter set {hp_set!r} has no {algo} (it has {', '.join(have)})")
    return dict(data[algo])


def set_defaults(hp_set: str = "paper") -> dict[str, Any]:
    """The train options a set chooses (``algo``, ``n_envs``, ``obs_history``, ``reward``)."""
    base = {"algo": "sac", "n_envs": 1, "obs_history": 0, "reward": "paper"}
    if hp_set == "paper":
        return base
    defaults = _load_set(hp_set).get("defaults") or {}
    unknown = set(defaults) - set(SET_DEFAULT_KEYS)
    if unknown:
        raise ValueError(f"yaml/{hp_set}.yaml: unknown defaults {sorted(unknown)}")
    return {**base, **defaults}


def _load_set(hp_set: str) -> dict[str, Any]:
    if hp_set not in SETS:
        raise ValueError(f"hyper-parameter set must be one of {', '.join(SETS)} (got {hp_set!r})")
    return _read_mapping(f"{hp_set}.yaml")


def _read_mapping(name: str) -> dict[str, Any]:
    """A YAML file of this folder that must hold a mapping."""
    path = HYPERPARAMS_DIR / name
    data = yaml.safe_load(path.read_text())
    if not isinstance(data, dict):
        raise ValueError(f"{path} must hold a mapping")
    return data


#: The keys every benchmark profile has (``profiles.yaml``).
PROFILE_KEYS = (
    "stage",
    "modes",
    "algos",
    "seeds",
    "timesteps",
    "episode_steps",
    "eval",
    "stage_runs",
    "traces",
    "hyperparams",
)
#: The keys of a training-bench candidate (``candidates.yaml``).
CANDIDATE_KEYS = ("algo", "hyperparams_set", "n_envs", "obs_history", "overrides")


def profiles() -> dict[str, dict[str, Any]]:
    """The benchmark's profiles (``profiles.yaml``): name -> protocol (see the file)."""
    return _checked(_read_mapping("profiles.yaml"), PROFILE_KEYS, "profiles.yaml")


def candidates() -> dict[str, dict[str, Any]]:
    """The training bench's candidates (``candidates.yaml``): name -> ``algo``,
    ``hyperparams_set``, ``n_envs``, ``obs_history``, ``overrides`` (``key=value`` strings)."""
    out = _checked(_read_mapping("candidates.yaml"), CANDIDATE_KEYS, "candidates.yaml")
    for name, c in out.items():
        if c["algo"] not in ALL_ALGOS or c["hyperparams_set"] not in SETS:
            raise ValueError(f"yaml/candidates.yaml: {name}: unknown algo or set")
    return out


def _checked(data: dict, keys: tuple[str, ...], name: str) -> dict[str, dict[str, Any]]:
    """Every entry of ``data`` a mapping with exactly ``keys``."""
    for entry, value in data.items():
        have = set(value) if isinstance(value, dict) else set()
        if have != set(keys):
            raise ValueError(
                f"yaml/{name}: {entry} must have the keys {', '.join(keys)} "
                f"(missing {sorted(set(keys) - have)}, unknown {sorted(have - set(keys))})"
            )
    return data


def parse_override(text: str) -> tuple[str, Any]:
    """``"key=value"`` -> (key, YAML-parsed value)."""
    return parse_key_value(text, "hyper-parameter override")


def apply_overrides(
    params: dict[str, Any], overrides: list[str] | None, algo: str | None = None
) -> dict[str, Any]:
    """A copy of ``params`` with ``key=value`` overrides; unknown keys are checked against SB3."""
    out = dict(params)
    for text in overrides or []:
        key, value = parse_override(text)
        if key not in out and key not in CLI_KEYS and algo is not None:
            allowed = _sb3_arguments(algo)
            if allowed and key not in allowed:
                raise ValueError(
                    f"unknown hyper-parameter {key!r} for {algo}; known: "
                    f"{', '.join(sorted(set(allowed) | set(CLI_KEYS)))}"
                )
        out[key] = value
    return out


def _sb3_arguments(algo: str) -> set[str]:
    import inspect

    from ops_controller_ros.policy_io import algo_class

    sig = inspect.signature(algo_class(algo).__init__)
    return {n for n in sig.parameters if n not in ("self", "env", "policy")}


def sb3_kwargs(algo: str, params: dict[str, Any], action_dim: int) -> dict[str, Any]:
    """Constructor arguments for the SB3 class of ``algo`` (policy included)."""
    kwargs = {k: v for k, v in params.items() if k not in CLI_KEYS}
    kwargs["policy"] = params.get("policy", "MlpPolicy")
    net_arch = params.get("net_arch")
    if net_arch is not None:
        policy_kwargs = dict(kwargs.get("policy_kwargs") or {})
        # A list for every network, or a dict (e.g. {pi: [256, 256], qf: [512, 512]}).
        policy_kwargs["net_arch"] = dict(net_arch) if isinstance(net_arch, dict) else list(net_arch)
        kwargs["policy_kwargs"] = policy_kwargs
    noise = params.get("action_noise")
    if noise:
        import numpy as np
        from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

        sigma = float(params.get("action_noise_sigma", 0.1)) * np.ones(action_dim)
        mean = np.zeros(action_dim)
        if noise == "normal":
            kwargs["action_noise"] = NormalActionNoise(mean, sigma)
        elif noise in ("ornstein-uhlenbeck", "ou"):
            kwargs["action_noise"] = OrnsteinUhlenbeckActionNoise(mean, sigma)
        else:
            raise ValueError(f"action_noise must be normal or ornstein-uhlenbeck (got {noise!r})")
    return kwargs
