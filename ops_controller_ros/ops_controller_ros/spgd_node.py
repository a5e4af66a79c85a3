"""The SPGD-PID controller node ``ops_spgd``: closes the loop on a running simulator (or rig).

The loop (pairing readings with commands, re-sending, restarts, the progress log) is
:class:`~ops_controller_ros.loop_node.ControllerLoopNode`'s; this node declares SPGD's parameters
and builds :class:`~ops_controller_ros.spgd.SpgdPid`.
"""

from __future__ import annotations

from ops_sim_ros.node_params import ParamSpec
from ops_sim_ros.ros_interface import ParameterError, run_node

from .loop_node import ControllerLoopNode
from .spgd import SpgdParams, SpgdPid

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
}
PARAMS = [
    ParamSpec(name, getattr(_DEFAULTS, name), desc, low=lo, high=hi, low_exclusive=excl)
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
        return SpgdPid(delays.size, self._params, setpoints_fs=delays, seed=self.seed)

    def progress(self) -> str:
        return f"iteration {self.ctrl.iterations}"


def main(args=None):
    raise SystemExit(run_node(SpgdNode, args))


if __name__ == "__main__":
    main()
