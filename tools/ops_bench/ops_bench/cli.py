"""``ops-bench``: every benchmark, figure and model tool of the project as one command with
subcommands (after rl-zoo3's one CLI). ``ops-bench NAME --help`` gives a subcommand's options;
``ops-bench all [NAME ...]`` runs the speed benchmarks one after the other (``make bench``).

A subcommand's module is imported only when it runs, so ``ops-bench --help`` stays fast and a
tool's heavy imports (torch, matplotlib, rclpy) load only for that tool.
"""

from __future__ import annotations

import argparse
import importlib
import os
import subprocess
import sys
from typing import NamedTuple

from ops_contract.heap import freeze_after_heavy_imports

from ops_bench import REPO


class Tool(NamedTuple):
    module: str  # ops_bench.<module>, with main(argv) -> exit code (or None)
    summary: str  # one line for ``ops-bench --help``


#: name -> tool; ``figures`` has kinds of its own (``ops-bench figures physics``).
TOOLS: dict[str, Tool] = {
    "physics": Tool("physics", "simulator and environment speed (batched physics, OpsEnv steps)"),
    "physical-time": Tool(
        "physical_time", "time_base seconds against step, the lab vibration's bands and cost"
    ),
    "bridge": Tool("bridge", "Gymnasium bridge over DDS against the in-process environment"),
    "bridge-faults": Tool(
        "bridge_faults", "training over the bridge on a lossy, cut or stuck link"
    ),
    "closed-loop": Tool("closed_loop", "sim + SPGD over DDS: loop rate, latency, raw round trip"),
    "continuous-dds": Tool("continuous_dds", "a controller node's continuous run over DDS"),
    "continuous-table": Tool("continuous_table", "continuous-dds' table beside the in-process one"),
    "faults": Tool("faults", "controller nodes on a lossy, delayed, cut link between two hosts"),
    "loop-rate": Tool(
        "loop_rate", "sim + each controller over DDS: highest rate held, per executor"
    ),
    "first-run": Tool(
        "first_run", "a first run over DDS (README commands): seconds to lock, SPGD or tracker"
    ),
    "ray-cluster": Tool("ray_bench", "the benchmark's smoke profile on a two-node Ray cluster"),
    "rig-calibration": Tool("rig_calibration", "calibrate on the simulated lab, seed by seed"),
    "rig-tracker": Tool("rig_tracker", "simulated lab + rig + tracker over DDS, a long run"),
    "tracker": Tool("tracker", "the tracker's goals: episodes per mode, mismatch, compute"),
    "controller-speed": Tool(
        "controller_speed", "compute per reading: tracker, SPGD-PID, learned models; N 3/5/7"
    ),
    "tracker-reference": Tool(
        "tracker_reference", "record the tracker's runs on fixed cases; compare two records"
    ),
    "training": Tool("training", "training speed and learning of hyper-parameter sets"),
    "two-hosts": Tool("two_hosts", "the closed loop with sim and SPGD on one host or two"),
    "spgd-baseline": Tool("spgd_baseline", "SPGD-PID's episodes: figure and parameter sweep"),
    "rate-sweep": Tool("rate_sweep", "controllers at loop rates 10 Hz-1 kHz under lab vibration"),
    "soak": Tool("soak", "the tracker for hours of simulated time on the lab rig (checkpointed)"),
    "soak-steps": Tool("soak_steps", "the soak's loop, every step logged: where locks were lost"),
    "figures": Tool("", "figures of the docs: ops-bench figures KIND, KIND one of"),
    "ship-model": Tool("ship_model", "ship a trained run as a model folder with its curve"),
    "reference-actions": Tool("reference_actions", "store a shipped model's reference actions"),
    "switch-model": Tool("switch_model", "a switching model: one policy acquires, one holds"),
    "learning-curves": Tool("learning_curves", "training recipes on their learning curves"),
    "recipes": Tool("recipes", "train the learning recipes side by side, then their curves"),
    "results": Tool(
        "results_pages", "the results pages (docs/results.md, its topics) from stored runs"
    ),
    "relay": Tool("relay", "the lossy link's frame relay (run inside a network namespace)"),
}
FIGURES: dict[str, Tool] = {
    "physics": Tool("figures_physics", "landscape, traces and rig figures (docs/physics.md)"),
    "tracker": Tool("figures_tracker", "the tracker's figures (docs/tracker.md)"),
    "learned": Tool("figures_learned", "learned agents against training time (models/README)"),
}
#: ``ops-bench all``: the speed benchmarks of docs/benchmarks.md, in this order, with these
#: options and environment (they share the machine's cores: never run them in parallel).
ALL: dict[str, tuple[list[str], dict[str, str]]] = {
    "physics": ([], {"OPENBLAS_NUM_THREADS": "1"}),
    "closed-loop": ([], {}),
    "bridge": (["--write", "docs/benchmarks.md"], {}),
}


