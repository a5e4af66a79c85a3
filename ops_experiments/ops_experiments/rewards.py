"""Training rewards: what the learner is paid, computed from the same P_N / P_max the paper's
reward is (the simulator's ``power``; ``info["power"]`` of every env here).

``paper`` is eq. (3), -(1 - P)^2: near the optimum it is nearly flat (P = 0.8 and P = 0.99 differ
by 0.04 per step), so an agent that holds 80 % of the energy is paid almost as much as one that
holds 99 %. ``nines`` pays the number of nines of P (``-log10(1 - P)``, capped at 3 = 99.9 %,
divided by 3): 0.8 -> 0.23, 0.9 -> 0.33, 0.99 -> 0.67, 0.999 -> 1, so every halving of the loss
is worth the same. The choice only changes what the learner optimizes; every evaluation, the
ROS topics and the benchmark keep measuring P_N / P_max.
"""

from __future__ import annotations

import numpy as np

#: The training rewards ``train --reward`` offers.
REWARDS = ("paper", "nines")
#: ``nines`` is capped at this loss (1 - P): 3 nines.
NINES_FLOOR = 1e-3


def nines_reward(power) -> np.ndarray:
    """-log10(max(1 - P, 1e-3)) / 3, in [0, 1] (P >= 1 or P <= 0 clipped). Shape of ``power``."""
    loss = np.clip(1.0 - np.asarray(power, dtype=np.float64), NINES_FLOOR, 1.0)
    return -np.log10(loss) / 3.0


def wrap_training_reward(venv, reward: str):
    """``venv`` paying ``reward`` instead of eq. (3): an SB3 VecEnvWrapper over a monitored vector
    env (so the monitor's episode returns stay the paper's, comparable across runs)."""
    if reward not in REWARDS:
        raise ValueError(f"reward must be one of {', '.join(REWARDS)} (got {reward!r})")
    if reward == "paper":
        return venv
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class NinesReward(VecEnvWrapper):
        """Replaces each step's reward with ``nines_reward(info["power"])``."""

        def reset(self):
            return self.venv.reset()

        def step_wait(self):
            obs, _, dones, infos = self.venv.step_wait()
            power = np.fromiter((info["power"] for info in infos), np.float64, len(infos))
            return obs, nines_reward(power).astype(np.float32), dones, infos

    return NinesReward(venv)
