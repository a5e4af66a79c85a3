"""``ros2 bag record|info|play``: rosbag2 bags in MCAP through the ops_bag library."""

from __future__ import annotations

import contextlib
import datetime
import os
import signal
import sys
import time

from ops_ros2cli import graph
from ops_ros2cli.cli import Interrupted

LOGGER_RECORDER = "rosbag2_recorder"
LOGGER_PLAYER = "rosbag2_player"
DISCOVERY_PERIOD_S = 0.1
MATCH_WAIT_S = 2.0


def _log(level, logger, text, stream=None):
    stamp = f"{time.time():.9f}"
    print(f"[{level}] [{stamp}] [{logger}]: {text}", file=stream or sys.stdout, flush=True)


def _positive_float(string):
    import argparse

    try:
        value = float(string)
    except ValueError:
        value = -1.0
    if not value > 0:
        raise argparse.ArgumentTypeError("value must be a positive number")
    return value


def add_verbs(verbs):
    """The verbs of ``ros2 bag``, one parser each."""
    _add_record(verbs)
    _add_info(verbs)
    _add_play(verbs)


def _add_record(verbs):
    p = verbs.add_parser(
        "record",
        help="Record ROS data to a bag",
        description="Record ROS data to a bag (rosbag2 layout, MCAP storage)",
    )
    p.add_argument("topics", nargs="*", default=[], help="List of topics to record.")
    p.add_argument(
        "-a", "--all", action="store_true", help="Record all topics (hidden ones excluded)."
    )
    p.add_argument("--all-topics", action="store_true", help="Record all topics (same as -a here).")
    p.add_argument(
        "-e", "--regex", default="", help="Record only topics matching the regular expression."
    )
    p.add_argument(
        "--include-hidden-topics", action="store_true", help="Record hidden topics as well."
    )
    p.add_argument(
        "--include-unpublished-topics",
        action="store_true",
        help="Subscribe to topics that have no publisher yet (their QoS cannot be adapted to "
        "the publishers' offers). By default such a topic is subscribed when a publisher appears.",
    )
    p.add_argument(
        "-o",
        "--output",
        help="Destination of the bagfile to create, defaults to a timestamped folder "
        "in the current directory (rosbag2_YYYY_MM_DD-HH_MM_SS).",
    )
    p.add_argument("-s", "--storage", default="mcap", help="Storage identifier (only 'mcap' here).")
    p.add_argument(
        "--max-duration",
        type=_positive_float,
        default=None,
        metavar="SECONDS",
        help="Stop recording after this many seconds (this subset's option).",
    )
    p.add_argument(
        "--flush-period",
        type=_positive_float,
        default=0.25,
        metavar="SECONDS",
        help="Write buffered messages to disk at least this often; a recorder killed "
        "outright loses at most this much (default: 0.25).",
    )
    p.add_argument("--use-sim-time", action="store_true", help="Accepted; ignored")
    p.set_defaults(_main=main_record)


def _add_info(verbs):
    p = verbs.add_parser(
        "info",
        help="Print information about a bag to the screen",
        description="Print information about a bag to the screen",
    )
    p.add_argument("bag_path", help="Bag to open (a bag directory or an .mcap file)")
    p.add_argument("-s", "--storage", default="mcap", help="Storage identifier (only 'mcap').")
    p.set_defaults(_main=main_info)


def _add_play(verbs):
    p = verbs.add_parser(
        "play", help="Play back ROS data from a bag", description="Play back ROS data from a bag"
    )
    p.add_argument("bag_path", help="Bag to open (a bag directory or an .mcap file)")
    p.add_argument("-s", "--storage", default="mcap", help="Storage identifier (only 'mcap').")
    p.add_argument(
        "-r",
        "--rate",
        type=_positive_float,
        default=1.0,
        help="Rate at which to play back messages. Valid range > 0.0.",
    )
    p.add_argument(
        "-l", "--loop", action="store_true", help="Enables loop playback when playing a bagfile"
    )
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC", help="Topics to replay.")
    p.add_argument(
        "-d",
        "--delay",
        type=float,
        default=0.0,
        help="Sleep duration before play (each loop), in seconds.",
    )
    p.set_defaults(_main=main_play)


