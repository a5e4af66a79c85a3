"""Each controller through a fault schedule on a lossy link: lock fraction per condition.

The simulator runs on host A, the controller on host B; the hosts are two network namespaces
joined through ops_bench.relay (ops_bench.hosts.RelayedHosts), which drops frames and
cuts the link as the schedule says (this kernel has no netem). A recorder on host A (next to the
simulator, so it loses nothing) notes every ``ops/power`` reading with its time. After the
controller has settled on a clean link, each phase lasts ``--phase-s`` seconds:

- clean, 5 % and 20 % frame loss each way;
- an outage of 1 s and one of 30 s (the link drops everything), then ``--phase-s`` seconds on a
  clean link: the lock fraction of that window and the time from the link's return to the first
  reading >= 0.95 (``recovery``);
- CPU load: ``--load`` busy processes on the machine (2 cores here), clean link;
- a flood: ``--flood-rate`` rejected commands per second (one delay too few) published on
  ``ops/delay_cmd`` on host A for the whole phase; the simulator's steps/s are in the table;
- viewers: ``--viewers`` subscribers of the trace (``ros2 topic echo /ops/intensity``, output
  discarded) and the Foxglove bridge with ``--ws-clients`` WebSocket clients subscribed to every
  channel, all on host A.

The lock fraction is the share of the simulator's readings with P_N/P_max >= 0.95 in the
phase. Prints the table and rewrites the "Faults" section of docs/benchmarks.md. Needs root and
`ip` (iproute2). Usage (after `source setup.bash`, as root):
ops-bench faults [--controllers tracker spgd policy] [--stage 5] [--mode hard]
[--phase-s 30] [--settle-s 30] [--phases clean loss5 loss20 outage1 outage30 load flood viewers]
[--section '## Faults']
"""

from __future__ import annotations

import argparse
import contextlib
import platform
import re
import shlex
import sys
import tempfile
import time
from pathlib import Path

from ops_bench import REPO
from ops_bench.docs import write_section
from ops_bench.hosts import RelayedHosts, netns_unavailable_reason
from ops_bench.processes import (
    ProcessGroup,
    busy_processes,
    executable,
    ros2_command,
    sim_command,
)

SECTION = "## Faults"
THRESHOLD = 0.95


def record_main() -> None:
    """Run on host A: print 'wall-time power' for every ops/power reading."""
    import rclpy
    from ops_contract.ros_interface import QOS_RELIABLE, TOPIC_POWER
    from std_msgs.msg import Float32

    rclpy.init(args=[])  # not this tool's argv: NAME:=VALUE there is for the nodes
    node = rclpy.create_node("fault_recorder")
    node.create_subscription(
        Float32,
        TOPIC_POWER,
        lambda m: print(f"{time.time():.4f} {m.data:.5f}", flush=True),
        QOS_RELIABLE,
    )
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def flood_main(rate: float, seconds: float, stage: int) -> None:
    """Run on host A: publish rejected delay commands (one delay too few) at ``rate`` per s."""
    import rclpy
    from ops_contract.ros_interface import QOS_RELIABLE, TOPIC_DELAY_CMD
    from std_msgs.msg import Float32MultiArray

    rclpy.init(args=[])  # not this tool's argv: NAME:=VALUE there is for the nodes
    node = rclpy.create_node("fault_flooder")
    pub = node.create_publisher(Float32MultiArray, TOPIC_DELAY_CMD, QOS_RELIABLE)
    msg = Float32MultiArray(data=[0.0] * max(stage - 1, 2))
    time.sleep(1.0)  # discovery
    sent, t0 = 0, time.monotonic()
    while (now := time.monotonic()) - t0 < seconds:
        due = min(int((now - t0) * rate), sent + 1000)
        while sent < due:
            pub.publish(msg)
            sent += 1
    print(f"flood: {sent} messages in {seconds:g} s ({sent / seconds:.0f}/s)", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


def ws_clients_main(port: int, clients: int) -> None:
    """Run on host A: ``clients`` Foxglove WebSocket clients, each subscribed to every channel."""
    import asyncio
    import json

    import websockets
    import websockets.exceptions  # not loaded by `import websockets` alone (lazy imports)

    async def client(k: int) -> None:
        async with websockets.connect(
            f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], max_size=None
        ) as ws:
            subscribed = set()
            while True:
                data = await ws.recv()
                if isinstance(data, str):
                    msg = json.loads(data)
                    if msg.get("op") == "advertise":
                        new = [c["id"] for c in msg["channels"] if c["id"] not in subscribed]
                        subs = [{"id": 1000 * k + c, "channelId": c} for c in new]
                        subscribed.update(new)
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def run_all() -> None:
        # Until the bridge stops (the phase is over).
        with contextlib.suppress(websockets.exceptions.ConnectionClosed):
            await asyncio.gather(*(client(k) for k in range(clients)))

    with contextlib.suppress(KeyboardInterrupt):  # stopped at the end of its phase
        asyncio.run(run_all())


