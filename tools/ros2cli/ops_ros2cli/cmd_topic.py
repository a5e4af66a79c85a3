"""``ros2 topic list|echo|hz|pub|type``."""

import argparse
import math
import sys
import time

from ops_ros2cli import graph
from ops_ros2cli.qos import (
    adapt_to_publishers,
    add_qos_arguments,
    profile_from_args,
    qos_overridden,
)

DEFAULT_TRUNCATE_LENGTH = 128
DEFAULT_WINDOW_SIZE = 10000


def _non_negative_int(string):
    try:
        value = int(string)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError("value must be non-negative integer")
    return value


def _positive_float(string):
    try:
        value = float(string)
    except ValueError:
        value = -1.0
    if not value > 0 or math.isinf(value):
        raise argparse.ArgumentTypeError("value must be a positive float")
    return value


def add_verbs(verbs):
    """The verbs of ``ros2 topic``, one parser each."""
    _add_list(verbs)
    _add_echo(verbs)
    _add_hz(verbs)
    _add_pub(verbs)
    _add_info(verbs)
    _add_type(verbs)


def _add_list(verbs):
    p = verbs.add_parser(
        "list",
        help="Output a list of available topics",
        description="Output a list of available topics",
    )
    graph.add_spin_time_argument(p)
    p.add_argument(
        "-t", "--show-types", action="store_true", help="Additionally show the topic type"
    )
    p.add_argument(
        "-c",
        "--count-topics",
        action="store_true",
        help="Only display the number of topics discovered",
    )
    p.add_argument(
        "--include-hidden-topics", action="store_true", help="Consider hidden topics as well"
    )
    p.set_defaults(_main=main_list)


def _add_echo(verbs):
    p = verbs.add_parser(
        "echo", help="Output messages from a topic", description="Output messages from a topic"
    )
    graph.add_spin_time_argument(p)
    p.add_argument("topic_name", help="Name of the ROS topic to listen to (e.g. '/chatter')")
    p.add_argument(
        "message_type", nargs="?", help="Type of the ROS message (e.g. 'std_msgs/msg/String')"
    )
    add_qos_arguments(p, "subscribe", "sensor_data")
    p.add_argument(
        "--field",
        type=str,
        default=None,
        help="Echo a selected field of a message. Use '.' to select sub-fields. "
        "For example, to echo the position field of a nav_msgs/msg/Odometry "
        "message: 'ros2 topic echo /odom --field pose.pose.position'",
    )
    p.add_argument(
        "--full-length",
        "-f",
        action="store_true",
        help="Output all elements for arrays, bytes, and string with a length > "
        "'--truncate-length', by default they are truncated after "
        "'--truncate-length' elements with '...'",
    )
    p.add_argument(
        "--truncate-length",
        "-l",
        type=_non_negative_int,
        default=DEFAULT_TRUNCATE_LENGTH,
        help="The length to truncate arrays, bytes, and string to "
        f"(default: {DEFAULT_TRUNCATE_LENGTH})",
    )
    p.add_argument("--no-arr", action="store_true", help="Don't print array fields of messages")
    p.add_argument("--no-str", action="store_true", help="Don't print string fields of messages")
    p.add_argument("--flow-style", action="store_true", help="Print collections in the block style")
    p.add_argument(
        "--once", action="store_true", help="Print the first message received and then exit."
    )
    p.add_argument(
        "--timeout",
        metavar="N",
        type=_positive_float,
        default=None,
        help="Set a timeout in seconds for waiting (for the topic to be "
        "published and for messages)",
    )
    p.set_defaults(_main=main_echo)


def _add_hz(verbs):
    p = verbs.add_parser(
        "hz",
        help="Print the average receiving rate to screen",
        description="Print the average receiving rate to screen",
    )
    graph.add_spin_time_argument(p)
    p.add_argument("topic_name", help="Name of the ROS topic to listen to (e.g. '/chatter')")
    p.add_argument(
        "--window",
        "-w",
        dest="window_size",
        type=_non_negative_int,
        default=DEFAULT_WINDOW_SIZE,
        metavar="WINDOW",
        help="window size, in # of messages, for calculating rate "
        f"(default: {DEFAULT_WINDOW_SIZE})",
    )
    p.add_argument(
        "--filter",
        dest="filter_expr",
        default=None,
        metavar="EXPR",
        help="only measure messages matching the specified Python expression",
    )
    p.add_argument(
        "--wall-time",
        dest="use_wtime",
        default=False,
        action="store_true",
        help="calculates rate using wall time which can be helpful when clock "
        "is not published during simulation",
    )
    p.set_defaults(_main=main_hz)


