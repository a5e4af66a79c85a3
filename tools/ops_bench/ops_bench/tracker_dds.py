"""The tracker's closed loop over DDS (issue 10's last goal): `ros2 run ops_sim_ros sim` (stage 5,
medium, free-running at its default rate) and `ros2 run ops_controller_ros tracker` as real
processes; per simulator seed, the seconds from starting the tracker's process until the mean
P_N / P_max of the last 10 readings of `ops/power` is >= 0.95 (process start-up included).

Usage (after `source setup.bash`):
  ops-bench tracker-dds [--seeds 5] [--write docs/tracker.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from ops_bench.closed_loop import local_dds, power_node, start, stop_all
from ops_bench.docs import write_section

SECTION = "## Closed loop over DDS: `sim` + `tracker`"


def lock_time(
    seed: int,
    logdir: Path,
    timeout: float = 60.0,
    sim_params: tuple[str, ...] = ("stage:=5", "mode:=medium"),
    controller: list[str] | None = None,
    extra: list[list[str]] = (),
) -> float:
    """Seconds from the controller's start to 0.95 over the last 10 readings (inf: not within
    ``timeout``). ``controller``: its command line (default: the tracker with ``seed``);
    ``extra``: more commands started with it (e.g. ``ros2 topic echo``), stopped with it."""
    import rclpy

    params = [a for p in (*sim_params, f"seed:={seed}") for a in ("-p", p)]
    sim_cmd = ["ros2", "run", "ops_sim_ros", "sim", "--ros-args", *params]
    procs = [start(sim_cmd, logdir / f"sim_{seed}.log")]
    controller = controller or [
        "ros2", "run", "ops_controller_ros", "tracker", "--ros-args", "-p", f"seed:={seed}"
    ]  # fmt: skip
    with power_node(f"bench_tracker_dds_{seed}") as (node, power):
        try:
            deadline = time.monotonic() + 30
            while len(power) < 20 and time.monotonic() < deadline:  # the simulator is up
                rclpy.spin_once(node, timeout_sec=0.05)
            if len(power) < 20:
                raise RuntimeError(f"no ops/power from the simulator (see {logdir})")
            t0 = time.monotonic()
            procs.append(start(controller, logdir / f"{controller[3]}_{seed}.log"))
            for k, cmd in enumerate(extra):
                procs.append(start(cmd, logdir / f"{cmd[1]}_{k}_{seed}.log"))
            power.clear()
            while time.monotonic() - t0 < timeout:
                rclpy.spin_once(node, timeout_sec=0.05)
                if len(power) >= 10 and np.mean(power[-10:]) >= 0.95:
                    return time.monotonic() - t0
            return float("inf")
        finally:
            stop_all(procs)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--write", help="markdown file whose section is replaced")
    args = ap.parse_args(argv)
    logdir = local_dds("bench_tracker_dds")
    import rclpy

    rclpy.init(args=[])  # not this tool's argv: NAME:=VALUE there is for the nodes
    try:
        times = []
        for seed in range(args.seeds):
            times.append(lock_time(seed, logdir))
            print(f"[bench] seed {seed}: P_N/P_max >= 0.95 after {times[-1]:.1f} s", flush=True)
    finally:
        rclpy.shutdown()
    t = np.array(times)
    cmd = "ops-bench tracker-dds " + " ".join(sys.argv[1:])
    text = (
        f"{SECTION}\n\nCommand: `{cmd.strip()}` (simulator stage 5, medium, free-running at "
        "100 Hz; seconds from starting the tracker's process, its start-up included, until "
        "the mean "
        "P_N / P_max of the last 10 readings is >= 0.95; goal: within 10 s).\n\n"
        "| simulator seed | " + " | ".join(str(s) for s in range(args.seeds)) + " |\n"
        "|---|" + "---|" * args.seeds + "\n"
        "| seconds | " + " | ".join(f"{x:.1f}" for x in t) + " |\n\n"
        f"Median {np.median(t):.1f} s, worst {t.max():.1f} s (load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at the end).\n"
    )
    print(text)
    if args.write:
        write_section(SECTION, text, Path(args.write))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
