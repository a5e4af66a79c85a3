"""``ops-bench rate-sweep``: at a lab's loop rate and vibration, which controller holds the stack,
and to how many mrad?

In process (:mod:`ops_experiments.timed_loop`), under ``time_base`` seconds with ``lab``
vibration on the ``lab`` rig (its latency and the delay lines' response given in ms), each
controller runs ``--seconds`` of simulated time per cell (controller x loop rate x seed), N = 5
hard, testing split. Its compute caps its rate: a reading that costs more than a period is
answered a whole number of periods later, the set-points holding in between (measured per
reading, or ``--compute-ms NAME=MS``). Per cell, from the first reading at 0.95 on: each stage's
residual phase error (rms, mrad), P_N/P_max's mean and rms fluctuation, the fraction >= 0.95 and
the lock losses.

Each cell is appended to ``OUT/cells.jsonl`` as it finishes; a cell stored with the same
settings is not run again, so a stopped sweep resumes where it stopped (delete lines to re-run
them). Then the figure (``--figure``; residual and P_N/P_max rms against the loop rate, one line
per controller, LBNL's 50 mrad and 1.5 % marked) and ``OUT/index.md`` (every stored group of
settings, a table each) are written from every stored cell.

Usage (after ``source setup.bash``):
  ops-bench rate-sweep               # 10 seeds x 60 s: tracker, SPGD-PID, n5_hard_lab_dagger
  ops-bench rate-sweep --quick       # 3 seeds x 10 s
  ops-bench rate-sweep --seconds 3600 --rates 1000 --controllers spgd --seeds 7101 --no-figure
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from ops_contract.config import VIBRATIONS

from ops_bench import REPO

RATES = (10, 30, 100, 300, 1000)
CONTROLLERS = ("tracker", "spgd", "models/n5_hard_lab_dagger", "oracle")
SEEDS = tuple(range(7101, 7111))  # never used to tune anything
QUICK_SEEDS, QUICK_SECONDS = SEEDS[:3], 10.0
OUT = REPO / "docs" / "results" / "rate_sweep"
FIGURE = REPO / "docs" / "figures" / "rate_sweep.png"
#: LBNL's goals for a coherently combined laser: residual phase per stage and power stability.
GOAL_MRAD, GOAL_RMS_PCT = 50.0, 1.5
#: The settings that make a group of cells (a table of the page; the figure draws one group).
GROUP_KEYS = ("seconds", "mode", "vibration", "latency_ms", "lag_ms")
#: ... and the compute's: a stored cell is reused only where these match too.
COMPUTE_KEYS = ("compute", "compute_scale")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ops-bench rate-sweep", description=__doc__.split("\n\n")[0].split(": ", 1)[1]
    )
    p.add_argument(
        "--controllers",
        nargs="+",
        default=list(CONTROLLERS),
        metavar="NAME",
        help="tracker, tracker-answer-first (answer_first: a reading answered by the "
        "prediction, fitted after), spgd, model directories, or oracle: the floor of any "
        "controller at each rate and latency (it reads the true delay errors: "
        "ops_experiments.timed_loop.TrueErrorReference) (default: %(default)s)",
    )
    p.add_argument(
        "--rates",
        nargs="+",
        type=float,
        default=list(RATES),
        metavar="HZ",
        help="loop rates, Hz (default: %(default)s)",
    )
    p.add_argument(
        "--seeds",
        nargs="+",
        type=int,
        default=None,
        help=f"seeds (default: {SEEDS[0]}-{SEEDS[-1]}; --quick: the first 3)",
    )
    p.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="simulated seconds per cell (default 60; --quick: 10)",
    )
    p.add_argument("--quick", action="store_true", help="3 seeds x 10 s")
    p.add_argument("--mode", default="hard", choices=("easy", "medium", "hard", "extreme"))
    p.add_argument("--vibration", default="lab", choices=VIBRATIONS)
    p.add_argument(
        "--latency-ms",
        type=float,
        default=1.0,
        help="the rig's latency, ms (rounded to steps of each rate; default 1)",
    )
    p.add_argument(
        "--lag-ms", type=float, default=1.0, help="the delay lines' response time, ms (default 1)"
    )
    p.add_argument(
        "--compute-ms",
        nargs="+",
        default=[],
        metavar="NAME=MS",
        help="a controller's compute per reading, fixed (NAME: tracker, spgd or the "
        "model folder's name); default: measured per reading in the run",
    )
    p.add_argument(
        "--compute-scale",
        type=float,
        default=1.0,
        help="measured compute times this (a lab machine faster or slower than this "
        "one; default 1)",
    )
    p.add_argument("--out", type=Path, default=OUT, help="cells.jsonl and index.md go here")
    p.add_argument("--figure", type=Path, default=FIGURE, help="the figure (default: %(default)s)")
    p.add_argument("--no-figure", action="store_true", help="no figure (the page still)")
    p.add_argument("--report", action="store_true", help="only the figure and page, no runs")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def compute_table(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            ms = float(value)
        except ValueError:
            ms = -1.0
        if not sep or not math.isfinite(ms) or ms < 0.0:
            raise ValueError(f"--compute-ms takes NAME=MS with MS >= 0 (got {item!r})")
        out[name.rstrip("/").split("/")[-1]] = ms
    return out


def settings(args, label: str) -> dict[str, Any]:
    """The settings of ``label``'s cells (what a stored cell must match to be reused)."""
    fixed = args.compute_table.get(label)
    return {
        "seconds": args.seconds,
        "mode": args.mode,
        "vibration": args.vibration,
        "latency_ms": args.latency_ms,
        "lag_ms": args.lag_ms,
        "compute": "measured" if fixed is None else fixed,
        "compute_scale": args.compute_scale if fixed is None else 1.0,
    }


