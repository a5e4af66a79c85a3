"""Many stackers stepped by ONE batched physics call: a Gymnasium ``VectorEnv`` and a
stable-baselines3 ``VecEnv``, both thin shells around :class:`BatchedSimulation`.

Autoreset conventions differ between the libraries:

* :class:`OpsVectorEnv` declares ``autoreset_mode = AutoresetMode.SAME_STEP``: an env whose episode
  ends is reset inside that same ``step``; the returned observation is the new episode's first one,
  the last observation is in ``info["final_obs"]`` (object array, ``None`` elsewhere) with mask
  ``info["_final_obs"]``, and its info in ``info["final_info"]``, exactly as
  ``gymnasium.vector.SyncVectorEnv(..., autoreset_mode=SAME_STEP)`` lays them out.
* :class:`OpsSb3VecEnv` follows stable-baselines3: ``step_wait`` returns ``(obs, rewards, dones,
  infos)``, resets finished envs inside the step and puts ``terminal_observation`` and
  ``TimeLimit.truncated`` into their info dicts.

All episodes end by truncation (``max_episode_steps``), never by termination.

``continue_prob = q`` (default 0): an episode that ends continues the same run with probability
q instead of starting afresh: only its step count restarts, the delay errors, the drift and the
set-points carry on (and so does the observation's memory). Training data then holds the states
a long run reaches (delays carried cycles away by drift, hours into a run) besides fresh starts;
a chain of episodes lasts 1 / (1 - q) episodes on average. The random draws come from the
simulation's stream, so a seed still fixes everything.

``hold_steps = k`` (default 1; :mod:`ops_contract.held`): each ``step`` is one decision of k
simulator steps (the action, then k - 1 held steps), its observation built from the last reading
alone, as ``OpsEnv(hold_steps=k)``; 0 (auto): k = the rig's latency_steps + 1 (one rig for the
batch).
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from ops_contract.held import hold_after, resolve_hold_steps
from ops_contract.observation import ObservationBuilder

from .env_setup import config_arguments, env_setup
from .simulation import BatchedSimulation, StepResult


class _BatchCore:
    """Shared by both adapters: config, spaces, simulation, action handling and info arrays."""

    def _setup(
        self,
        num_envs: int,
        seed=None,
        stage: int = 5,
        mode: str = "medium",
        split: str = "train",
        action_type: str = "increment",
        max_episode_steps: int = 200,
        observation_options: dict[str, Any] | None = None,
        continue_prob: float = 0.0,
        hold_steps: int = 1,
        **overrides: Any,
    ) -> None:
        if overrides.pop("rig_randomize", None):
            raise ValueError(
                "rig_randomize: the batched envs share one rig; a rig drawn per env and episode "
                "needs a vector of OpsEnv (OpsEnv(rig_randomize=...), as train --rig-randomize "
                "builds it)"
            )
        q = continue_prob
        if isinstance(q, bool) or not isinstance(q, int | float) or not 0.0 <= q < 1.0:
            raise ValueError(f"continue_prob must be in [0, 1) (got {q!r})")
        self.continue_prob = float(q)
        setup = env_setup(
            stage, mode, split, action_type, max_episode_steps, observation_options, overrides
        )
        setup.apply_to(self)
        self.single_observation_space = setup.observation_space
        self.single_action_space = setup.action_space
        self.sim = BatchedSimulation(self.config, num_envs=num_envs, seed=seed)
        self._observations = ObservationBuilder(self.obs_spec, num_envs)
        self.hold_steps = resolve_hold_steps(hold_steps, self.config.latency_steps)
        self._abs_scale = self.config.absolute_action_range_fs

    @classmethod
    def from_config(cls, config, num_envs: int = 8, **kwargs: Any):
        """``num_envs`` envs running ``config`` (an OpsConfig)."""
        steps = kwargs.pop("max_episode_steps", None)
        return cls(num_envs=num_envs, **config_arguments(config, steps), **kwargs)

    def _apply(self, actions) -> tuple[StepResult, np.ndarray]:
        """Step every env; returns the result and its observations."""
        if self.action_type == "increment":
            r = self.sim.step_increments(actions)
        else:
            a = np.asarray(actions, dtype=np.float64)
            r = self.sim.step_setpoints(np.clip(a, -1.0, 1.0) * self._abs_scale)
        r = hold_after(self.sim, r, self.hold_steps)
        obs = self._observations.step(
            r.pulse_energies, r.power, r.setpoints_fs, actions, applied_fs=r.applied_fs
        )
        return r, obs

    def _end_episodes(self, done: np.ndarray, obs: np.ndarray) -> tuple[np.ndarray, StepResult]:
        """After the step that ended the episodes in ``done``: start new ones there (or, with
        ``continue_prob``, let some carry on); the observations and result after that."""
        fresh = done
        if self.continue_prob > 0.0:
            fresh = done & (self.sim.rng.random(self.num_envs) >= self.continue_prob)
            self.sim.continue_episodes(done & ~fresh)
        if not fresh.any():
            return obs, self.sim.last
        r = self.sim.reset(mask=fresh)
        return self._reset_obs(r, fresh), r

    def _reset_obs(self, r: StepResult, mask=None) -> np.ndarray:
        """Observations after new episodes started (all, or where ``mask`` is True)."""
        return self._observations.reset(
            r.pulse_energies, r.power, r.setpoints_fs, mask, applied_fs=r.applied_fs
        )

    @staticmethod
    def _info_arrays(r: StepResult) -> dict[str, Any]:
        return {
            "power": r.power,
            "delays_fs": r.applied_fs,
            "setpoints_fs": r.setpoints_fs,
            "main_pulse_energy": r.main_pulse_energy,
            "rejected_energy": r.rejected_energy,
            "clipped": r.clipped,
        }


class OpsVectorEnv(_BatchCore, VectorEnv):
    """Gymnasium vector env of ``num_envs`` stackers (SAME_STEP autoreset)."""

    metadata: ClassVar[dict[str, Any]] = {
        "autoreset_mode": AutoresetMode.SAME_STEP,
        "render_modes": [],
    }

    def __init__(
        self,
        num_envs: int = 8,
        stage: int = 5,
        mode: str = "medium",
        split: str = "train",
        action_type: str = "increment",
        max_episode_steps: int = 200,
        seed: int | None = None,
        observation_options: dict[str, Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.num_envs = int(num_envs)
        self._setup(
            self.num_envs,
            seed,
            stage,
            mode,
            split,
            action_type,
            max_episode_steps,
            observation_options,
            **overrides,
        )
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self._ones = np.ones(self.num_envs, dtype=bool)

    def _infos(self, r: StepResult) -> dict[str, Any]:
        info = self._info_arrays(r)
        for key in list(info):
            info["_" + key] = self._ones
        return info

    def reset(self, *, seed: int | list | None = None, options: dict[str, Any] | None = None):
        if isinstance(seed, list | tuple):
            seed = seed[0]  # one shared random stream for the whole batch
        if seed is not None:
            self._np_random, _ = gym.utils.seeding.np_random(seed)
            r = self.sim.reset(seed=self._np_random)
        else:
            mask = None if options is None else options.get("reset_mask")
            r = self.sim.reset(mask=mask)
            return self._reset_obs(r, mask), self._infos(r)
        return self._reset_obs(r), self._infos(r)

    def step(self, actions):
        r, obs = self._apply(actions)
        done = r.truncated
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = done.copy()
        rewards = r.reward.copy()
        if not done.any():
            return obs, rewards, terminated, truncated, self._infos(r)
        final_obs = np.full(self.num_envs, None, dtype=object)
        for i in np.flatnonzero(done):
            final_obs[i] = obs[i]
        final_info = self._infos(r)
        for key, value in list(final_info.items()):
            if key.startswith("_"):
                final_info[key] = done.copy()
            else:
                final_info[key] = np.where(
                    done.reshape(-1, *([1] * (value.ndim - 1))), value, np.zeros_like(value)
                )
        obs, r2 = self._end_episodes(done, obs)
        info = self._infos(r2)
        info.update(
            final_obs=final_obs,
            _final_obs=done.copy(),
            final_info=final_info,
            _final_info=done.copy(),
        )
        return obs, rewards, terminated, truncated, info

    def close_extras(self, **kwargs: Any) -> None:
        pass


_SB3_CLASS = None


def __getattr__(name: str):
    # OpsSb3VecEnv subclasses stable-baselines3's VecEnv, which imports torch: build the class on
    # first use so that importing this module (and OpsVectorEnv) stays light.
    if name == "OpsSb3VecEnv":
        global _SB3_CLASS
        if _SB3_CLASS is None:
            _SB3_CLASS = _make_sb3_class()
        return _SB3_CLASS
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _make_sb3_class():
    from stable_baselines3.common.vec_env import VecEnv

    class OpsSb3VecEnv(_BatchCore, VecEnv):
        """stable-baselines3 ``VecEnv`` of ``num_envs`` stackers on one batched simulation."""

        def __init__(self, num_envs: int = 8, seed: int | None = None, **kwargs: Any) -> None:
            """Arguments as OpsVectorEnv (stage, mode, split, action_type, max_episode_steps,
            observation_options, OpsConfig overrides)."""
            self._setup(int(num_envs), seed, **kwargs)
            super().__init__(int(num_envs), self.single_observation_space, self.single_action_space)
            self._actions = None

        def reset(self):
            seed = self._seeds[0] if self._seeds and self._seeds[0] is not None else None
            r = self.sim.reset(seed=seed)
            self._reset_seeds()
            self._reset_options()
            return self._reset_obs(r)

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = actions

        def step_wait(self):
            r, obs = self._apply(self._actions)
            dones = r.truncated.copy()
            rewards = r.reward.astype(np.float32)
            power = r.power.tolist()
            infos = [{"power": p} for p in power]
            if dones.any():
                for i in np.flatnonzero(dones):
                    infos[i]["terminal_observation"] = obs[i]
                    infos[i]["TimeLimit.truncated"] = True
                obs, _ = self._end_episodes(dones, obs)
            return obs, rewards, dones, infos

        def close(self) -> None:
            pass

        def get_attr(self, attr_name: str, indices=None) -> list[Any]:
            return [getattr(self, attr_name) for _ in self._get_indices(indices)]

        def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
            setattr(self, attr_name, value)

        def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs):
            return [
                getattr(self, method_name)(*method_args, **method_kwargs)
                for _ in self._get_indices(indices)
            ]

        def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
            return [False for _ in self._get_indices(indices)]

    OpsSb3VecEnv.__module__ = __name__
    return OpsSb3VecEnv
