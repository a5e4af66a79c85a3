"""The learned-policy runner ``ops_policy``: a trained stable-baselines3 model closing the loop.

``ros2 run ops_controller_ros policy --ros-args -p model:=DIR`` loads ``DIR/model.zip`` and the
metadata saved beside it by training, builds each observation with the same builder as the
in-process environment (``ops_contract.observation.ObservationBuilder``, through
``policy_io.PolicyRunner``; a model trained with memory gets its last observations and actions,
the history starting at the node's first reading) from the simulator's trace, power and
set-points, and publishes new set-points: the reading's set-points + action * max step (the only
action type ``ops_controller_ros.policy_io`` loads is "increment"). A switching model (one policy
acquires, another holds: ``ops_controller_ros.policy_switch``) runs both on every reading and
logs which one acts. A model whose metadata has a ``reacquire`` entry runs inside the
re-acquiring watchdog (``ops_controller_ros.reacquire``: a stack lost for ``patience`` readings
is kicked to a fresh point), as ``evaluate`` runs it; the progress line counts its kicks.
``hold_steps`` (k > 1, or 0: the told ``latency_steps`` + 1) makes the policy decide on one
reading in k and hold its command on the others, seeing only the readings it decides on
(``ops_controller_ros.policy_hold``, as ``evaluate --hold-steps`` runs it): a model trained
without latency on a rig with one. By default (-1) the node holds the model as it was trained
(its metadata's ``hold_steps``, ``train --hold-steps``; every reading for a model without).

The loop is every controller node's (:class:`~ops_controller_ros.loop_node.ControllerLoopNode`):
readings paired with their command and their own step's trace by sequence number, re-sends, the
steps between readings counted, ``ops/controller/status``. A model trained for another stage
than the simulator runs stops the node with a clear error (exit code 1). The rig (``realism`` and
its figures, as the simulator node takes them) is every controller node's parameter: a policy is
not built from a model, so the node checks the values and warns where they differ from the rig
the model was trained on.
"""

from __future__ import annotations

import numpy as np
from ops_contract.node_params import ParamSpec
from ops_contract.observation import OBSERVATION_SETS
from ops_contract.rig_params import RIG_PARAM_KEYS
from ops_contract.ros_interface import NodeFatalError, ParameterError, run_node

from .loop_node import ControllerLoopNode
from .policy_hold import (
    HOLD_STEPS,
    HOLD_STEPS_AUTO,
    HOLD_STEPS_DEFAULT,
    HOLD_STEPS_HELP,
    HOLD_STEPS_MAX,
    HOLD_STEPS_MODEL,
    HeldRunner,
    model_hold_steps,
    resolve_hold_steps,
)
from .policy_io import PolicyLoadError, check_observation, check_stage, load_policy
from .policy_switch import SwitchingRunner, make_runner
from .reacquire import ReacquireWatchdog

PARAMS = [
    ParamSpec("model", "", "trained model: the training output DIR or DIR/model.zip"),
    ParamSpec(
        "observation",
        "rig",
        "observation set the model was trained on: rig (measurable on a real stacker) or "
        "authors (needs the simulator's ops/delays_actual oracle)",
        choices=OBSERVATION_SETS,
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


def _load(model: str, observation: str, hold_steps: int = 1, latency_steps: int = 0):
    """(policy, runner, resolved hold) of the model; ``hold_steps`` as the parameter takes it
    (-1: the model's, 0: auto against ``latency_steps``)."""
    if not model:
        raise ParameterError(
            "model must be the path of a trained model (the training output directory or "
            "its model.zip), e.g. --ros-args -p model:=runs/sac_n3_easy"
        )
    try:
        policy = load_policy(model)
        asked = model_hold_steps(policy.metadata) if hold_steps == HOLD_STEPS_MODEL else hold_steps
        hold = resolve_hold_steps(asked, latency_steps)
        runner = make_runner(policy, hold_steps=hold)
        check_observation(policy.metadata, observation, "-p observation:=")
    except PolicyLoadError as exc:
        raise ParameterError(f"model: {exc}") from None
    return policy, runner, hold


class PolicyNode(ControllerLoopNode):
    def __init__(self):
        super().__init__("ops_policy", PARAMS)
        latency = self.nominal_model().latency_steps  # the told rig's (any stage)
        policy, runner, hold = _load(
            self.values["model"], self.values["observation"], self.values[HOLD_STEPS], latency
        )
        self._policy, self._runner = policy, runner
        self._check_rig(policy)
        if runner.spec.needs_applied_delays:
            self.use_applied_delays()
        if isinstance(runner, HeldRunner):
            self.get_logger().info(
                f"the policy decides on one reading in {hold} and holds its command on the "
                f"others ({HOLD_STEPS}={self.values[HOLD_STEPS]}"
                + (
                    f": the model's, {policy.metadata.get(HOLD_STEPS)}"
                    if self.values[HOLD_STEPS] == HOLD_STEPS_MODEL
                    else ""
                )
                + f", told latency_steps={latency})"
            )
        inner = runner.runner if isinstance(runner, HeldRunner) else runner
        inner = inner.runner if isinstance(inner, ReacquireWatchdog) else inner
        if isinstance(inner, SwitchingRunner):
            self.get_logger().info(
                f"switching model: {inner.acquire.policy.path} acquires, the model in "
                f"{policy.path} holds ({inner.params})"
            )
        if isinstance(runner, ReacquireWatchdog):
            self.get_logger().info(
                f"re-acquiring watchdog on (the model's 'reacquire' entry): {runner.params}"
            )
        self.get_logger().info(
            f"loaded {policy.algo.upper()} model for stage {policy.stage} "
            f"({policy.mode} mode, observation {runner.spec.describe()}) from "
            f"{policy.path}; waiting for the simulator"
        )

    def _check_rig(self, policy) -> None:
        """Say where the rig this node is told of differs from the one the model was trained
        on (a learned policy is not built from a model: it acts on its observations alone); a
        figure inside the ranges the model's training drew its rigs from (``rig_randomize``)
        counts as trained on."""
        trained = dict(policy.metadata.get("config") or {})
        ranges = dict(policy.metadata.get("rig_randomize") or {})
        told = self.nominal_model(stage=policy.stage).to_dict()
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
            check_stage(self._policy, delays.size)
        except PolicyLoadError as exc:
            raise NodeFatalError(str(exc)) from None
        self.get_logger().info("simulator found: running the policy")
        return PolicyController(self._runner, self._policy.max_step_fs, delays)

    def progress(self) -> str:
        return f"step {self.readings}"

    def progress_note(self) -> str:
        r = self._runner
        notes = []
        if isinstance(r, HeldRunner):
            notes.append(f"{r.decisions} decisions since start")
            r = r.runner
        if isinstance(r, ReacquireWatchdog):
            kicking = ", kicking" if r.kicking else ""
            notes.append(f"{r.kicks} re-acquiring kicks since start{kicking}")
            r = r.runner
        if isinstance(r, SwitchingRunner):
            acting = "holding policy acts" if r.holding else "acquiring policy acts"
            if r.holder_acts and not r.holding:
                acting = "holding policy searches in turn"
            notes.insert(0, f"{acting}; {r.switches} hand-overs since start")
        return f" ({'; '.join(notes)})" if notes else ""


def main(args=None):
    raise SystemExit(run_node(PolicyNode, args))


if __name__ == "__main__":
    main()
