#!/usr/bin/env python3
"""Figure of the shipped learned agents (issue 11): the periodic test evaluation (final
P_N / P_max, 20 episodes) against minutes of training, one line per model folder under models/,
from their learning.csv (written by scripts/ship_model.py), with the paper's TD3 testing figures
at N = 5 for reference.

Usage (after `source setup.bash`): python scripts/make_learned_figures.py
Writes docs/figures/learned_agents.png and the table of models/README.md (between its markers).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

REPO = Path(__file__).resolve().parents[1]
PAPER_TD3_TEST_N5 = {"easy": 0.954, "medium": 0.911, "hard": 0.813}  # the paper's Table 1
GOALS_N5 = {"easy": 0.99, "medium": 0.97, "hard": 0.95}  # issue 11
BEGIN, END = "<!-- table: make_learned_figures.py -->", "<!-- end of table -->"


def table_rows() -> list[str]:
    """One markdown row per shipped model, from its metadata, learning curve and evaluation."""
    rows = [
        "| model | N, mode | memory k | training run (one core) | env steps of the kept model "
        "| held-out test final P_N / P_max | issue 11 goal | paper's TD3 (N = 5, its detector) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for folder in sorted((REPO / "models").glob("*/eval/evaluation.json")):
        model = folder.parents[1]
        meta = json.loads((model / "metadata.json").read_text())
        test = json.loads(folder.read_text())["splits"]["test"]
        with open(model / "learning.csv", newline="") as f:
            curve = list(csv.DictReader(f))
        minutes = float(curve[-1]["minutes"]) if curve else float("nan")
        n, mode = meta["stage"], meta["mode"]
        goal = f">= {GOALS_N5[mode]}" if n == 5 and mode in GOALS_N5 else "-"
        paper = f"{PAPER_TD3_TEST_N5[mode]}" if n == 5 and mode in PAPER_TD3_TEST_N5 else "-"
        rows.append(
            f"| `models/{model.name}` | {n}, {mode} | {meta.get('obs_history', 0)} | "
            f"{minutes:.0f} min | {meta['timesteps']:,} | {test['final_power_mean']:.3f} ± "
            f"{test['final_power_std']:.3f} | {goal} | {paper} |"
        )
    return rows


def write_table(path: Path) -> None:
    text = path.read_text()
    head, rest = text.split(BEGIN, 1)
    tail = rest.split(END, 1)[1]
    path.write_text(head + BEGIN + "\n" + "\n".join(table_rows()) + "\n" + END + tail)
    print("wrote", path)


def main() -> int:
    fig, ax = plt.subplots(figsize=(9, 4.8))
    colors = {"easy": "tab:green", "medium": "tab:orange", "hard": "tab:red"}
    for folder in sorted((REPO / "models").glob("*/learning.csv")):
        meta = json.loads((folder.parent / "metadata.json").read_text())
        cfg = meta["config"]
        with open(folder, newline="") as f:
            rows = list(csv.DictReader(f))
        minutes = [float(r["minutes"]) for r in rows]
        power = [float(r["test_final_power"]) for r in rows]
        history = meta.get("obs_history", 0)
        label = f"{folder.parent.name}: N = {cfg['stage']} {cfg['mode']}, memory k = {history}"
        style = "-" if cfg["stage"] == 5 else ":"
        ax.plot(minutes, power, style, color=colors.get(cfg["mode"]), label=label)
    for mode, value in PAPER_TD3_TEST_N5.items():
        ax.axhline(value, color=colors[mode], lw=0.8, ls="--", alpha=0.6)
        ax.text(0.5, value + 0.005, f"paper TD3, N = 5 {mode} (300k steps)", fontsize=7)
    ax.set_xlabel("training time (minutes, one core)")
    ax.set_ylabel("test final P_N / P_max (20 episodes)")
    ax.set_ylim(0, 1.02)
    ax.set_title("Learned agents (SAC, `--hyperparams-set fast`, polarizer detector)")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    out = REPO / "docs" / "figures" / "learned_agents.png"
    fig.savefig(out, dpi=110)
    print("wrote", out)
    write_table(REPO / "models" / "README.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
