"""An asymmetric actor-critic (``train --algo sac --critic-observation privileged``): the critic
sees the rig's observation and what only the simulator knows, the actor the rig's observation
alone.

Privileged values (:func:`.oracle.privileged_features`, 3 N of them): each delay line's true error
relative to its nearest optimum as the phase of an optical period (its cosine and sine: the power
is periodic in it, and both signs of an error give the same readings, which the true error tells
apart) and the drift's slope in actuator steps. The training env (:class:`PrivilegedVecEnv`, the
batched simulator) appends them to every observation, the terminal ones included; the actor's
features extractor (:class:`RigSlice`) keeps the first ``rig_dim`` values, the rig's observation,
and the critic's takes all (``share_features_extractor`` False, SB3's default for SAC).

What is saved (``model.zip``, the checkpoints, ``DIR/best``) is the actor alone, as a plain SAC
model on the rig's observation (:func:`export_actor`): ``evaluate``, the policy node and
``ship-model`` run it as any SAC model, without the privileged part. Its metadata says how it was
made: ``recipe`` ``asymmetric-sac``, ``critic_observation`` ``privileged``. A saved model holds no
trained critic, so such a run cannot be resumed or fine-tuned with its critic
(``train --resume`` / ``--init-from`` refuse it).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from ops_contract.policy_meta import CRITIC_OBSERVATIONS  # noqa: F401  (re-exported)
from ops_sim_ros.vec_env import OpsSb3VecEnv
from stable_baselines3.common.callbacks import CheckpointCallback
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.sac.policies import SACPolicy

from .oracle import privileged_dim, privileged_features

RECIPE = "asymmetric-sac"


def is_asymmetric(args) -> bool:
    """Whether a run's critic sees the privileged values."""
    return getattr(args, "critic_observation", "rig") == "privileged"


class PrivilegedVecEnv(OpsSb3VecEnv):
    """The batched SB3 env whose observations are the rig's followed by
    :func:`privileged_features` of the same state (terminal observations too: they are built
    before the episodes that ended start again)."""

    def __init__(self, num_envs: int = 8, seed: int | None = None, **kwargs: Any) -> None:
        super().__init__(num_envs, seed, **kwargs)
        rig = self.observation_space
        self.rig_dim = int(np.prod(rig.shape))
        extra = np.full(privileged_dim(self.sim.stage), np.inf, dtype=np.float32)
        self.observation_space = gym.spaces.Box(
            np.concatenate([rig.low, -extra]), np.concatenate([rig.high, extra]), dtype=np.float32
        )
        self.single_observation_space = self.observation_space

    def _extend(self, obs: np.ndarray) -> np.ndarray:
        return np.concatenate([obs, privileged_features(self.sim)], axis=1)

    def _apply(self, actions):
        r, obs = super()._apply(actions)
        return r, self._extend(obs)

    def _reset_obs(self, r, mask=None) -> np.ndarray:
        return self._extend(super()._reset_obs(r, mask))


class RigSlice(BaseFeaturesExtractor):
    """The actor's features: the first ``rig_dim`` values of the observation (the rig's)."""

    def __init__(self, observation_space: gym.spaces.Box, rig_dim: int) -> None:
        super().__init__(observation_space, features_dim=int(rig_dim))
        self.rig_dim = int(rig_dim)

    def forward(self, observations):
        return observations[..., : self.rig_dim]


class AsymmetricSACPolicy(SACPolicy):
    """SAC's policy whose actor reads the rig's observation only (:class:`RigSlice`)."""

    def __init__(self, *args, rig_dim: int, **kwargs) -> None:
        self.rig_dim = int(rig_dim)
        kwargs["share_features_extractor"] = False
        super().__init__(*args, **kwargs)

    def make_actor(self, features_extractor=None):
        return super().make_actor(RigSlice(self.observation_space, self.rig_dim))

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "rig_dim": self.rig_dim}


def asymmetric_policy(venv, policy_kwargs: dict | None) -> dict[str, Any]:
    """The SAC constructor's ``policy`` and ``policy_kwargs`` that make it asymmetric on
    ``venv`` (a :func:`make_privileged_vec_env`)."""
    rig_dim = int(venv.get_attr("rig_dim")[0])
    kwargs = {**(policy_kwargs or {}), "rig_dim": rig_dim}
    return {"policy": AsymmetricSACPolicy, "policy_kwargs": kwargs}


def make_privileged_vec_env(args):
    """The monitored :class:`PrivilegedVecEnv` of a training run (train's resolved options)."""
    from .envs import monitored_batched
    from .training_run import observation_options

    return monitored_batched(
        PrivilegedVecEnv,
        num_envs=args.n_envs,
        seed=args.seed,
        stage=args.stage,
        mode=args.mode,
        split=args.split,
        max_episode_steps=args.episode_steps,
        observation_options=observation_options(args),
        continue_prob=args.continue_prob,
        hold_steps=args.hold_steps,
        detector=args.detector,
        **args.rig_config,
    )


class _Spaces(gym.Env):
    """An env that only has spaces: what SB3 needs to build a model."""

    def __init__(self, observation_space, action_space) -> None:
        self.observation_space, self.action_space = observation_space, action_space


def export_actor(model):
    """A plain SAC model on the rig's observation whose actor is ``model``'s (weights copied;
    its critic untrained): what the runner and ``evaluate`` load."""
    import torch
    from stable_baselines3 import SAC

    policy = model.policy
    rig_dim = policy.rig_dim
    full = model.observation_space
    rig = gym.spaces.Box(full.low[:rig_dim], full.high[:rig_dim], dtype=np.float32)
    plain = SAC(
        "MlpPolicy",
        _Spaces(rig, model.action_space),
        buffer_size=1,
        learning_starts=0,
        device="cpu",
        use_sde=model.use_sde,
        policy_kwargs={
            "net_arch": policy.net_arch,
            "activation_fn": policy.activation_fn,
            **{k: policy.actor_kwargs[k] for k in ("log_std_init", "clip_mean")},
        },
    )
    with torch.no_grad():
        plain.actor.load_state_dict(policy.actor.state_dict())
    plain.num_timesteps = model.num_timesteps
    return plain


def actor_predict(model):
    """``predict(obs)`` of the deterministic actor on rig observations (the in-loop test)."""
    import torch

    actor = model.policy.actor

    def predict(obs) -> np.ndarray:
        with torch.no_grad():
            x = torch.as_tensor(np.asarray(obs, dtype=np.float32))
            return actor(x, deterministic=True).numpy()

    return predict


class ExportCheckpoint(CheckpointCallback):
    """SB3's checkpoints, each the exported actor (:func:`export_actor`)."""

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            path = self._checkpoint_path(extension="zip")
            export_actor(self.model).save(path)
            if self.verbose >= 2:
                print(f"Saving model checkpoint to {path}")
        return True
