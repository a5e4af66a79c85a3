"""The tracker's compute per reading, against a node's 10 ms at 100 Hz.

In process, in the testing environment (N = 5, polarizer detector; the ideal rig, or
``--realism``, told to the tracker): ``command`` + ``observe`` of every reading after the first
lock (median, p99, max, share over 10 ms), with BLAS on one thread (what every node and CLI
sets, ops_contract.threads) and on the library's default (one per core), plus the time of one
knot test (the hypotheses of :meth:`PhaseTracker._knot_fit`: stage x knot position x side) and
one tracking fit on a locked state. Timings depend on the load: the 1-minute load average is
printed and written beside them; ``--busy N`` runs N busy-looping processes beside the
measurement (a machine whose cores are all taken, where a second BLAS thread waits for one).

Usage (after `source setup.bash`):
  ops-bench tracker-compute [--mode extreme] [--realism lab] [--steps 3000] [--seeds 1000]
      [--busy 2] [--param defer_knot_test=true knot_budget_ms=4] [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time

import numpy as np
from ops_contract.config import REALISMS
from ops_experiments.cli_args import parse_key_values
from threadpoolctl import threadpool_limits

from ops_bench.docs import write_section
from ops_bench.tracker_knots import tracker_run

SECTION = "## The tracker's compute per reading (issue 20)"


def fit_times(ctl, repeats: int) -> tuple[float, float]:
    """Median ms of one tracking fit and of one knot test on the tracker's present window."""
    u, y, age = ctl._window()
    x, drift, p = ctl.estimate + ctl.drift, ctl.drift, ctl.params
    lock, knot = ctl.lock, ctl.knot
    state = (lock.path, lock.objective, lock.ratio, lock.gain_step, lock.level_step)
    counts = (knot.taken, knot.tick, knot.cut_short)

    def timed(call) -> float:
        out = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            call()
            out.append(time.perf_counter() - t0)
        return 1e3 * float(np.median(out))

    track = timed(lambda: ctl._fit_path(x, drift, u, y, age, p.track_iterations))
    knot = timed(lambda: ctl._knot_fit(x, x, drift, 1.0, u, y, age))
    lock.path, lock.objective, lock.ratio, lock.gain_step, lock.level_step = state
    knot.taken, knot.tick, knot.cut_short = counts
    return track, knot


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--mode", default="extreme")
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1000])
    ap.add_argument(
        "--realism", choices=REALISMS, default="ideal", help="the rig, told to the tracker"
    )
    ap.add_argument("--repeats", type=int, default=30, help="calls per fit timing")
    ap.add_argument("--busy", type=int, default=0, help="busy processes beside the measurement")
    ap.add_argument("--write", action="store_true", help="write docs/benchmarks.md")
    ap.add_argument(
        "--param",
        nargs="*",
        default=[],
        help="tracker parameters KEY=VALUE (the node's: defer_knot_test=true knot_budget_ms=4)",
    )
    args = ap.parse_args(argv)
    args.params = parse_key_values(args.param, "--param")
    cores = os.cpu_count() or 1
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        rows = measure(args, cores)
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
    write(args, cores, rows)
    return 0


def measure(args, cores: int) -> list[str]:
    """One table row per BLAS thread count and seed."""
    rows = []
    for threads in (1, cores):
        for seed in args.seeds:
            with threadpool_limits(limits=threads, user_api="blas"):
                run = tracker_run(args.mode, args.steps, seed, args.params, args.realism)
                track_ms, knot_ms = fit_times(run["ctl"], args.repeats)
            power = run["power"]
            first = int(np.argmax(power >= 0.95))
            ms, answer, think = (run[k][first:] for k in ("compute_ms", "answer_ms", "think_ms"))
            row = (
                f"| {threads} | {seed} | {np.median(ms):.2f} | {np.percentile(ms, 99):.1f} | "
                f"{ms.max():.1f} | {100 * np.mean(ms > 10):.2f} | "
                f"{np.percentile(answer, 99):.1f} | {np.percentile(think, 99):.1f} | "
                f"{track_ms:.2f} | {knot_ms:.1f} | "
                f"{100 * np.mean(power[first:] >= 0.95):.2f} | {os.getloadavg()[0]:.1f} |"
            )
            rows.append(row)
            print(row, flush=True)
    return rows


def write(args, cores: int, rows: list[str]) -> None:
    """Print the section (and write it into docs/benchmarks.md with ``--write``)."""
    cmd = "ops-bench tracker-compute " + " ".join(sys.argv[1:])
    title = SECTION + (f", {args.busy} busy processes beside it" if args.busy else "")
    title += f", tracker {' '.join(args.param)}" if args.param else ""
    text = "\n".join(
        [
            title,
            "",
            f"Command: `{cmd.strip()}` ({args.mode} mode, `{args.realism}` rig, N = 5, testing "
            f"split, {args.steps} steps per seed; machine: "
            f"{platform.processor() or platform.machine()}, "
            f"{cores} cores; {args.busy} busy processes beside it). Per reading after the first "
            "lock: `observe`, `command`, `think` and the revised command of the tracker in process "
            "(the answer: `observe` + `command`, what a node sends before it thinks; the rest "
            "only with `defer_knot_test`); a node at 100 Hz has 10 ms. "
            "Fit timings: median of "
            f"{args.repeats} calls on the run's last window (one tracking fit of "
            "`track_iterations`; one knot test: its hypotheses (stage x knot position x side), "
            "fitted together).",
            "",
            "| BLAS threads | seed | median ms | p99 ms | max ms | readings > 10 ms, % | "
            "answer p99 ms | think p99 ms | tracking fit ms | knot test ms | readings >= 0.95, % "
            "| load (1 min) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    print(text)
    if args.write:
        write_section(title, text)


if __name__ == "__main__":
    raise SystemExit(main())
