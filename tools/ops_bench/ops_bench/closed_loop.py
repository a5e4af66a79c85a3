"""Closed-loop speed over DDS: simulator + controller at N = 5, against the transport's own limit.

Three measurements in one run, each with its own processes (started with `ros2 run` as a user
would, except the raw echo, which is this script in ``--echo`` mode):

1. raw rclpy round trip: a probe publishes a Float32MultiArray of N values, an echo process
   republishes it, the probe waits for it (median, p99, and the rate 1 / median);
2. command -> observation latency: the probe sends delay commands to ``ops_sim`` in lockstep and
   waits for that step's ``ops/power`` (all four outputs are published per step);
3. control rate of sim (lockstep) + ``ops_spgd``: readings per second the SPGD node turns into new
   commands, from its own progress log (two readings per SPGD iteration) over a fixed window, with
   no other subscriber on the simulator's topics.

Prints the figures and rewrites the "Closed loop over DDS" section of docs/benchmarks.md.
Usage (after `source setup.bash`): ops-bench closed-loop [--stage 5] [--samples 2000]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ops_bench import REPO
from ops_bench.docs import publish

SECTION = "## Closed loop over DDS"


def echo_main():
    """Republish every ops/delay_cmd on ops/delays, nothing else (the raw transport)."""
    from ops_contract.ros_interface import QOS_RELIABLE, TOPIC_DELAY_CMD, TOPIC_DELAYS, run_node
    from rclpy.node import Node
    from std_msgs.msg import Float32MultiArray

    class Echo(Node):
        def __init__(self):
            super().__init__("bench_echo")
            pub = self.create_publisher(Float32MultiArray, TOPIC_DELAYS, QOS_RELIABLE)
            self.create_subscription(Float32MultiArray, TOPIC_DELAY_CMD, pub.publish, QOS_RELIABLE)

    raise SystemExit(run_node(Echo))


class Probe:
    """The measuring side: a node in this process, spun by hand for the lowest overhead."""

    def __init__(self):
        import rclpy
        from ops_contract.ros_interface import QOS_RELIABLE
        from std_msgs.msg import Float32, Float32MultiArray

        self.rclpy = rclpy
        rclpy.init(args=[])  # not this tool's argv: NAME:=VALUE there is for the nodes
        self.node = rclpy.create_node("bench_probe")
        self.pub = self.node.create_publisher(Float32MultiArray, "ops/delay_cmd", QOS_RELIABLE)
        self.got = {"delays": 0, "power": 0}
        self.node.create_subscription(
            Float32MultiArray, "ops/delays", lambda m: self._count("delays"), QOS_RELIABLE
        )
        self.node.create_subscription(
            Float32, "ops/power", lambda m: self._count("power"), QOS_RELIABLE
        )
        self.Float32MultiArray = Float32MultiArray

    def _count(self, name):
        self.got[name] += 1

    def spin_until(self, cond, timeout):
        deadline = time.perf_counter() + timeout
        while not cond():
            if time.perf_counter() > deadline:
                raise TimeoutError("no answer")
            self.rclpy.spin_once(self.node, timeout_sec=0.01)

    def wait_for_peer(self, stage, timeout=30.0):
        self.spin_until(lambda: self.pub.get_subscription_count() > 0, timeout)
        # Discovery of our subscriptions by the peer is not visible here: ping until answered.
        deadline = time.perf_counter() + timeout
        while True:
            n = self.got["delays"]
            self.pub.publish(self.Float32MultiArray(data=[0.0] * stage))
            try:
                self.spin_until(lambda n=n: self.got["delays"] > n, 0.5)
                return
            except TimeoutError:
                if time.perf_counter() > deadline:
                    raise

    def round_trips(self, topic, samples, stage, rng):
        self.wait_for_peer(stage)
        times = []
        for _ in range(samples):
            n = self.got[topic]
            msg = self.Float32MultiArray(data=rng.uniform(-1, 1, stage).astype(float).tolist())
            t0 = time.perf_counter()
            self.pub.publish(msg)
            self.spin_until(lambda n=n: self.got[topic] > n, 5.0)
            times.append(time.perf_counter() - t0)
        return np.asarray(times)

    def close(self):
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def spgd_rate(log_path: Path, seconds: float) -> float:
    """Readings per second from the SPGD node's progress lines over ``seconds``."""
    line = re.compile(r"\[(\d+\.\d+)\] \[ops_spgd\]: iteration (\d+)[^:\n]*:")  # ", N restarts"

    def points():
        return [(float(t), int(i)) for t, i in line.findall(log_path.read_text(errors="replace"))]

    deadline = time.monotonic() + 60
    while len(points()) < 2:  # the loop is closed and logging
        if time.monotonic() > deadline:
            raise TimeoutError(f"no SPGD progress in {log_path}")
        time.sleep(0.2)
    time.sleep(seconds)
    pts = points()[1:]
    (t0, i0), (t1, i1) = pts[0], pts[-1]
    return 2.0 * (i1 - i0) / (t1 - t0)


def start(args, log_path: Path):
    with open(log_path, "wb") as log:
        return subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def group_cpu_s(sid: int) -> float:
    """CPU seconds (user and system) used so far by the live processes of session ``sid`` (a
    process :func:`start` made leads its own; ``ros2 run`` puts the node in a process group of
    its own within it): Linux's /proc."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # (exited meanwhile)
        if int(fields[3]) == sid:  # fields after the name: state, ppid, pgrp, session, ...
            total += int(fields[11]) + int(fields[12])  # utime, stime
    return total / tick


def machine_times() -> tuple[int, int]:
    """(steal, all) of the machine's CPU time so far, in ticks (/proc/stat's first line): the
    share of steal over a window is the time a virtual machine's cores waited for the host,
    which a loop of a few ms feels as late wake-ups whatever its own load."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    ticks = [int(f) for f in fields[:8]]  # user nice system idle iowait irq softirq steal
    return (ticks[7] if len(ticks) > 7 else 0), sum(ticks)