def run_tool(tool: Tool, prog: str, argv: list[str]) -> int:
    """Import ``ops_bench.<tool.module>`` and run its ``main(argv)`` as ``prog``."""
    module = importlib.import_module(f"ops_bench.{tool.module}")
    saved = sys.argv
    # As if run alone: argparse's usage line says "ops-bench NAME", and a tool that records its
    # own command line (sys.argv[1:]) in the docs it writes sees its options only.
    sys.argv = [prog, *argv]
    try:
        code = module.main(argv)
    finally:
        sys.argv = saved
    return int(code or 0)


def run_all(parts: list[str]) -> int:
    """Each part in a process of its own (its environment set before numpy loads)."""
    parts = parts or list(ALL)
    unknown = [p for p in parts if p not in TOOLS or p == "figures"]
    if unknown:
        print(f"ops-bench all: no such benchmark: {' '.join(unknown)}", file=sys.stderr)
        return 2
    for i, name in enumerate(parts, 1):
        args, env = ALL.get(name, ([], {}))
        print(f"[bench] {i}/{len(parts)} {name}: {TOOLS[name].summary}", flush=True)
        cmd = [sys.executable, "-m", "ops_bench", name, *args]
        done = subprocess.run(cmd, cwd=REPO, env={**os.environ, **env}, check=False)
        if done.returncode != 0:
            print(f"[bench] {name} failed ({done.returncode})", file=sys.stderr)
            return done.returncode
    return 0


def parser() -> argparse.ArgumentParser:
    width = max(map(len, TOOLS)) + 2
    lines = []
    for name, tool in TOOLS.items():
        lines.append(f"  {name:<{width}}{tool.summary}")
        if name == "figures":
            lines += [f"    {kind:<{width - 2}}{t.summary}" for kind, t in FIGURES.items()]
    all_parts = " ".join(ALL)
    lines.append(f"  {'all [NAME ...]':<{width}}run benchmarks in turn (default: {all_parts})")
    p = argparse.ArgumentParser(
        prog="ops-bench",
        description="The project's benchmarks, figure and model tools as one command.",
        epilog="subcommands:\n" + "\n".join(lines),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("name", metavar="SUBCOMMAND", help="one of the subcommands below")
    p.add_argument("args", nargs=argparse.REMAINDER, help="its options (SUBCOMMAND --help)")
    return p


def main(argv: list[str] | None = None) -> int:
    freeze_after_heavy_imports()  # (ship-model, the benchmarks that load models)
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        parser().print_help()
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name == "all":
        return run_all(rest)
    if name == "figures":
        if not rest or rest[0] not in FIGURES:
            kinds = ", ".join(FIGURES)
            print(f"usage: ops-bench figures {{{kinds}}} [options]", file=sys.stderr)
            return 0 if rest and rest[0] in ("-h", "--help") else 2
        return run_tool(FIGURES[rest[0]], f"ops-bench figures {rest[0]}", rest[1:])
    if name not in TOOLS:
        parser().error(f"no subcommand {name!r} (ops-bench --help lists them)")
    return run_tool(TOOLS[name], f"ops-bench {name}", rest)


if __name__ == "__main__":
    sys.exit(main())