def _add_pub(verbs):
    p = verbs.add_parser(
        "pub", help="Publish a message to a topic", description="Publish a message to a topic"
    )
    graph.add_spin_time_argument(p)
    p.add_argument("topic_name", help="Name of the ROS topic to publish to (e.g. '/chatter')")
    p.add_argument("message_type", help="Type of the ROS message (e.g. 'std_msgs/String')")
    p.add_argument(
        "values",
        nargs="?",
        default="{}",
        help="Values to fill the message with in YAML format (e.g. 'data: Hello "
        "World'), otherwise the message will be published with default values",
    )
    p.add_argument(
        "-r",
        "--rate",
        metavar="N",
        type=_positive_float,
        default=1.0,
        help="Publishing rate in Hz (default: 1)",
    )
    p.add_argument(
        "-p",
        "--print",
        metavar="N",
        type=int,
        default=1,
        help="Only print every N-th published message (default: 1)",
    )
    group = p.add_mutually_exclusive_group()
    group.add_argument("-1", "--once", action="store_true", help="Publish one message and exit")
    group.add_argument(
        "-t",
        "--times",
        type=_non_negative_int,
        default=0,
        help="Publish this number of times and then exit",
    )
    p.add_argument(
        "-w",
        "--wait-matching-subscriptions",
        type=_non_negative_int,
        default=None,
        help="Wait until finding the specified number of matching subscriptions. "
        'Defaults to 1 when using "-1"/"--once"/"--times", otherwise '
        "defaults to 0.",
    )
    p.add_argument(
        "--keep-alive",
        metavar="N",
        type=_positive_float,
        default=0.1,
        help="Keep publishing node alive for N seconds after the last msg (default: 0.1)",
    )
    p.add_argument("-n", "--node-name", help="Name of the created publishing node")
    add_qos_arguments(p, "publish", "default")
    p.set_defaults(_main=main_pub)


def _add_info(verbs):
    p = verbs.add_parser(
        "info",
        help="Print information about a topic",
        description="Print information about a topic",
    )
    graph.add_spin_time_argument(p)
    p.add_argument("topic_name", help="Name of the ROS topic to get info (e.g. '/chatter')")
    p.add_argument(
        "--verbose",
        "-v",
        action="store_true",
        help="Prints detailed information like the node name, node namespace, topic type, "
        "topic type hash, GUID, and QoS Profile of the publishers and subscribers to this topic",
    )
    p.set_defaults(_main=main_info)


def _add_type(verbs):
    p = verbs.add_parser("type", help="Print a topic's type", description="Print a topic's type")
    graph.add_spin_time_argument(p)
    p.add_argument("topic_name", help="Name of the ROS topic to get type (e.g. '/chatter')")
    p.set_defaults(_main=main_type)


# list / type ------------------------------------------------------------------


def main_list(args):
    return graph.print_list(
        args,
        lambda node: node.get_topic_names_and_types(),
        args.include_hidden_topics,
        args.count_topics,
    )


def main_type(args):
    return graph.print_type(
        args,
        lambda node: graph.expand_topic(node, args.topic_name),
        lambda node: node.get_topic_names_and_types(),
    )


