"""Recording, replaying and watching over real DDS: `ros2 bag record/info/play`, the bag of
`evaluate --record`, the Foxglove live view, and `topic info`, `node info`, `param dump/load`,
`interface show`, `pkg executables` and tab completion of the project's `ros2` subset.

Bags are read back with mcap-ros2-support's own reader (independent of ops_bag's). Trace
lengths and stage counts come from the messages, never from constants.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import struct
import subprocess
import time
from pathlib import Path

import pytest
from ops_bench.observer import TopicObserver
from ops_bench.processes import REPO, assert_no_traceback, ros2_command, run_ros2, start_sim

pytest.importorskip("ops_ros2cli", reason="a real ros2 is in use; the subset is not installed")
pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

OPS_TOPICS = ("/ops/delays", "/ops/intensity", "/ops/power", "/ops/reward")


def read_independently(bag: Path) -> list[tuple[str, str, object]]:
    """(topic, schema name, decoded message) of every message, via mcap_ros2 only."""
    from mcap_ros2.reader import read_ros2_messages

    (mcap_file,) = sorted(bag.glob("*.mcap"))
    return [(m.channel.topic, m.schema.name, m.ros_msg) for m in read_ros2_messages(str(mcap_file))]


def _values(msg):
    return list(msg.data) if hasattr(msg.data, "__len__") else [float(msg.data)]


def _contiguous_in(part: list, whole: list) -> bool:
    """``part`` equals ``whole[i : i + len(part)]`` for some i (the same float32 values)."""
    part = [list(map(float, p)) if isinstance(p, list) else float(p) for p in part]
    whole = [list(map(float, w)) if isinstance(w, list) else float(w) for w in whole]
    return any(whole[i : i + len(part)] == part for i in range(len(whole) - len(part) + 1))


# --- record / info / play of the simulator --------------------------------------------------


@pytest.fixture(scope="module")
def recorded(module_procs, tmp_path_factory):
    """A free-running simulator recorded for a while by `ros2 bag record` (stopped by Ctrl-C),
    with what an rclpy subscriber started before the recorder received meanwhile."""
    observer = TopicObserver()
    try:
        sim = start_sim(module_procs, stage=3, mode="easy", lockstep=False, seed=3)
        observer.wait_count("power", 5)
        bag = tmp_path_factory.mktemp("bags") / "sim_run"
        rec = module_procs.ros2("bag", "record", "-o", str(bag), *OPS_TOPICS, name="record")
        rec.wait_for(r"Subscribed to topic '/ops/power'")
        rec.wait_for(r"All requested topics are subscribed")
        # the recorder's subscriptions in the graph (a loaded machine discovers them late)
        observer.wait_until(
            lambda: all(observer.node.count_subscribers(t) >= 2 for t in OPS_TOPICS),
            timeout=30,
            what="the recorder's subscriptions in the graph",
        )
        start = observer.count("power")
        observer.wait_count("power", start + 150)
        rec.signal(signal.SIGINT)  # Ctrl-C: the bag is finalized
        code = rec.wait_exit(30)
        seen = {name: observer.values(name) for name in ("power", "delays", "intensity")}
        sim.stop()  # the tests that play the bag want ops/ to themselves
    finally:
        observer.close()
    return {"bag": bag, "code": code, "output": rec.output, "seen": seen}


def test_ctrl_c_finalizes_a_readable_bag(recorded):
    assert recorded["code"] == 0, recorded["output"]
    assert_no_traceback(recorded["output"])
    bag = recorded["bag"]
    assert (bag / "metadata.yaml").is_file()
    from mcap.reader import make_reader

    with open(next(bag.glob("*.mcap")), "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 0  # finished: has a summary


def test_recorded_bag_matches_what_a_subscriber_received(recorded):
    import yaml

    messages = read_independently(recorded["bag"])
    by_topic: dict[str, list] = {}
    for topic, schema, msg in messages:
        by_topic.setdefault(topic, []).append((schema, msg))
    assert set(by_topic) == set(OPS_TOPICS)
    types = {t: {s for s, _ in v} for t, v in by_topic.items()}
    assert types["/ops/power"] == {"std_msgs/msg/Float32"}
    assert types["/ops/intensity"] == {"std_msgs/msg/Float32MultiArray"}
    power = [_values(m)[0] for _, m in by_topic["/ops/power"]]
    assert len(power) >= 50  # of the 150 the subscriber saw while recording (DDS matching lags)
    # the recording is a contiguous run of what the subscriber saw, in order
    seen = recorded["seen"]
    assert _contiguous_in(power, seen["power"])
    traces = [_values(m) for _, m in by_topic["/ops/intensity"]]
    assert len(traces[0]) == len(seen["intensity"][0])  # whatever the trace length is
    assert _contiguous_in(traces, seen["intensity"])
    # metadata.yaml: rosbag2 version 9, counts and QoS as recorded (delays latched)
    info = yaml.safe_load((recorded["bag"] / "metadata.yaml").read_text())
    info = info["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    counts = {
        t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]
    }
    assert counts == {t: len(v) for t, v in by_topic.items()}
    qos = {
        t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
        for t in info["topics_with_message_count"]
    }
    assert qos["/ops/delays"][0]["durability"] == "transient_local"
    assert qos["/ops/power"][0]["reliability"] == "reliable"


def test_bag_info(recorded):
    result = run_ros2("bag", "info", str(recorded["bag"]))
    assert result.returncode == 0, result.stderr
    count = len(read_independently(recorded["bag"]))
    assert re.search(rf"^Messages:\s+{count}$", result.stdout, re.M), result.stdout
    assert "Topic: /ops/power" in result.stdout and "Type: std_msgs/msg/Float32 " in result.stdout


def test_play_reproduces_the_messages_in_order(recorded, procs):
    # no simulator now: only `ros2 bag play` publishes on ops/
    observer = TopicObserver()
    try:
        power = [
            _values(m)[0] for t, _, m in read_independently(recorded["bag"]) if t.endswith("power")
        ]
        # -d: time for discovery beyond play's own 2 s wait for matching subscribers (a loaded
        # machine can take longer to discover the observer, and then the first messages are lost)
        args = ["bag", "play", str(recorded["bag"]), "--rate", "2", "-d", "3"]
        play = procs.ros2(*args, name="play")
        assert play.wait_exit(90) == 0, play.output
        observer.wait_count("power", len(power), timeout=30)
        assert observer.values("power") == pytest.approx(power)
        assert observer.count("intensity") == len(
            [1 for t, _, _ in read_independently(recorded["bag"]) if t == "/ops/intensity"]
        )
    finally:
        observer.close()


def test_play_keeps_latched_topics_latched(tmp_path, procs):
    """A subscriber that joins after the one /ops/delays message was played still gets it."""
    import rclpy
    from ops_contract.ros_interface import QOS_RELIABLE, QOS_STATE
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float32, Float32MultiArray

    from ops_bag import BagWriter
    from ops_bag import qos as qos_io

    bag = tmp_path / "latched"
    with BagWriter(bag) as w:
        w.add_topic("/ops/delays", "std_msgs/msg/Float32MultiArray", [qos_io.to_dict(QOS_STATE)])
        w.add_topic("/ops/power", "std_msgs/msg/Float32", [qos_io.to_dict(QOS_RELIABLE)])
        t0 = time.time_ns()
        w.write("/ops/delays", serialize_message(Float32MultiArray(data=[1.5, -2.5])), t0)
        for i in range(60):
            w.write("/ops/power", serialize_message(Float32(data=i / 100)), t0 + i * 50_000_000)
    observer = TopicObserver()
    try:
        play = procs.ros2("bag", "play", str(bag), name="play")
        observer.wait_count("power", 3)  # the delays message (t=0) was published before
        latched = []
        qos = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        with observer.lock:
            observer.node.create_subscription(
                Float32MultiArray, "/ops/delays", lambda m: latched.append(list(m.data)), qos
            )
        observer.wait_until(lambda: latched, 10, "the latched /ops/delays")
        assert latched[0] == [1.5, -2.5]
        assert play.wait_exit(30) == 0
    finally:
        observer.close()
    assert rclpy is not None


# --- failures -------------------------------------------------------------------------------


def test_record_refuses_an_existing_directory(tmp_path):
    (tmp_path / "old").mkdir()
    result = run_ros2("bag", "record", "-a", "-o", str(tmp_path / "old"))
    assert result.returncode == 1
    assert "already exists" in result.stderr
    assert_no_traceback(result.stderr)
    assert list((tmp_path / "old").iterdir()) == []  # nothing touched


def test_play_missing_or_truncated_bag(recorded, tmp_path):
    missing = run_ros2("bag", "play", str(tmp_path / "nope"))
    assert missing.returncode == 1
    assert "does not exist" in missing.stderr
    assert_no_traceback(missing.stderr)
    not_bag = tmp_path / "empty_dir"
    not_bag.mkdir()
    result = run_ros2("bag", "info", str(not_bag))
    assert result.returncode == 1 and "not a readable bag" in result.stderr
    # a bag cut in the middle (no summary): info and play recover what is before the cut
    src = next(recorded["bag"].glob("*.mcap"))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
    info = run_ros2("bag", "info", str(cut))
    assert info.returncode == 0, info.stderr
    assert "truncated or damaged" in info.stderr
    recovered = int(re.search(r"^Messages:\s+(\d+)$", info.stdout, re.M).group(1))
    assert 0 < recovered < len(read_independently(recorded["bag"]))
    play = run_ros2("bag", "play", str(cut), "--rate", "50")
    assert play.returncode == 0, play.stderr
    assert "truncated or damaged" in play.stderr
    assert f"Played {recovered} messages" in play.stdout
    assert_no_traceback(play.stderr)


def test_full_disk_keeps_the_bag_written_so_far(procs, tmp_path):
    """The file-size limit stands in for a full disk: writes fail with an OSError (EFBIG, as
    ENOSPC would) and the recorder stops with a clear error; what it flushed stays readable."""
    from ops_bag import BagReader

    start_sim(procs, stage=3, mode="easy", lockstep=False)
    bag = tmp_path / "full"
    cmd = " ".join(
        [*ros2_command(), "bag", "record", "-o", str(bag), "--flush-period", "0.2", *OPS_TOPICS]
    )
    # 64 KiB per file; SIGXFSZ ignored so that writing past it fails with EFBIG
    rec = procs.start(["bash", "-c", f"ulimit -f 64; trap '' XFSZ; exec {cmd}"], name="record")
    code = rec.wait_exit(90)
    assert code == 1, rec.output
    assert "failed (File too large); recording stopped" in rec.output
    assert "stay readable" in rec.output
    assert_no_traceback(rec.output)
    reader = BagReader(bag)
    assert reader.message_count > 50
    kept = sum(1 for _ in reader.messages())
    assert kept == reader.message_count
    import yaml

    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert 0 < info["message_count"] <= kept  # metadata describes only what is on disk


def test_a_recorder_killed_outright_after_10_s_keeps_its_messages(procs, tmp_path, observer):
    """SIGKILL (no chance to finalize): the flushed chunks hold >= 90 % of what the recorder was
    sent, and `bag info` / `bag play` read them."""
    from ops_bag import BagReader

    start_sim(procs, stage=3, mode="easy", lockstep=False, seed=8)
    observer.wait_count("power", 5)
    bag = tmp_path / "killed"
    rec = procs.ros2("bag", "record", "-o", str(bag), *OPS_TOPICS, name="record")
    rec.wait_for(r"All requested topics are subscribed")
    observer.wait_until(
        lambda: all(observer.node.count_subscribers(t) >= 2 for t in OPS_TOPICS),
        timeout=30,
        what="the recorder's subscriptions in the graph",
    )
    t0 = time.monotonic()
    observer.wait_until(lambda: time.monotonic() - t0 >= 10.0, timeout=20, what="10 s")
    os.killpg(rec.popen.pid, signal.SIGKILL)
    killed_at = time.monotonic()
    rec.wait_exit(10)
    wall_minus_mono = time.time_ns() - time.monotonic_ns()

    reader = BagReader(bag)
    stamps = [m.log_time_ns for m in reader.messages(["/ops/power"])]
    assert len(stamps) > 100, (reader.problem, rec.output)
    first = (stamps[0] - wall_minus_mono) / 1e9  # monotonic time of the first recorded reading
    with observer.lock:
        sent = [t for t, _, _ in observer.messages["power"] if first - 0.005 <= t <= killed_at]
    # The recorder received what the observer did (same publisher, same host): it kept >= 90 %.
    assert len(stamps) >= 0.9 * len(sent), (len(stamps), len(sent), reader.problem)
    assert killed_at - first >= 8.0  # it had recorded for (nearly) the whole 10 s

    info = run_ros2("bag", "info", str(bag))
    assert info.returncode == 0, info.stderr
    count = int(re.search(r"^Messages:\s+(\d+)$", info.stdout, re.M).group(1))
    assert count == reader.message_count
    play = run_ros2("bag", "play", str(bag), "--rate", "20")
    assert play.returncode == 0, play.stderr
    assert f"Played {count} messages" in play.stdout
    assert_no_traceback(info.stderr + play.stderr)


# --- episodes from Python -------------------------------------------------------------------


def test_evaluate_record_writes_the_same_format(tmp_path):
    bag = tmp_path / "episodes"
    steps, episodes = 20, 2
    result = subprocess.run(
        [
            *ros2_command(), "run", "ops_gym_bridge", "evaluate", "--spgd", "--stage", "3",
            "--mode", "easy", "--episodes", str(episodes), "--seeds", "0", "--splits", "train",
            "--steps", str(steps), "--no-plot", "--out", str(tmp_path / "eval"),
            "--record", str(bag),
        ],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    messages = read_independently(bag)
    counts = {}
    for topic, _, _ in messages:
        counts[topic] = counts.get(topic, 0) + 1
    assert counts == {t: episodes * (steps + 1) for t in OPS_TOPICS}
    delays = [m for t, _, m in messages if t == "/ops/delays"]
    assert all(len(m.data) == 3 for m in delays)
    evaluation = json.loads((tmp_path / "eval" / "evaluation.json").read_text())
    curve = evaluation["splits"]["train"]["curve_mean"]
    power = [float(m.data) for t, _, m in messages if t == "/ops/power"]
    per_episode = [power[i * (steps + 1) : (i + 1) * (steps + 1)] for i in range(episodes)]
    mean = [sum(v) / episodes for v in zip(*per_episode, strict=True)]
    # the recorded episodes are the evaluated ones (evaluation.json keeps 5 decimals)
    assert mean == pytest.approx(curve, abs=1e-5)
    again = subprocess.run(
        [*ros2_command(), "run", "ops_gym_bridge", "evaluate", "--spgd", "--record", str(bag)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert again.returncode == 2 and "already exists" in again.stderr


# --- live view ------------------------------------------------------------------------------


def test_foxglove_websocket_serves_power(procs):
    websockets = pytest.importorskip("websockets")
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    start_sim(procs, stage=3, mode="easy", lockstep=False)
    fox = procs.start(
        [*ros2_command(), "run", "ops_sim_ros", "foxglove", "--ros-args", "-p", "port:=0"],
        name="foxglove",
    )
    port = int(fox.wait_for(r"ws://127\.0\.0\.1:(\d+)").group(1))
    fox.wait_for(r"serving /ops/power")

    async def receive():
        async with websockets.connect(
            f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"]
        ) as ws:
            channel = None
            while channel is None:
                msg = json.loads(await asyncio.wait_for(ws.recv(), 20))
                if msg.get("op") == "advertise":
                    channel = next((c for c in msg["channels"] if c["topic"] == "/ops/power"), None)
            await ws.send(
                json.dumps(
                    {"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channel["id"]}]}
                )
            )
            values = []
            while len(values) < 5:
                data = await asyncio.wait_for(ws.recv(), 20)
                if isinstance(data, bytes) and data[0] == 0x01:
                    sub_id, _stamp = struct.unpack_from("<IQ", data, 1)
                    assert sub_id == 7
                    values.append(data[13:])
            return channel, values

    channel, payloads = asyncio.run(receive())
    assert channel["encoding"] == "cdr" and channel["schemaName"] == "std_msgs/msg/Float32"
    schema = Schema(id=1, name=channel["schemaName"], encoding="ros2msg",
                    data=channel["schema"].encode())  # fmt: skip
    decode = DecoderFactory().decoder_for("cdr", schema)
    values = [decode(p).data for p in payloads]
    assert all(0.0 <= v <= 1.0 for v in values) and len(set(values)) > 1
    fox.signal(signal.SIGINT)
    assert fox.wait_exit(20) == 0, fox.output
    assert_no_traceback(fox.output)


# --- graph commands -------------------------------------------------------------------------


def test_topic_info_node_info_param_dump_load(procs, tmp_path):
    start_sim(procs, stage=3, mode="easy", lockstep=False)
    info = run_ros2("topic", "info", "/ops/delays")
    assert info.returncode == 0, info.stderr
    assert info.stdout.splitlines()[:2] == [
        "Type: std_msgs/msg/Float32MultiArray",
        "Publisher count: 1",
    ]
    # The endpoint can be seen before its node's name (_NODE_NAME_UNKNOWN_ on a busy machine):
    # ask again until the name has been discovered.
    deadline = time.monotonic() + 20
    verbose = run_ros2("topic", "info", "-v", "/ops/delays")
    while "_NODE_NAME_UNKNOWN_" in verbose.stdout and time.monotonic() < deadline:
        time.sleep(0.5)
        verbose = run_ros2("topic", "info", "-v", "/ops/delays")
    assert "Node name: ops_sim" in verbose.stdout, verbose.stdout
    assert "  Durability: TRANSIENT_LOCAL" in verbose.stdout
    node = run_ros2("node", "info", "/ops_sim")
    assert node.returncode == 0, node.stderr
    assert "    /ops/delay_cmd: std_msgs/msg/Float32MultiArray" in node.stdout
    assert "    /ops/reset: std_srvs/srv/Trigger" in node.stdout
    dump = run_ros2("param", "dump", "/ops_sim")
    assert dump.returncode == 0, dump.stderr
    import yaml

    params = yaml.safe_load(dump.stdout)["/ops_sim"]["ros__parameters"]
    assert params["stage"] == 3 and params["mode"] == "easy"
    params["rate_hz"] = 50.0
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({"/ops_sim": {"ros__parameters": params}}))
    load = run_ros2("param", "load", "/ops_sim", str(path))
    assert load.returncode == 0, load.stderr
    assert "Set parameter rate_hz successful" in load.stdout
    got = run_ros2("param", "get", "/ops_sim", "rate_hz")
    assert got.stdout == "Double value is: 50.0\n"
    again = yaml.safe_load(run_ros2("param", "dump", "/ops_sim").stdout)
    assert again["/ops_sim"]["ros__parameters"] == params  # round trip


def test_interface_show_and_pkg_executables():
    show = run_ros2("interface", "show", "std_msgs/msg/Float32MultiArray", "--no-comments")
    assert show.returncode == 0, show.stderr
    assert show.stdout.splitlines()[:3] == [
        "MultiArrayLayout  layout",
        "\tMultiArrayDimension[] dim",
        "\t\tstring label",
    ]
    srv = run_ros2("interface", "show", "std_srvs/srv/Trigger")
    assert "---" in srv.stdout.splitlines() and "bool success" in srv.stdout
    bad = run_ros2("interface", "show", "std_msgs/msg/Nope")
    assert bad.returncode == 1 and "Unknown msg type" in bad.stderr
    exes = run_ros2("pkg", "executables", "ops_sim_ros")
    assert {"ops_sim_ros sim", "ops_sim_ros monitor", "ops_sim_ros foxglove"} <= set(
        exes.stdout.splitlines()
    )


def test_bash_completion_offers_subcommands():
    script = (
        f"source {REPO}/setup.bash >/dev/null; "
        'COMP_LINE="ros2 bag "; COMP_POINT=${#COMP_LINE}; COMP_WORDS=(ros2 bag ""); '
        'COMP_CWORD=2; _python_argcomplete ros2 "" bag; echo "[${COMPREPLY[*]}]"; '
        'COMP_LINE="ros2 "; COMP_POINT=5; COMP_WORDS=(ros2 ""); COMP_CWORD=1; '
        '_python_argcomplete ros2 "" ros2; echo "[${COMPREPLY[*]}]"'
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("_ARGCOMPLETE")}
    result = subprocess.run(
        ["bash", "-c", script], capture_output=True, text=True, timeout=60, env=env
    )
    bag_line, top_line = result.stdout.splitlines()[-2:]
    assert {"record", "info", "play"} <= set(bag_line.strip("[]").split()), result.stderr
    assert {"bag", "topic", "run", "interface", "pkg"} <= {
        w.strip() for w in top_line.strip("[]").split()
    }