def readings(proc, t0: float, t1: float) -> list[tuple[float, float]]:
    out = []
    for line in proc.output.splitlines():
        parts = line.split()
        if len(parts) == 2:
            try:
                t, p = float(parts[0]), float(parts[1])
            except ValueError:
                continue
            if t0 <= t < t1:
                out.append((t, p))
    return out


def lock_fraction(rows) -> float:
    return sum(p >= THRESHOLD for _, p in rows) / len(rows) if rows else float("nan")


def controller_args(name: str, model: str) -> list[str]:
    args = [*executable("ops_controller_ros", name), "--ros-args", "-p", "seed:=1"]
    if name == "policy":
        args += ["-p", f"model:={model}"]
    return args


#: This module run for one of its helper modes (--record, --ws-clients, --flood).
SELF = [sys.executable, "-m", "ops_bench.faults"]


class Schedule:
    """One controller's fault phases on ``hosts``: each phase sets the link's conditions (or
    load, a flood, viewers), then counts the readings ``rec`` recorded in its window."""

    def __init__(self, name: str, args, hosts, group, rec):
        self.name, self.args, self.hosts, self.group, self.rec = name, args, hosts, group, rec
        self.env = hosts.env()
        self.results: dict = {}
        self.stopped: list = []  # the phases' own processes (viewers, flooders), stopped by them

    def start(self, cmd, name: str):
        return self.hosts.a.start(self.group, cmd, name=name, env=self.env)

    def start_viewers(self) -> list:
        args = self.args
        echo = [*ros2_command(), "topic", "echo", "/ops/intensity"]
        viewers = [self.start(echo, f"echo{k}") for k in range(args.viewers)]
        if args.ws_clients:
            fox = self.start(
                [*executable("ops_sim_ros", "foxglove"), "--ros-args", "-p", "port:=0"], "foxglove"
            )
            port = fox.wait_for(r"ws://127\.0\.0\.1:(\d+)", timeout=60).group(1)
            fox.wait_for("serving /ops/intensity", timeout=60)
            ws = [*SELF, "--ws-clients", str(args.ws_clients), "--port", port]
            viewers += [fox, self.start(ws, "ws_clients")]
        return viewers

    def phase(self, label, loss=0.0, down_s=0.0, load=0, flood=0.0, viewers=False) -> None:
        args, hosts = self.args, self.hosts
        extra = []
        if down_s:
            hosts.set(down=True)
            time.sleep(down_s)
        hosts.set(loss=loss)
        if viewers:
            extra = self.start_viewers()
            time.sleep(5.0)  # subscribed and streaming before the window opens
        if flood:
            cmd = [*SELF, "--flood", str(flood)]
            cmd += ["--seconds", str(args.phase_s + 1.0), "--stage", str(args.stage)]
            extra.append(self.start(cmd, "flood"))
            time.sleep(1.0)  # its discovery
        t0 = time.time()
        with busy_processes(load):
            time.sleep(args.phase_s)
        rows = readings(self.rec, t0, time.time())
        row = {"fraction": lock_fraction(rows), "readings": len(rows)}
        row["steps_per_s"] = len(rows) / max(time.time() - t0, 1e-9)
        if flood:
            sent = re.search(r"\((\d+)/s\)", extra[-1].wait_for(r"flood: .*", 30)[0])
            row["flood_per_s"] = int(sent.group(1))
        for proc in reversed(extra):  # clients before the servers they use
            proc.stop()
            self.stopped.append(proc)
        if down_s:
            locked = [t for t, p in rows if p >= THRESHOLD]
            row["recovery_s"] = locked[0] - t0 if locked else float("inf")
        self.results[label] = row
        print(f"[{self.name}] {label}: {row}", flush=True)

    def run(self, phases) -> dict:
        args, phase = self.args, self.phase
        table = {
            "clean": lambda: phase("clean"),
            "loss5": lambda: phase("loss 5 %", loss=0.05),
            "loss20": lambda: phase("loss 20 %", loss=0.20),
            "outage1": lambda: phase("outage 1 s", down_s=1.0),
            "outage30": lambda: phase("outage 30 s", down_s=30.0),
            "load": lambda: phase(f"load ({args.load} busy processes)", load=args.load),
            "flood": lambda: phase(
                f"flood of {args.flood_rate:g} rejected commands/s", flood=args.flood_rate
            ),
            "viewers": lambda: phase(
                f"{args.viewers} trace subscribers + {args.ws_clients} Foxglove clients",
                viewers=True,
            ),
        }
        for name in phases:
            table[name]()
        for proc in self.group.started:  # an exit the schedule did not ask for
            if proc not in self.stopped and proc.popen.poll() is not None:
                self.results["exited"] = f"{proc.args[-1]} exited ({proc.popen.returncode})"
        return self.results


