"""Gymnasium environment over the simulator's ROS 2 topics (a running ``ops_sim`` in lockstep).

``RosOpsEnv(stage=3, mode="easy")`` has the same observation and action spaces as
``ops_sim_ros.OpsEnv`` for the same stage and configuration (the same set-up,
:func:`ops_sim_ros.env_setup.env_setup`), and builds its observations with the same function
(:class:`ops_contract.observation.ObservationBuilder`, memory included).

``step`` adds the scaled action to the current set-points and sends the absolute set-points;
``reset`` calls ``ops/reset``. The ROS side (context, node, the lockstep protocol, waits,
retries) is :class:`~.lockstep_client.LockstepClient`; this module keeps spaces,
reset, step and observe. ``close()`` shuts the client's private context down.
"""

from __future__ import annotations

import time
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from ops_contract.observation import ObservationBuilder, pulse_energies_from_trace
from ops_sim_ros.env_setup import env_setup

from .lockstep_client import (  # noqa: F401  (the bridge's errors, importable from here)
    BridgeError,
    LockstepClient,
    LockstepError,
    SimulatorTimeoutError,
    StageMismatchError,
)

ENV_ID = "ops_gym_bridge/RosPulseStacking-v0"


class RosOpsEnv(gym.Env):
    """N-stage optical pulse stacking through a running simulator's topics.

    Arguments: ``stage``, ``mode``, ``split`` and config ``overrides`` (as ``OpsEnv``; they must
    describe the simulator that runs: the bridge cannot set them, but it checks the stage),
    ``namespace`` (e.g. ``"/rig2"`` for a sim started with ``-r __ns:=/rig2``), ``domain_id``
    (None: ``ROS_DOMAIN_ID``), ``timeout_s`` (deadline of every wait; None: no deadline, the env
    waits through outages of any length and re-sends every ``retry_after_s``),
    ``reconnect_after_s`` (a request unanswered this long, the simulator's endpoints matched all
    the while, is sent again over a new DDS participant; None: never), ``max_episode_steps``.

    ``info``: ``power`` (P_N/P_max), ``setpoints_fs`` (set-points now applied, as echoed by the
    simulator), ``delays_fs`` (with the authors' observation set only: the applied delays of the
    simulator-only ``ops/delays_actual``), ``reward``, ``step_time_s`` (wall time of the round
    trip), ``retries`` (requests
    sent again so far because an answer went missing for ``retry_after_s``; in lockstep a resent
    command makes the simulator step once more with the same set-points).
    """

    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(
        self,
        stage: int = 5,
        mode: str = "medium",
        split: str = "train",
        namespace: str = "",
        domain_id: int | None = None,
        timeout_s: float | None = None,
        max_episode_steps: int = 200,
        action_type: str = "increment",
        observation_options: dict[str, Any] | None = None,
        node_name: str | None = None,
        retry_after_s: float | None = 1.0,
        reconnect_after_s: float | None = 30.0,
        **overrides: Any,
    ) -> None:
        super().__init__()
        setup = env_setup(
            stage,
            mode,
            split,
            action_type,
            max_episode_steps,
            observation_options,
            overrides,
            action_types=("increment",),  # the bridge commands increments only
        )
        setup.apply_to(self)
        self.observation_space = setup.observation_space
        self.action_space = setup.action_space
        self.max_step_fs = self.config.max_step_fs
        self.range_fs = self.config.actuator_range_fs
        self.max_episode_steps = int(max_episode_steps)
        self.namespace = namespace
        self._setpoints: np.ndarray | None = None
        self._observations = ObservationBuilder(self.obs_spec)
        self._steps = 0
        self._closed = False
        if self.spec is None:  # direct construction: declare the nondeterminism gym.make would
            from gymnasium.envs.registration import EnvSpec

            self.spec = EnvSpec(
                ENV_ID,
                entry_point="ops_gym_bridge.bridge.bridge_env:RosOpsEnv",
                nondeterministic=True,
                max_episode_steps=None,
            )
        self.client = LockstepClient(
            self.stage,
            self.config.mode,
            namespace,
            domain_id,
            timeout_s,
            retry_after_s,
            node_name,
            with_actual=self.obs_spec.needs_applied_delays,  # the authors' set: the oracle topic
            reconnect_after_s=reconnect_after_s,
        )
        self.timeout_s = self.client.timeout_s
        self.domain_id = self.client.domain_id

    @property
    def retries(self) -> int:
        """Requests sent again so far because an answer went missing."""
        return self.client.retries

    def _check_open(self) -> None:
        if self._closed:
            raise BridgeError("the bridge is closed")

    def _observe(self, msgs, action=None) -> tuple[np.ndarray, dict[str, Any]]:
        """Observation and info of the simulator's answer; ``action``: the normalized action of
        the step that produced it (None: a new episode)."""
        from ops_contract.ros_interface import trace_from_msg

        intensity, power_msg, reward_msg, delays_msg, *actual_msg = msgs
        trace, samples = trace_from_msg(intensity)
        energies = pulse_energies_from_trace(trace, samples)
        if energies.shape[-1] != self.obs_spec.num_slots:
            raise StageMismatchError(
                f"the simulator's intensity trace has {energies.shape[-1]} slots, stage "
                f"{self.stage} has {self.obs_spec.num_slots}"
            )
        setpoints = np.asarray(delays_msg.data, dtype=np.float64)
        power = float(power_msg.data)
        # The authors' set: the applied delays of ops/delays_actual (a simulator-only oracle).
        applied = np.asarray(actual_msg[0].data, dtype=np.float64) if actual_msg else None
        if action is None:
            obs = self._observations.reset(energies, power, setpoints, applied_fs=applied)
        else:
            obs = self._observations.step(energies, power, setpoints, action, applied_fs=applied)
        self._setpoints = setpoints
        info = {
            "power": power,
            "setpoints_fs": setpoints.copy(),
            "reward": float(reward_msg.data),
            "retries": self.client.retries,
        }
        if applied is not None:
            info["delays_fs"] = applied.copy()
        return obs, info

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start a new episode on the simulator. ``seed`` seeds only the bridge's own generator
        (the simulator's noise is seeded by its ``seed`` parameter)."""
        self._check_open()
        super().reset(seed=seed)
        t0 = time.monotonic()
        msgs = self.client.reset()
        self._steps = 0
        obs, info = self._observe(msgs)
        info["step_time_s"] = time.monotonic() - t0
        return obs, info

    def step(self, action):
        self._check_open()
        if self._setpoints is None:
            raise RuntimeError("call reset() before step()")
        t0 = time.monotonic()
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(self.stage), -1.0, 1.0)
        command = np.clip(self._setpoints + a * self.max_step_fs, -self.range_fs, self.range_fs)
        command = command.astype(np.float32).astype(np.float64)  # what the message carries
        msgs = self.client.command(command, t0, f"step {self._steps + 1}")
        self._steps += 1
        obs, info = self._observe(msgs, a)
        info["step_time_s"] = time.monotonic() - t0
        truncated = self._steps >= self.max_episode_steps
        return obs, float(info["reward"]), False, truncated, info

    def set_setpoints(self, setpoints_fs) -> tuple[np.ndarray, dict[str, Any]]:
        """Command absolute set-points (fs) for one step; returns (observation, info). With memory
        the step is recorded as the normalized increment that it equals (clipped to [-1, 1])."""
        self._check_open()
        if self._setpoints is None:
            raise RuntimeError("call reset() before set_setpoints()")
        command = (
            np.clip(
                np.asarray(setpoints_fs, dtype=np.float64).reshape(self.stage),
                -self.range_fs,
                self.range_fs,
            )
            .astype(np.float32)
            .astype(np.float64)
        )
        t0 = time.monotonic()
        msgs = self.client.command(command, t0, "set_setpoints")
        action = (command - self._setpoints) / self.max_step_fs
        obs, info = self._observe(msgs, action)
        info["step_time_s"] = time.monotonic() - t0
        return obs, info

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.client.close()


def make_bridge_env(**kwargs) -> RosOpsEnv:
    return RosOpsEnv(**kwargs)
