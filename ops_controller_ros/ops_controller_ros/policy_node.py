"""The learned-policy runner ``ops_policy``: a trained stable-baselines3 model closing the loop.

``ros2 run ops_controller_ros policy --ros-args -p model:=DIR`` builds the model's runner with
:func:`ops_controller_ros.runner_factory.load_model` (``DIR/model.zip`` and the metadata saved
beside it by training, read once), builds each observation with the same builder as the
in-process environment (``ops_contract.observation.ObservationBuilder``; a model trained with
memory gets its last observations and actions, a recurrent one its state, from the node's first
reading) from the simulator's trace, power and set-points, and publishes new set-points: the
reading's set-points + action * max step (the only action type is "increment"). A switching
model (one policy acquires, another holds: ``ops_controller_ros.policy_switch``) runs both on
every reading and logs which one acts. A model whose metadata has a ``reacquire`` entry runs
inside the re-acquiring watchdog (``ops_controller_ros.reacquire``: a stack lost for
``patience`` readings is kicked to a fresh point), as ``evaluate`` runs it; the progress line
counts its kicks. ``hold_steps`` (k > 1, or 0: the told ``latency_steps`` + 1) makes the policy
decide on one reading in k and hold its command on the others, seeing only the readings it
decides on (``ops_controller_ros.policy_hold``, as ``evaluate --hold-steps`` runs it): a model
trained without latency on a rig with one. By default (-1) the node holds the model as it was
trained (its metadata's ``hold_steps``, ``train --hold-steps``; every reading for a model
without).

The loop is every controller node's (:class:`~ops_controller_ros.loop_node.ControllerLoopNode`):
readings paired with their command and their own step's trace by sequence number, re-sends, the
steps between readings counted, ``ops/controller/status``.

A model the node cannot run is refused with what differs: at start (exit code 2, before the
node spins) a missing or malformed model directory, a recipe, observation or recurrent state
the runner does not know, another observation set than ``observation``, another detector than
``detector`` (or the rig file's) and another stage than the rig file's; once the simulator is
found, another stage than it runs (exit code 1). ``model`` may change while the node runs
(``ros2 param set /ops_policy model DIR``): the new model is checked the same way (against the
running simulator's stage) and, if refused, the parameter keeps its value and the node goes on
with its old model; if taken, the loop carries on from the present set-points with the new
runner (a new history). The rig (``realism`` and its figures, as the simulator node takes them)
is every controller node's parameter: a policy is not built from a model, so the node checks the
values and warns where they differ from the rig the model was trained on.
"""

from __future__ import annotations

import numpy as np
from ops_contract.node_params import ParamSpec, declare_all
from ops_contract.observation import OBSERVATION_SETS
from ops_contract.policy_meta import DETECTORS, PolicyLoadError, check_asked
from ops_contract.rig_params import RIG_PARAM_KEYS
from ops_contract.ros_interface import NodeFatalError, ParameterError, run_node
from ops_contract.threads import limit_torch_threads
from rcl_interfaces.msg import SetParametersResult

from .loop_node import EXECUTOR, ControllerLoopNode
from .policy_hold import (
    HOLD_STEPS,
    HOLD_STEPS_AUTO,
    HOLD_STEPS_DEFAULT,
    HOLD_STEPS_HELP,
    HOLD_STEPS_MAX,
    HOLD_STEPS_MODEL,
    HeldRunner,
)
from .policy_switch import SwitchingRunner
from .reacquire import ReacquireWatchdog
from .runner_factory import ModelStack, load_model
from .runner_wrapper import find_layer

#: The model: the one parameter that may change while the node runs (checked like at start).
MODEL = ParamSpec(
    "model",
    "",
    "trained model: the training output DIR or DIR/model.zip; may change while the node runs "
    "(a model the node cannot run is refused, and the old one goes on)",
)
PARAMS = [
    ParamSpec(
        "observation",
        "rig",
        "observation set the model was trained on: rig (measurable on a real stacker) or "
        "authors (needs the simulator's ops/delays_actual oracle)",
        choices=OBSERVATION_SETS,
        read_only=True,
    ),
    ParamSpec(
        "detector",
        "",
        "the rig's detector (polarizer or total): a model trained for another is refused; "
        "'' (default): the rig file's (rig_config), else not checked",
        read_only=True,
    ),
    ParamSpec(
        HOLD_STEPS,
        HOLD_STEPS_MODEL,
        HOLD_STEPS_HELP,
        low=HOLD_STEPS_DEFAULT,
        high=HOLD_STEPS_MAX,
        special=(HOLD_STEPS_MODEL, HOLD_STEPS_AUTO),
        read_only=True,
    ),
]


