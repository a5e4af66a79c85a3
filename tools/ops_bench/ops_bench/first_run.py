"""A new user's first run, as real processes over DDS (issue 18): the README's commands

    ros2 run ops_sim_ros sim --ros-args -p stage:=3      (+ -p seed:=S, to name the run)
    ros2 run ops_controller_ros spgd
    ros2 topic echo /ops/power                           (--echo intensity: /ops/intensity)

for simulator seeds S; per seed, the seconds from starting `spgd`'s process (its start-up
included) until the mean P_N / P_max of the last 10 readings of ops/power is >= 0.95. Goal: within
10 s in at least 19 of 20 seeds. The echo's output goes to a log file (runs/bench_first_run/).

Usage (after `source setup.bash`):
  ops-bench first-run [--seeds 20] [--first-seed 0] [--write docs/results/spgd/notes.md]
With --write, its section of the SPGD-PID results page's hand-kept text is replaced; then
`ops-bench results` writes the page (docs/results/spgd/index.md).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from ops_bench.closed_loop import local_dds
from ops_bench.docs import write_section
from ops_bench.results_pages import refresh_results_pages
from ops_bench.tracker_dds import lock_time

SECTION = "## SPGD-PID: the user's first run"
GOAL_S = 10.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20, help="how many simulator seeds")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--echo", choices=("power", "intensity", "none"), default="power")
    ap.add_argument(
        "--timeout", type=float, default=30.0, help="seconds before a seed counts as stalled"
    )
    ap.add_argument("--write", help="markdown file whose section is replaced")
    args = ap.parse_args(argv)
    logdir = local_dds("bench_first_run")
    import rclpy

    spgd = ["ros2", "run", "ops_controller_ros", "spgd"]
    extra = [] if args.echo == "none" else [["ros2", "topic", "echo", f"/ops/{args.echo}"]]
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    rclpy.init(args=[])  # not this tool's argv: NAME:=VALUE there is for the nodes
    try:
        times = []
        for seed in seeds:
            t = lock_time(seed, logdir, args.timeout, ("stage:=3",), spgd, extra)
            times.append(t)
            print(f"[bench] seed {seed}: P_N/P_max >= 0.95 after {t:.1f} s", flush=True)
    finally:
        rclpy.shutdown()
    t = np.array(times)
    ok = int((t <= GOAL_S).sum())
    cmd = "ops-bench first-run " + " ".join(sys.argv[1:])
    text = (
        f"{SECTION}\n\nCommand: `{cmd.strip()}`: `sim -p stage:=3` (medium mode, 100 Hz) and "
        f"`spgd` with its defaults as real processes, `ros2 topic echo /ops/{args.echo}` beside "
        "them; seconds from starting `spgd`'s process (start-up included) until the mean P_N / "
        "P_max of the last 10 readings is >= 0.95.\n\n"
        f"**{ok} of {len(seeds)} seeds within {GOAL_S:.0f} s**; median {np.median(t):.1f} s, "
        f"worst {t.max():.1f} s (simulator seeds {seeds[0]}-{seeds[-1]}; load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at the end).\n\n"
        "| simulator seed | seconds |\n|---|---|\n"
        + "".join(f"| {s} | {x:.1f} |\n" for s, x in zip(seeds, t, strict=True))
    )
    print(text)
    if args.write:
        write_section(SECTION, text, Path(args.write))
        refresh_results_pages(Path(args.write))
    return 0 if ok >= 0.95 * len(seeds) else 1


if __name__ == "__main__":
    raise SystemExit(main())
