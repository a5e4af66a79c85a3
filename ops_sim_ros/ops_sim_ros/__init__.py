"""Optical pulse stacking simulator: physics, Gymnasium environments, ROS 2 nodes.

Importing this package registers the Gymnasium id ``ops_sim_ros/PulseStacking-v0``, without
importing gymnasium itself: the id is registered at once when gymnasium is already loaded, or the
moment it is imported. ``OpsEnv`` is loaded on first use (module ``__getattr__``), so a process
that needs only the ROS helpers (a controller node: ``ops_contract.ros_interface``,
``ops_contract.node_params``) loads neither the environment nor gymnasium.
"""

from __future__ import annotations

from ops_contract.import_hooks import after_import

ENV_ID = "ops_sim_ros/PulseStacking-v0"
__all__ = ["ENV_ID", "OpsEnv"]


def __getattr__(name: str):
    if name == "OpsEnv":
        from .env import OpsEnv

        return OpsEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _register(_gymnasium=None) -> None:
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="ops_sim_ros.env:OpsEnv")


after_import("gymnasium", _register)
