"""Closed-loop speed across a network link: the simulator on host A, its clients on host B.

The hosts are two Linux network namespaces joined by a veth pair (ops_bench.hosts.TwoHosts), so
DDS between them goes over UDP on that link as between two computers; on one host the same
processes talk as on one computer (loopback, or Fast DDS's shared memory). For each placement,
one host (everything in A) and two hosts (sim in A, clients in B), the same three measurements as
`ops-bench closed-loop`, in the same run, the two placements taking turns ``--repeats``
times (so the load of other jobs falls on both alike):

1. raw rclpy round trip: a probe publishes N floats, an echo process on A republishes them;
2. command -> observation: the probe commands ``ops_sim`` (lockstep) on A and waits for
   ``ops/power``;
3. readings per second of ``ops_sim`` (lockstep, on A) + ``ops_spgd`` (from its own log).

A veth link has no cable, switch or NIC: a real Ethernet link adds its own latency (typically
tens of microseconds per hop on a quiet gigabit LAN). Needs root and `ip` (iproute2).
Prints the figures and rewrites the "Two hosts" section of docs/benchmarks.md.
Usage (after `source setup.bash`, as root): ops-bench two-hosts [--stage 5]
[--samples 1000] [--repeats 3] [--seconds 5]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np

from ops_bench import REPO
from ops_bench.docs import publish

SECTION = "## Two hosts"


def probe_main(topic: str, samples: int, stage: int) -> None:
    """Run in a namespace: round trips against whatever answers, as JSON on stdout."""
    from ops_bench.closed_loop import Probe

    probe = Probe()
    try:
        times = probe.round_trips(topic, samples, stage, np.random.default_rng(0))
    finally:
        probe.close()
    print(json.dumps({"times": times.tolist()}), flush=True)


def run_probe(host, topic: str, samples: int, stage: int) -> np.ndarray:
    """Round-trip times (s) of a probe run on ``host``."""
    cmd = [
        sys.executable,
        "-m",
        "ops_bench.two_hosts",
        "--probe",
        topic,
        "--samples",
        str(samples),
        "--stage",
        str(stage),
    ]
    done = subprocess.run(host.command(cmd), capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        raise RuntimeError(f"probe failed:\n{done.stdout}\n{done.stderr}")
    return np.asarray(json.loads(done.stdout.strip().splitlines()[-1])["times"])


def measure(pair, args, logdir: Path) -> dict:
    """Every measurement for both placements, alternating one host / two hosts ``repeats``
    times, so that the load of other jobs on the machine falls on both alike."""
    from ops_bench.closed_loop import spgd_rate, start, stop

    placements = (("one_host", pair.a), ("two_hosts", pair.b))
    res = {tag: {"raw": [], "sim": [], "spgd": []} for tag, _ in placements}
    echo = start(
        pair.a.command([sys.executable, "-m", "ops_bench.closed_loop", "--echo"]),
        logdir / "echo.log",
    )
    try:
        for _ in range(args.repeats):
            for tag, host in placements:
                res[tag]["raw"].append(run_probe(host, "delays", args.samples, args.stage))
    finally:
        stop(echo)
    sim_args = ["ros2", "run", "ops_sim_ros", "sim", "--ros-args", "-p", f"stage:={args.stage}"]
    sim_args += ["-p", "lockstep:=true", "-p", "mode:=easy", "-p", "seed:=1"]
    sim = start(pair.a.command(sim_args), logdir / "sim.log")
    try:
        for _ in range(args.repeats):
            for tag, host in placements:
                res[tag]["sim"].append(run_probe(host, "power", args.samples, args.stage))
        for r in range(args.repeats):
            for tag, host in placements:
                log = logdir / f"spgd_{tag}_{r}.log"
                spgd_args = ["ros2", "run", "ops_controller_ros", "spgd", "--ros-args"]
                spgd = start(host.command([*spgd_args, "-p", "log_period_s:=0.5"]), log)
                try:
                    res[tag]["spgd"].append(spgd_rate(log, args.seconds))
                finally:
                    stop(spgd)
                print(f"[bench] {tag}: {res[tag]['spgd'][-1]:,.0f} readings/s", flush=True)
    finally:
        stop(sim)
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stage", type=int, default=5)
    ap.add_argument("--samples", type=int, default=1000, help="round trips per probe run")
    ap.add_argument("--seconds", type=float, default=5.0, help="window of the SPGD rate count")
    ap.add_argument("--repeats", type=int, default=3, help="alternations of the two placements")
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument("--probe", choices=["delays", "power"], help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.probe:
        probe_main(args.probe, args.samples, args.stage)
        return

    from ops_bench.hosts import NetnsUnavailable, TwoHosts

    # Every process started inherits this environment (ip netns exec keeps it).
    os.environ.setdefault("ROS_DOMAIN_ID", "42")  # the namespaces see no other participant
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
    os.environ["PYTHONUNBUFFERED"] = "1"
    os.environ.pop("ROS_STATIC_PEERS", None)
    logdir = REPO / "runs" / "bench_two_hosts"
    logdir.mkdir(parents=True, exist_ok=True)
    try:
        pair = TwoHosts()
    except NetnsUnavailable as exc:
        raise SystemExit(f"[bench] cannot make two hosts here: {exc}") from None
    with pair:
        print(f"[bench] raw, sim and sim + spgd, one host / two hosts, x{args.repeats}", flush=True)
        out = measure(pair, args, logdir)
    publish(SECTION, section(args, out), write=not args.no_write)


def section(args, out: dict) -> list[str]:
    """The lines of docs/benchmarks.md's section from ``measure``'s results."""
    from ops_bench.closed_loop import stats

    load = os.getloadavg()[0]
    cpu = platform.processor() or platform.machine()
    rows = [
        ("raw rclpy round trip (probe -> echo on A -> probe)", "raw"),
        (f"command -> observation, `ops_sim` lockstep N={args.stage} on A", "sim"),
    ]
    lines = [
        SECTION,
        "",
        f"Command: `source setup.bash && ops-bench two-hosts "
        f"--stage {args.stage} --samples {args.samples} --repeats {args.repeats} --seconds "
        f"{args.seconds:g}` (as root: it makes two network namespaces "
        "joined by a veth pair; docs/deployment.md).",
        f"Machine: {cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, ROS 2 Jazzy "
        f"wheels (rmw_fastrtps_cpp), discovery range SUBNET. 1-minute load average at the end: "
        f"{load:.2f}. One host: every process in namespace A, as on one computer. Two hosts: "
        "the simulator (and echo) in A, the probe and `ops_spgd` in B, UDP over the veth link.",
        "",
        "| measurement | one host: median / p99 (us) | two hosts: median / p99 (us) | "
        "one host rate (Hz) | two hosts rate (Hz) |",
        "|---|---|---|---|---|",
    ]
    for label, key in rows:
        (m1, p1, r1), (m2, p2, r2) = (
            stats(np.concatenate(out[tag][key])) for tag in ("one_host", "two_hosts")
        )
        lines.append(
            f"| {label} | {m1:.0f} / {p1:.0f} | {m2:.0f} / {p2:.0f} | {r1:,.0f} | {r2:,.0f} |"
        )
    s1, s2 = (float(np.median(out[tag]["spgd"])) for tag in ("one_host", "two_hosts"))

    def each(tag):
        return ", ".join(f"{v:,.0f}" for v in out[tag]["spgd"])

    lines += [
        f"| closed loop `ops_sim` (lockstep, A) + `ops_spgd` (readings/s from its log; median of "
        f"{args.repeats} windows of {args.seconds:g} s) | | | {s1:,.0f} ({each('one_host')}) | "
        f"{s2:,.0f} ({each('two_hosts')}) |",
        "",
        f"Closed loop across the link: {s2:,.0f} readings/s ({s2 / 2:,.0f} SPGD iterations/s), "
        f"{s2 / s1:.0%} of the one-host rate measured in the same run (single windows move with "
        "the other jobs on the machine). Real rigs need 10-100 Hz "
        "(paper, appendix C.1). A veth link adds no cable or switch latency; on a real LAN add "
        "its round-trip time to each reading.",
        "",
    ]
    return lines


if __name__ == "__main__":
    main()
