"""Bridge overhead per step (ROS 2 topics, lockstep) vs the in-process env, and its growth.

Starts its own simulator process (``ros2 run ops_sim_ros sim`` in lockstep, on a ROS_DOMAIN_ID and a
namespace of its own), steps ``RosOpsEnv`` ``--steps`` times with random actions (an episode reset
every 200 steps, timed separately), steps the in-process ``OpsEnv`` the same way, and reports the
per-step wall time (mean, median, p99) and the first vs the last ``--window`` steps of the bridge
run. ``--write docs/benchmarks.md`` replaces (or appends) that file's ``## Bridge`` section only.

    source setup.bash
    ops-bench bridge --steps 100000 --window 10000 --write docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import os
import platform
import random
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ops_bench import REPO
from ops_bench.docs import write_section


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


def measure(args) -> dict:
    """Step and reset times of the in-process env and of the bridge against a real simulator."""
    from ops_gym_bridge.bridge.bridge_env import RosOpsEnv
    from ops_sim_ros import OpsEnv

    m = {}
    ref = OpsEnv(stage=args.stage, mode="easy")
    m["in_t"], m["in_reset"] = run_env(ref, args.inprocess_steps, 200, seed=1)

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
    m["load_before"] = os.getloadavg()
    try:
        env = RosOpsEnv(stage=args.stage, mode="easy", namespace="/bench", timeout_s=30.0)
        m["rss0"] = rss_mb()
        t0 = time.monotonic()
        m["br_t"], m["br_reset"] = run_env(env, args.steps, 200, seed=1)
        m["wall"] = time.monotonic() - t0
        m["rss1"] = rss_mb()
        env.close()
    finally:
        os.killpg(sim.pid, signal.SIGINT)
        try:
            sim.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(sim.pid, signal.SIGKILL)
    m["load_after"] = os.getloadavg()
    return m


def section(args, m: dict) -> str:
    """The '## Bridge' section of docs/benchmarks.md from the measurements ``m``."""
    br_t, in_t, br_reset, in_reset = m["br_t"], m["in_t"], m["br_reset"], m["in_reset"]
    w, wall = args.window, m["wall"]
    first, last = stats(br_t[:w]), stats(br_t[-w:])
    bridge, inproc = stats(br_t), stats(in_t)
    growth = last["mean_ms"] / first["mean_ms"]
    cmd = "ops-bench bridge " + " ".join(sys.argv[1:])
    lines = [
        "## Bridge",
        "",
        f"Per-step wall time of `ops_gym_bridge`'s `RosOpsEnv` (a Gymnasium `step` = publish the "
        f"set-points, wait for the simulator's four lockstep outputs) against a real `ops_sim` "
        f"process, beside the in-process `OpsEnv`; stage {args.stage}, easy mode, random actions, "
        f"a reset every 200 steps (timed separately). Measured with `{cmd}` "
        f"(after `source setup.bash`) on {platform.machine()} with {os.cpu_count()} cores, "
        f"Python {platform.python_version()}; machine load average {m['load_before'][0]:.1f} "
        f"before, {m['load_after'][0]:.1f} after (the machine is shared, so absolute times vary).",
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
        f"- Peak RSS of the benchmark process: {m['rss0']:.0f} MB before the bridge run, "
        f"{m['rss1']:.0f} MB after.",
        "",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=100_000)
    p.add_argument("--window", type=int, default=10_000)
    p.add_argument("--inprocess-steps", type=int, default=20_000)
    p.add_argument("--stage", type=int, default=3)
    p.add_argument("--write", help="markdown file whose '## Bridge' section to replace")
    args = p.parse_args(argv)
    if args.steps < 2 * args.window:
        p.error("--steps must be at least twice --window")
    text = section(args, measure(args))
    print(text)
    if args.write:
        write_section("## Bridge", text, Path(args.write))
    return 0


if __name__ == "__main__":
    sys.exit(main())
