"""One way to build a learned policy's runner: read a model directory once, check it against what
the run asks, load its policies and compose the layers its metadata asks for.

:func:`load_model` reads ``metadata.json`` once (:func:`ops_contract.policy_meta.read_meta`;
a switching model's acquiring policy's once too), refuses a model that cannot run where it is
asked to (another stage, detector or observation set: :func:`~ops_contract.policy_meta.
check_asked`; a recipe, observation or recurrent state this runner does not know:
:class:`~ops_contract.policy_meta.PolicyMeta`; a missing ``model.zip`` or ``metadata.json``), loads
the networks and resolves the hold. It returns a :class:`ModelStack`, which builds runners
without reading anything again: :meth:`ModelStack.build` composes, inside out,

1. :class:`~ops_controller_ros.policy_io.PolicyRunner` (observations from readings, the recurrent
   state carried from reading to reading), two of them in a
   :class:`~ops_controller_ros.policy_switch.SwitchingRunner` for a ``switch`` entry;
2. :class:`~ops_controller_ros.reacquire.ReacquireWatchdog` for a ``reacquire`` entry;
3. :class:`~ops_controller_ros.policy_hold.HeldRunner` when the hold is more than one reading.

:func:`build_runner` does both at once. The policy node, ``evaluate`` and the benchmark
(``ops_experiments.table1.bench_worker``) build their runners here.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

from ops_contract.policy_meta import (
    MODEL_FILE,
    PolicyLoadError,
    PolicyMeta,
    check_asked,
    read_meta,
)

from .policy_hold import HeldRunner, resolve_hold_steps
from .policy_io import LoadedPolicy, PolicyRunner, load_policy, run_observation_spec
from .policy_switch import SwitchingRunner, check_pair
from .reacquire import ReacquireWatchdog


@dataclass(frozen=True)
class ModelStack:
    """A model directory read and loaded once: its metadata, its policies and the layers it
    asks for. ``hold_steps``: readings per decision, resolved (>= 1)."""

    meta: PolicyMeta
    policy: LoadedPolicy  # the acting policy (a switching model's holding policy)
    acquire: LoadedPolicy | None = None  # a switching model's acquiring policy
    hold_steps: int = 1

    @property
    def path(self):
        return self.policy.path

    @property
    def layered(self) -> bool:
        """Whether the runner is more than the bare policy (a switch, a watchdog or a hold): an
        evaluation then runs it on every reading, as the policy node does."""
        return self.acquire is not None or self.meta.reacquire is not None or self.hold_steps != 1

    def with_hold(self, asked: int | None, latency_steps: int = 0) -> ModelStack:
        """The same model deciding on one reading in ``asked`` (None: the model's own
        ``hold_steps``; 0, auto: ``latency_steps`` + 1). PolicyLoadError for a bad value."""
        asked = self.meta.hold_steps if asked is None else asked
        try:
            hold = resolve_hold_steps(asked, latency_steps)
        except ValueError as exc:
            raise PolicyLoadError(str(exc)) from None
        return dataclasses.replace(self, hold_steps=hold)

    def build(self, num_envs: int | None = None):
        """A fresh runner (module docstring) for one rig (``num_envs`` None: readings of one rig,
        1-D arrays) or a batch of ``num_envs`` rigs ((B, ...) arrays)."""
        runner = PolicyRunner(self.policy, num_envs, run_observation_spec(self.meta))
        switch = self.meta.switch
        if self.acquire is not None:
            spec = run_observation_spec(self.acquire.meta, switch.acquire_setpoint_window)
            acquire = PolicyRunner(self.acquire, num_envs, spec)
            runner = SwitchingRunner(runner, acquire, switch, num_envs)
        if self.meta.reacquire is not None:
            runner = ReacquireWatchdog(runner, self.meta.reacquire, num_envs)
        if self.hold_steps != 1:
            runner = HeldRunner(runner, self.hold_steps, num_envs)
        return runner

    def predictor(self):
        """The bare policy's batched ``predict(obs)`` for one rollout of env-built
        observations (:meth:`~ops_controller_ros.policy_io.LoadedPolicy.predictor`)."""
        return self.policy.predictor()

    def describe(self) -> list[str]:
        """What the runner is made of, a line per layer (for logs)."""
        m = self.meta
        lines = [
            f"loaded {m.algo.upper()} model for stage {m.stage} ({m.mode} mode, observation "
            f"{run_observation_spec(m).describe()}) from {self.path}"
            + (f"; recipe {m.recipe}" if m.recipe != m.algo else "")
            + (
                f"; recurrent {m.recurrent.kind} state of {m.recurrent.hidden}"
                if m.recurrent
                else ""
            )
        ]
        if self.acquire is not None:
            lines.append(
                f"switching model: {self.acquire.path} acquires, the model in {self.path} holds "
                f"({m.switch})"
            )
        if m.reacquire is not None:
            lines.append(f"re-acquiring watchdog on (the model's 'reacquire' entry): {m.reacquire}")
        return lines


def load_model(
    model: str | os.PathLike | PolicyMeta | LoadedPolicy,
    *,
    stage: int | None = None,
    detector: str | None = None,
    observation: str | None = None,
    hold_steps: int | None = None,
    latency_steps: int = 0,
    source: str = "the simulator",
    observation_flag: str = "--observation",
    device: str = "cpu",
) -> ModelStack:
    """Read and load a model directory (or ``DIR/model.zip``; metadata already read; a policy
    already loaded) once, as a :class:`ModelStack`.

    ``stage``, ``detector``, ``observation``: what the run asks (None: not asked), refused with a
    PolicyLoadError that names what differs (``source``: who asks, e.g. "the simulator";
    ``observation_flag``: the option that chooses the observation set). ``hold_steps``: readings
    per decision (None: the model's ``hold_steps``; 0: auto, ``latency_steps`` + 1). Every other
    problem of the directory is a PolicyLoadError too (module docstring)."""
    if isinstance(model, LoadedPolicy):
        meta = model.meta
    else:
        meta = model if isinstance(model, PolicyMeta) else read_meta(model)
    check_asked(
        meta,
        stage=stage,
        detector=detector,
        observation=observation,
        source=source,
        flag=observation_flag,
    )
    policy = model if isinstance(model, LoadedPolicy) else load_policy(meta, device)
    acquire = _load_acquire(meta, device) if meta.switch is not None else None
    return ModelStack(meta, policy, acquire).with_hold(hold_steps, latency_steps)


def build_runner(model, *, num_envs: int | None = None, **asked):
    """:func:`load_model` (``asked``: its keywords) and :meth:`ModelStack.build`."""
    return load_model(model, **asked).build(num_envs)


def _load_acquire(meta: PolicyMeta, device: str) -> LoadedPolicy:
    path = meta.acquire_dir
    if not (path / MODEL_FILE).is_file():
        raise PolicyLoadError(
            f"switching model {meta.name}: the acquiring policy {path / MODEL_FILE} is missing; "
            "copy the acquiring model's folder there, or write the switching model again with "
            f"`ops-bench switch-model --hold HOLD_DIR --acquire ACQUIRE_DIR --out {meta.name}`"
        )
    acquire = read_meta(path)
    check_pair(meta, acquire)
    return load_policy(acquire, device)
