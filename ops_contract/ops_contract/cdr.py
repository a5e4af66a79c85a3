"""``std_msgs/Float32`` and ``std_msgs/Float32MultiArray`` in their serialized form (CDR), for
the paths every step of the loop takes.

A publisher given these bytes sends what it would send for the message (``Publisher.publish``
takes bytes; the same encoding rclpy's ``serialize_message`` writes), and a subscription created
with ``raw=True`` hands them over as they came; reading them here costs a few struct reads and
one ``numpy.frombuffer`` instead of building the message's Python objects (its layout's
dimensions and labels) and converting them back. Plain CDR in either byte order is read; any
other representation raises :class:`UnknownEncoding` (the caller then deserializes it with
rclpy), and bytes that do not hold a whole message raise :class:`CdrError`.
"""

from __future__ import annotations

import functools
import struct

import numpy as np

#: The encapsulation header of plain CDR, little endian (what this module writes).
HEADER_LE = b"\x00\x01\x00\x00"
_BYTE_ORDER = {b"\x00\x01": "<", b"\x00\x00": ">"}  # representation id -> struct order
_U32 = {order: struct.Struct(order + "I") for order in "<>"}


class CdrError(ValueError):
    """Bytes that do not hold a whole message of the type."""


class UnknownEncoding(CdrError):
    """A representation other than plain CDR (e.g. XCDR2): not read here."""


def float32_bytes(value: float) -> bytes:
    """A serialized ``std_msgs/Float32``."""
    return HEADER_LE + struct.pack("<f", value)


@functools.lru_cache(maxsize=64)
def _layout_bytes(shape: tuple[int, ...], labels: tuple[str, ...]) -> bytes:
    """The layout (row-major dimensions, data offset 0) and the data's length, serialized."""
    strides = np.cumprod(shape[::-1])[::-1]
    out = [struct.pack("<I", len(shape))]
    for label, size, stride in zip(labels, shape, strides, strict=True):
        text = label.encode() + b"\x00"
        out.append(struct.pack("<I", len(text)) + text + b"\x00" * (-len(text) % 4))
        out.append(struct.pack("<II", size, stride))
    out.append(struct.pack("<II", 0, int(np.prod(shape))))
    return HEADER_LE + b"".join(out)


def float_array_bytes(values: np.ndarray, labels: tuple[str, ...]) -> bytes:
    """A serialized ``std_msgs/Float32MultiArray`` of ``values`` (one label per dimension),
    its layout filled as :func:`~ops_contract.ros_interface.float_array_msg` fills it."""
    arr = np.asarray(values, dtype="<f4")
    if arr.ndim != len(labels):
        raise ValueError(f"{arr.ndim}-D values need {arr.ndim} labels, got {list(labels)}")
    return _layout_bytes(arr.shape, labels) + arr.tobytes()


def _order(raw: bytes) -> str:
    if len(raw) < 4:
        raise CdrError(f"{len(raw)} bytes: no encapsulation header")
    order = _BYTE_ORDER.get(bytes(raw[:2]))
    if order is None:
        raise UnknownEncoding(f"representation {bytes(raw[:2]).hex()} is not plain CDR")
    return order


def read_float32(raw: bytes) -> float:
    """The value of a serialized ``std_msgs/Float32``."""
    order = _order(raw)
    if len(raw) < 8:
        raise CdrError(f"a Float32 of {len(raw)} bytes")
    return struct.unpack_from(order + "f", raw, 4)[0]


def read_float_array(raw: bytes) -> tuple[tuple[int, ...], int, np.ndarray]:
    """The sizes of the layout's dimensions, its data offset and the values (float32: a
    read-only view of ``raw``) of a serialized ``std_msgs/Float32MultiArray``."""
    order = _order(raw)
    u32 = _U32[order]
    try:
        (ndims,) = u32.unpack_from(raw, 4)
        at, sizes = 8, []
        for _ in range(ndims):
            (length,) = u32.unpack_from(raw, at)
            at += 4 + length + (-length % 4)  # the label, its NUL and the padding
            sizes.append(u32.unpack_from(raw, at)[0])
            at += 8  # size and stride
        offset, count = struct.unpack_from(order + "II", raw, at)
        values = np.frombuffer(raw, dtype=order + "f4", count=count, offset=at + 8)
    except (struct.error, ValueError):
        raise CdrError(f"{len(raw)} bytes do not hold a Float32MultiArray") from None
    return tuple(sizes), offset, values
