"""Held decisions (ops_controller_ros.policy_hold): a policy that acts on one reading in
``hold_steps`` and holds its command on the others, seeing only the readings it acts on; one
implementation for ``evaluate --hold-steps`` and the policy node's ``hold_steps``."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.policy_hold import (
    HOLD_STEPS_MAX,
    HeldRunner,
    check_hold_steps,
    resolve_hold_steps,
)
from ops_controller_ros.policy_io import PolicyRunner, load_policy
from ops_controller_ros.runner_factory import build_runner
from ops_sim_ros.env import OpsEnv

STAGE = 5
MODELS = Path(__file__).resolve().parents[2] / "models"


class Recorder:
    """A stand-in runner: returns a fixed action and records the power of every reading it
    was asked about."""

    def __init__(self, num_envs=None, action=0.5):
        self.policy = SimpleNamespace(path="stand-in")
        self.spec = SimpleNamespace(stage=STAGE)
        self.n = num_envs
        self.action = action
        self.seen: list = []
        self.restarts = 0

    def restart(self):
        self.restarts += 1

    def act(self, pulse_energies, power, setpoints_fs, applied_fs=None):
        self.seen.append(np.asarray(power).copy())
        shape = (STAGE,) if self.n is None else (self.n, STAGE)
        return np.full(shape, self.action, dtype=np.float32)

    def took(self, action):
        pass


def test_hold_steps_values_are_checked_with_their_range():
    assert HOLD_STEPS_MAX == 1001  # the longest latency a rig takes, plus one
    for good in (0, 1, 2, HOLD_STEPS_MAX, np.int64(3)):
        assert check_hold_steps(good) == int(good)
    for bad in (-1, HOLD_STEPS_MAX + 1, 1.5, 2.0, True, "2", None):
        with pytest.raises(ValueError, match=r"hold_steps must be 0 \(auto.*from 1 to 1001"):
            check_hold_steps(bad)
    assert resolve_hold_steps(0, 0) == 1  # auto on an ideal rig: every reading
    assert resolve_hold_steps(0, 2) == 3  # auto: the told latency + 1
    assert resolve_hold_steps(4, 1) == 4  # a number is taken as it is
    with pytest.raises(ValueError, match="resolved"):
        HeldRunner(Recorder(), 0)


def test_a_held_runner_decides_on_one_reading_in_k_and_holds_on_the_others():
    inner = Recorder()
    held = HeldRunner(inner, 3)
    e, sp = np.zeros(2**STAGE - 1), np.zeros(STAGE)
    actions = [held.act(e, float(t), sp) for t in range(10)]
    assert [float(p) for p in inner.seen] == [0.0, 3.0, 6.0, 9.0]  # decisions' readings only
    for t, a in enumerate(actions):
        assert a.shape == (STAGE,) and a.dtype == np.float32
        assert np.all(a == (0.5 if t % 3 == 0 else 0.0))
    assert held.decisions == 4 and held.readings == 10 and held.decided  # reading 9 decided
    held.restart()  # a new start: the next reading decides again
    assert inner.restarts == 1 and held.readings == 0 and not held.decided
    held.act(e, 42.0, sp)
    assert float(inner.seen[-1]) == 42.0 and held.decided
    # A batch: every rig decides on the same readings.
    batch = HeldRunner(Recorder(num_envs=3), 2, num_envs=3)
    out = [batch.act(np.zeros((3, 31)), np.zeros(3), np.zeros((3, STAGE))) for _ in range(4)]
    assert [a.shape for a in out] == [(3, STAGE)] * 4
    assert [float(a.max()) for a in out] == [0.5, 0.0, 0.5, 0.0]


def test_the_set_points_change_only_every_k_steps_in_process_and_in_the_node():
    """The rollout's loop (the env's increments) and the node's controller (PolicyController)
    both move the set-points on the decisions' readings only."""
    from ops_controller_ros.policy_node import PolicyController

    k = 3
    env = OpsEnv.from_config(make_config(STAGE, "hard", "test", latency_steps=2))
    env.reset(seed=8301)
    runner = HeldRunner(Recorder(action=1.0), k)
    changed = []
    r = env.sim.last
    for _ in range(12):
        before = env.sim.setpoints_fs.copy()
        action = runner.act(r.pulse_energies[0], r.power[0], r.setpoints_fs[0])
        env.step(action)
        r = env.sim.last
        changed.append(not np.array_equal(before, env.sim.setpoints_fs))
    assert changed == [t % k == 0 for t in range(12)]

    ctl = PolicyController(HeldRunner(Recorder(action=1.0), k), 0.05, np.zeros(STAGE))
    commands = []
    for _ in range(12):
        ctl.observe(0.5, np.zeros(2**STAGE - 1))
        commands.append(ctl.command())
    steps = np.diff(np.array([np.zeros(STAGE), *commands]), axis=0)
    assert [bool(np.any(s)) for s in steps] == [t % k == 0 for t in range(12)]
    assert np.allclose(commands[-1], 4 * 0.05)  # four decisions, each the largest step


