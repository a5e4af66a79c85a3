"""The common part of a runner that wraps another runner (held decisions, the re-acquiring
watchdog): the interface of :class:`~ops_controller_ros.policy_io.PolicyRunner` passed through,
so wrappers nest in any order (:mod:`ops_controller_ros.runner_factory` composes them). Pure
Python: no rclpy, no torch.

The interface every layer has: ``act(pulse_energies, power, setpoints_fs, applied_fs=None)``
(an action in [-1, 1]^N), ``restart()`` (a new episode: histories and recurrent states start
afresh), ``took(action)`` (the action applied, if another part chose it), ``reset_state(rigs)``
(the recurrent state starts afresh at the next reading on those rigs, the memory kept: a lost
lock), ``spec`` (the observation) and ``policy`` (the acting policy, a ``LoadedPolicy``).
"""

from __future__ import annotations


class RunnerWrapper:
    """A runner around ``runner`` (a :class:`~ops_controller_ros.policy_io.PolicyRunner`, a
    switching model or another wrapper): ``policy`` and ``spec`` are the wrapped runner's, and
    so is any figure the wrapper does not have itself (a switching model's ``holding``, a
    watchdog's ``kicks``), so a caller reads them through every wrapper. ``num_envs`` None: one
    rig (``act`` takes and returns one reading's arrays); n: a batch of n rigs. A subclass
    defines ``act`` and ``restart``."""

    def __init__(self, runner, num_envs: int | None = None) -> None:
        self.runner = runner
        self.policy = runner.policy
        self.spec = runner.spec
        self._single = num_envs is None
        self._n = 1 if num_envs is None else int(num_envs)

    def __getattr__(self, name):
        # Only for names the wrapper lacks; "runner" itself is never looked up in the wrapped
        # runner (before __init__ set it, that would recurse).
        if name == "runner":
            raise AttributeError(name)
        return getattr(self.runner, name)

    def took(self, action) -> None:
        """The action applied, if another part chose it; passed on to the wrapped runner."""
        self.runner.took(action)

    def reset_state(self, rigs=None) -> None:
        """The recurrent state starts afresh at the next reading; passed on."""
        self.runner.reset_state(rigs)


def find_layer(runner, kind):
    """The layer of class ``kind`` in a runner's stack (following ``.runner``), or None."""
    while runner is not None:
        if isinstance(runner, kind):
            return runner
        runner = runner.__dict__.get("runner")
    return None
