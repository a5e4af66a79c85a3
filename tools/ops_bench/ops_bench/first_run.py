"""A first run over DDS, as real processes: the README's commands

    ros2 run ops_sim_ros sim --ros-args -p stage:=3      (+ -p seed:=S, to name the run)
    ros2 run ops_controller_ros spgd                     (--controller tracker: the tracker,
                                                          with -p seed:=S)
    ros2 topic echo /ops/power                           (--echo intensity: /ops/intensity)

for simulator seeds S; per seed, the seconds from starting the controller's process (its start-up
included) until the mean P_N / P_max of the last 10 readings of ops/power is >= 0.95. Goal: within
10 s in at least 19 of 20 seeds. The echo's output goes to a log file (runs/bench_first_run/).

Usage (after `source setup.bash`):
  ops-bench first-run [--seeds 20] [--first-seed 0] [--write docs/results/spgd/notes.md]
  ops-bench first-run --controller tracker --stage 5 --echo none --seeds 5 \\
      --write docs/results/tracker/notes.md
With --write, the controller's section of that Markdown file is replaced; a results page's
hand-kept text (docs/results/*/notes.md) also rewrites the results pages (`ops-bench results`).
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
from ops_bench.results_pages import refresh_results_pages

#: The section each controller's run writes (its title, as in the file --write names).
SECTIONS = {
    "spgd": "## SPGD-PID: the user's first run",
    "tracker": "## Closed loop over DDS: `sim` + `tracker`",
}
GOAL_S = 10.0


def controller_command(controller: str, seed: int) -> list[str]:
    """The controller's command line: SPGD with its defaults, as the README starts it; the
    tracker with the simulator's seed."""
    cmd = ["ros2", "run", "ops_controller_ros", controller]
    return cmd if controller == "spgd" else [*cmd, "--ros-args", "-p", f"seed:={seed}"]


def lock_time(
    seed: int,
    logdir: Path,
    timeout: float,
    sim_params: tuple[str, ...],
    controller: list[str],
    extra: list[list[str]] = (),
) -> float:
    """Seconds from the controller's start to 0.95 over the last 10 readings (inf: not within
    ``timeout``). ``controller``: its command line; ``extra``: more commands started with it
    (e.g. ``ros2 topic echo``), stopped with it."""
    import rclpy

    params = [a for p in (*sim_params, f"seed:={seed}") for a in ("-p", p)]
    sim_cmd = ["ros2", "run", "ops_sim_ros", "sim", "--ros-args", *params]
    procs = [start(sim_cmd, logdir / f"sim_{seed}.log")]
    with power_node(f"bench_first_run_{seed}") as (node, power):
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


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--controller", choices=tuple(SECTIONS), default="spgd")
    ap.add_argument("--stage", type=int, default=3, help="the simulator's stage count")
    ap.add_argument("--mode", default="medium", help="the simulator's noise mode")
    ap.add_argument("--seeds", type=int, default=20, help="how many simulator seeds")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--echo", choices=("power", "intensity", "none"), default="power")
    ap.add_argument(
        "--timeout", type=float, default=30.0, help="seconds before a seed counts as stalled"
    )
    ap.add_argument("--write", help="markdown file whose section is replaced")
    args = ap.parse_args(argv)
    if args.seeds < 1:
        ap.error(f"--seeds: must be >= 1 (got {args.seeds})")
    return args


def section(args, seeds: list[int], t: np.ndarray) -> str:
    ok = int((t <= GOAL_S).sum())
    cmd = "ops-bench first-run " + " ".join(sys.argv[1:])
    echo = "" if args.echo == "none" else f", `ros2 topic echo /ops/{args.echo}` beside them"
    return (
        f"{SECTIONS[args.controller]}\n\nCommand: `{cmd.strip()}`: `sim -p stage:={args.stage}` "
        f"({args.mode} mode, 100 Hz) and `{args.controller}` with its defaults as real "
        f"processes{echo}; seconds from starting `{args.controller}`'s process (start-up "
        "included) until the mean P_N / P_max of the last 10 readings is >= 0.95.\n\n"
        f"**{ok} of {len(seeds)} seeds within {GOAL_S:.0f} s**; median {np.median(t):.1f} s, "
        f"worst {t.max():.1f} s (simulator seeds {seeds[0]}-{seeds[-1]}; load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at the end).\n\n"
        "| simulator seed | seconds |\n|---|---|\n"
        + "".join(f"| {s} | {x:.1f} |\n" for s, x in zip(seeds, t, strict=True))
    )


def main(argv=None) -> int:
    args = parse_args(argv)
    logdir = local_dds("bench_first_run")
    import rclpy

    sim_params = (f"stage:={args.stage}", f"mode:={args.mode}")
    extra = [] if args.echo == "none" else [["ros2", "topic", "echo", f"/ops/{args.echo}"]]
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    rclpy.init(args=[])  # not this tool's argv: NAME:=VALUE there is for the nodes
    try:
        times = []
        for seed in seeds:
            ctl = controller_command(args.controller, seed)
            t = lock_time(seed, logdir, args.timeout, sim_params, ctl, extra)
            times.append(t)
            print(f"[bench] seed {seed}: P_N/P_max >= 0.95 after {t:.1f} s", flush=True)
    finally:
        rclpy.shutdown()
    t = np.array(times)
    text = section(args, seeds, t)
    print(text)
    if args.write:
        write_section(SECTIONS[args.controller], text, Path(args.write))
        refresh_results_pages(Path(args.write))
    return 0 if (t <= GOAL_S).sum() >= 0.95 * len(seeds) else 1


if __name__ == "__main__":
    raise SystemExit(main())
