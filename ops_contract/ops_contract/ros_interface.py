"""The ROS 2 face shared by every node of the project: topic names, QoS, message conversions.

Topic names are relative (``ops/...``) so that ``--ros-args -r __ns:=/rig2`` moves a whole rig.
Delays are femtoseconds relative to each stage's nominal stacking delay (see docs/interfaces.md).

Every message a node takes in goes through one rule (:func:`delays_from_msg`,
:func:`trace_from_msg`, :func:`power_from_msg`, :func:`array_of`): shape, layout, finiteness and
magnitude; what breaks it is dropped with a throttled warning (:class:`MessageGuard`), so no
message can stop a node.
"""

from __future__ import annotations

import array
import contextlib
import functools
import math
import signal
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from std_msgs.msg import Float32, Float32MultiArray, MultiArrayDimension

from . import cdr
from .config import LIMITS, MAX_STAGE
from .heap import freeze_after_heavy_imports
from .threads import limit_blas_threads

TOPIC_INTENSITY = "ops/intensity"
TOPIC_POWER = "ops/power"
TOPIC_REWARD = "ops/reward"
TOPIC_DELAYS = "ops/delays"
TOPIC_DELAY_CMD = "ops/delay_cmd"
#: Simulator-only oracle: the delays really applied (set-point + hidden delay-line error), fs. A
#: real rig cannot publish it; a policy trained on the authors' observation set needs it.
TOPIC_DELAYS_ACTUAL = "ops/delays_actual"
SERVICE_RESET = "ops/reset"
TOPIC_DIAGNOSTICS = "/diagnostics"

#: Outputs and commands: reliable, a short queue. A flood of commands is bounded by the depth.
QOS_RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
#: A subscriber that wants every reading although its own callbacks can be slow (the monitor draws
#: a frame in ~0.1 s while 100 readings/s arrive): ten seconds of readings queue up.
QOS_EVERY_READING = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
#: A controller's view of a free-running simulator's outputs: best effort, the latest few. A lost
#: reading is not repaired (the next step's comes one sample period later, where a reliable
#: reader would hold every later one until the lost one is sent again), and under CPU load stale
#: readings are dropped instead of queued. Reliable publishers match it.
QOS_READINGS = QoSProfile(depth=2, reliability=ReliabilityPolicy.BEST_EFFORT)
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


class MessageError(ValueError):
    """A message a node cannot use: it is dropped (see :class:`MessageGuard`)."""


#: Largest magnitude of a reading (normalized power, reward, trace sample) and of a delay (fs) in
#: a message; beyond them a message is malformed, not a measurement.
MAX_READING = 1.0e3
MAX_DELAY_FS = 1.0e6


@functools.lru_cache(maxsize=64)
def _layout_dims(shape: tuple[int, ...], labels: tuple[str, ...]) -> tuple:
    """The dimensions of a row-major layout (made once per shape: the simulator sends three
    arrays a step, and building them costs more than the rest of the message)."""
    strides = np.cumprod(shape[::-1])[::-1]
    return tuple(
        MultiArrayDimension(label=label, size=int(size), stride=int(stride))
        for label, size, stride in zip(labels, shape, strides, strict=True)
    )


def float_array_msg(values, labels: Sequence[str] = ("stage",)) -> Float32MultiArray:
    """A Float32MultiArray with its layout filled (one dimension per label, row-major)."""
    arr = np.asarray(values, dtype=np.float32)
    if arr.ndim != len(labels):
        raise ValueError(f"{arr.ndim}-D values need {arr.ndim} labels, got {list(labels)}")
    msg = Float32MultiArray()
    # (the dimensions are shared between messages: no one changes a message once it is made)
    msg.layout.dim = list(_layout_dims(arr.shape, tuple(labels)))
    data = array.array("f")
    data.frombytes(arr.tobytes())  # the fast path of the generated setter: no per-element checks
    msg.data = data
    return msg


def float_array_bytes(values, labels: Sequence[str] = ("stage",)) -> bytes:
    """:func:`float_array_msg`, serialized (what a publisher sends for it: publishing these
    bytes skips building the message and converting it, :mod:`~ops_contract.cdr`)."""
    return cdr.float_array_bytes(values, tuple(labels))


def trace_msg(trace: np.ndarray, samples_per_slot: int) -> Float32MultiArray:
    """The detected trace as a (slot, sample) array message."""
    trace = np.asarray(trace, dtype=np.float32).reshape(-1, samples_per_slot)
    return float_array_msg(trace, labels=("slot", "sample"))


def trace_bytes(trace: np.ndarray, samples_per_slot: int) -> bytes:
    """:func:`trace_msg`, serialized (what a publisher sends for it)."""
    return cdr.float_array_bytes(np.reshape(trace, (-1, samples_per_slot)), ("slot", "sample"))


#: A serialized ``std_msgs/Float32`` of a value (what a publisher sends for the message).
float32_bytes = cdr.float32_bytes