# record ------------------------------------------------------------------------------------


def _default_output():
    return datetime.datetime.now().strftime("rosbag2_%Y_%m_%d-%H_%M_%S")


def _wanted(name, args, regex, explicit):
    if name in explicit:
        return True
    if not args.include_hidden_topics and graph.is_hidden_name(name):
        return False
    if args.all or args.all_topics:
        return True
    return bool(regex is not None and regex.search(name))


def _request_qos(infos):
    """rosbag2's adapt_request_to_offers: reliable / transient_local when every publisher
    offers it."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000)
    if infos and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos):
        profile.reliability = ReliabilityPolicy.RELIABLE
    else:
        profile.reliability = ReliabilityPolicy.BEST_EFFORT
    if infos and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos):
        profile.durability = DurabilityPolicy.TRANSIENT_LOCAL
    else:
        profile.durability = DurabilityPolicy.VOLATILE
    return profile


class _Recorder:
    """What ``ros2 bag record`` does while the node runs: discover the wanted topics, subscribe
    (each message written as it comes), flush, and stop on a signal, a write error or
    ``--max-duration``."""

    def __init__(self, cli, writer, args, regex, explicit, signals):
        self.cli, self.writer, self.args, self.regex = cli, writer, args, regex
        self.explicit, self.signals = explicit, signals
        self.failure = []
        self.warned = set()
        self.subscriptions = []

    def _callback(self, topic):
        from ops_bag import BagWriteError

        def callback(data):
            if self.failure:
                return
            try:
                self.writer.write(topic, data, time.time_ns())
            except BagWriteError as exc:
                self.failure.append(exc)

        return callback

    def _subscribe(self, name, types) -> None:
        from ops_bag import qos as qos_io

        from ops_ros2cli.msgutil import get_message

        if len(types) != 1:
            self.warned.add(name)
            _log("WARN", LOGGER_RECORDER, f"Topic '{name}' has several types: skipped")
            return
        infos = self.cli.node.get_publishers_info_by_topic(name)
        if not infos and not self.args.include_unpublished_topics:
            return  # like rosbag2: wait for a publisher, whose QoS the request adapts to
        try:
            msg_class = get_message(types[0])
            self.writer.add_topic(name, types[0], [qos_io.to_dict(i.qos_profile) for i in infos])
        except (AttributeError, ImportError, ValueError) as exc:
            self.warned.add(name)
            _log("WARN", LOGGER_RECORDER, f"Topic '{name}' not recorded: {exc}")
            return
        self.subscriptions.append(
            self.cli.node.create_subscription(
                msg_class, name, self._callback(name), _request_qos(infos), raw=True
            )
        )
        _log("INFO", LOGGER_RECORDER, f"Subscribed to topic '{name}'")

    def discover(self) -> bool:
        """Subscribe to the wanted topics seen so far; False once no more can come."""
        args, writer = self.args, self.writer
        for name, types in self.cli.node.get_topic_names_and_types():
            if writer.has_topic(name) or name in self.warned:
                continue
            if _wanted(name, args, self.regex, self.explicit):
                self._subscribe(name, types)
        return not (
            self.explicit
            and all(writer.has_topic(t) for t in self.explicit)
            and not (args.all or args.all_topics or self.regex)
        )

    def _flush(self) -> None:
        from ops_bag import BagWriteError

        if not self.failure:
            try:  # also while no message comes: what was received reaches the disk
                self.writer.flush_if_due()
            except BagWriteError as exc:
                self.failure.append(exc)

    def run(self) -> str | None:
        """Record until stopped; returns why ("max duration", "interrupt") or None (a failure)."""
        start = time.monotonic()
        next_discovery = 0.0
        stopped_by = None
        try:
            keep_discovering = True
            while not self.signals:
                now = time.monotonic()
                if self.args.max_duration is not None and now - start >= self.args.max_duration:
                    stopped_by = "max duration"
                    break
                if keep_discovering and now >= next_discovery:
                    keep_discovering = self.discover()
                    if not keep_discovering:
                        _log(
                            "INFO",
                            LOGGER_RECORDER,
                            "All requested topics are subscribed. Stopping discovery...",
                        )
                    next_discovery = now + DISCOVERY_PERIOD_S
                self.cli.spin_once(graph.SLICE)
                self._flush()
                if self.failure:
                    break
        except Interrupted:
            self.signals.append(signal.SIGINT)
        if self.signals:
            stopped_by = "interrupt"
            for signum in (signal.SIGINT, signal.SIGTERM):
                signal.signal(signum, signal.SIG_IGN)
        for sub in self.subscriptions:
            self.cli.node.destroy_subscription(sub)
        return stopped_by


def main_record(args):
    import re

    from ops_bag import BagExistsError, BagWriteError, BagWriter

    if args.storage != "mcap":
        raise RuntimeError(f"storage '{args.storage}' is not provided here; use mcap")
    if not (args.topics or args.all or args.all_topics or args.regex):
        raise RuntimeError("Invalid choice: Must specify topic(s), --all, --all-topics or --regex")
    regex = re.compile(args.regex) if args.regex else None
    output = args.output or _default_output()
    try:
        writer = BagWriter(output, flush_period_s=args.flush_period)
    except BagExistsError as exc:
        _log("ERROR", "ros2bag", str(exc), sys.stderr)
        return 1
    except OSError as exc:
        _log("ERROR", "ros2bag", f"cannot create '{output}': {exc.strerror}", sys.stderr)
        return 1
    # Ctrl-C / SIGTERM only set a flag: the loop stops between two messages and the bag is
    # finalized (never interrupted in the middle of writing a record).
    signals = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda s, f: signals.append(s))

    with graph.CliNode(args, node_name=f"_rosbag2_recorder_{os.getpid()}") as cli:
        explicit = {graph.expand_topic(cli.node, t) for t in args.topics}
        _log("INFO", LOGGER_RECORDER, f"Opened bag '{writer.file_path}' for writing.")
        _log("INFO", LOGGER_RECORDER, "Listening for topics...")
        _log("INFO", LOGGER_RECORDER, "Recording...")
        recorder = _Recorder(cli, writer, args, regex, explicit, signals)
        stopped_by = recorder.run()

    if recorder.failure:
        _log("ERROR", LOGGER_RECORDER, str(recorder.failure[0]), sys.stderr)
        with contextlib.suppress(BagWriteError):
            writer.close()
        return 1
    try:
        writer.close()
    except BagWriteError as exc:
        _log("ERROR", LOGGER_RECORDER, str(exc), sys.stderr)
        return 1
    _log(
        "INFO",
        LOGGER_RECORDER,
        f"Recording stopped ({stopped_by}): {writer.message_count} messages in '{output}'",
    )
    return 0


# info ----------------------------------------------------------------------------------------


def _size(n):
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{n} B"
        n /= 1024.0
    return f"{n} B"


def _stamp(ns):
    t = datetime.datetime.fromtimestamp(ns / 1e9)
    millis = int(ns % 1_000_000_000) // 1_000_000
    return f"{t.strftime('%b %d %Y %H:%M:%S')}.{millis:03d} ({ns / 1e9:.9f})"


def _open(path, storage):
    from ops_bag import BagReader, BagReadError

    if storage != "mcap":
        raise RuntimeError(f"storage '{storage}' is not provided here; use mcap")
    try:
        return BagReader(path)
    except BagReadError as exc:
        raise RuntimeError(f"[ERROR] [ros2bag]: {exc}") from None


def main_info(args):
    from ops_bag import qos as qos_io

    reader = _open(args.bag_path, args.storage)
    if reader.problem:
        print(f"[WARN] [ros2bag]: {reader.problem}", file=sys.stderr)
    topics = reader.topics
    lines = [
        "",
        f"Files:             {reader.file_path.name}",
        f"Bag size:          {_size(reader.size_bytes)}",
        "Storage id:        mcap",
        "ROS Distro:        jazzy",
        f"Duration:          {reader.duration_ns / 1e9:.9f}s",
        f"Start:             {_stamp(reader.start_ns)}",
        f"End:               {_stamp(reader.end_ns)}",
        f"Messages:          {reader.message_count}",
    ]
    width = max((len(t.name) for t in topics), default=0)
    for i, t in enumerate(topics):
        head = "Topic information: " if i == 0 else " " * 19
        qos = "; ".join(qos_io.describe(p) for p in t.offered_qos_profiles) or "unknown"
        lines.append(
            f"{head}Topic: {t.name:<{width}} | Type: {t.type} | Count: {t.count} | "
            f"Serialization Format: {t.serialization_format} | QoS: {qos}"
        )
    if not topics:
        lines.append("Topic information: ")
    lines += ["Service:           0", "Service information: "]
    print("\n".join(lines))
    return 0


# play -----------------------------------------------------------------------------------------


def _wait_for_matches(cli, publishers, timeout):
    """Until each publisher has matched the subscriptions already in the graph (bounded)."""
    end = time.monotonic() + timeout

    def matched():
        return all(
            pub.get_subscription_count() >= cli.node.count_subscribers(name) > 0
            for name, pub in publishers.items()
        )

    while time.monotonic() < end and not matched():
        cli.spin_once(graph.SLICE)


def main_play(args):
    from ops_bag import qos as qos_io

    from ops_ros2cli.msgutil import get_message

    reader = _open(args.bag_path, args.storage)
    if reader.problem:
        _log("WARN", LOGGER_PLAYER, reader.problem, sys.stderr)
    topics = [t for t in reader.topics if args.topics is None or t.name in args.topics]
    if not topics or not sum(t.count for t in topics):
        raise RuntimeError(f"[ERROR] [ros2bag]: bag '{args.bag_path}' has no messages to play")
    with graph.CliNode(args, node_name=f"_rosbag2_player_{os.getpid()}") as cli:
        publishers = {}
        for t in topics:
            try:
                msg_class = get_message(t.type)
            except (AttributeError, ImportError, ValueError):
                _log("WARN", LOGGER_PLAYER, f"Topic '{t.name}': unknown type {t.type}; skipped")
                continue
            profile = qos_io.playback_profile(t.offered_qos_profiles)
            publishers[t.name] = cli.node.create_publisher(msg_class, t.name, profile)
        if not publishers:
            raise RuntimeError("[ERROR] [ros2bag]: no topic of the bag can be played here")
        _wait_for_matches(cli, publishers, MATCH_WAIT_S)
        _log("INFO", LOGGER_PLAYER, f"Playing '{reader.path}' at rate {args.rate:g}")
        while True:
            if args.delay > 0:
                cli.spin_for(args.delay)
            first_bag = None
            first_wall = time.monotonic()
            played = 0
            for msg in reader.messages(topics=list(publishers)):
                if first_bag is None:
                    first_bag = msg.log_time_ns
                due = first_wall + (msg.log_time_ns - first_bag) / 1e9 / args.rate
                while True:
                    left = due - time.monotonic()
                    if left <= 0:
                        break
                    cli.spin_once(min(graph.SLICE, left))
                publishers[msg.topic].publish(msg.data)
                played += 1
            _log("INFO", LOGGER_PLAYER, f"Played {played} messages")
            if not args.loop:
                break
        # let reliable readers fetch the last messages before the publishers go away
        cli.spin_for(0.2)
    return 0
