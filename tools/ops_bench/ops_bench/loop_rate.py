"""How fast a controller node keeps up with the free-running simulator over DDS, per executor.

For each controller node (``spgd``, ``tracker``, ``policy -p model:=DIR``) and each executor
(the nodes' ``executor`` parameter, ops_contract.executors) the simulator (N = 5) runs free at
increasing ``rate_hz``, each rate with a fresh simulator and controller as real processes
(``ros2 run``). After the controller says it closes the loop and ``--settle`` seconds more, for
``--seconds``:

- readings/s: ``ops/power`` messages received by a subscriber in this process;
- missed: the share of the simulator's steps that took no new command, from its own count
  (``step`` and ``steps_without_command`` in its /diagnostics, every 0.5 s here);
- locked: the share of the readings >= 0.95 after the first one >= 0.95
  (ops_experiments.continuous.lock_figures);
- CPU per step: each process group's CPU time over the window (/proc, the DDS threads too)
  per simulator step: what bounds the rate on a machine of few cores;
- steal: the share of the machine's CPU time its host took over the window (/proc/stat). On a
  virtual machine that shares its cores, a loop of a few ms then wakes late whatever its own
  load (docs/loop_rate.md, "Over DDS").

A rate is held when readings/s reach 90 % of it (the simulator's own warning threshold), at most
1 % of the steps missed their command, and, for the tracker and the policy, at least 99 % of
the readings after the first lock are >= 0.95. A controller's sweep stops after ``--stop-after``
rates in a row not held. Prints a table and, unless --no-write, rewrites the section of
docs/benchmarks.md with the command and the machine's load (``uptime``) at start and end.

Usage (after `source setup.bash`):
  ops-bench loop-rate [--controllers spgd tracker policy] [--executors default events]
      [--rates 100 200 300 500 700 1000 1500 2000] [--seconds 10] [--model models/n5_hard_switch]
      [--time-base seconds [--vibration lab]] [--realtime-priority 50] [--busy 2]

``--realtime-priority P`` runs both nodes (and this process's subscriber) under ``SCHED_FIFO``
at P (their ``realtime_priority`` parameter, ops_contract.realtime; refused with exit 2 where
the machine does not allow it); ``--busy K`` runs K processes that keep a core busy each beside
every rate's loop, as a lab computer that does other work: together they measure what the
priority buys (docs/loop_rate.md, "Over DDS").

Under ``--time-base seconds`` a step of the simulator lasts 1 / rate_hz s (docs/physics.md,
"Physical time and vibration"): a faster loop meets less drift and walk per step, as on a
stacker; the default ``step`` applies the paper's 0.1 s of disturbance every step at any rate.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from ops_contract.config import TIME_BASES, VIBRATIONS
from ops_contract.realtime import MAX_PRIORITY, set_priority

from ops_bench.closed_loop import (
    REPO,
    group_cpu_s,
    local_dds,
    machine_times,
    power_node,
    start,
    steal_share,
    stop_all,
)
from ops_bench.docs import publish
from ops_bench.processes import busy_processes

SECTION = "## Loop rate over DDS, by executor"
CONTROLLERS = ("spgd", "tracker", "policy")
#: Each controller's simulator mode: SPGD-PID's goal is stated in medium, the others' in hard.
MODES = {"spgd": "medium", "tracker": "hard", "policy": "hard"}
RATES = (100, 200, 300, 500, 700, 1000, 1500, 2000)
MAX_MISSED = 0.01
MIN_LOCKED = 0.99
MIN_RATE_SHARE = 0.9
DIAGNOSTICS_PERIOD_S = 0.5


def commands(args, controller: str, executor: str, rate: float) -> tuple[list[str], list[str]]:
    """The simulator's and the controller's command lines."""
    mode = args.mode or MODES[controller]
    sim = ["ros2", "run", "ops_sim_ros", "sim", "--ros-args"]
    for p in (
        f"stage:={args.stage}",
        f"mode:={mode}",
        f"split:={args.split}",
        f"seed:={args.seed}",
        f"rate_hz:={rate:g}",
        f"executor:={executor}",
        f"diagnostics_period_s:={DIAGNOSTICS_PERIOD_S}",
        f"time_base:={args.time_base}",
        f"vibration:={args.vibration}",
        *realtime_params(args),
    ):
        sim += ["-p", p]
    ctl = ["ros2", "run", "ops_controller_ros", controller, "--ros-args"]
    params = [f"seed:={args.seed}", f"executor:={executor}", *realtime_params(args)]
    if controller == "tracker" and args.vibration != "none":
        # the tracker told the vibration and the loop's period (docs/interfaces.md)
        params += [f"vibration:={args.vibration}", f"step_s:={1.0 / rate:g}"]
    if controller == "policy":
        params.append(f"model:={Path(args.model).resolve()}")
    params += args.param
    for p in params:
        ctl += ["-p", p]
    return sim, ctl


def realtime_params(args) -> list[str]:
    """Both nodes' ``realtime_priority`` (ops_contract.realtime), where one is asked for."""
    return [f"realtime_priority:={args.realtime_priority}"] if args.realtime_priority else []


