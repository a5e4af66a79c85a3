"""Which rclpy executor spins a node: the ``executor`` parameter of the simulator and the
controller nodes (:func:`~ops_contract.ros_interface.run_node`).

``default``: rclpy's ``SingleThreadedExecutor``, which rebuilds a wait set and walks every entity
in Python on each turn. ``events``: ``rclpy.experimental.EventsExecutor`` (rclpy >= 7.1), whose
loop is C++: the middleware calls it when a message arrives, its timers keep their own queue, and
Python runs only the callbacks, so each step of a simulator and each reading of a controller cost
less CPU (``ops-bench loop-rate`` measures it, docs/benchmarks.md).

What the events executor of rclpy 7.1 does otherwise, and how the project's code copes:

- it calls a callback that takes the message info with one argument, the tuple
  ``(msg, info)`` (the default executor passes two): :func:`subscribe_with_info` takes both;
- it ignores callback groups: a subscription in a group that the default executor never waits
  on (``command_inbox``) has its messages taken and passed to its callback as they come;
- its ``spin()`` runs no callback and never returns (rclpy 7.1.5): :func:`spin` spins it in
  bounded turns instead, and stops when rclpy's signal handlers (Ctrl-C, SIGTERM) have shut the
  context down;
- it cannot wait on guard conditions: a node with one cannot use it.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.subscription import Subscription
from rclpy.task import Future

from .node_params import ParamSpec
from .ros_interface import NodeFatalError

EXECUTORS = ("default", "events")


def executor_spec(default: str) -> ParamSpec:
    """The ``executor`` parameter with a node's default (fixed while the node runs)."""
    return ParamSpec(
        "executor",
        default,
        "how rclpy runs the node's callbacks: default (SingleThreadedExecutor, a wait set per "
        "turn) or events (rclpy.experimental.EventsExecutor: a C++ loop woken by each message "
        "and timer, less CPU per step)",
        choices=EXECUTORS,
        read_only=True,
    )


def make_executor(name: str, context=None):
    """A new executor of kind ``name`` (one of :data:`EXECUTORS`) on ``context``."""
    if name == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    if name == "default":
        from rclpy.executors import SingleThreadedExecutor

        return SingleThreadedExecutor(context=context)
    raise ValueError(f"executor must be one of {', '.join(EXECUTORS)} (got {name!r})")


#: The events executor runs in turns of this long (see :func:`spin`).
EVENTS_TURN_S = 0.1


def spin(executor, node: Node) -> None:
    """Run ``node``'s callbacks on ``executor`` until the context is shut down (by Ctrl-C or
    SIGTERM: rclpy's signal handlers shut it down; ExternalShutdownException may be raised)."""
    executor.add_node(node)
    if isinstance(executor, Executor):
        executor.spin()
        return
    # The events executor's spin() of rclpy 7.1 runs nothing (no timer fired within a second)
    # and does not return when the context is shut down; a bounded spin works: turns of
    # EVENTS_TURN_S, each waiting on a future nothing completes, until the context is shut down.
    while node.context.ok():
        executor.spin_until_future_complete(Future(), EVENTS_TURN_S)


#: The node attribute where :func:`guarded` keeps a NodeFatalError for :func:`raise_fatal`.
_FATAL = "_ops_fatal_error"


def guarded(node: Node, callback: Callable) -> Callable:
    """``callback`` for a timer or subscription of ``node``, quiet once the context is shut
    down: Ctrl-C or SIGTERM shuts it down from the signal handler, while a callback may be
    publishing, which then raises ("publisher's context is invalid"), and the events executor
    logs that with a traceback. A :class:`NodeFatalError` (the node cannot go on: a model for
    another stage) shuts the context down and is kept for :func:`raise_fatal`, so that the
    node exits with its message alone under either executor. Any other error raised while the
    context is up goes on as before."""

    def call(*args):
        try:
            return callback(*args)
        except NodeFatalError as exc:
            if getattr(node, _FATAL, None) is None:
                setattr(node, _FATAL, exc)
            node.context.try_shutdown()
            return None
        except Exception:
            if node.context.ok():
                raise
            return None

    return call


def raise_fatal(node: Node | None) -> None:
    """Raise the NodeFatalError a :func:`guarded` callback of ``node`` met, if any."""
    fatal = getattr(node, _FATAL, None)
    if fatal is not None:
        raise fatal


def subscribe_with_info(
    node: Node, msg_type, topic: str, callback: Callable, qos, **kwargs
) -> Subscription:
    """``node.create_subscription`` for ``callback(msg, info)`` (``info``: the message's
    ``MessageInfo`` dict: sequence numbers, source timestamp) under either executor."""

    quiet = guarded(node, callback)

    def either(msg, info=None):
        if info is None and isinstance(msg, tuple):  # the events executor's one argument
            msg, info = msg
        return quiet(msg, info)

    subscription = node.create_subscription(msg_type, topic, either, qos, **kwargs)
    # ``either`` can be called with the message alone, so rclpy took it for a message-only
    # callback; both executors read this attribute to decide what to pass.
    subscription._callback_type = Subscription.CallbackType.WithMessageInfo
    return subscription