def test_the_history_is_built_from_the_decisions_readings_alone():
    """A model with memory (n3_easy: history 4) held every 2 readings observes exactly what a
    runner fed only the decisions' readings observes."""
    loaded = load_policy(MODELS / "n3_easy")
    held = build_runner(loaded, hold_steps=2)
    alone = PolicyRunner(loaded)
    assert isinstance(held, HeldRunner) and isinstance(held.runner, PolicyRunner)
    env = OpsEnv.from_config(make_config(3, "easy", "test", latency_steps=1))
    env.reset(seed=1)
    r = env.sim.last
    for t in range(12):
        reading = (r.pulse_energies[0], r.power[0], r.setpoints_fs[0])
        action = held.act(*reading)
        if t % 2 == 0:
            assert np.array_equal(action, alone.act(*reading))
            assert np.array_equal(held.runner.last_observation, alone.last_observation)
        env.step(action)
        r = env.sim.last
    assert build_runner(loaded, hold_steps=1).__class__ is PolicyRunner  # 1: no wrapper


def test_the_node_declares_hold_steps_once_with_its_range():
    from ops_contract.node_params import check_value
    from ops_controller_ros.policy_node import PARAMS

    spec = {s.name: s for s in PARAMS}["hold_steps"]
    assert spec.default == -1 and spec.read_only  # -1: the model's (1 where it has none)
    assert check_value(spec, 0) is None and check_value(spec, HOLD_STEPS_MAX) is None
    assert check_value(spec, 1) is None and check_value(spec, -1) is None
    assert "hold_steps must be -1 or 0 or int in [1, 1001] (got -3)" in check_value(spec, -3)
    assert "hold_steps must be" in check_value(spec, HOLD_STEPS_MAX + 1)


@pytest.fixture
def make_node():
    """PolicyNode() on the default context with ``-p`` overrides (no simulator needed)."""
    pytest.importorskip("rclpy")
    from nodes_in_process import NodesInProcess
    from ops_controller_ros.policy_node import PolicyNode

    nodes = NodesInProcess()
    yield lambda *overrides: nodes.start(PolicyNode, *overrides)
    nodes.close()


def test_the_node_holds_as_told_and_refuses_a_bad_value_before_spinning(make_node):
    from ops_contract.ros_interface import ParameterError

    model = f"model:={MODELS / 'n3_easy'}"
    with pytest.raises(ParameterError, match=r"hold_steps must be -1 or 0 or int in \[1, 1001\]"):
        make_node(model, "hold_steps:=-3")


def test_the_node_resolves_auto_from_the_told_latency(make_node):
    node = make_node(f"model:={MODELS / 'n3_easy'}", "hold_steps:=0", "realism:=lab")
    assert isinstance(node._runner, HeldRunner) and node._runner.hold_steps == 2  # lab: 1 + 1
    assert "0 decisions" in node.progress_note()


@pytest.mark.parametrize(
    ("entry", "extra", "expected"),
    [(0, (), 2), (3, (), 3), (0, ("hold_steps:=1",), 1), (None, (), 1)],
)
def test_the_node_holds_a_model_as_it_was_trained_unless_told(
    make_node, tmp_path, entry, extra, expected
):
    """A model trained with held decisions (metadata ``hold_steps``, train --hold-steps; 0:
    auto, here the told latency 1 + 1) is held so by default; an explicit value overrides; a
    model without the entry decides on every reading."""
    import json
    import shutil

    model = tmp_path / "held"
    model.mkdir()
    shutil.copy2(MODELS / "n3_easy" / "model.zip", model / "model.zip")
    meta = json.loads((MODELS / "n3_easy" / "metadata.json").read_text())
    if entry is not None:
        meta["hold_steps"] = entry
    (model / "metadata.json").write_text(json.dumps(meta))
    node = make_node(f"model:={model}", "realism:=lab", *extra)
    held = isinstance(node._runner, HeldRunner)
    assert (node._runner.hold_steps if held else 1) == expected
