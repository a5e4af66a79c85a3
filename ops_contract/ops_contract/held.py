"""Held decisions: a controller that acts on one reading in ``hold_steps`` and holds its command
(increment 0: the same set-points) on the others.

One declaration of the option (its values, ``auto``, its range) and one hold of the simulator,
shared by the places that run it:

* the environments (``OpsEnv(hold_steps=k)``, the batched vector envs, ``train --hold-steps``):
  one ``step`` is one *decision*: the action moves the set-points on the first simulator step,
  ``k - 1`` held steps follow (fewer where the episode's ``max_episode_steps`` simulator steps
  end first), and the observation is built from the last reading alone, pushed into the
  observation's memory with the decided action (:func:`hold_after`). The held readings never
  reach the observation; the reward and ``info`` are the last reading's;
* the runners (:class:`ops_controller_ros.policy_hold.HeldRunner`: ``evaluate --hold-steps``,
  the policy node's ``hold_steps``), which see every reading and pass on only the decisions'.

Both give a policy the very same observations on the same episodes (tested:
``ops_experiments/test/test_train_hold.py``). Values: 1 decides on every reading (no hold); k
from 2 to :data:`HOLD_STEPS_MAX` on one reading in k; 0 (``auto``) on one in latency_steps + 1
of the rig (an env: its own rig, drawn anew per episode with ``rig_randomize``; a runner: the
rig it is told of). Pure numpy.
"""

from __future__ import annotations

import numpy as np

from .config import LIMITS

#: The option's name: ``train`` / ``evaluate --hold-steps``, the policy node's parameter and
#: a model's metadata entry.
HOLD_STEPS = "hold_steps"
#: Decide on every reading (no hold).
HOLD_STEPS_DEFAULT = 1
#: Decide on one reading in latency_steps + 1 of the rig.
HOLD_STEPS_AUTO = 0
#: The longest hold: the longest latency a rig takes, plus one.
HOLD_STEPS_MAX = int(LIMITS["latency_steps"][1]) + 1


def check_hold_steps(value) -> int:
    """``value`` as an int if it is an allowed ``hold_steps`` (0, auto, or 1 to
    :data:`HOLD_STEPS_MAX`), else ValueError naming the allowed range."""
    ok = isinstance(value, int | np.integer) and not isinstance(value, bool)
    if not ok or not (value == HOLD_STEPS_AUTO or 1 <= value <= HOLD_STEPS_MAX):
        raise ValueError(
            f"{HOLD_STEPS} must be 0 (auto: the told latency_steps + 1) or an integer from 1 to "
            f"{HOLD_STEPS_MAX} (got {value!r})"
        )
    return int(value)


def resolve_hold_steps(value, latency_steps: int) -> int:
    """The readings per decision ``value`` asks for on a rig with a latency of
    ``latency_steps``: ``value`` itself, or latency_steps + 1 for 0 (auto)."""
    value = check_hold_steps(value)
    return int(latency_steps) + 1 if value == HOLD_STEPS_AUTO else value


def hold_after(sim, result, hold_steps: int):
    """After a decision's step (``result``, of :class:`~ops_sim_ros.simulation.
    BatchedSimulation` ``sim``): ``hold_steps`` - 1 more steps at the same set-points
    (increment 0), fewer where an episode ends first (a batch holds together: its envs' episodes
    end on the same step). Returns the last step's result."""
    if hold_steps > 1 and not result.truncated.any():
        zeros = np.zeros((sim.num_envs, sim.stage))
        for _ in range(hold_steps - 1):
            result = sim.step_increments(zeros)
            if result.truncated.any():
                break
    return result
