"""Optical pulse stacking simulator: physics, Gymnasium environments, ROS 2 nodes.

Importing this package registers the Gymnasium id ``ops_sim_ros/PulseStacking-v0``, without
importing gymnasium itself: the id is registered at once when gymnasium is already loaded, or the
moment it is imported. ``OpsEnv`` is loaded on first use (module ``__getattr__``), so a process
that needs only the ROS helpers (a controller node: ``ops_contract.ros_interface``,
``ops_contract.node_params``) loads neither the environment nor gymnasium.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys

ENV_ID = "ops_sim_ros/PulseStacking-v0"
__all__ = ["ENV_ID", "OpsEnv"]


def __getattr__(name: str):
    if name == "OpsEnv":
        from .env import OpsEnv

        return OpsEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _register() -> None:
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="ops_sim_ros.env:OpsEnv")


class _RegisterOnGymnasiumImport(importlib.abc.MetaPathFinder):
    """Registers the id right after ``gymnasium`` is imported (then leaves sys.meta_path)."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None:
            return spec
        exec_module = spec.loader.exec_module

        def exec_then_register(module):
            exec_module(module)
            _register()

        spec.loader.exec_module = exec_then_register
        return spec


if "gymnasium" in sys.modules:
    _register()
elif not any(isinstance(f, _RegisterOnGymnasiumImport) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterOnGymnasiumImport())
