"""The serialized messages of ops_contract.cdr are rclpy's: what they write deserializes to the
message the node would have built, what rclpy serializes reads back the same, and bytes that
hold no message are refused."""

from __future__ import annotations

import struct

import numpy as np
import pytest

pytest.importorskip("rclpy")

from ops_contract.ros_interface import (
    MessageError,
    array_of,
    delays_from_msg,
    float32_bytes,
    float_array_bytes,
    float_array_msg,
    power_from_msg,
    trace_bytes,
    trace_from_msg,
    trace_msg,
)
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float32, Float32MultiArray, MultiArrayDimension

from ops_contract import cdr

SHAPES = [((1,), ("stage",)), ((5,), ("stage",)), ((31, 8), ("slot", "sample")), ((3, 2, 4), "abc")]


@pytest.mark.parametrize(("shape", "labels"), SHAPES)
def test_written_bytes_are_the_message_the_node_would_build(shape, labels):
    values = np.random.default_rng(0).normal(size=shape)
    raw = float_array_bytes(values, labels)
    msg = float_array_msg(values, labels)
    assert deserialize_message(raw, Float32MultiArray) == msg
    assert len(raw) == len(serialize_message(msg))


@pytest.mark.parametrize(("shape", "labels"), SHAPES)
def test_rclpy_serialized_arrays_read_back_as_sent(shape, labels):
    values = np.random.default_rng(1).normal(size=shape).astype(np.float32)
    sizes, offset, back = cdr.read_float_array(serialize_message(float_array_msg(values, labels)))
    assert sizes == shape and offset == 0
    np.testing.assert_array_equal(back, values.ravel())


def test_a_message_without_layout_reads_as_flat():
    raw = serialize_message(Float32MultiArray(data=[1.0, 2.0, 3.0]))
    shape, values = array_of(raw)
    assert shape == (3,) and values.tolist() == [1.0, 2.0, 3.0]


def test_floats_and_traces_round_trip():
    assert deserialize_message(float32_bytes(0.75), Float32).data == 0.75
    assert power_from_msg(float32_bytes(0.25)) == power_from_msg(Float32(data=0.25)) == 0.25
    assert cdr.read_float32(serialize_message(Float32(data=-2.5))) == -2.5
    trace = np.linspace(0.0, 1.0, 7 * 4).astype(np.float32)
    assert deserialize_message(trace_bytes(trace, 4), Float32MultiArray) == trace_msg(trace, 4)
    back, samples = trace_from_msg(trace_bytes(trace, 4))
    assert samples == 4 and back.tolist() == trace.tolist()


def test_big_endian_cdr_reads_as_little_endian():
    body = struct.pack(">I", 1) + struct.pack(">I", 6) + b"stage\x00\x00\x00"
    body += struct.pack(">IIII", 2, 2, 0, 2) + struct.pack(">ff", 1.5, -3.0)
    shape, values = array_of(b"\x00\x00\x00\x00" + body)
    assert shape == (2,) and values.tolist() == [1.5, -3.0]
    assert power_from_msg(b"\x00\x00\x00\x00" + struct.pack(">f", 0.5)) == 0.5


def _layout_problem(msg) -> str | None:
    """Why array_of refuses a message or its bytes, or None."""
    try:
        array_of(msg)
    except MessageError as exc:
        return str(exc)
    return None


def test_bad_layouts_and_values_are_refused_alike_from_bytes_and_messages():
    msg = Float32MultiArray(data=[1.0, 2.0, 3.0])
    msg.layout.dim = [MultiArrayDimension(label="stage", size=4, stride=4)]
    assert _layout_problem(serialize_message(msg)) == _layout_problem(msg) is not None
    msg.layout.dim, msg.layout.data_offset = [], 1
    assert _layout_problem(serialize_message(msg)) == _layout_problem(msg) is not None
    bad = float_array_msg(np.array([0.0, np.nan, 1.0]))
    with pytest.raises(MessageError, match="at index 1"):
        delays_from_msg(serialize_message(bad))
    with pytest.raises(MessageError):
        power_from_msg(float32_bytes(float("inf")))


@pytest.mark.parametrize("cut", [0, 3, 7, 20, 55])
def test_bytes_that_hold_no_whole_message_are_refused(cut):
    raw = float_array_bytes(np.arange(5.0))[:cut]
    with pytest.raises(MessageError, match="undecodable"):
        array_of(raw)
    with pytest.raises(MessageError, match="undecodable"):
        power_from_msg(float32_bytes(1.0)[: min(cut, 7)])


def test_another_representation_is_left_to_rclpy():
    with pytest.raises(cdr.UnknownEncoding):
        cdr.read_float_array(b"\x00\x07\x00\x00" + bytes(16))
    with pytest.raises(MessageError, match="undecodable"):
        array_of(b"\x00\x07\x00\x00" + bytes(3))
