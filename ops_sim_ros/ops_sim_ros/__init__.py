"""Optical pulse stacking simulator: physics, Gymnasium environments, ROS 2 nodes.

Importing this package registers the Gymnasium id ``ops_sim_ros/PulseStacking-v0``.
"""

from .env import OpsEnv

ENV_ID = "ops_sim_ros/PulseStacking-v0"


def _register() -> None:
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="ops_sim_ros.env:OpsEnv")


_register()

__all__ = ["ENV_ID", "OpsEnv"]
