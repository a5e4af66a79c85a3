"""The SPGD-PID controller node ``ops_spgd``: closes the loop on a running simulator (or rig).

The loop (pairing readings with commands, re-sending, restarts, the progress log) is
:class:`~ops_controller_ros.loop_node.ControllerLoopNode`'s; this node declares SPGD's parameters
(each field of :class:`~ops_controller_ros.spgd.SpgdParams`, as declared there) and builds
:class:`~ops_controller_ros.spgd.SpgdPid` for the rig it is told of (``realism`` and the rig's
figures, as the simulator node takes them: the latency is what SPGD uses).
"""

from __future__ import annotations

from dataclasses import fields

from ops_contract.ros_interface import ParameterError, run_node

from .loop_node import EXECUTOR, ControllerLoopNode
from .param_fields import param_specs
from .spgd import SpgdParams, SpgdPid

#: The node's parameters of the algorithm: one per field of SpgdParams, with the default,
#: description and range declared there (the dataclass checks the same ranges in process).
PARAMS = param_specs(SpgdParams)
_NAMES = tuple(f.name for f in fields(SpgdParams))


class SpgdNode(ControllerLoopNode):
    reads_trace = False  # SPGD-PID climbs the power alone

    def __init__(self):
        super().__init__("ops_spgd", PARAMS)
        try:
            self._params = SpgdParams(**{name: self.values[name] for name in _NAMES})
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
    raise SystemExit(run_node(SpgdNode, args, executor=EXECUTOR))


if __name__ == "__main__":
    main()