def sim_counts(msg) -> tuple[int, int] | None:
    """(step, steps_without_command) of the simulator's /diagnostics message (None: another
    node's)."""
    for status in msg.status:
        if status.name == "ops_sim":
            values = {kv.key: kv.value for kv in status.values}
            return int(values["step"]), int(values["steps_without_command"])
    return None


class Listener:
    """ops/power readings and the simulator's diagnostics, on a node of this process spun by
    the events executor (the cheapest for a subscriber at thousands of messages per second)."""

    def __init__(self, node, power: list[float]):
        from diagnostic_msgs.msg import DiagnosticArray
        from ops_contract.executors import make_executor
        from ops_contract.ros_interface import TOPIC_DIAGNOSTICS

        self.power = power
        self.diagnostics: list[tuple[float, int, int]] = []  # (monotonic, step, without)
        node.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, self._on_diagnostics, 10)
        self.executor = make_executor("events", node.context)
        self.executor.add_node(node)

    def _on_diagnostics(self, msg) -> None:
        counts = sim_counts(msg)
        if counts is not None:
            self.diagnostics.append((time.monotonic(), *counts))

    def spin_until(self, condition, timeout: float) -> bool:
        from rclpy.task import Future

        deadline = time.monotonic() + timeout
        while not condition():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            self.executor.spin_until_future_complete(Future(), min(0.1, left))
        return True

    def close(self) -> None:
        self.executor.shutdown()


def measure_point(args, controller: str, executor: str, rate: float, logdir: Path) -> dict:
    """One rate: the figures of the window (see the module docstring)."""
    from ops_experiments.continuous import lock_figures

    sim_cmd, ctl_cmd = commands(args, controller, executor, rate)
    tag = f"{controller}_{executor}_{rate:g}"
    ctl_log = logdir / f"ctl_{tag}.log"
    with busy_processes(args.busy), power_node(f"bench_loop_rate_{os.getpid()}") as (node, power):
        listener = Listener(node, power)
        set_priority(args.realtime_priority)  # this process's threads, for the subscriber
        procs = [start(sim_cmd, logdir / f"sim_{tag}.log")]
        try:
            if not listener.spin_until(lambda: len(power) >= 20, 60):
                raise RuntimeError(f"no ops/power from the simulator (see {logdir})")
            procs.append(start(ctl_cmd, ctl_log))
            if not listener.spin_until(lambda: "closing the loop" in ctl_log.read_text(), 180):
                raise RuntimeError(f"the controller did not close the loop (see {ctl_log})")
            listener.spin_until(lambda: False, args.settle)
            power.clear()
            first_diag = len(listener.diagnostics)
            cpu0 = [group_cpu_s(proc.pid) for proc in procs]
            machine0 = machine_times()
            t0 = time.monotonic()
            listener.spin_until(lambda: False, args.seconds)
            elapsed = time.monotonic() - t0
            cpu = [group_cpu_s(proc.pid) - c for proc, c in zip(procs, cpu0, strict=True)]
            steal = steal_share(machine0, machine_times())
            readings = list(power)
            diag = listener.diagnostics[first_diag:]
        finally:
            listener.close()
            stop_all(procs)
            set_priority(0)
    if len(diag) < 2:
        raise RuntimeError(f"fewer than 2 diagnostics of the simulator in the window ({logdir})")
    (ta, step_a, miss_a), (tb, step_b, miss_b) = diag[0], diag[-1]
    lock = lock_figures(readings) if readings else {"first_lock_step": None}
    return {
        "controller": controller,
        "executor": executor,
        "rate_hz": rate,
        "readings_per_s": len(readings) / elapsed,
        "sim_steps_per_s": (step_b - step_a) / (tb - ta),
        "missed": (miss_b - miss_a) / max(step_b - step_a, 1),
        "locked": lock.get("locked_fraction", 0.0) if lock["first_lock_step"] is not None else 0.0,
        "first_lock_reading": lock["first_lock_step"],
        # CPU a simulator step cost each process (its DDS threads too), microseconds
        "sim_cpu_us_per_step": 1e6 * cpu[0] / max(step_b - step_a, 1) * (tb - ta) / elapsed,
        "controller_cpu_us_per_step": 1e6 * cpu[1] / max(step_b - step_a, 1) * (tb - ta) / elapsed,
        "steal": steal,  # the host's share of this VM's CPU time over the window
    }