class PolicyController:
    """A learned policy as a loop controller: each reading's set-points plus the policy's
    action are the next command (asked again before the next reading, the same command)."""

    def __init__(self, runner, max_step_fs: float, setpoints_fs: np.ndarray):
        self.runner = runner
        self.stage = int(np.asarray(setpoints_fs).size)
        self._max_step_fs = float(max_step_fs)
        self._command = np.asarray(setpoints_fs, dtype=np.float64).copy()
        # The whole periods (fs) the node moved the set-points by (move_setpoints), which the
        # policy is not shown: it observes the set-points (and applied delays) less these.
        self._moved = np.zeros(self.stage)
        self.last_power = float("nan")

    def command(self) -> np.ndarray:
        return self._command.copy()

    @property
    def moved_fs(self) -> np.ndarray:
        """The whole periods (fs, per stage) the set-points were moved by so far."""
        return self._moved.copy()

    def move_setpoints(self, delta_fs) -> None:
        """Move the set-points by ``delta_fs`` (whole optical periods: the node keeps them
        inside a rig's range, :mod:`ops_controller_ros.setpoint_range`). The policy acts by
        increments on the set-points it commanded: those move. The interference is the same
        there, and the policy is not told: it observes its set-points less the moves, so its
        observations and memory read as if nothing had moved (a jump of a cycle in its history
        is nothing it was trained on)."""
        delta = np.asarray(delta_fs, dtype=np.float64).reshape(self.stage)
        self._command = self._command + delta
        self._moved = self._moved + delta

    def with_runner(self, runner, max_step_fs: float) -> PolicyController:
        """Another model's controller, carrying on from this one's command (and its moves)."""
        ctl = PolicyController(runner, max_step_fs, self._command)
        ctl._moved = self._moved.copy()
        return ctl

    def observe(
        self, power: float, pulse_energies, steps: int = 1, applied=None, command_age=None
    ) -> None:
        """A reading of the last command (``steps``: the loop's count, unused: a policy acts
        on its observation alone)."""
        seen = self._command - self._moved
        if applied is not None:
            applied = np.asarray(applied, dtype=np.float64) - self._moved
        action = self.runner.act(pulse_energies, power, seen, applied)
        self._command = self._command + np.asarray(action, dtype=np.float64) * self._max_step_fs
        self.last_power = float(power)


