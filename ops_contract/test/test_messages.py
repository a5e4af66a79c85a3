"""The one rule every message goes through (ops_contract.ros_interface): a layout that matches
its data, finite and bounded values; and the arrays the nodes send with their layout."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("rclpy")

from ops_contract.ros_interface import (
    MAX_DELAY_FS,
    MessageError,
    delays_from_msg,
    float_array_msg,
    power_from_msg,
    trace_from_msg,
    trace_msg,
)
from std_msgs.msg import Float32


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 2 * MAX_DELAY_FS])
@pytest.mark.parametrize("where", [0, 2, 4])
def test_a_delay_that_is_not_finite_and_bounded_is_refused_naming_its_index(bad, where):
    values = np.zeros(5)
    values[where] = bad
    with pytest.raises(MessageError, match=f"at index {where}"):
        delays_from_msg(float_array_msg(values))


def test_good_messages_come_back_as_sent():
    delays = np.array([0.5, -1.25, 3.0])
    np.testing.assert_array_equal(delays_from_msg(float_array_msg(delays)), delays)
    trace = np.linspace(0.0, 1.0, 7 * 4).astype(np.float32)
    back, samples = trace_from_msg(trace_msg(trace, 4))
    assert samples == 4
    np.testing.assert_array_equal(back, trace)
    assert power_from_msg(Float32(data=0.75)) == 0.75
    with pytest.raises(MessageError):
        power_from_msg(Float32(data=math.nan))


def test_messages_of_one_shape_share_a_layout_that_describes_each():
    a, b = float_array_msg(np.zeros((7, 4)), ("slot", "sample")), float_array_msg(np.ones(5))
    c = float_array_msg(np.full((7, 4), 2.0), ("slot", "sample"))
    assert [(d.label, d.size, d.stride) for d in a.layout.dim] == [
        ("slot", 7, 28),
        ("sample", 4, 4),
    ]
    assert [(d.label, d.size, d.stride) for d in b.layout.dim] == [("stage", 5, 5)]
    assert c.layout.dim == a.layout.dim and c.layout.dim is not a.layout.dim