def cell_key(cell: dict[str, Any]) -> tuple:
    head = (cell["controller"], float(cell["rate_hz"]), int(cell["seed"]))
    return (*head, *(cell[k] for k in (*GROUP_KEYS, *COMPUTE_KEYS)))


def read_cells(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def run_cell(spec: dict[str, Any], name: str, model, on_chunk=None) -> dict[str, Any]:
    """One cell: ``name`` at ``spec``'s rate and seed for its seconds; its stored record."""
    from ops_experiments.timed_loop import RunStats, run_for, start_loop, timed_config

    config = timed_config(
        spec["rate_hz"],
        mode=spec["mode"],
        vibration=spec["vibration"],
        latency_ms=spec["latency_ms"],
        lag_ms=spec["lag_ms"],
    )
    fixed = spec["compute"] if spec["compute"] != "measured" else None
    t0 = time.monotonic()
    loop = start_loop(name, config, spec["seed"], model, fixed, spec["compute_scale"])
    stats = RunStats(config.stage, config.optical_period_fs)
    steps = round(spec["seconds"] * spec["rate_hz"])
    run_for(loop, steps, stats, on_chunk=on_chunk)
    return {
        **spec,
        "latency_steps": config.latency_steps,
        "lag_steps": round(config.actuator_lag_steps, 4),
        **stats.figures(),
        **loop.compute_figures(),
        "wall_s": round(time.monotonic() - t0, 1),
    }


def pending_cells(args, done: set) -> list[tuple[dict[str, Any], str]]:
    """The cells to run, seed by seed (a stopped sweep has whole seeds of every cell)."""
    from ops_experiments.timed_loop import label_of

    todo = []
    for seed in args.seeds:
        for name in args.controllers:
            label = label_of(name)
            for rate in args.rates:
                spec = {"controller": label, "rate_hz": float(rate), "seed": seed}
                spec.update(settings(args, label))
                if cell_key(spec) not in done:
                    todo.append((spec, name))
    return todo


def run_sweep(args) -> None:
    path = args.out / "cells.jsonl"
    done = {cell_key(c) for c in read_cells(path)}
    todo = pending_cells(args, done)
    total = sum(round(s["seconds"] * s["rate_hz"]) for s, _ in todo)
    print(
        f"[rate-sweep] {len(todo)} cells to run ({len(done)} stored in {path}), "
        f"{total:,} simulated steps",
        flush=True,
    )
    if not todo:
        return
    models = preload(args.controllers)
    version = code_version()
    bar = progress_bar(total, args.no_progress)
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        for spec, name in todo:
            bar.set_postfix_str(f"{spec['controller']} {spec['rate_hz']:g} Hz seed {spec['seed']}")
            cell = run_cell(spec, name, models[name], lambda n, *_: bar.update(n))
            cell["command"] = args.command
            cell["code"] = version
            with open(path, "a") as f:
                f.write(json.dumps(cell) + "\n")
            bar.write(summary_line(cell))
    finally:
        bar.close()


def preload(names: list[str]) -> dict[str, Any]:
    """Every model read and loaded, and every controller's modules imported, before the first
    cell: an hours-long sweep runs the code it started with, though files change meanwhile."""
    import ops_controller_ros.controllers
    import ops_controller_ros.spgd
    import ops_controller_ros.tracker
    from ops_experiments.timed_loop import CONTROLLER_NAMES, REFERENCE, load_model_stack

    models = {n: None for n in names if n in (*CONTROLLER_NAMES, REFERENCE)}
    for name in names:
        if name not in models:
            import ops_controller_ros.policy_node  # noqa: F401

            models[name] = load_model_stack(str(model_path(name)))
    return models


def code_version() -> str:
    """The commit the controllers ran from, ``+dirty`` where their files differ from it."""
    import subprocess

    def git(*cmd: str) -> str:
        done = subprocess.run(["git", *cmd], cwd=REPO, capture_output=True, text=True)
        return done.stdout.strip()

    dirty = git("status", "--porcelain", "ops_controller_ros", "ops_sim_ros", "ops_contract")
    return git("rev-parse", "--short", "HEAD") + ("+dirty" if dirty else "")


def model_path(name: str) -> Path:
    """A model directory as given, or under the repository (the default's models/...)."""
    path = Path(name)
    return path if path.exists() or path.is_absolute() else REPO / path


def progress_bar(total: int, off: bool):
    from tqdm import tqdm

    return tqdm(
        total=total, unit="step", unit_scale=True, disable=off, mininterval=2.0, file=sys.stderr
    )


def summary_line(cell: dict[str, Any]) -> str:
    residual = cell["residual_mrad"]
    figures = "never locked"
    if residual is not None:
        figures = (
            f"{residual:.1f} mrad, P {cell['power_mean']:.4f} rms {cell['power_rms_pct']:.2f} "
            f"%, {100 * cell['locked_fraction']:.2f} % >= 0.95, {cell['losses']} losses"
        )
    return (
        f"[rate-sweep] {cell['controller']} {cell['rate_hz']:g} Hz seed {cell['seed']}: "
        f"{figures}; {cell['steps_per_command_median']:g} steps/command, compute "
        f"{cell['compute_ms_median']:.2f} ms ({cell['wall_s']:.0f} s)"
    )


def main(argv: list[str] | None = None) -> int:
    from ops_contract.threads import limit_blas_threads

    from .rate_sweep_report import write_report

    args = build_parser().parse_args(argv)
    args.command = shlex.join(sys.argv[1:] if argv is None else argv)
    try:
        args.compute_table = compute_table(args.compute_ms)
    except ValueError as exc:
        print(f"ops-bench rate-sweep: {exc}", file=sys.stderr)
        return 2
    if args.seeds is None:
        args.seeds = list(QUICK_SEEDS if args.quick else SEEDS)
    if args.seconds is None:
        args.seconds = QUICK_SECONDS if args.quick else 60.0
    if args.seconds <= 0 or any(r <= 0 for r in args.rates):
        print("ops-bench rate-sweep: --seconds and --rates must be > 0", file=sys.stderr)
        return 2
    limit_blas_threads()
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    if not args.report:
        run_sweep(args)
    cells = read_cells(args.out / "cells.jsonl")
    figure = None if args.no_figure else args.figure
    group = {k: v for k, v in settings(args, "").items() if k in GROUP_KEYS}
    write_report(cells, args.out, figure, group)
    return 0


if __name__ == "__main__":
    sys.exit(main())
