"""The policy node and the models it is given: one it cannot run stops it before it spins (exit
code 2, ParameterError); one set while it runs (``ros2 param set model``) is refused with what
differs, and the node goes on with its old model; a good one takes over from the present
set-points. Nodes built in this process (no simulator: the controller is built as the loop
builds it when the simulator is found)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from tiny_models import edit_metadata, tiny_model

pytest.importorskip("rclpy")

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture
def make_node():
    from nodes_in_process import NodesInProcess
    from ops_controller_ros.policy_node import PolicyNode

    nodes = NodesInProcess()
    yield lambda *overrides: nodes.start(PolicyNode, *overrides)
    nodes.close()


@pytest.mark.parametrize(
    "build, overrides, message",
    [
        (
            lambda d: edit_metadata(tiny_model(d), recipe="evolution"),
            (),
            r"model: model .* was trained with the recipe 'evolution', which this runner",
        ),
        (
            lambda d: edit_metadata(tiny_model(d), recurrent={"kind": "gru", "hidden": 64}),
            (),
            r"recurrent state of kind 'gru'",
        ),
        (lambda d: MODELS / "n3_easy", ("detector:=total",), r"'polarizer' detector, .*'total'"),
        (lambda d: MODELS / "n3_easy", ("detector:=both",), r"detector must be '' or one of"),
        (lambda d: tiny_model(d, observation="authors"), (), r"-p observation:=authors"),
        (lambda d: d / "nowhere", (), r"model not found: .*nowhere"),
    ],
)
def test_a_model_the_node_cannot_run_stops_it_before_it_spins(
    make_node, tmp_path, build, overrides, message
):
    from ops_contract.ros_interface import ParameterError

    model = build(tmp_path / "m")
    with pytest.raises(ParameterError, match=message):
        make_node(f"model:={model}", *overrides)


def _set_model(node, path) -> tuple[bool, str]:
    from rclpy.parameter import Parameter

    (result,) = node.set_parameters([Parameter("model", Parameter.Type.STRING, str(path))])
    return result.successful, result.reason


def test_a_model_set_while_running_is_refused_with_why_and_a_good_one_takes_over(
    make_node, tmp_path
):
    first = MODELS / "n3_easy"
    node = make_node(f"model:={first}")
    node.ctrl = node.build_controller(np.array([1.0, 2.0, 3.0]), 8)  # the simulator found
    for _ in range(3):
        node.ctrl.observe(0.5, np.full(7, 0.1))
    command = node.ctrl.command()
    for bad, why in [
        (
            MODELS / "n5_hard",
            r"model .*n5_hard was trained for stage 5, the simulator runs stage 3",
        ),
        (tmp_path / "nowhere", r"model not found"),
        (edit_metadata(tiny_model(tmp_path / "odd", stage=3), recipe="evolution"), "recipe"),
        (MODELS / "n5_sac300k_authors", r"stage 5"),
    ]:
        ok, reason = _set_model(node, bad)
        assert not ok and re.search(why, reason), reason
        assert node.get_parameter("model").value == str(first)  # the parameter kept
        assert node._stack.path == first and np.array_equal(node.ctrl.command(), command)
    other = tmp_path / "other"
    shutil.copytree(first, other)
    loads = []
    load = node._load
    node._load = lambda model: (loads.append(model), load(model))[1]
    assert _set_model(node, other) == (True, "")
    assert loads == [str(other)]  # read and loaded once
    assert node.get_parameter("model").value == str(other) and node._stack.path == other
    assert node.ctrl.runner is node._runner and node._runner.state is None
    np.testing.assert_array_equal(node.ctrl.command(), command)  # on from the same set-points
    node.ctrl.observe(0.5, np.full(7, 0.1))
    assert not np.array_equal(node.ctrl.command(), command)  # and the new model acts


def test_a_recurrent_model_runs_in_the_node(make_node, tmp_path):
    model = tiny_model(tmp_path / "rppo", "recurrent_ppo")
    node = make_node(f"model:={model}")
    ctl = node.build_controller(np.zeros(2), 8)
    for _ in range(3):
        ctl.observe(0.3, np.full(3, 0.2))
    assert node._runner.state is not None and node._runner.state[0].shape == (1, 1, 8)
