"""The SPGD-PID controller node ``ops_spgd``: closes the loop on a running simulator (or rig).

The loop (pairing readings with commands, re-sending, restarts, the progress log) is
:class:`~ops_controller_ros.loop_node.ControllerLoopNode`'s; this node declares SPGD's parameters
and builds :class:`~ops_controller_ros.spgd.SpgdPid` for the rig it is told of (``realism`` and the
rig's figures, as the simulator node takes them: the latency is what SPGD uses).
"""

from __future__ import annotations

from ops_contract.node_params import ParamSpec
from ops_contract.ros_interface import ParameterError, run_node

from .loop_node import ControllerLoopNode
from .spgd import RECOVERIES, SpgdParams, SpgdPid

_DEFAULTS = SpgdParams()
# The node's parameters of the algorithm: SpgdParams' own fields (their defaults and types),
# with the description and range the node declares; one table, read twice.
_SPGD_FIELDS = {
    "gain": ("SPGD gain: fs^2 per unit of normalized power", 0.0, 1e6, True),
    "perturbation_fs": ("dither amplitude per stage, fs", 0.0, 1e3, True),
    "kp": ("PID proportional gain on the SPGD update", -1e6, 1e6, False),
    "ki": ("PID integral gain", -1e6, 1e6, False),
    "kd": ("PID derivative gain", -1e6, 1e6, False),
    "momentum": ("momentum of the update, in [0, 1)", 0.0, 0.999, False),
    "max_update_fs": ("largest set-point change per iteration", 0.0, 1e3, True),
    "normalized": ("divide the gradient by the power (false: the paper's SPGD)", None, None, False),
    "normalize_floor": ("smallest power the gradient is divided by", 0.0, 1.0, True),
    "recovery": (
        "restart: leave a side peak by random restarts; none: the paper's",
        None,
        None,
        False,
    ),
    "restart_below": (
        "restart while P_N/P_max is below this (above every side peak) ...",
        0.0,
        1.0,
        False,
    ),
    "restart_after": ("... and flat over this many iterations since the last", 1, 100000, False),
    "restart_flat": ("... within this fraction of its level", 0.0, 1.0, False),
    "restart_after_per_latency": (
        "... a window longer by this many iterations per step of the rig's latency",
        0.0,
        1e3,
        False,
    ),
    "restart_range_fs": ("width of a restart's random offset, fs (one cycle)", 0.0, 1e3, False),
    "restart_step_fs": ("set-point change per reading on the way to a restart", 0.0, 1e3, True),
}
_CHOICES = {"recovery": RECOVERIES}
PARAMS = [
    ParamSpec(
        name,
        getattr(_DEFAULTS, name),
        desc,
        low=lo,
        high=hi,
        low_exclusive=excl,
        choices=_CHOICES.get(name, ()),
    )
    for name, (desc, lo, hi, excl) in _SPGD_FIELDS.items()
]


class SpgdNode(ControllerLoopNode):
    def __init__(self):
        super().__init__("ops_spgd", PARAMS)
        try:
            self._params = SpgdParams(**{name: self.values[name] for name in _SPGD_FIELDS})
        except ValueError as exc:
            raise ParameterError(str(exc)) from None

    def build_controller(self, delays, samples_per_slot):
        # the rig's latency, as evaluate tells it (controllers.make_controller)
        latency = self.nominal_model(stage=delays.size).latency_steps
        return SpgdPid(
            delays.size, self._params, setpoints_fs=delays, seed=self.seed, latency=latency
        )

    def progress(self) -> str:
        restarts = f", {self.ctrl.restarts} restarts since start" if self.ctrl.restarts else ""
        return f"iteration {self.ctrl.iterations}{restarts}"


def main(args=None):
    raise SystemExit(run_node(SpgdNode, args))


if __name__ == "__main__":
    main()