def held(point: dict) -> bool:
    """The rate held: readings/s, missed commands and (but for SPGD) the lock."""
    ok = point["readings_per_s"] >= MIN_RATE_SHARE * point["rate_hz"]
    ok = ok and point["missed"] <= MAX_MISSED
    return ok and (point["controller"] == "spgd" or point["locked"] >= MIN_LOCKED)


def sweep(args, logdir: Path) -> list[dict]:
    """Every controller and executor over the rates (see ``--stop-after``)."""
    points = []
    for controller in args.controllers:
        for executor in args.executors:
            misses = 0
            for rate in args.rates:
                point = measure_point(args, controller, executor, rate, logdir)
                point["held"] = held(point)
                points.append(point)
                print(format_row(point), flush=True)
                misses = 0 if point["held"] else misses + 1
                if misses >= args.stop_after:
                    break
    return points


def format_row(p: dict) -> str:
    cpu = [p.get(k) for k in ("sim_cpu_us_per_step", "controller_cpu_us_per_step")]
    cpu_cells = " | ".join("—" if c is None else f"{c:.0f}" for c in cpu)
    steal = "—" if p.get("steal") is None else f"{100 * p['steal']:.1f} %"
    return (
        f"| {p['controller']} | {p['executor']} | {p['rate_hz']:g} | "
        f"{p['readings_per_s']:.0f} | {100 * p['missed']:.1f} % | {100 * p['locked']:.1f} % | "
        f"{cpu_cells} | {steal} | {'yes' if p['held'] else 'no'} |"
    )


def highest_held(points: list[dict]) -> dict[tuple[str, str], float | None]:
    best: dict[tuple[str, str], float | None] = {}
    for p in points:
        key = (p["controller"], p["executor"])
        best.setdefault(key, None)
        if p["held"] and (best[key] is None or p["rate_hz"] > best[key]):
            best[key] = p["rate_hz"]
    return best


def code_version() -> str:
    """``git describe --always --dirty`` of the repository (what the nodes ran)."""
    done = subprocess.run(
        ["git", "-C", str(REPO), "describe", "--always", "--dirty"],
        capture_output=True,
        text=True,
        check=False,
    )
    return done.stdout.strip() or "unknown"


def uptime() -> str:
    done = subprocess.run(["uptime"], capture_output=True, text=True, check=False)
    return done.stdout.strip() or f"load average {os.getloadavg()}"


def section_title(args) -> str:
    """The benchmarks.md section of these settings: the default's, or one per set of
    controllers (where not all of them), time base, vibration, controller parameters, priority
    and load (a run of other settings keeps the others' tables)."""
    told = [] if set(args.controllers) == set(CONTROLLERS) else [" ".join(args.controllers)]
    told += [f"time_base {args.time_base}"] if args.time_base != "step" else []
    told += [f"vibration {args.vibration}"] if args.vibration != "none" else []
    told += args.param
    told += [f"realtime_priority {args.realtime_priority}"] if args.realtime_priority else []
    told += [f"{args.busy} busy processes"] if args.busy else []
    return SECTION + (f": {', '.join(told)}" if told else "")


