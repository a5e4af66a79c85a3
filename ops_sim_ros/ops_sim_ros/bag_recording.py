"""Recording in-process episodes as a rosbag2 MCAP bag, the format ``ros2 bag record`` writes.

``RecordBag(OpsEnv(...), "DIR")`` is a Gymnasium wrapper: after every reset and step it writes
what the simulator node would publish - ``/ops/delays`` (set-points), ``/ops/intensity`` (the
detected trace, layout filled), ``/ops/power`` and ``/ops/reward`` - with the node's message types
and QoS, so an agent's episodes open in ``ros2 bag info/play``, Foxglove and Lichtblick like a
recorded run. Time stamps follow a simulated clock: one step every ``step_period_s`` (the
simulator node's default 100 Hz) from the start of the recording, and ``episode_gap_s`` between
episodes, so a replay runs at the rig's pace however fast the episodes were computed.
"""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np
from ops_contract.ros_interface import (
    QOS_RELIABLE,
    QOS_STATE,
    TOPIC_DELAYS,
    TOPIC_INTENSITY,
    TOPIC_POWER,
    TOPIC_REWARD,
    float_array_msg,
    trace_msg,
)
from rclpy.serialization import serialize_message
from std_msgs.msg import Float32

TOPICS = (
    ("/" + TOPIC_DELAYS, "std_msgs/msg/Float32MultiArray", QOS_STATE),
    ("/" + TOPIC_INTENSITY, "std_msgs/msg/Float32MultiArray", QOS_RELIABLE),
    ("/" + TOPIC_POWER, "std_msgs/msg/Float32", QOS_RELIABLE),
    ("/" + TOPIC_REWARD, "std_msgs/msg/Float32", QOS_RELIABLE),
)


class RecordBag(gym.Wrapper):
    """Record an :class:`~ops_sim_ros.OpsEnv`'s episodes to the bag directory ``path`` (new).

    ``close()`` finalizes the bag. Raises ``ops_bag.BagExistsError`` if ``path`` exists.
    """

    def __init__(
        self,
        env: gym.Env,
        path,
        step_period_s: float = 0.01,
        episode_gap_s: float = 0.5,
        custom_data: dict[str, str] | None = None,
    ):
        super().__init__(env)
        from ops_bag import BagWriter
        from ops_bag import qos as qos_io

        self.writer = BagWriter(path, custom_data=custom_data)
        for name, type_name, qos in TOPICS:
            self.writer.add_topic(name, type_name, [qos_io.to_dict(qos)])
        self._period_ns = int(step_period_s * 1e9)
        self._gap_ns = int(episode_gap_s * 1e9)
        self._clock_ns = time.time_ns()
        self._started = False
        self.episodes = 0

    def _write(self, setpoints, trace, power: float, reward: float) -> None:
        stamp = self._clock_ns
        w = self.writer
        spp = self.env.unwrapped.config.samples_per_slot
        w.write(TOPICS[0][0], serialize_message(float_array_msg(setpoints)), stamp)
        w.write(TOPICS[1][0], serialize_message(trace_msg(trace, spp)), stamp)
        w.write(TOPICS[2][0], serialize_message(Float32(data=float(power))), stamp)
        w.write(TOPICS[3][0], serialize_message(Float32(data=float(reward))), stamp)

    def _write_info(self, reward: float, info: dict[str, Any]) -> None:
        self._write(info["setpoints_fs"], self.env.unwrapped.trace(), info["power"], reward)

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        if self._started:
            self._clock_ns += self._gap_ns
        self._started = True
        self.episodes += 1
        # after a reset the node publishes the starting point's reward too: eq. (3)
        self._write_info(-((1.0 - float(info["power"])) ** 2), info)
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._clock_ns += self._period_ns
        self._write_info(float(reward), info)
        return obs, reward, terminated, truncated, info

    def step_setpoints(self, setpoints_fs):
        """One step to absolute set-points (fs), as the simulator node takes a delay command;
        returns the simulation's step result (``power``, ``reward``, ... batched by 1)."""
        sim = self.env.unwrapped.sim
        r = sim.step_setpoints(np.asarray(setpoints_fs, dtype=np.float64)[None, :])
        self._clock_ns += self._period_ns
        self._write(r.setpoints_fs[0], sim.trace(r)[0], float(r.power[0]), float(r.reward[0]))
        return r

    def close(self):
        try:
            self.writer.close()
        finally:
            super().close()