def run_controller(name: str, args, tmp: Path) -> dict:
    with RelayedHosts(tmp, seed=1, relay_nice=args.nice) as hosts:
        group = ProcessGroup(tmp)
        try:
            env = hosts.env()
            sim = sim_command(
                f"stage:={args.stage}", f"mode:={args.mode}", "seed:=11", "rate_hz:=100.0"
            )
            # --nice: the loop's processes (simulator and controller) get that priority, and so
            # does the relay: it stands in for the network, which takes no CPU of the hosts
            # (with the relay at normal priority, a niced loop starved it).
            prio = ["nice", "-n", str(args.nice)] if args.nice else []
            hosts.a.start(group, [*prio, *sim], name="sim", env=env).wait_for("stage=", 120)
            rec = hosts.a.start(group, [*SELF, "--record"], name="rec", env=env)
            ctrl_args = [*prio, *controller_args(name, args.model)]
            ctrl = hosts.b.start(group, ctrl_args, name=name, env=env)
            ctrl.wait_for("simulator found", timeout=180)
            time.sleep(args.settle_s)  # the controller acquires on a clean link (not measured)
            return Schedule(name, args, hosts, group, rec).run(args.phases)
        finally:
            group.stop_all()


def table(all_results: dict) -> str:
    labels = list(next(iter(all_results.values())).keys())
    labels = [x for x in labels if x != "exited"]
    head = "| condition | " + " | ".join(all_results) + " |"
    lines = [head, "|---" * (len(all_results) + 1) + "|"]
    for label in labels:
        cells = []
        for res in all_results.values():
            row = res.get(label)
            if row is None:
                cells.append("–")
                continue
            cell = f"{row['fraction']:.3f} ({row['readings']}, {row['steps_per_s']:.0f} steps/s)"
            if "flood_per_s" in row:
                cell += f", {row['flood_per_s']} commands/s sent"
            if "recovery_s" in row:
                cell += f", back in {row['recovery_s']:.1f} s"
            cells.append(cell)
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--flood", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--seconds", type=float, default=10.0, help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    parser.add_argument(
        "--phases",
        nargs="+",
        default=["clean", "loss5", "loss20", "outage1", "outage30", "load"],
        choices=["clean", "loss5", "loss20", "outage1", "outage30", "load", "flood", "viewers"],
    )
    parser.add_argument("--flood-rate", type=float, default=30000.0, help="commands/s")
    parser.add_argument("--viewers", type=int, default=10, help="trace subscribers")
    parser.add_argument("--ws-clients", type=int, default=5, help="Foxglove WebSocket clients")
    parser.add_argument("--section", default=SECTION, help="section of docs/benchmarks.md")
    parser.add_argument(
        "--nice",
        type=int,
        default=0,
        help="niceness of the simulator, the controller and the relay (the network)",
    )
    parser.add_argument("--controllers", nargs="+", default=["tracker", "spgd", "policy"])
    parser.add_argument("--stage", type=int, default=5)
    parser.add_argument("--mode", default="hard")
    parser.add_argument("--model", default=str(REPO / "models" / "n5_hard"))
    parser.add_argument("--phase-s", type=float, default=30.0)
    parser.add_argument("--settle-s", type=float, default=30.0)
    parser.add_argument("--load", type=int, default=2, help="busy processes of the load phase")
    parser.add_argument("--no-docs", action="store_true", help="do not rewrite docs/benchmarks.md")
    parser.add_argument(
        "--logs", default="/tmp/bench_faults", help="each run's process logs go under this folder"
    )
    args = parser.parse_args(argv)
    if args.record:
        record_main()
        return 0
    if args.flood is not None:
        flood_main(args.flood, args.seconds, args.stage)
        return 0
    if args.port is not None:
        ws_clients_main(args.port, args.ws_clients)
        return 0
    reason = netns_unavailable_reason()
    if reason:
        print(f"bench_faults: {reason}", file=sys.stderr)
        return 1
    all_results = {}
    Path(args.logs).mkdir(parents=True, exist_ok=True)
    for name in args.controllers:
        logs = Path(tempfile.mkdtemp(prefix=f"{name}_", dir=args.logs))
        all_results[name] = run_controller(name, args, logs)
        print(f"[{name}] logs in {logs}", flush=True)
    text = table(all_results)
    cmd = "ops-bench faults " + shlex.join(a for a in sys.argv[1:] if not re.match(r"--no-docs", a))
    exits = [f"{n}: {r['exited']}" for n, r in all_results.items() if "exited" in r]
    section = (
        f"{args.section}\n\nLock fraction (share of the simulator's readings with P_N/P_max >= "
        f"{THRESHOLD}, readings and the simulator's steps/s in brackets) of each controller on "
        f"host B driving a stage {args.stage} {args.mode} simulator on host A through "
        "ops_bench.relay, "
        f"{args.phase_s:g} s per condition after {args.settle_s:g} s on a clean link; after an "
        "outage, the window starts when the link returns and `back in` is the time to the "
        f"first reading >= {THRESHOLD}. Command: `{cmd.strip()}` "
        f"({platform.node()}, {time.strftime('%Y-%m-%d')}, one run; the machine's other jobs "
        "load it too).\n\n"
        + text
        + "\n\n"
        + ("Exited: " + "; ".join(exits) if exits else "No process exited.")
        + "\n"
    )
    print(section)
    if not args.no_docs:
        write_section(args.section, section)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
