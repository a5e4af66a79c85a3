#!/usr/bin/env python3
"""Bridge overhead per step (ROS 2 topics, lockstep) vs the in-process env, and its growth.

Starts its own simulator process (``ros2 run ops_sim_ros sim`` in lockstep, on a ROS_DOMAIN_ID and a
namespace of its own), steps ``RosOpsEnv`` ``--steps`` times with random actions (an episode reset
every 200 steps, timed separately), steps the in-process ``OpsEnv`` the same way, and reports the
per-step wall time (mean, median, p99) and the first vs the last ``--window`` steps of the bridge
run. ``--write docs/benchmarks.md`` replaces (or appends) that file's ``## Bridge`` section only.

    source setup.bash
    python scripts/bench_bridge.py --steps 100000 --window 10000 --write docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import os
import platform
import random
import re
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def sim_command(stage: int, namespace: str) -> list[str]:
    ros2 = shutil.which("ros2")
    base = (
        [ros2, "run", "ops_sim_ros", "sim"]
        if ros2
        else [str(REPO / "install/ops_sim_ros/lib/ops_sim_ros/sim")]
    )
    return [
        *base,
        "--ros-args",
        "-p",
        f"stage:={stage}",
        "-p",
        "mode:=easy",
        "-p",
        "lockstep:=true",
        "-p",
        "seed:=1",
        "-r",
        f"__ns:={namespace}",
    ]


def stats(t: np.ndarray) -> dict[str, float]:
    return {
        "mean_ms": 1e3 * t.mean(),
        "median_ms": 1e3 * np.median(t),
        "p99_ms": 1e3 * np.percentile(t, 99),
        "max_ms": 1e3 * t.max(),
    }


def run_env(env, steps: int, episode: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, size=(min(steps, 10000), env.action_space.shape[0]))
    actions = actions.astype(np.float32)
    step_t = np.empty(steps)
    reset_t = []
    t = time.perf_counter()
    env.reset(seed=seed)
    reset_t.append(time.perf_counter() - t)
    for i in range(steps):
        t = time.perf_counter()
        env.step(actions[i % len(actions)])
        step_t[i] = time.perf_counter() - t
        if (i + 1) % episode == 0:
            t = time.perf_counter()
            env.reset()
            reset_t.append(time.perf_counter() - t)
    return step_t, np.asarray(reset_t)


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=100_000)
    p.add_argument("--window", type=int, default=10_000)
    p.add_argument("--inprocess-steps", type=int, default=20_000)
    p.add_argument("--stage", type=int, default=3)
    p.add_argument("--write", help="markdown file whose '## Bridge' section to replace")
    args = p.parse_args()
    if args.steps < 2 * args.window:
        p.error("--steps must be at least twice --window")

    from ops_gym_bridge.bridge_env import RosOpsEnv

    from ops_sim_ros import OpsEnv

    ref = OpsEnv(stage=args.stage, mode="easy")
    in_t, in_reset = run_env(ref, args.inprocess_steps, 200, seed=1)

    domain = random.Random(os.getpid()).randint(150, 230)
    env_vars = {
        **os.environ,
        "ROS_DOMAIN_ID": str(domain),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    }
    os.environ.update({k: env_vars[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    sim = subprocess.Popen(
        sim_command(args.stage, "/bench"),
        env=env_vars,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )
    load_before = os.getloadavg()
    try:
        env = RosOpsEnv(stage=args.stage, mode="easy", namespace="/bench", timeout_s=30.0)
        rss0 = rss_mb()
        t0 = time.monotonic()
        br_t, br_reset = run_env(env, args.steps, 200, seed=1)
        wall = time.monotonic() - t0
        rss1 = rss_mb()
        env.close()
    finally:
        os.killpg(sim.pid, signal.SIGINT)
        try:
            sim.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(sim.pid, signal.SIGKILL)
    load_after = os.getloadavg()

    w = args.window
    first, last = stats(br_t[:w]), stats(br_t[-w:])
    bridge, inproc = stats(br_t), stats(in_t)
    growth = last["mean_ms"] / first["mean_ms"]
    cmd = "python scripts/bench_bridge.py " + " ".join(sys.argv[1:])
    lines = [
        "## Bridge",
        "",
        f"Per-step wall time of `ops_gym_bridge`'s `RosOpsEnv` (a Gymnasium `step` = publish the "
        f"set-points, wait for the simulator's four lockstep outputs) against a real `ops_sim` "
        f"process, beside the in-process `OpsEnv`; stage {args.stage}, easy mode, random actions, "
        f"a reset every 200 steps (timed separately). Measured with `{cmd}` "
        f"(after `source setup.bash`) on {platform.machine()} with {os.cpu_count()} cores, "
        f"Python {platform.python_version()}; machine load average {load_before[0]:.1f} before, "
        f"{load_after[0]:.1f} after (the machine is shared, so absolute times vary).",
        "",
        "| env | steps | mean | median | p99 | max |",
        "|---|---|---|---|---|---|",
        f"| in-process `OpsEnv` | {args.inprocess_steps} | {inproc['mean_ms']:.3f} ms | "
        f"{inproc['median_ms']:.3f} ms | {inproc['p99_ms']:.3f} ms | {inproc['max_ms']:.1f} ms |",
        f"| bridge `RosOpsEnv` (all) | {args.steps} | {bridge['mean_ms']:.3f} ms | "
        f"{bridge['median_ms']:.3f} ms | {bridge['p99_ms']:.3f} ms | {bridge['max_ms']:.1f} ms |",
        f"| bridge, first {w} steps | {w} | {first['mean_ms']:.3f} ms | "
        f"{first['median_ms']:.3f} ms | {first['p99_ms']:.3f} ms | {first['max_ms']:.1f} ms |",
        f"| bridge, last {w} steps | {w} | {last['mean_ms']:.3f} ms | "
        f"{last['median_ms']:.3f} ms | {last['p99_ms']:.3f} ms | {last['max_ms']:.1f} ms |",
        "",
        f"- Overhead of the bridge per step (mean): {bridge['mean_ms'] - inproc['mean_ms']:.3f} ms"
        f" ({bridge['mean_ms'] / inproc['mean_ms']:.0f}x the in-process step); "
        f"{args.steps} bridge steps took {wall:.0f} s ({args.steps / wall:.0f} steps/s).",
        f"- Growth: mean step time of the last {w} steps / first {w} steps = {growth:.3f} "
        f"(median {last['median_ms'] / first['median_ms']:.3f}); "
        f"{'no growth' if growth < 1.2 else 'GROWTH'} over {args.steps // 200} episodes.",
        f"- Mean step time per {w}-step window, in order: "
        + ", ".join(f"{1e3 * br_t[i : i + w].mean():.2f}" for i in range(0, len(br_t) - w + 1, w))
        + " ms (no trend means no creep; single windows move with the machine's load).",
        f"- Resets (service call + four outputs): mean {1e3 * br_reset.mean():.2f} ms over "
        f"{br_reset.size} resets (first one, with discovery: {1e3 * br_reset[0]:.0f} ms); "
        f"in-process {1e3 * in_reset.mean():.3f} ms.",
        f"- Peak RSS of the benchmark process: {rss0:.0f} MB before the bridge run, "
        f"{rss1:.0f} MB after.",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    if args.write:
        path = Path(args.write)
        old = path.read_text() if path.exists() else ""
        rx = re.compile(r"^## Bridge\n.*?(?=^## |\Z)", re.S | re.M)
        if rx.search(old):
            new = rx.sub(lambda _m: text + "\n", old, count=1)
        else:
            new = old.rstrip("\n") + ("\n\n" if old else "") + text
        path.write_text(new)
        print(f"[bench_bridge] wrote the '## Bridge' section of {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