def steal_share(before: tuple[int, int], after: tuple[int, int]) -> float:
    """The share of the machine's CPU time stolen by its host between two machine_times()."""
    return (after[0] - before[0]) / max(after[1] - before[1], 1)


def stop(proc):
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)


def stop_all(procs) -> None:
    """Stop ``procs``, the last started first."""
    for proc in reversed(procs):
        stop(proc)


def local_dds(name: str) -> Path:
    """DDS kept on this machine, on a domain of the run's own unless ROS_DOMAIN_ID is set; the
    run's log folder runs/NAME (made)."""
    os.environ.setdefault("ROS_DOMAIN_ID", str(60 + os.getpid() % 30))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    logdir = REPO / "runs" / name
    logdir.mkdir(parents=True, exist_ok=True)
    return logdir


@contextlib.contextmanager
def power_node(name: str):
    """An rclpy node (rclpy initialised) that records every ops/power reading: yields
    ``(node, readings)``, the list growing as the node spins; destroyed on leaving."""
    import rclpy
    from ops_contract.ros_interface import QOS_RELIABLE, TOPIC_POWER
    from std_msgs.msg import Float32

    node = rclpy.create_node(name)
    power: list[float] = []
    node.create_subscription(Float32, TOPIC_POWER, lambda m: power.append(m.data), QOS_RELIABLE)
    try:
        yield node, power
    finally:
        node.destroy_node()


def stats(times):
    med, p99 = np.median(times), np.percentile(times, 99)
    return med * 1e6, p99 * 1e6, 1.0 / med


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stage", type=int, default=5)
    ap.add_argument("--samples", type=int, default=2000, help="round trips per measurement")
    ap.add_argument("--seconds", type=float, default=10.0, help="window of the SPGD rate count")
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument("--echo", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.echo:
        echo_main()
    logdir = local_dds("bench_closed_loop")
    publish(SECTION, section(args, measure(args, logdir)), write=not args.no_write)


def measure(args, logdir: Path) -> dict:
    """The three measurements, each with processes of its own (logs in ``logdir``)."""
    rng = np.random.default_rng(0)
    probe = Probe()
    results = {}
    procs = []
    try:
        print(f"[bench] 1/3 raw rclpy round trip ({args.samples} samples)", flush=True)
        echo = start([sys.executable, "-m", "ops_bench.closed_loop", "--echo"], logdir / "echo.log")
        procs.append(echo)
        results["raw"] = stats(probe.round_trips("delays", args.samples, args.stage, rng))
        stop(echo)

        print(
            f"[bench] 2/3 command -> observation latency, sim lockstep N={args.stage}", flush=True
        )
        sim_cmd = [
            "ros2",
            "run",
            "ops_sim_ros",
            "sim",
            "--ros-args",
            "-p",
            f"stage:={args.stage}",
            "-p",
            "lockstep:=true",
            "-p",
            "mode:=easy",
            "-p",
            "seed:=1",
        ]
        sim = start(sim_cmd, logdir / "sim.log")
        procs.append(sim)
        results["sim"] = stats(probe.round_trips("power", args.samples, args.stage, rng))

        print(
            f"[bench] 3/3 sim (lockstep) + ops_spgd control rate over {args.seconds} s", flush=True
        )
        probe.close()  # no extra subscriber on the loop being measured
        probe = None
        spgd = start(
            ["ros2", "run", "ops_controller_ros", "spgd", "--ros-args", "-p", "log_period_s:=0.5"],
            logdir / "spgd.log",
        )
        procs.append(spgd)
        results["spgd_rate"] = spgd_rate(logdir / "spgd.log", args.seconds)
    finally:
        stop_all(procs)
        if probe is not None:
            probe.close()
    return results


def section(args, results: dict) -> list[str]:
    """The lines of docs/benchmarks.md's section from ``measure``'s results."""
    raw_med, raw_p99, raw_rate = results["raw"]
    sim_med, sim_p99, sim_rate = results["sim"]
    rate = results["spgd_rate"]
    load = os.getloadavg()[0]
    cpu = platform.processor() or platform.machine()
    lines = [
        SECTION,
        "",
        f"Command: `source setup.bash && ops-bench closed-loop --stage {args.stage}"
        f" --samples {args.samples}`.",
        f"Machine: {cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, ROS 2 Jazzy "
        f"wheels (rmw_fastrtps_cpp). 1-minute load average at the end: {load:.2f}.",
        "",
        "| measurement | median (us) | p99 (us) | rate (1/median or counted, Hz) |",
        "|---|---|---|---|",
        f"| raw rclpy round trip (publish -> echo process -> back) | {raw_med:.0f} | "
        f"{raw_p99:.0f} | {raw_rate:,.0f} |",
        f"| command -> observation, `ops_sim` lockstep N={args.stage} | {sim_med:.0f} | "
        f"{sim_p99:.0f} | {sim_rate:,.0f} |",
        f"| closed loop `ops_sim` (lockstep) + `ops_spgd` (from its log: 2 readings per "
        f"iteration) | | | {rate:,.0f} |",
        "",
        f"Closed loop vs raw round-trip rate: {rate / raw_rate:.0%} (goal >= 60 %, and >= 1 kHz: "
        f"{'met' if rate >= 1000 and rate >= 0.6 * raw_rate else 'not met'}). Real rigs run at "
        "10-100 Hz (paper, appendix C.1).",
        "",
    ]
    return lines


if __name__ == "__main__":
    main()
