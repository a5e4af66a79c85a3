"""Figure of the shipped learned agents: the periodic test evaluation (final
P_N / P_max, 20 episodes) against minutes of training, one line per model folder under models/,
from their learning.csv (written by `ops-bench ship-model`), with the paper's TD3 testing figures
at N = 5 for reference.

Usage (after `source setup.bash`): ops-bench figures learned
Writes docs/figures/learned_agents.png and the table of models/README.md (between its markers).
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from ops_experiments.table1.report import PAPER_TABLE1

from ops_bench import REPO
from ops_bench.reference_actions import model_realism

MODES = ("easy", "medium", "hard")
PAPER_TD3_TEST_N5 = {m: PAPER_TABLE1[(m, "test")]["td3"][0] for m in MODES}  # N = 5
GOALS_N5 = {"easy": 0.99, "medium": 0.97, "hard": 0.95}  # the learned agents' goals, N = 5
ABLATIONS = REPO / "docs" / "results" / "issue11"  # runs kept as curves only
TABLE1_RUNS = REPO / "docs" / "results" / "n5_quick" / "runs"
BEGIN, END = "<!-- table: make_learned_figures.py -->", "<!-- end of table -->"


def load_models() -> list[dict]:
    """Per shipped folder: its name, metadata, learning curve and held-out test summary."""
    models = []
    for meta_path in sorted((REPO / "models").glob("*/metadata.json")):
        folder = meta_path.parent
        with open(folder / "learning.csv", newline="") as f:
            curve = list(csv.DictReader(f))
        evaluation = json.loads((folder / "eval" / "evaluation.json").read_text())
        models.append(
            {
                "name": folder.name,
                "meta": json.loads(meta_path.read_text()),
                "curve": curve,
                "test": evaluation["splits"]["test"],
            }
        )
    return models


def table_rows(models: list[dict]) -> list[str]:
    """One markdown row per shipped model."""
    rows = [
        "| model | N, mode | memory k | training reward | training run (one core) "
        "| env steps of the kept model | held-out test final P_N / P_max (mean ± std over seeds) "
        "| worst episode | episodes | goal | paper's TD3 (N = 5, its detector) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m in models:
        meta, test, curve = m["meta"], m["test"], m["curve"]
        # a fine-tune without periodic evaluations has no curve: its runs' wall time, summed
        wall = sum(float(h.get("wall_s") or 0.0) for h in meta.get("history", []))
        minutes = float(curve[-1]["minutes"]) if curve else wall / 60.0
        n, mode = meta["stage"], meta["mode"]
        n5 = n == 5 and mode in GOALS_N5
        goal = f">= {GOALS_N5[mode]}" if n5 else "-"
        paper = f"{PAPER_TD3_TEST_N5[mode]:.3f}" if n5 else "-"
        realism = model_realism(meta)
        where = f"{n}, {mode}" + ("" if realism == "ideal" else f", `{realism}` rig")
        rows.append(
            f"| `models/{m['name']}` | {where} | {meta.get('obs_history', 0)} | "
            f"{meta.get('reward') or 'paper'} | "
            f"{minutes:.0f} min | {meta['timesteps']:,} | {test['final_power_mean']:.3f} ± "
            f"{test['final_power_std']:.3f} | {test['final_power_min_episode']:.3f} | "
            f"{len(test.get('final_power_per_episode', [])) or '-'} | {goal} | {paper} |"
        )
    return rows


def write_table(path: Path, models: list[dict]) -> None:
    text = path.read_text()
    head, rest = text.split(BEGIN, 1)
    tail = rest.split(END, 1)[1]
    path.write_text(head + BEGIN + "\n" + "\n".join(table_rows(models)) + "\n" + END + tail)
    print("wrote", path)


def load_ablations() -> list[dict]:
    """Runs kept for the figure only (`ops-bench ship-model --curve-only`): metadata + curve."""
    runs = []
    for meta_path in sorted(ABLATIONS.glob("*/metadata.json")):
        with open(meta_path.parent / "learning.csv", newline="") as f:
            curve = list(csv.DictReader(f))
        meta = json.loads(meta_path.read_text())
        runs.append({"name": meta_path.parent.name, "meta": meta, "curve": curve})
    return runs


def paper_faithful_curves(mode: str) -> list[tuple[list[float], list[float]]]:
    """The Table 1 SAC runs of ``mode`` (the paper's set, k = 0; docs/results/n5_quick): the
    training episodes' final P_N/P_max (moving mean of 20) against minutes of training, the
    minutes spread evenly over the run's measured training wall time."""
    curves = []
    for run in sorted(TABLE1_RUNS.glob(f"n5_{mode}_sac_s*")):
        info = json.loads((run / "run.json").read_text())
        with open(run / "training.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        steps = np.array([float(r["timesteps"]) for r in rows])
        power = np.array([float(r["final_power"]) for r in rows])
        if steps.size < 20:
            continue
        smooth = np.convolve(power, np.ones(20) / 20, mode="valid")
        minutes = steps[19:] / info["timesteps"] * info["train_wall_s"] / 60.0
        curves.append((minutes.tolist(), smooth.tolist()))
    return curves


def run_label(meta: dict, prefix: str) -> str:
    k = meta.get("obs_history", 0)
    reward = meta.get("reward") or "paper"
    detector = meta.get("detector", "polarizer")
    n = meta["stage"]
    realism = model_realism(meta)
    rig = "" if realism == "ideal" else f", {realism} rig"
    return f"{prefix}: N = {n}, {meta['algo']}, k = {k}, reward {reward}, {detector}{rig}"


def plot_curve(ax, run: dict, label: str, **style) -> None:
    minutes = [float(r["minutes"]) for r in run["curve"]]
    power = [float(r["test_final_power"]) for r in run["curve"]]
    ax.plot(minutes, power, label=label, **style)


def main(argv=None) -> int:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args(argv)
    fig, axes = plt.subplots(1, 3, figsize=(15, 5), sharey=True)
    models, ablations = load_models(), load_ablations()
    for ax, mode in zip(axes, MODES, strict=True):
        for m in (m for m in models if m["meta"]["mode"] == mode and m["curve"]):
            five = m["meta"]["stage"] == 5
            on_rig = model_realism(m["meta"]) != "ideal"
            ls = "--" if on_rig else "-" if five else ":"
            style = {"lw": 2.2 if five else 1.4, "ls": ls, "color": "black"}
            plot_curve(ax, m, run_label(m["meta"], f"models/{m['name']}"), **style)
        colors = iter(plt.cm.tab10.colors)
        for a in (a for a in ablations if a["meta"]["mode"] == mode):
            plot_curve(ax, a, run_label(a["meta"], a["name"]), lw=1.2, color=next(colors))
        for i, (minutes, power) in enumerate(paper_faithful_curves(mode)):
            label = "Table 1 SAC (paper set, k = 0, total; training episodes)" if i == 0 else None
            ax.plot(minutes, power, color="0.6", lw=0.9, label=label)
        ax.axhline(PAPER_TD3_TEST_N5[mode], color="tab:blue", lw=0.9, ls="--")
        ax.text(0.5, PAPER_TD3_TEST_N5[mode] - 0.035, "paper TD3, 300k steps", fontsize=7)
        ax.axhline(GOALS_N5[mode], color="tab:green", lw=0.9, ls="--")
        ax.text(0.5, GOALS_N5[mode] + 0.008, "goal", fontsize=7)
        ax.set_title(f"N = 5, {mode} mode (testing environment)")
        ax.set_xlabel("training time (minutes, one core)")
        ax.set_ylim(0, 1.03)
        ax.legend(fontsize=6.5, loc="lower right")
    axes[0].set_ylabel("final P_N / P_max (periodic test evaluation, 20 episodes)")
    fig.suptitle(
        "Learned agents against training time; black: shipped models (dashed: "
        "trained and tested on a rig that is not ideal)"
    )
    fig.tight_layout()
    out = REPO / "docs" / "figures" / "learned_agents.png"
    fig.savefig(out, dpi=110)
    print("wrote", out)
    write_table(REPO / "models" / "README.md", models)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
