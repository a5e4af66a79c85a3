"""The simulator node's parameters, in-process: integers for floats, live-ness, bounds."""

from __future__ import annotations

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.parameter import Parameter  # noqa: E402


@pytest.fixture
def make_node():
    """SimNode() on the default context, initialized with ``-p`` overrides."""
    nodes = []

    def make(*overrides: str):
        from ops_sim_ros.sim_node import SimNode

        rclpy.init(args=["sim", "--ros-args", *[a for o in overrides for a in ("-p", o)]])
        node = SimNode()
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()


def test_float_parameters_take_integers_at_start_and_at_runtime(make_node):
    node = make_node("rate_hz:=50", "samples_per_slot:=1")
    p = node.get_parameter("rate_hz")
    assert p.type_ == Parameter.Type.DOUBLE and p.value == 50.0
    assert node.set_parameters([Parameter("rate_hz", value=70)])[0].successful
    assert node.get_parameter("rate_hz").value == 70.0
    assert not node.set_parameters([Parameter("rate_hz", value="fast")])[0].successful


def test_read_only_parameters_and_bounded_noise(make_node):
    node = make_node()
    refused = node.set_parameters([Parameter("stage", value=4)])[0]
    assert not refused.successful and "stage cannot change" in refused.reason
    too_big = node.set_parameters([Parameter("jitter_sigma_cycles", value=1.0e30)])[0]
    assert not too_big.successful and "jitter_sigma_cycles" in too_big.reason


def test_unbounded_noise_at_start_is_a_parameter_error(make_node):
    from ops_contract.ros_interface import ParameterError

    with pytest.raises(ParameterError, match="jitter_sigma_cycles"):
        make_node("jitter_sigma_cycles:=1.0e+30")
