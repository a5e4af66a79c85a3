"""Moved to :mod:`ops_gym_bridge.experiments.rollouts`; this name stays for a benchmark worker
started before the move (it imports ``policy_episodes`` from here when it evaluates)."""

from .experiments.rollouts import (  # noqa: F401
    controller_episodes,
    episode_seed,
    policy_episodes,
    rollout_controller,
    rollout_policy,
    rollout_runner,
)