def _shape(sizes: tuple[int, ...], data_offset: int, n: int) -> tuple[int, ...]:
    """The shape a layout of these dimension sizes declares for ``n`` values ((n,) without
    dimensions); MessageError when it does not describe them (see :func:`layout_shape`)."""
    if data_offset != 0:
        raise MessageError(f"layout data_offset is {data_offset}, expected 0")
    if not sizes:
        return (n,)
    if math.prod(sizes) != n:
        raise MessageError(
            f"layout says {' x '.join(map(str, sizes))} but the message has {n} values"
        )
    return sizes


def layout_shape(msg: Float32MultiArray) -> tuple[int, ...]:
    """The shape an array message's layout declares ((len(data),) when it has none).

    MessageError when the layout does not describe the data (sizes whose product is not the
    number of values, a data offset)."""
    sizes = tuple(int(d.size) for d in msg.layout.dim)
    return _shape(sizes, msg.layout.data_offset, len(msg.data))


def array_of(msg: Float32MultiArray | bytes) -> tuple[tuple[int, ...], np.ndarray]:
    """The shape (:func:`layout_shape`) and the float32 values of an array message, or of its
    serialized bytes (a subscription with ``raw=True``: read without building the message,
    :mod:`~ops_contract.cdr`). MessageError when they do not hold a message whose layout
    describes its data."""
    if not isinstance(msg, bytes):
        return layout_shape(msg), np.asarray(msg.data, dtype=np.float32)
    try:
        sizes, offset, values = cdr.read_float_array(msg)
    except cdr.UnknownEncoding:
        return array_of(_deserialized(msg, Float32MultiArray))
    except cdr.CdrError as exc:
        raise MessageError(f"undecodable message ({exc})") from None
    return _shape(sizes, offset, values.size), values


def _deserialized(raw: bytes, msg_type):
    try:
        return deserialize_message(raw, msg_type)
    except Exception as exc:  # malformed bytes: a message like any other bad one
        raise MessageError(f"undecodable message ({type(exc).__name__})") from None


def _bounded(data, limit: float, what: str) -> np.ndarray:
    arr = np.asarray(data, dtype=np.float32)
    if arr.size == 0 or np.abs(arr).max() <= limit:  # (NaN fails it: found below)
        return arr
    bad = np.flatnonzero(~(np.abs(arr) <= limit))  # NaN, inf and too large
    if bad.size:
        i = int(bad[0])
        raise MessageError(f"{what} {arr[i]!r} at index {i} (allowed: finite, |x| <= {limit:g})")
    return arr


def delays_from_msg(msg: Float32MultiArray | bytes) -> np.ndarray:
    """The set-points (fs) of an ``ops/delays`` message (or its serialized bytes); MessageError
    when it is malformed."""
    shape, values = array_of(msg)
    if len(shape) != 1 or not 1 <= shape[0] <= MAX_STAGE:
        raise MessageError(
            f"delays of shape {shape}: expected one value per stage, 1 to {MAX_STAGE} values"
        )
    return _bounded(values, MAX_DELAY_FS, "delay").astype(np.float64)


def trace_from_msg(msg: Float32MultiArray | bytes) -> tuple[np.ndarray, int]:
    """Flat trace and samples per slot from an intensity message or its serialized bytes
    (inverse of :func:`trace_msg`).

    MessageError unless the layout is (slot, sample) (or flat: one sample per slot) with 2^N - 1
    slots, N = 1 .. MAX_STAGE, samples per slot within ``LIMITS``, and finite, bounded values."""
    shape, values = array_of(msg)
    if len(shape) not in (1, 2):
        raise MessageError(f"trace of shape {shape}: expected (slot, sample)")
    slots, samples = (shape[0], 1) if len(shape) == 1 else shape
    low, high = LIMITS["samples_per_slot"]
    if not low <= samples <= high:
        raise MessageError(f"{samples} samples per slot (allowed: {low} to {high})")
    stage = (slots + 1).bit_length() - 1
    if slots + 1 != 2**stage or not 1 <= stage <= MAX_STAGE:
        raise MessageError(f"{slots} pulse slots (a stage-N trace has 2^N - 1, N = 1 .. 10)")
    return _bounded(values, MAX_READING, "trace sample"), samples


def power_from_msg(msg: Float32 | bytes) -> float:
    """The value of an ``ops/power`` (or ``ops/reward``) message or its serialized bytes;
    MessageError unless finite and within +-MAX_READING."""
    if isinstance(msg, bytes):
        try:
            value = cdr.read_float32(msg)
        except cdr.UnknownEncoding:
            value = _deserialized(msg, Float32).data
        except cdr.CdrError as exc:
            raise MessageError(f"undecodable message ({exc})") from None
    else:
        value = msg.data
    if math.isfinite(value) and abs(value) <= MAX_READING:
        return float(value)
    raise MessageError(f"reading {value!r} at index 0 (allowed: finite, |x| <= {MAX_READING:g})")


