"""The one set-up shared by every environment class (in-process, vector, SB3 vector, ROS bridge):
arguments -> validated :class:`~ops_contract.config.OpsConfig` -> :class:`ObservationSpec` ->
observation and action spaces.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ops_contract.config import OpsConfig, make_config
from ops_contract.observation import ObservationSpec

ACTION_TYPES = ("increment", "absolute")


@dataclass(frozen=True)
class EnvSetup:
    config: OpsConfig
    action_type: str
    obs_spec: ObservationSpec
    observation_space: Any  # gymnasium.spaces.Box of one env
    action_space: Any  # Box [-1, 1]^N of one env

    @property
    def stage(self) -> int:
        return self.config.stage

    def apply_to(self, env) -> None:
        """Set ``config``, ``stage``, ``action_type`` and ``obs_spec`` on ``env``."""
        env.config = self.config
        env.stage = self.config.stage
        env.action_type = self.action_type
        env.obs_spec = self.obs_spec


def env_setup(
    stage: int,
    mode: str,
    split: str,
    action_type: str = "increment",
    max_episode_steps: int = 200,
    observation_options: dict[str, Any] | None = None,
    overrides: dict[str, Any] | None = None,
    action_types: tuple[str, ...] = ACTION_TYPES,
) -> EnvSetup:
    """Validate the arguments of an environment and build its configuration and spaces."""
    import numpy as np
    from gymnasium import spaces

    if action_type not in action_types:
        raise ValueError(
            f"action_type must be one of {', '.join(action_types)} (got {action_type!r})"
        )
    config = make_config(
        stage=stage, mode=mode, split=split, episode_steps=max_episode_steps, **(overrides or {})
    )
    spec = ObservationSpec.from_config(config, **(observation_options or {}))
    action_space = spaces.Box(-1.0, 1.0, shape=(config.stage,), dtype=np.float32)
    return EnvSetup(config, action_type, spec, spec.space(), action_space)


def config_arguments(config: OpsConfig, max_episode_steps: int | None = None) -> dict[str, Any]:
    """Constructor arguments (stage, mode, split, max_episode_steps, overrides) of an environment
    that runs ``config`` (with another episode length if given)."""
    data = config.to_dict()
    steps = data.pop("episode_steps")
    return {
        "stage": data.pop("stage"),
        "mode": data.pop("mode"),
        "split": data.pop("split"),
        "max_episode_steps": steps if max_episode_steps is None else int(max_episode_steps),
        **data,
    }
