#!/usr/bin/env python3
"""Figure of the shipped learned agents (issue 11): the periodic test evaluation (final
P_N / P_max, 20 episodes) against minutes of training, one line per model folder under models/,
from their learning.csv (written by scripts/ship_model.py), with the paper's TD3 testing figures
at N = 5 for reference.

Usage (after `source setup.bash`): python scripts/make_learned_figures.py
Writes docs/figures/learned_agents.png.
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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