class MessageGuard:
    """Takes messages through a check; drops those it rejects, with one warning per topic at
    most every ``period_s`` that counts the drops and names the latest reason."""

    def __init__(self, node: Node, period_s: float = 5.0):
        self._node = node
        self.period_s = float(period_s)
        self.dropped: dict[str, int] = {}
        self._warned: dict[str, tuple[float, int]] = {}  # topic -> (time, drops then)

    def take(self, topic: str, check: Callable, msg):
        """``check(msg)``, or None when it raises MessageError (the message is dropped)."""
        try:
            return check(msg)
        except MessageError as exc:
            self.drop(topic, str(exc))
            return None

    def drop(self, topic: str, reason: str) -> None:
        count = self.dropped[topic] = self.dropped.get(topic, 0) + 1
        now = time.monotonic()
        last, before = self._warned.get(topic, (float("-inf"), 0))
        if now - last < self.period_s:
            return
        self._warned[topic] = (now, count)
        new = count - before
        self._node.get_logger().warning(
            f"dropped {new} malformed message{'s' if new > 1 else ''} on "
            f"{self._node.resolve_topic_name(topic)}: {reason}"
        )


def check_command(values: Sequence[float] | np.ndarray, stage: int) -> str | None:
    """Why a delay command cannot be used, or None when it can."""
    if len(values) != stage:
        return f"expected {stage} delays (one per stage), got {len(values)}"
    finite = np.isfinite(values)
    if not finite.all():
        bad = int(finite.argmin())
        return f"non-finite delay at index {bad} ({float(values[bad])})"
    return None


def _stop_requested(signum, frame) -> None:
    """Ctrl-C / SIGTERM: nothing to do here; rclpy's handler has shut the context down."""


def run_node(
    make_node: Callable[[], Node], args=None, executor: str | None = None, loops: bool = False
) -> int:
    """The ``main()`` of every node: init, spin, clean exit on Ctrl-C / SIGTERM.

    ``executor``: the node's default for its ``executor`` parameter (declared here, after the
    node is built: ``default`` or ``events``, :mod:`~ops_contract.executors`); None: the node
    has no such parameter and rclpy's default executor spins it. A node with an ``executor``
    parameter, or ``loops``, has a ``realtime_priority`` (:mod:`~ops_contract.realtime`).

    A :class:`ParameterError` raised while building the node stops it before it spins, with the
    message on stderr and exit code 2; a :class:`NodeFatalError` raised while spinning stops it
    with the message and exit code 1. Returns the process exit code. BLAS runs on one thread
    (:func:`~ops_contract.threads.limit_blas_threads`) unless the environment says otherwise.
    """
    limit_blas_threads()
    freeze_after_heavy_imports()  # (the policy node's torch: ops_contract.heap)
    # rclpy's own handlers (installed by init, for SIGINT and SIGTERM) shut the context down, and
    # spin returns; they then call the Python handler found here. Python's default raises
    # KeyboardInterrupt wherever the main thread is, even inside rclpy's Task constructor, which
    # then printed "Exception ignored in Future.__del__ ... AttributeError" on exit (seen in CI).
    # The events executor replaces rclpy's handlers with its own, to the same end.
    for stop in (signal.SIGINT, signal.SIGTERM):
        signal.signal(stop, _stop_requested)
    rclpy.init(args=args)
    # (imported here: node_params, which executors uses, imports this module)
    from .executors import raise_fatal, spin

    node = None
    spinner = None
    code = 0
    try:
        node = make_node()
        spinner = _executor_of(node, executor, loops or executor is not None)
        with contextlib.suppress(KeyboardInterrupt, ExternalShutdownException):
            spin(spinner, node)
        raise_fatal(node)  # (a callback's, which shut the context down: executors.guarded)
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
        if spinner is not None:
            spinner.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def _executor_of(node: Node, default: str | None, loops: bool):
    """The executor the node's ``executor`` parameter names (declared with ``default``; None:
    no parameter, the default executor). A node that ``loops`` has a ``realtime_priority``
    too (:mod:`~ops_contract.realtime`), applied to its threads here."""
    from .executors import executor_spec, make_executor
    from .node_params import declare_all
    from .realtime import REALTIME_PRIORITY_SPEC

    specs = ([executor_spec(default)] if default is not None else []) + (
        [REALTIME_PRIORITY_SPEC] if loops else []
    )
    values = declare_all(node, specs) if specs else {}
    executor = make_executor(values.get("executor", "default"), node.context)
    _take_priority(node, values.get("realtime_priority", 0))
    return executor


def _take_priority(node: Node, priority: int) -> None:
    """Every thread of the node's process under SCHED_FIFO at ``priority`` (0: left as it is),
    or a warning that says why not and how to allow it."""
    from .realtime import set_priority

    if priority == 0:
        return
    refused = set_priority(priority)
    if refused is None:
        node.get_logger().info(f"realtime_priority {priority}: every thread under SCHED_FIFO")
    else:
        node.get_logger().warning(
            f"realtime_priority {priority} not taken, the node runs under the normal "
            f"scheduler: {refused}"
        )