def main_info(args):
    with graph.CliNode(args) as cli:
        name = graph.expand_topic(cli.node, args.topic_name)
        own = (cli.node.get_name(), cli.node.get_namespace())

        def endpoints():
            types = dict(cli.node.get_topic_names_and_types()).get(name)
            if not types:
                return None
            pubs = cli.node.get_publishers_info_by_topic(name)
            subs = [
                s
                for s in cli.node.get_subscriptions_info_by_topic(name)
                if (s.node_name, s.node_namespace) != own
            ]
            return types, pubs, subs

        found = cli.wait_for(endpoints, graph.discovery_timeout(args))
        if found:
            # a moment more for the other endpoints of a topic just discovered
            cli.spin_for(0.3)
            found = endpoints() or found
    if not found:
        print(f"Unknown topic '{args.topic_name}'", file=sys.stderr)
        return 1
    types, pubs, subs = found
    type_str = types[0] if len(types) == 1 else str(types)
    print(f"Type: {type_str}", end="\n" if not args.verbose else "\n\n")
    print(f"Publisher count: {len(pubs)}", end="\n" if not args.verbose else "\n\n")
    if args.verbose:
        for info in pubs:
            print(info, end="\n\n")
    print(f"Subscription count: {len(subs)}", end="\n" if not args.verbose else "\n\n")
    if args.verbose:
        for info in subs:
            print(info, end="\n\n")
    return 0


# echo / hz ---------------------------------------------------------------------


def _wait_for_topic_type(cli, topic_name, timeout):
    """Wait until the topic is in the graph; return its message class or None (timeout).

    Prints the real tool's warning when the topic is not found within WARNING_GRACE.
    """
    from ops_ros2cli.msgutil import get_message

    expanded = graph.expand_topic(cli.node, topic_name)
    start = time.monotonic()
    warned = False

    def lookup():
        for name, types in cli.node.get_topic_names_and_types():
            if name == expanded:
                return types
        return None

    while True:
        types = lookup()
        if types:
            break
        elapsed = time.monotonic() - start
        timed_out = timeout is not None and elapsed >= timeout
        if not warned and (elapsed >= graph.WARNING_GRACE or timed_out):
            print(f"WARNING: topic [{topic_name}] does not appear to be published yet")
            warned = True
        if timed_out:
            return None
        cli.spin_once(graph.SLICE)
    if len(types) > 1:
        raise RuntimeError(
            f"Cannot echo topic '{topic_name}', as it contains more than one type: "
            f"[{', '.join(types)}]"
        )
    try:
        return get_message(types[0])
    except (AttributeError, ImportError, ValueError):
        raise RuntimeError(f"The message type '{types[0]}' is invalid") from None


def main_echo(args):
    from ops_ros2cli.msgutil import get_message, message_to_yaml

    field = None
    if args.field is not None:
        field = [f for f in args.field.split(".") if f]
        if not field:
            raise RuntimeError(f"Invalid field value '{args.field}'")
    truncate_length = None if args.full_length else args.truncate_length
    deadline = None if args.timeout is None else time.monotonic() + args.timeout

    with graph.CliNode(args) as cli:
        if args.message_type is None:
            msg_class = _wait_for_topic_type(cli, args.topic_name, args.timeout)
            if msg_class is None:
                raise RuntimeError("Could not determine the type for the passed topic")
        else:
            try:
                msg_class = get_message(args.message_type)
            except (AttributeError, ImportError, ValueError):
                raise RuntimeError("The passed message type is invalid") from None
            # give discovery a moment so the QoS can follow the publishers
            expanded = graph.expand_topic(cli.node, args.topic_name)
            grace = 1.0 if deadline is None else min(1.0, max(0.0, deadline - time.monotonic()))
            cli.wait_for(lambda: cli.node.get_publishers_info_by_topic(expanded), grace)

        profile = profile_from_args(args)
        if not qos_overridden(args):
            profile = adapt_to_publishers(cli.node, args.topic_name, profile)

        done = []

        def callback(msg):
            sub = msg
            if field is not None:
                for name in field:
                    try:
                        sub = getattr(sub, name)
                    except AttributeError as ex:
                        raise RuntimeError(f"Invalid field '{'.'.join(field)}': {ex}") from None
            if args.once:
                done.append(True)
            if not hasattr(sub, "get_fields_and_field_types"):
                print(sub, end="\n---\n")
            else:
                print(
                    message_to_yaml(
                        sub,
                        truncate_length=truncate_length,
                        no_arr=args.no_arr,
                        no_str=args.no_str,
                        flow_style=args.flow_style,
                    ),
                    end="---\n",
                )

        cli.node.create_subscription(msg_class, args.topic_name, callback, profile)
        while not done:
            if deadline is not None and time.monotonic() >= deadline:
                break
            cli.spin_once(graph.SLICE)
    return 0


