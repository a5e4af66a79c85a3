"""The SPGD-PID baseline in every mode: where the classic controller works and where it stalls.

Runs ``ros2 run ops_gym_bridge evaluate --spgd`` with the paper's SPGD-PID (``spgd.PAPER``: no
normalized gradient, no restarts; ``--variant default`` runs the node's defaults instead) -- the
same evaluation as for learned policies: 5 seeds x 5 episodes of 200 steps, train and test
environments -- for every mode at the given stage, then draws the figure (default
runs/spgd/spgd_baseline.png; docs/results/spgd/index.md's is made with
``--figure docs/figures/spgd_baseline.png``: P_N / P_max against the step, mean and standard
deviation over seeds, on the test environment) and prints a markdown table. ``--store FILE``
also keeps each cell's figures (mode x environment: initial and final P_N / P_max, episode
return) in a small JSON, from which ``ops-bench results`` writes docs/results/spgd/index.md's
table (``--store docs/results/spgd/baseline.json``).

``--sweep`` instead measures, in-process, whether other SPGD settings change the picture in medium
and hard mode, and whether SPGD can hold the optimum against the hard-mode drift when it starts
next to it (``initial_sigma_cycles=0.025, initial_offset_sigmas=0``): mean P_N / P_max over
the last 50 of 300 iterations.

Usage (after `source setup.bash`): ops-bench spgd-baseline [--stage 5] [--out runs/spgd]
                                   [--figure docs/figures/spgd_baseline.png] [--variant paper]
                                   [--store docs/results/spgd/baseline.json]
                                   ops-bench spgd-baseline --sweep [--stage 5]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np


def variant_params(variant: str) -> dict:
    """SPGD's parameters: ``paper`` (Table 1's baseline) or ``default`` (the node's)."""
    from ops_controller_ros.spgd import PAPER

    return dict(PAPER) if variant == "paper" else {}


def evaluate(stage: int, mode: str, out: Path, params: dict) -> dict:
    ros2 = shutil.which("ros2")
    cmd = (
        [ros2, "run", "ops_gym_bridge", "evaluate"]
        if ros2
        else [sys.executable, "-m", "ops_experiments.evaluate"]
    )
    cmd += [
        "--spgd",
        "--stage",
        str(stage),
        "--mode",
        mode,
        "--out",
        str(out),
        "--quiet",
        "--no-plot",
        *(f"--controller-param={k}={str(v).lower()}" for k, v in params.items()),
    ]
    print(f"[spgd] {mode}: {' '.join(cmd[1:] if ros2 else cmd)}", flush=True)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return json.loads((out / "evaluation.json").read_text())


#: a cell's figures kept by ``--store`` (of evaluate's summary of one split)
CELL_KEYS = (
    "initial_power_mean",
    "final_power_mean",
    "final_power_std",
    "episode_return_mean",
    "episode_return_std",
)
TABLE_HEAD = [
    "| mode | environment | initial P_N/P_max | final P_N/P_max (mean ± std over seeds) | "
    "episode return |",
    "|---|---|---|---|---|",
]


def stored_results(results: dict, args, argv: list[str]) -> dict:
    """What ``--store`` keeps: the protocol, the command and each cell's figures, so the
    results page's table needs no run folder (runs/ is not committed)."""
    first = next(iter(results.values()))
    return {
        "command_line": ["ops-bench", "spgd-baseline", *argv],
        "stage": args.stage,
        "variant": args.variant,
        "controller_params": variant_params(args.variant),
        "seeds": first["seeds"],
        "episodes_per_seed": first["episodes_per_seed"],
        "steps": first["steps"],
        "modes": {
            mode: {
                split: {k: round(float(s[k]), 6) for k in CELL_KEYS}
                for split, s in res["splits"].items()
            }
            for mode, res in results.items()
        },
    }


def table_lines(stored: dict) -> list[str]:
    """The markdown table of a stored run (:func:`stored_results`): one row per mode and
    environment; printed here and written by ``ops-bench results``."""
    lines = list(TABLE_HEAD)
    for mode, splits in stored["modes"].items():
        for split in ("train", "test"):
            s = splits[split]
            lines.append(
                f"| {mode} | {split} | {s['initial_power_mean']:.3f} | "
                f"{s['final_power_mean']:.4f} ± {s['final_power_std']:.4f} | "
                f"{s['episode_return_mean']:.1f} ± {s['episode_return_std']:.1f} |"
            )
    return lines


SWEEP = (  # (gain, ki, perturbation_fs, momentum)
    (0.05, 0.0, 0.03, 0.0),
    (0.2, 0.0, 0.03, 0.0),
    (1.0, 0.0, 0.03, 0.0),
    (0.1, 0.1, 0.03, 0.0),
    (0.1, 0.3, 0.03, 0.0),
    (0.2, 0.2, 0.05, 0.0),
    (0.1, 0.0, 0.03, 0.8),
)


def sweep(stage: int, base: dict, seeds: int = 4, iterations: int = 300) -> None:
    from ops_contract.config import make_config
    from ops_experiments.rollouts import rollout_controller

    def run(params, mode, **overrides):
        config = make_config(stage, mode, "test", **overrides)
        finals = []
        for seed in range(seeds):
            # The evaluation's own loop; two steps per SPGD iteration, P_N after each iteration.
            r = rollout_controller("spgd", params, config, config, 1, 2 * iterations, seed)
            finals.append(r["power"][0, 2 * (iterations - 49) :: 2].mean())
        return np.mean(finals)

    print("| gain | ki | perturbation (fs) | momentum | medium | hard | hard, start at optimum |")
    print("|---|---|---|---|---|---|---|")
    for gain, ki, pert, mom in SWEEP:
        p = dict(base, gain=gain, ki=ki, perturbation_fs=pert, momentum=mom)
        print(
            f"| {gain} | {ki} | {pert} | {mom} | {run(p, 'medium'):.3f} | {run(p, 'hard'):.3f} | "
            f"{run(p, 'hard', initial_sigma_cycles=0.025, initial_offset_sigmas=0.0):.3f} |",
            flush=True,
        )


def draw(results: dict, stage: int, variant: str, figure: Path) -> None:
    """P_N / P_max against the step on the test environment, one curve per mode."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 3.6), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    colors = {"easy": "tab:green", "medium": "tab:orange", "hard": "tab:red", "extreme": "k"}
    for mode, res in results.items():
        test = res["splits"]["test"]
        mean = np.asarray(test["curve_mean"])
        std = np.asarray(test.get("curve_std", np.zeros_like(mean)))
        steps = np.arange(mean.size)
        ax.plot(
            steps, mean, color=colors[mode], label=f"{mode}: final {test['final_power_mean']:.3f}"
        )
        ax.fill_between(steps, mean - std, mean + std, color=colors[mode], alpha=0.2, linewidth=0)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("control step (2 steps per SPGD iteration)")
    ax.set_ylabel("P_N / P_max (test environment)")
    label = "the paper's SPGD-PID" if variant == "paper" else "SPGD-PID, node defaults"
    ax.set_title(f"{label}, {stage} stages (200-step episodes)")
    ax.grid(alpha=0.3)
    ax.legend(loc="center right", fontsize=9)
    fig.tight_layout()
    figure.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(figure)
    print(f"[spgd] wrote {figure}")


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stage", type=int, default=5)
    ap.add_argument("--out", default="runs/spgd", help="evaluation outputs")
    ap.add_argument("--figure", default="runs/spgd/spgd_baseline.png")
    ap.add_argument("--variant", choices=("paper", "default"), default="paper")
    ap.add_argument("--sweep", action="store_true", help="SPGD settings sweep (see above)")
    ap.add_argument(
        "--store",
        metavar="FILE",
        help="also keep each cell's figures in this JSON (docs/results/spgd/baseline.json: "
        "the results page's table, written by ops-bench results)",
    )
    args = ap.parse_args(argv)
    params = variant_params(args.variant)
    if args.sweep:
        sweep(args.stage, params)
        return

    from ops_contract.config import MODES

    out = Path(args.out)
    results = {m: evaluate(args.stage, m, out / f"n{args.stage}_{m}", params) for m in MODES}
    draw(results, args.stage, args.variant, Path(args.figure))
    stored = stored_results(results, args, argv)
    if args.store:
        Path(args.store).parent.mkdir(parents=True, exist_ok=True)
        Path(args.store).write_text(json.dumps(stored, indent=1) + "\n")
        print(f"[spgd] wrote {args.store}")
    print("\n".join(table_lines(stored)))


if __name__ == "__main__":
    main()
