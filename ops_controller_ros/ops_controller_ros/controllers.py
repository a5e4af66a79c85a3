"""The controllers that need no training, by name: one registry for the nodes, ``evaluate
--controller`` and the benchmark.

Every controller is a pure state machine with the same three calls, with no notion of time or
transport (the ROS nodes and the in-process evaluation drive them the same way):

* ``reset(setpoints_fs)``: start again from these set-points (a new episode, a restarted rig);
* ``command() -> np.ndarray``: the set-points (fs, one per stage) to apply now;
* ``observe(power, pulse_energies, steps=1)``: what the last command produced (P_N / P_max and
  the detected slot energies, normalized as on ``/ops/intensity``), ``steps`` simulator steps
  after the previous reading (more than 1 when a free-running simulator stepped before the
  command came; the nodes count them, :mod:`ops_controller_ros.loop_node`); ``command_age``
  the steps from the step that took the last command to this reading (None: the step after the
  previous reading; the nodes read it from ``ops/delays``), for a controller that pairs readings
  with commands under a latency.

A controller may also have ``think() -> bool``: work that can wait until the command is out (the
tracker's deferred knot test); True when it changed the command already given, which
``command()`` then returns anew. :func:`next_command` is the in-process loop's way of calling it.

A controller may also have ``move_setpoints(delta_fs)``: its set-points moved by whole optical
periods (the same interference), with the state built on them following; the loop node calls it
to keep the set-points inside a rig's range (:mod:`ops_controller_ros.setpoint_range`). SPGD and
the policy runner have it; the tracker keeps the range itself.

A controller is built from the *nominal* model of the rig (an
:class:`~ops_contract.config.OpsConfig` holding the wavelength, pulse width, detector, ...), never
from the simulator's true state.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from .spgd import PAPER as SPGD_PAPER


class Controller(Protocol):
    stage: int

    def reset(self, setpoints_fs) -> None: ...

    def command(self) -> np.ndarray: ...

    def observe(
        self, power: float, pulse_energies=None, steps: int = 1, command_age: int | None = None
    ) -> None: ...


def _make_spgd(model, params: dict[str, Any], setpoints_fs, seed):
    from .spgd import SpgdParams, SpgdPid

    return SpgdPid(
        model.stage,
        SpgdParams(**params),
        setpoints_fs=setpoints_fs,
        seed=seed,
        latency=getattr(model, "latency_steps", 0),
    )


def _make_tracker(model, params: dict[str, Any], setpoints_fs, seed):
    from .tracker import PhaseTracker, TrackerParams

    return PhaseTracker(model, TrackerParams(**params), setpoints_fs=setpoints_fs, seed=seed)


_FACTORIES = {"spgd": _make_spgd, "tracker": _make_tracker}
CONTROLLERS = tuple(_FACTORIES)
#: The parameters under which the benchmark runs each controller: the paper's SPGD-PID (no
#: normalization, no restarts: the baseline of Table 1, which stalls in medium and hard modes).
BENCHMARK_PARAMS: dict[str, dict[str, Any]] = {"spgd": dict(SPGD_PAPER)}


def next_command(ctl) -> np.ndarray:
    """The set-points to apply now, as a node with time to spare before the next step gives
    them: ``command()``, then ``think()`` if the controller has one, and the revised command if
    that changed it."""
    command = ctl.command()
    think = getattr(ctl, "think", None)
    if think is not None and think():
        command = ctl.command()
    return command


def make_controller(
    name: str, model, params: dict[str, Any] | None = None, setpoints_fs=None, seed=None
) -> Controller:
    """A controller by name for the nominal ``model`` (an OpsConfig); ValueError names the
    choices or the bad parameter."""
    if name not in _FACTORIES:
        raise ValueError(f"controller must be one of {', '.join(CONTROLLERS)} (got {name!r})")
    sp = np.zeros(model.stage) if setpoints_fs is None else setpoints_fs
    try:
        return _FACTORIES[name](model, dict(params or {}), sp, seed)
    except TypeError as exc:  # an unknown keyword of the controller's parameters
        raise ValueError(f"bad {name} parameter: {exc}") from None
