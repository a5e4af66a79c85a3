"""The short-lived node every graph command uses, and discovery helpers.

The real ros2cli asks its daemon, which already knows the graph. Here there is no
daemon, so each command starts a node and spins until DDS discovery has found what
it needs (a topic, a node, a service) or, for the list commands, until the graph
has settled.
"""

import contextlib
import os
import time

NODE_NAME_PREFIX = "_ros2cli"

# Longest wait for discovery of a named entity (node, topic publisher) before giving up.
DISCOVERY_TIMEOUT = 10.0
# Time after which a command that waits for a topic warns that it is not published.
WARNING_GRACE = 3.0
# List commands: default spin time, then how long the graph must have been unchanged to stop
# (at most SETTLE_EXTRA more seconds).
DEFAULT_SPIN_TIME = 3.0
SETTLE_TIME = 1.0
SETTLE_EXTRA = 2.0
SLICE = 0.05


def add_spin_time_argument(parser):
    parser.add_argument(
        "--spin-time",
        type=float,
        default=None,
        help="Spin time in seconds to wait for discovery (there is no daemon in this ros2 "
        f"subset). Listing commands spin up to {DEFAULT_SPIN_TIME} s by default (less once the "
        f"graph has settled); commands that wait for a named node or topic give up after "
        f"{DISCOVERY_TIMEOUT} s by default",
    )
    parser.add_argument(
        "--no-daemon",
        action="store_true",
        help="Accepted for compatibility; this ros2 subset never uses a daemon",
    )
    parser.add_argument("--use-sim-time", action="store_true", help="Enable ROS simulation time")


class CliNode:
    """A hidden node (``_ros2cli_<pid>``) with rclpy initialised without signal handlers."""

    def __init__(self, args=None, node_name=None):
        import rclpy
        from rclpy.parameter import Parameter
        from rclpy.signals import SignalHandlerOptions

        self._rclpy = rclpy
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        use_sim_time = bool(getattr(args, "use_sim_time", False))
        self.node = rclpy.create_node(
            node_name or f"{NODE_NAME_PREFIX}_{os.getpid()}",
            context=self.context,
            start_parameter_services=False,
            parameter_overrides=[Parameter("use_sim_time", value=use_sim_time)],
        )
        from rclpy.executors import SingleThreadedExecutor

        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self):
        with contextlib.suppress(Exception):
            self.executor.shutdown(timeout_sec=0.5)
        with contextlib.suppress(Exception):
            self.node.destroy_node()
        with contextlib.suppress(Exception):
            self._rclpy.try_shutdown(context=self.context)

    def spin_once(self, timeout_sec=SLICE):
        self.executor.spin_once(timeout_sec=timeout_sec)

    def spin_for(self, seconds):
        end = time.monotonic() + seconds
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return
            self.spin_once(min(SLICE, left))

    def wait_for(self, predicate, timeout):
        """Spin until ``predicate()`` is truthy; return its value, or None on timeout."""
        end = None if timeout is None else time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            if end is not None and time.monotonic() >= end:
                return None
            self.spin_once(SLICE)

    def spin_until_future_complete(self, future, timeout=None):
        end = None if timeout is None else time.monotonic() + timeout
        while not future.done():
            if end is not None and time.monotonic() >= end:
                return False
            self.spin_once(SLICE)
        return True

    # graph ------------------------------------------------------------------

    def _signature(self):
        node = self.node
        topics = tuple(
            (n, tuple(t))
            for n, t in node.get_topic_names_and_types()
            if n not in ("/rosout", "/parameter_events")
        )
        services = tuple(
            (n, tuple(t))
            for n, t in node.get_service_names_and_types()
            if not n.startswith(node.get_fully_qualified_name() + "/")
        )
        nodes = tuple(
            (n, ns)
            for n, ns in node.get_node_names_and_namespaces()
            if (n, ns) != (node.get_name(), node.get_namespace())
        )
        return (topics, services, nodes)

    def settle_graph(self, spin_time):
        """Spin ``spin_time`` seconds for discovery, longer while the graph still changes.

        After ``spin_time``, spinning goes on until the graph has not changed for SETTLE_TIME
        seconds, for at most SETTLE_EXTRA more seconds.
        """
        start = time.monotonic()
        last = self._signature()
        last_change = start
        while True:
            now = time.monotonic()
            if now >= start + spin_time and (
                now - last_change >= SETTLE_TIME or now >= start + spin_time + SETTLE_EXTRA
            ):
                return
            self.spin_once(SLICE)
            sig = self._signature()
            if sig != last:
                last = sig
                last_change = time.monotonic()


def list_spin_time(args):
    value = getattr(args, "spin_time", None)
    return DEFAULT_SPIN_TIME if value is None else value


def discovery_timeout(args):
    value = getattr(args, "spin_time", None)
    return DISCOVERY_TIMEOUT if value is None else value


def is_hidden_name(name):
    return any(token.startswith("_") for token in name.split("/"))


def full_node_name(name, namespace):
    return namespace + ("" if namespace.endswith("/") else "/") + name


def get_node_names(node, include_hidden_nodes=False):
    names = []
    for name, namespace in node.get_node_names_and_namespaces():
        full = full_node_name(name, namespace)
        if not include_hidden_nodes and is_hidden_name(full):
            continue
        names.append(full)
    return names


def absolute_node_name(name):
    if not name:
        return name
    return name if name.startswith("/") else "/" + name


def expand_topic(node, topic_name):
    from rclpy.expand_topic_name import expand_topic_name

    return expand_topic_name(topic_name, node.get_name(), node.get_namespace())


def print_list(args, names_and_types, include_hidden, count_only, skip_own=False):
    """``ros2 topic list`` / ``ros2 service list``: settle the graph, then print the number of
    entries, or each name (with its types under ``--show-types``), sorted.

    ``names_and_types(node)`` gives the graph's (name, types) pairs; hidden names are left out
    unless ``include_hidden``, and with ``skip_own`` the CLI node's own (its services).
    Returns the exit status, 0.
    """
    with CliNode(args) as cli:
        cli.settle_graph(list_spin_time(args))
        own = cli.node.get_fully_qualified_name() + "/"
        entries = [
            (name, types)
            for name, types in sorted(names_and_types(cli.node))
            if not (skip_own and name.startswith(own))
            and (include_hidden or not is_hidden_name(name))
        ]
    if count_only:
        print(len(entries))
        return 0
    for name, types in entries:
        if args.show_types:
            print(f"{name} [{', '.join(types)}]")
        else:
            print(name)
    return 0


def print_type(args, name_of, names_and_types):
    """``ros2 topic type`` / ``ros2 service type``: wait for the entity and print its types.

    ``name_of(node)`` gives the full name looked for; ``names_and_types(node)`` the graph's
    (name, types) pairs. Returns the exit status: 1 when it was not found in time.
    """
    with CliNode(args) as cli:
        name = name_of(cli.node)
        found = cli.wait_for(
            lambda: dict(names_and_types(cli.node)).get(name), discovery_timeout(args)
        )
    if not found:
        return 1
    for t in found:
        print(t)
    return 0
