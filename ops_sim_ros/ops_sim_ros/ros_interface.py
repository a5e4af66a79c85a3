"""The ROS 2 face shared by every node of the project: topic names, QoS, message conversions.

Topic names are relative (``ops/...``) so that ``--ros-args -r __ns:=/rig2`` moves a whole rig.
Delays are femtoseconds relative to each stage's nominal stacking delay (see docs/interfaces.md).
"""

from __future__ import annotations

import array
import math
import sys
from collections.abc import Callable, Sequence

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float32MultiArray, MultiArrayDimension

TOPIC_INTENSITY = "ops/intensity"
TOPIC_POWER = "ops/power"
TOPIC_REWARD = "ops/reward"
TOPIC_DELAYS = "ops/delays"
TOPIC_DELAY_CMD = "ops/delay_cmd"
SERVICE_RESET = "ops/reset"
TOPIC_DIAGNOSTICS = "/diagnostics"

#: Outputs and commands: reliable, a short queue. A flood of commands is bounded by the depth.
QOS_RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
#: ``ops/delays`` is state: latched (transient local, last value only), so a controller that
#: starts later - even against a lockstep simulator that publishes only when commanded - learns
#: the current set-points at once. Volatile subscribers match it too and see only new values.
QOS_STATE = QoSProfile(
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    history=HistoryPolicy.KEEP_LAST,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


class ParameterError(ValueError):
    """A node parameter has a value the node cannot run with."""


class NodeFatalError(RuntimeError):
    """The node met a condition it cannot run on (e.g. a model for another stage)."""


def float_array_msg(values, labels: Sequence[str] = ("stage",)) -> Float32MultiArray:
    """A Float32MultiArray with its layout filled (one dimension per label, row-major)."""
    arr = np.asarray(values, dtype=np.float32)
    if arr.ndim != len(labels):
        raise ValueError(f"{arr.ndim}-D values need {arr.ndim} labels, got {list(labels)}")
    msg = Float32MultiArray()
    strides = np.cumprod(arr.shape[::-1])[::-1]
    msg.layout.dim = [
        MultiArrayDimension(label=label, size=int(size), stride=int(stride))
        for label, size, stride in zip(labels, arr.shape, strides, strict=True)
    ]
    data = array.array("f")
    data.frombytes(arr.tobytes())  # the fast path of the generated setter: no per-element checks
    msg.data = data
    return msg


def trace_msg(trace: np.ndarray, samples_per_slot: int) -> Float32MultiArray:
    """The detected trace as a (slot, sample) array message."""
    trace = np.asarray(trace, dtype=np.float32).reshape(-1, samples_per_slot)
    return float_array_msg(trace, labels=("slot", "sample"))


def trace_from_msg(msg: Float32MultiArray) -> tuple[np.ndarray, int]:
    """Flat trace and samples per slot from an intensity message (inverse of :func:`trace_msg`)."""
    data = np.asarray(msg.data, dtype=np.float32)
    dims = msg.layout.dim
    samples = int(dims[1].size) if len(dims) >= 2 and dims[1].size > 0 else 1
    return data, samples


def check_command(values: Sequence[float], stage: int) -> str | None:
    """Why a delay command cannot be used, or None when it can."""
    if len(values) != stage:
        return f"expected {stage} delays (one per stage), got {len(values)}"
    bad = [i for i, v in enumerate(values) if not math.isfinite(v)]
    if bad:
        return f"non-finite delay at index {bad[0]} ({values[bad[0]]})"
    return None


def run_node(make_node: Callable[[], Node], args=None) -> int:
    """The ``main()`` of every node: init, spin, clean exit on Ctrl-C / SIGTERM.

    A :class:`ParameterError` raised while building the node stops it before it spins, with the
    message on stderr and exit code 2; a :class:`NodeFatalError` raised while spinning stops it
    with the message and exit code 1. Returns the process exit code.
    """
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = make_node()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ParameterError as exc:
        print(f"[ERROR] invalid parameter: {exc}", file=sys.stderr, flush=True)
        code = 2
    except NodeFatalError as exc:
        print(f"[ERROR] {exc}", file=sys.stderr, flush=True)
        code = 1
    except Exception:
        if rclpy.ok():
            raise
        # Ctrl-C / SIGTERM shut the context down while rclpy was taking a message (it then raises
        # from inside the executor): that is the requested exit, not an error.
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code