def section(args, points: list[dict], load_start: str, load_end: str) -> list[str]:
    niceness = os.nice(0)  # the priority it ran at, as the user typed it
    cmd = (f"nice -n {niceness} " if niceness else "") + "ops-bench loop-rate "
    cmd += " ".join(sys.argv[1:])
    modes = ", ".join(f"{c} {args.mode or MODES[c]}" for c in args.controllers)
    lines = [
        section_title(args),
        "",
        f"Command: `{cmd.strip()}`. Simulator N = {args.stage} free-running ({modes}; "
        f"split {args.split}, seed {args.seed}) and the controller as processes, fresh for each "
        f"rate; the window: {args.seconds:g} s from {args.settle:g} s after the controller "
        "closes the loop. Readings/s: ops/power received by a subscriber; missed: the "
        "simulator's steps that took no new command (its diagnostics' steps_without_command); "
        "locked: readings >= 0.95 after the first one; CPU per step: the CPU time of each "
        "process group over the window (its DDS threads included) per simulator step; steal: the "
        "host's share of this VM's CPU time over the window (/proc/stat). Held: "
        "readings/s >= 90 % of rate_hz, missed <= 1 %, and (tracker, policy) locked >= 99 %.",
        "",
        f"Machine: {os.cpu_count()} cores, shared with other work (a loop waits for a core "
        "while the load exceeds them: on an idle machine the same command measures the code "
        f"alone). `uptime` at the start: `{load_start}`; at the end: `{load_end}`. Code: "
        f"`{code_version()}`.",
        "",
        "| controller | executor | highest rate_hz held |",
        "|---|---|---|",
    ]
    for (controller, executor), rate in highest_held(points).items():
        lines.append(f"| {controller} | {executor} | {'none' if rate is None else f'{rate:g}'} |")
    lines += [
        "",
        "| controller | executor | rate_hz | readings/s | missed | locked | simulator CPU per "
        "step, µs | controller CPU per step, µs | steal | held |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *(format_row(p) for p in points),
        "",
    ]
    return lines


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--controllers", nargs="+", choices=CONTROLLERS, default=list(CONTROLLERS))
    ap.add_argument("--executors", nargs="+", choices=("default", "events"), default=None)
    ap.add_argument("--rates", nargs="+", type=float, default=list(RATES), help="rate_hz, Hz")
    ap.add_argument("--seconds", type=float, default=10.0, help="window per rate")
    ap.add_argument("--settle", type=float, default=2.0, help="s after the loop closes")
    ap.add_argument("--stop-after", type=int, default=2, help="rates in a row not held")
    ap.add_argument("--stage", type=int, default=5)
    ap.add_argument("--mode", help=f"every controller's simulator mode (default: {MODES})")
    ap.add_argument("--split", default="test")
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--model", default=str(REPO / "models" / "n5_hard_switch"))
    ap.add_argument(
        "--time-base",
        choices=TIME_BASES,
        default="step",
        help="the simulator's time_base: seconds makes a step last 1/rate_hz s (physical time)",
    )
    ap.add_argument(
        "--vibration",
        choices=VIBRATIONS,
        default="none",
        help="the simulator's vibration preset (needs --time-base seconds); the tracker is told it",
    )
    ap.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help="a parameter of the controller node (repeat for more), e.g. answer_first:=true",
    )
    ap.add_argument(
        "--realtime-priority",
        type=int,
        default=0,
        metavar="P",
        help="both nodes' realtime_priority (SCHED_FIFO, 1-98; 0: the normal scheduler); this "
        "process's subscriber takes it too",
    )
    ap.add_argument(
        "--busy", type=int, default=0, metavar="K", help="K busy processes beside each rate's loop"
    )
    ap.add_argument("--out", help="also write the points to this JSON file")
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args(argv)
    if args.busy < 0:
        ap.error(f"--busy: a count >= 0 (got {args.busy})")
    if args.realtime_priority:
        if not 0 < args.realtime_priority <= MAX_PRIORITY:
            ap.error(f"--realtime-priority: 0 to {MAX_PRIORITY} (got {args.realtime_priority})")
        refused = set_priority(args.realtime_priority)  # allowed here, so to the nodes too
        set_priority(0)  # (each rate's subscriber takes it once its threads are up)
        if refused:
            ap.error(f"--realtime-priority: {refused}")
    from ops_contract.executors import EXECUTORS

    args.executors = args.executors or list(EXECUTORS)
    if args.vibration != "none" and args.time_base != "seconds":
        ap.error("--vibration: a vibration needs --time-base seconds")
    if "policy" in args.controllers and not (Path(args.model) / "model.zip").is_file():
        ap.error(f"--model: no model.zip in {args.model}")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    logdir = local_dds("bench_loop_rate")
    import rclpy

    load_start = uptime()
    rclpy.init(args=[])  # not this tool's argv: NAME:=VALUE there is for the nodes
    try:
        points = sweep(args, logdir)
    finally:
        rclpy.try_shutdown()
    load_end = uptime()
    publish(
        section_title(args), section(args, points, load_start, load_end), write=not args.no_write
    )
    out = Path(args.out) if args.out else logdir / "results.json"
    out.write_text(json.dumps({"args": vars(args), "points": points}, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
