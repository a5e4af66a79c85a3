"""Gymnasium environment over the simulator's ROS 2 topics; train, evaluate and benchmark CLIs.

Three parts:

* :mod:`ops_gym_bridge.bridge`: the bridge itself, a Gymnasium env over the topics
  (``bridge_env``) and its lockstep protocol (``lockstep_client``);
* :mod:`ops_gym_bridge.experiments`: ``train``, ``evaluate`` (and ``realism_sweep``), the rollouts,
  the one evaluation summary, the one model-building path, the hyper-parameter sets;
* :mod:`ops_gym_bridge.table1`: the paper's Table 1, ``benchmark`` and ``report``.

``cli_args`` holds what every command line shares; ``hyperparams/`` the YAML files (the
hyper-parameter sets, the benchmark's profiles, the training bench's candidates).

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
