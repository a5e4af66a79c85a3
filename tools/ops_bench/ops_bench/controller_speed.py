"""Each controller's compute per reading, in process: the tracker, SPGD-PID and every shipped
learned model, at N = 3, 5 and 7.

Per stage, each controller runs ``--steps`` readings of the testing split of ``--mode`` (the
ideal rig, told to the controller) for each seed, as the nodes drive it: ``command`` (with
``think`` and the revised command where the controller has one, ``controllers.next_command``) and
``observe`` of each reading are its compute; the simulator's step is not. A learned model runs
through the policy runner (``ops_controller_ros.policy_node.PolicyController``, as ``soak`` and
``rate-sweep`` build it), on its own stage and detector only (models exist for N = 3 and 5).

Compute is the calling thread's CPU time (``time.thread_time``), BLAS and torch on one thread (as
every node and CLI runs them): a machine shared with other jobs then slows it less than the wall
clock, though it still does (caches, a shared core). Each run is repeated ``--repeats`` times
with the same seeds (the same readings: every controller here is deterministic), and each
reading's least time is kept, so a moment's interruption falls out. The 1-minute load average
at the start and at the end is printed and written beside the figures; ``--busy N`` runs N
busy-looping processes beside the measurement.

``--vibration lab`` (or ``open``) runs the ``lab`` rig in physical time at ``--rate`` Hz under
that vibration instead of the ideal rig, as ``rate-sweep`` and ``soak`` do (latency and the
lines' response 1 ms): the tracker then takes its vibration settings and, from a sixth of
``vibration_memory_s`` on (20 s), its drift memory, so give ``--steps`` enough readings for
that (6,000 at 100 Hz is a minute). Its section is one of its own, named by the vibration and
the rate.

Usage (after `source setup.bash`):
  ops-bench controller-speed [--stages 3 5 7] [--mode hard] [--steps 300] [--seeds 1 2]
      [--repeats 3] [--controllers tracker spgd models] [--busy 0] [--write]
  ops-bench controller-speed --stages 5 --controllers tracker --vibration lab --rate 100 \
      --steps 6000 --repeats 2 --write
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from ops_contract.config import MODES, VIBRATIONS

from ops_bench import REPO
from ops_bench.docs import publish
from ops_bench.processes import busy_processes

TITLE = "## Compute per reading, by controller"
CONTROLLERS = ("tracker", "spgd", "models")
#: How to read the tracker's rows (what its code does, not what a run measured).
READING = [
    "**Reading the tracker's rows.** Its largest readings are its global search, once a lock. "
    "At N <= 5 the search runs whole "
    "in the reading that starts it (about 30,000 rows of work, `tracker/work.py`). At N = 7 it "
    "is about 570,000 rows and a candidate of the latency check about 350,000: both run "
    "`spread_rows` (8,000) a reading, the search over some 50 readings, and a spread search "
    "refines what it found on the readings that came meanwhile before the tracker takes it "
    '(docs/tracker.md, "Acquire"). The knot test is held to `work_budget` per reading the '
    "same way. Hard mode takes a whole-cycle move every 10 readings; the period fits of the "
    "readings after each move adopt a new wavelength, which retunes the model's stacker by a "
    "copy (`tracker/model.py`, `at_wavelength`).",
    "",
]


def model_dirs(stage: int) -> list[Path]:
    """The shipped models (``models/*/metadata.json``) of this stage."""
    from ops_controller_ros.policy_io import read_metadata

    out = []
    for meta in sorted((REPO / "models").glob("*/metadata.json")):
        if int(read_metadata(meta.parent).get("stage", 0)) == stage:
            out.append(meta.parent)
    return out


def config_for(stage: int, args, stack=None):
    """The run's configuration: the ideal rig (the model's detector), or with a vibration the
    ``lab`` rig in physical time at ``args.rate``."""
    from ops_contract.config import make_config
    from ops_experiments.timed_loop import timed_config

    if args.vibration != "none":
        return timed_config(args.rate, stage=stage, mode=args.mode, vibration=args.vibration)
    detector = "polarizer" if stack is None else (stack.meta.detector or "polarizer")
    return make_config(stage=stage, mode=args.mode, split="test", detector=detector)


def run_once(name: str, config, steps: int, seed: int, stack=None) -> tuple:
    """Per-reading compute (ms) of one run, and its readings' P_N/P_max."""
    from ops_controller_ros.controllers import next_command
    from ops_experiments.timed_loop import make_agent
    from ops_sim_ros.env import OpsEnv

    env = OpsEnv.from_config(config, max_episode_steps=steps + 1)
    _, info = env.reset(seed=1000 * seed)
    ctl, _ = make_agent(name, config, seed, info["setpoints_fs"], model=stack)
    policy = stack is not None
    ms, power = np.empty(steps), np.empty(steps)
    try:
        for t in range(steps):
            t0 = time.thread_time()
            command = next_command(ctl)
            spent = time.thread_time() - t0
            r = env.step_setpoints(command)
            power[t] = float(r.power[0])
            t0 = time.thread_time()
            if policy:  # (the authors' observation holds the applied delays)
                ctl.observe(power[t], r.pulse_energies[0], applied=r.applied_fs[0])
            else:
                ctl.observe(power[t], r.pulse_energies[0])
            ms[t] = 1e3 * (spent + time.thread_time() - t0)
    finally:
        env.close()
    return ms, power


def measure(name: str, stage: int, args, stack=None) -> dict:
    """One table row: each reading's least compute over the repeats, all seeds pooled."""
    per_seed, locked = [], []
    config = config_for(stage, args, stack)
    for seed in args.seeds:
        runs = [run_once(name, config, args.steps, seed, stack) for _ in range(args.repeats)]
        per_seed.append(np.min([ms for ms, _ in runs], axis=0))
        locked.append(np.mean(runs[0][1][args.steps // 2 :] >= 0.95))
    ms = np.concatenate(per_seed)
    label = name if stack is None else f"`models/{Path(name).name}`"
    row = {
        "controller": label,
        "N": stage,
        "median": float(np.median(ms)),
        "p99": float(np.percentile(ms, 99)),
        "worst": float(ms.max()),
        "over 20 ms": int(np.sum(ms > 20.0)),
        "locked": 100.0 * float(np.mean(locked)),
        "readings": ms.size,
    }
    print(
        f"[controller-speed] {label} N={stage}: median {row['median']:.3f} ms, p99 "
        f"{row['p99']:.2f} ms, worst {row['worst']:.1f} ms ({row['readings']} readings; second "
        f"halves >= 0.95: {row['locked']:.0f} %)",
        flush=True,
    )
    return row


def rows_for(args) -> list[dict]:
    from ops_experiments.timed_loop import load_model_stack

    rows = []
    for stage in args.stages:
        for name in ("tracker", "spgd"):
            if name in args.controllers:
                rows.append(measure(name, stage, args))
        if "models" in args.controllers:
            for path in model_dirs(stage):
                rows.append(measure(str(path), stage, args, load_model_stack(str(path), stage)))
    return rows


def table(rows: list[dict]) -> list[str]:
    out = [
        "| controller | N | median ms | p99 ms | worst ms | readings over 20 ms | readings "
        "| second halves >= 0.95, % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        out.append(
            f"| {r['controller']} | {r['N']} | {r['median']:.3f} | {r['p99']:.2f} | "
            f"{r['worst']:.1f} | {r['over 20 ms']} | {r['readings']} | {r['locked']:.0f} |"
        )
    return out


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--stages", type=int, nargs="+", default=[3, 5, 7])
    ap.add_argument("--mode", choices=MODES, default="hard")
    ap.add_argument("--steps", type=int, default=300, help="readings per run")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=3, help="runs per seed; least time per reading")
    ap.add_argument("--controllers", nargs="+", choices=CONTROLLERS, default=list(CONTROLLERS))
    ap.add_argument("--busy", type=int, default=0, help="busy processes beside the measurement")
    ap.add_argument(
        "--vibration",
        choices=VIBRATIONS,
        default="none",
        help="none: the ideal rig; else the lab rig in physical time at --rate under it",
    )
    ap.add_argument("--rate", type=float, default=10.0, help="loop rate with a vibration, Hz")
    ap.add_argument("--write", action="store_true", help="write docs/benchmarks.md")
    args = ap.parse_args(argv)
    if args.steps < 1 or args.repeats < 1:
        ap.error("--steps and --repeats must be >= 1")
    if not args.rate > 0.0:
        ap.error("--rate must be > 0")
    return args


def main(argv=None) -> int:
    from ops_contract.threads import limit_blas_threads, limit_torch_threads

    args = parse_args(argv)
    limit_blas_threads()
    if "models" in args.controllers:
        limit_torch_threads()
    with busy_processes(args.busy):
        load_start = os.getloadavg()[0]
        rows = rows_for(args)
    load_end = os.getloadavg()[0]
    command = "ops-bench controller-speed " + " ".join(sys.argv[1:])
    title = TITLE + (f", {args.busy} busy processes beside it" if args.busy else "")
    rig = "the ideal rig"
    if args.vibration != "none":
        title += f", the {args.vibration} vibration at {args.rate:g} Hz"
        rig = f"the lab rig in physical time at {args.rate:g} Hz, {args.vibration} vibration"

    lines = [
        title,
        "",
        f"Command: `{command.strip()}` ({args.mode} mode, testing split, {rig}; "
        f"{args.steps} readings per run, seeds {' '.join(map(str, args.seeds))}, each run "
        f"{args.repeats} time(s) and each reading's least time kept; BLAS and torch on one thread; "
        f"{os.cpu_count()} cores, {args.busy} busy processes beside it, 1-minute load "
        f"{load_start:.1f} at the start and {load_end:.1f} at the end). Compute per reading: "
        "the calling thread's CPU time in `command` (with `think` and the revised command) and "
        "`observe`; a node at 100 Hz has 10 ms. Learned models run through the policy runner "
        "on their own stage (there are none for N = 7).",
        "",
        *table(rows),
        "",
        *READING,
    ]
    publish(title, lines, write=args.write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
