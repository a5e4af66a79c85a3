"""Continuous operation over DDS: `ros2 run ops_sim_ros sim` (free-running) and a controller node
(`tracker`, `spgd` or `policy -p model:=DIR`) as real processes, for a given time per simulator
seed; prints the figures of `evaluate --continuous` (ops_experiments.continuous)
computed from every `ops/power` reading received: fraction >= 0.95 after the first lock, lock
losses (< 0.8), worst reading, readings to the first lock.

Usage (after `source setup.bash`):
  ops-bench continuous-dds --controller tracker --mode hard --seconds 600 \\
      --seeds 1000 [--model models/n5_hard] [--nice -5] [--param hop_every:=0]
      [--sim-param lockstep:=true] [--out x.json]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from ops_bench.closed_loop import REPO, power_node, start, stop_all


def run_once(args, seed: int, logdir: Path) -> list[float]:
    """The `ops/power` readings of one run: from the controller's start for ``args.seconds``."""
    import rclpy
    from ops_contract.ros_interface import TOPIC_POWER

    sim_cmd = ["ros2", "run", "ops_sim_ros", "sim", "--ros-args", "-p", f"stage:={args.stage}"]
    sim_cmd += ["-p", f"mode:={args.mode}", "-p", f"split:={args.split}", "-p", f"seed:={seed}"]
    if args.controller == "policy":
        ctl_cmd = ["ros2", "run", "ops_controller_ros", "policy", "--ros-args", "-p"]
        ctl_cmd += [f"model:={Path(args.model).resolve()}", "-p", f"seed:={seed}"]
    else:
        ctl_cmd = ["ros2", "run", "ops_controller_ros", args.controller, "--ros-args"]
        ctl_cmd += ["-p", f"seed:={seed}"]
    for assignment in args.param:  # the controller node's own parameters, NAME:=VALUE
        ctl_cmd += ["-p", assignment]
    for assignment in args.sim_param:  # the simulator's (e.g. lockstep:=true), NAME:=VALUE
        sim_cmd += ["-p", assignment]
    tag = f"{args.controller}_{args.mode}_{seed}"
    if args.nice:  # the loop's priority on a busy machine (a rig's controller would have it)
        prio = ["nice", "-n", str(args.nice)]
        sim_cmd, ctl_cmd = prio + sim_cmd, prio + ctl_cmd
    procs = [start(sim_cmd, logdir / f"sim_{tag}.log")]
    with power_node(f"bench_continuous_dds_{seed}") as (node, power):
        try:
            # The simulator is up once its ops/power publisher is found (a lockstep one
            # publishes nothing until the controller commands; the controller node waits for
            # its readings)
            deadline = time.monotonic() + 30
            while not node.count_publishers(TOPIC_POWER) and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.05)
            if not node.count_publishers(TOPIC_POWER):
                raise RuntimeError(f"no ops/power publisher from the simulator (see {logdir})")
            procs.append(start(ctl_cmd, logdir / f"ctl_{tag}.log"))
            power.clear()
            t0 = time.monotonic()
            while time.monotonic() - t0 < args.seconds:
                rclpy.spin_once(node, timeout_sec=0.05)
            return list(power)
        finally:
            stop_all(procs)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--controller", choices=("tracker", "spgd", "policy"), default="tracker")
    ap.add_argument("--model", help="model directory (with --controller policy)")
    ap.add_argument("--stage", type=int, default=5)
    ap.add_argument("--mode", default="hard")
    ap.add_argument("--split", default="test")
    ap.add_argument("--seconds", type=float, default=600.0, help="time per run")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1000])
    ap.add_argument("--out", help="also write the figures to this JSON file")
    ap.add_argument(
        "--param", nargs="*", default=[], help="controller node parameters, NAME:=VALUE each"
    )
    ap.add_argument(
        "--sim-param",
        nargs="*",
        default=[],
        help="simulator node parameters, NAME:=VALUE each (lockstep:=true: one step per command)",
    )
    ap.add_argument(
        "--nice",
        type=int,
        default=0,
        help="niceness of the simulator and the controller (e.g. -5: ahead of other work; "
        "below 0 needs root)",
    )
    args = ap.parse_args(argv)
    if (args.controller == "policy") != bool(args.model):
        ap.error("--model DIR goes with --controller policy (and only with it)")
    if args.seconds <= 0:
        ap.error("--seconds must be > 0")
    os.environ.setdefault("ROS_DOMAIN_ID", str(60 + os.getpid() % 30))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    import rclpy
    from ops_experiments import continuous

    logdir = REPO / "runs" / "bench_continuous_dds"
    logdir.mkdir(parents=True, exist_ok=True)
    rclpy.init(args=[])  # not this tool's argv: NAME:=VALUE there is for the nodes
    runs = []
    try:
        for seed in args.seeds:
            readings = run_once(args, seed, logdir)
            if not readings:
                raise RuntimeError(f"no readings with the controller running (see {logdir})")
            runs.append(continuous.lock_figures(readings))
            print(continuous.format_run(f"seed {seed}", runs[-1]), flush=True)
    finally:
        rclpy.shutdown()
    total = continuous.overall(runs)
    print(continuous.format_run("overall", total))
    print(
        f"({args.controller} {args.model or ''} stage {args.stage} {args.mode} {args.split}, "
        f"{args.seconds:.0f} s per run, {sum(r['readings'] for r in runs)} readings; load "
        f"average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at the end)"
    )
    if args.out:
        load = [round(v, 2) for v in os.getloadavg()]
        out = {"args": vars(args), "overall": total, "per_seed": runs, "load_average_end": load}
        Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
