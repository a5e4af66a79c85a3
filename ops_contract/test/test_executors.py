"""The two executors a node can run on (ops_contract.executors), in this process over DDS: a
callback that takes the message info gets it from both, the command inbox takes every command
under both, and a bad name is refused naming the allowed ones."""

from __future__ import annotations

import time

import pytest

rclpy = pytest.importorskip("rclpy")

from ops_contract.command_inbox import CommandInbox  # noqa: E402
from ops_contract.executors import (  # noqa: E402
    EXECUTORS,
    executor_spec,
    make_executor,
    subscribe_with_info,
)
from ops_contract.node_params import check_value  # noqa: E402
from rclpy.task import Future  # noqa: E402
from std_msgs.msg import Float32, Float32MultiArray  # noqa: E402


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def spin_until(executor, condition, timeout: float = 20.0) -> None:
    """Spin in short turns until ``condition()`` (AssertionError after ``timeout``)."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "condition not met"
        executor.spin_until_future_complete(Future(), 0.05)


@pytest.mark.parametrize("kind", EXECUTORS)
def test_a_callback_with_message_info_gets_it_under_either_executor(context, kind):
    node = rclpy.create_node(f"info_{kind}", context=context)
    executor = make_executor(kind, context)
    executor.add_node(node)
    got = []
    subscribe_with_info(node, Float32, "info_probe", lambda m, i: got.append((m, i)), 10)
    pub = node.create_publisher(Float32, "info_probe", 10)
    node.create_timer(0.01, lambda: pub.publish(Float32(data=2.5)))
    try:
        spin_until(executor, lambda: len(got) >= 5)
    finally:
        executor.shutdown()
        node.destroy_node()
    msg = got[-1][0]
    assert isinstance(msg, Float32) and msg.data == 2.5
    seqs = [i["publication_sequence_number"] for _, i in got]
    assert all(isinstance(s, int) for s in seqs) and seqs == sorted(seqs), seqs


@pytest.mark.parametrize("kind", EXECUTORS)
def test_the_command_inbox_takes_every_command_under_either_executor(context, kind):
    """Commands published between two steps: the step takes all of them and keeps the newest
    valid one (the events executor delivers them to the inbox, the default one leaves them in
    the reader)."""
    node = rclpy.create_node(f"inbox_{kind}", context=context)
    executor = make_executor(kind, context)
    executor.add_node(node)
    inbox = CommandInbox(node, "inbox_probe", lambda v: None if len(v) == 2 else "length")
    pub = node.create_publisher(Float32MultiArray, "inbox_probe", 10)
    try:
        spin_until(executor, lambda: pub.get_subscription_count() > 0)
        for values in ([1.0, 2.0], [3.0, 4.0], [9.0]):  # the last one is rejected
            pub.publish(Float32MultiArray(data=values))
        taken = []

        def took_all() -> bool:
            values = inbox.take_latest()
            if values is not None:
                taken.append(values.tolist())
            return inbox.taken >= 3

        spin_until(executor, took_all)
    finally:
        executor.shutdown()
        node.destroy_node()
    assert taken[-1] == [3.0, 4.0]
    assert inbox.rejected == {"length": 1}


def test_a_bad_executor_name_is_refused_naming_the_allowed_ones():
    spec = executor_spec("events")
    problem = check_value(spec, "threads")
    assert problem is not None and "default, events" in problem
    assert check_value(spec, "default") is None and check_value(spec, "events") is None
    with pytest.raises(ValueError, match="default, events"):
        make_executor("threads")
