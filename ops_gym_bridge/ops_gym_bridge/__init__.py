"""Gymnasium environment over the simulator's ROS 2 topics.

:mod:`ops_gym_bridge.bridge` holds the bridge: a Gymnasium env over the topics (``bridge_env``) and
its lockstep protocol (``lockstep_client``). The experiment harness that trains and evaluates on it
is the ``ops_experiments`` package; this package's ``train``, ``evaluate``, ``benchmark``,
``report`` and ``realism_sweep`` executables run it, so ``ros2 run ops_gym_bridge train`` works.

Importing this package registers the Gymnasium id ``ops_gym_bridge/RosPulseStacking-v0``
(:class:`ops_gym_bridge.bridge.bridge_env.RosOpsEnv`; rclpy is imported only when one is created).
"""

ENV_ID = "ops_gym_bridge/RosPulseStacking-v0"


def _register() -> None:
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        # A real simulator's noise cannot be replayed from the bridge's seed: nondeterministic.
        register(
            id=ENV_ID,
            entry_point="ops_gym_bridge.bridge.bridge_env:RosOpsEnv",
            nondeterministic=True,
        )


_register()

__all__ = ["ENV_ID"]