class PolicyNode(ControllerLoopNode):
    def __init__(self):
        super().__init__("ops_policy", PARAMS)
        limit_torch_threads()  # (ops_contract.threads: a thread per core stalls on a busy CPU)
        self.values.update(declare_all(self, [MODEL], on_change=self._on_model_change))
        self._latency = self.nominal_model().latency_steps  # the told rig's (any stage)
        detector = self.values["detector"]
        if detector and detector not in DETECTORS:
            raise ParameterError(
                f"detector must be '' or one of {', '.join(DETECTORS)} (got {detector!r})"
            )
        rig = self.rig_model
        self._detector = detector or (rig.optics["detector"] if rig is not None else None)
        self._stack: ModelStack | None = None
        self._runner = None
        self._use(self._load(self.values["model"]))
        self.get_logger().info("waiting for the simulator")

    def _load(self, model: str) -> ModelStack:
        """The model checked against what the node is told (module docstring): ParameterError
        naming what differs."""
        if not model:
            raise ParameterError(
                "model must be the path of a trained model (the training output directory or "
                "its model.zip), e.g. --ros-args -p model:=runs/sac_n3_easy"
            )
        stage, source = None, "the simulator"
        if self.ctrl is not None:
            stage = self.ctrl.stage
        elif self.rig_model is not None:
            stage, source = self.rig_model.stage, f"the rig file {self.values['rig_config']}"
        hold = self.values[HOLD_STEPS]
        try:
            return load_model(
                model,
                stage=stage,
                detector=self._detector,
                observation=self.values["observation"],
                hold_steps=None if hold == HOLD_STEPS_MODEL else hold,
                latency_steps=self._latency,
                source=source,
                observation_flag="-p observation:=",
            )
        except PolicyLoadError as exc:
            raise ParameterError(f"model: {exc}") from None

    def _use(self, stack: ModelStack) -> None:
        """Run ``stack``'s model from now on (a running loop goes on from its command)."""
        self._stack, self._runner = stack, stack.build()
        self._check_rig(stack)
        if self._runner.spec.needs_applied_delays and not self._applied_delays:
            self.use_applied_delays()
        if self.ctrl is not None:
            self.ctrl = self.ctrl.with_runner(self._runner, stack.meta.max_step_fs)
        if stack.hold_steps != 1:
            asked = self.values[HOLD_STEPS]
            model = stack.meta.entries.get(HOLD_STEPS)
            self.get_logger().info(
                f"the policy decides on one reading in {stack.hold_steps} and holds its command "
                f"on the others ({HOLD_STEPS}={asked}"
                + (f": the model's, {model}" if asked == HOLD_STEPS_MODEL else "")
                + f", told latency_steps={self._latency})"
            )
        for line in stack.describe():
            self.get_logger().info(line)

    def _on_model_change(self, params) -> SetParametersResult:
        """``model`` set while the node runs: the new model if the node can run it, else
        refused with why (the old one goes on). rclpy may hand the same parameter more than
        once (each declare_all's pre-set callback passes the whole list on): the last counts."""
        asked = [p.value for p in params if p.name == MODEL.name]
        if not asked:
            return SetParametersResult(successful=True)
        try:
            stack = self._load(asked[-1])
        except ParameterError as exc:
            self.get_logger().warning(f"{exc}; the node goes on with {self._stack.path}")
            return SetParametersResult(successful=False, reason=str(exc))
        self._use(stack)
        return SetParametersResult(successful=True)

    def _check_rig(self, stack: ModelStack) -> None:
        """Say where the rig this node is told of differs from the one the model was trained
        on (a learned policy is not built from a model: it acts on its observations alone); a
        figure inside the ranges the model's training drew its rigs from (``rig_randomize``)
        counts as trained on."""
        trained = stack.meta.config
        ranges = dict(stack.meta.entries.get("rig_randomize") or {})
        told = self.nominal_model(stage=stack.meta.stage).to_dict()
        keys = ("realism", *RIG_PARAM_KEYS)

        def drawn(k) -> bool:
            low, high = ranges.get(k) or (None, None)
            return low is not None and low <= told[k] <= high

        diff = [
            f"{k}={told[k]} (trained: {trained[k]})"
            for k in keys
            if k in trained and trained[k] != told[k] and not drawn(k)
        ]
        if diff:
            self.get_logger().warning(
                "this rig is not the one the model was trained on: " + ", ".join(diff)
            )

    def build_controller(self, delays, samples_per_slot):
        try:
            check_asked(self._stack.meta, stage=delays.size)
        except PolicyLoadError as exc:
            raise NodeFatalError(str(exc)) from None
        self.get_logger().info("simulator found: running the policy")
        return PolicyController(self._runner, self._stack.meta.max_step_fs, delays)

    def progress(self) -> str:
        return f"step {self.readings}"

    def progress_note(self) -> str:
        notes = []
        held = find_layer(self._runner, HeldRunner)
        if held is not None:
            notes.append(f"{held.decisions} decisions since start")
        watchdog = find_layer(self._runner, ReacquireWatchdog)
        if watchdog is not None:
            kicking = ", kicking" if watchdog.kicking else ""
            notes.append(f"{watchdog.kicks} re-acquiring kicks since start{kicking}")
        switch = find_layer(self._runner, SwitchingRunner)
        if switch is not None:
            acting = "holding policy acts" if switch.holding else "acquiring policy acts"
            if switch.holder_acts and not switch.holding:
                acting = "holding policy searches in turn"
            notes.insert(0, f"{acting}; {switch.switches} hand-overs since start")
        return f" ({'; '.join(notes)})" if notes else ""


def main(args=None):
    raise SystemExit(run_node(PolicyNode, args, executor=EXECUTOR))


if __name__ == "__main__":
    main()
