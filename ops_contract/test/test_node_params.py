"""declare_all on a real rclpy node (in process, no other process needed)."""

from __future__ import annotations

import pytest
import rclpy
from ops_contract.node_params import ParamSpec, declare_all
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter


@pytest.fixture
def node():
    context = rclpy.Context()
    rclpy.init(context=context)
    made = Node("params_under_test", context=context)
    yield made
    made.destroy_node()
    rclpy.shutdown(context=context)


def test_two_declare_alls_hand_each_change_on_once(node):
    """A node that declares its parameters in two groups sees a change once, as a double."""
    seen = []

    def record(params):
        seen.extend((p.name, p.value) for p in params)
        return SetParametersResult(successful=True)

    declare_all(node, [ParamSpec("gain", 1.0, "a float", low=0.0, high=10.0)], record)
    declare_all(node, [ParamSpec("rate", 2.0, "another", low=0.0, high=10.0)], record)
    results = node.set_parameters([Parameter("gain", value=3)])
    assert results[0].successful
    assert seen == [("gain", 3.0)]
    assert isinstance(node.get_parameter("gain").value, float)
    seen.clear()
    assert node.set_parameters([Parameter("rate", value=4)])[0].successful
    assert seen == [("rate", 4.0)]


def test_a_value_out_of_range_is_refused_naming_the_parameter(node):
    declare_all(
        node,
        [ParamSpec("gain", 1.0, "a float", low=0.0, high=10.0)],
        lambda params: SetParametersResult(successful=True),
    )
    result = node.set_parameters([Parameter("gain", value=11.0)])[0]
    assert not result.successful
    assert "gain" in result.reason and "10" in result.reason
    assert node.get_parameter("gain").value == 1.0