class _RateMeter:
    """Receive times and statistics of ``ros2 topic hz`` (ROSTopicHz)."""

    def __init__(self, clock, window_size, filter_fn, use_wtime):
        self.clock = clock
        self.window_size = window_size
        self.filter_fn = filter_fn
        self.use_wtime = use_wtime
        self.msg_t0 = -1
        self.msg_tn = 0
        self.last_printed_tn = 0
        self.times = []

    def _now_ns(self):
        if self.use_wtime:
            return time.time_ns()
        return self.clock.now().nanoseconds

    def callback(self, msg):
        if self.filter_fn is not None and not self.filter_fn(msg):
            return
        curr = self._now_ns()
        if curr == 0:
            if self.times:
                print("time has reset, resetting counters")
                self.times = []
            return
        if self.msg_t0 < 0 or self.msg_t0 > curr:
            self.msg_t0 = curr
            self.msg_tn = curr
            self.times = []
        else:
            self.times.append(curr - self.msg_tn)
            self.msg_tn = curr
        if len(self.times) > self.window_size:
            self.times.pop(0)

    def print_hz(self):
        if not self.times:
            return
        if self.last_printed_tn == 0:
            self.last_printed_tn = self.msg_tn
            return
        if self.msg_tn < self.last_printed_tn + 1e9:
            return
        n = len(self.times)
        mean = sum(self.times) / n
        rate = 1.0 / mean if mean > 0.0 else 0
        std_dev = math.sqrt(sum((x - mean) ** 2 for x in self.times) / n)
        self.last_printed_tn = self.msg_tn
        print(
            f"average rate: {rate * 1e9:.3f}\n"
            f"\tmin: {min(self.times) * 1e-9:.3f}s max: {max(self.times) * 1e-9:.3f}s "
            f"std dev: {std_dev * 1e-9:.5f}s window: {n}"
        )


def main_hz(args):
    from rclpy.qos import qos_profile_sensor_data

    filter_fn = None
    if args.filter_expr:
        code = compile(args.filter_expr, "<filter>", "eval")

        def filter_fn(m):
            return eval(code, {}, {"m": m})

    with graph.CliNode(args) as cli:
        msg_class = _wait_for_topic_type(cli, args.topic_name, None)
        meter = _RateMeter(cli.node.get_clock(), args.window_size, filter_fn, args.use_wtime)
        cli.node.create_subscription(
            msg_class, args.topic_name, meter.callback, qos_profile_sensor_data
        )
        while True:
            cli.spin_once(graph.SLICE)
            meter.print_hz()


# pub ---------------------------------------------------------------------------------


def main_pub(args):
    from ops_ros2cli.msgutil import fill_from_yaml, get_message

    try:
        msg_class = get_message(args.message_type)
    except (AttributeError, ImportError, ValueError):
        raise RuntimeError("The passed message type is invalid") from None
    msg = fill_from_yaml(msg_class(), args.values)

    times = 1 if args.once else args.times
    wait_matching = args.wait_matching_subscriptions
    if wait_matching is None:
        wait_matching = 1 if times != 0 else 0
    period = 1.0 / args.rate

    with graph.CliNode(args, node_name=args.node_name) as cli:
        pub = cli.node.create_publisher(msg_class, args.topic_name, profile_from_args(args))
        ticks = 0
        while pub.get_subscription_count() < wait_matching:
            if ticks % 20 == 0:
                print(f"Waiting for at least {wait_matching} matching subscription(s)...")
            ticks += 1
            cli.spin_once(graph.SLICE)

        print("publisher: beginning loop")
        count = 0
        next_time = time.monotonic()
        while times == 0 or count < times:
            now = time.monotonic()
            if now < next_time:
                cli.spin_once(min(graph.SLICE, next_time - now))
                continue
            next_time += period
            if next_time < now:
                next_time = now + period
            count += 1
            if args.print and count % args.print == 0:
                print(f"publishing #{count}: {msg!r}\n")
            pub.publish(msg)
        # give the last messages time to reach the wire before exiting
        cli.spin_for(args.keep_alive)
    return 0
