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
from ops_gym_bridge.report import PAPER_TABLE1

REPO = Path(__file__).resolve().parents[1]
MODES = ("easy", "medium", "hard")
PAPER_TD3_TEST_N5 = {m: PAPER_TABLE1[(m, "test")]["td3"][0] for m in MODES}  # N = 5
GOALS_N5 = {"easy": 0.99, "medium": 0.97, "hard": 0.95}  # issue 11
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
        "| model | N, mode | memory k | training run (one core) | env steps of the kept model "
        "| held-out test final P_N / P_max | issue 11 goal | paper's TD3 (N = 5, its detector) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in models:
        meta, test, curve = m["meta"], m["test"], m["curve"]
        minutes = float(curve[-1]["minutes"]) if curve else float("nan")
        n, mode = meta["stage"], meta["mode"]
        n5 = n == 5 and mode in GOALS_N5
        goal = f">= {GOALS_N5[mode]}" if n5 else "-"
        paper = f"{PAPER_TD3_TEST_N5[mode]:.3f}" if n5 else "-"
        rows.append(
            f"| `models/{m['name']}` | {n}, {mode} | {meta.get('obs_history', 0)} | "
            f"{minutes:.0f} min | {meta['timesteps']:,} | {test['final_power_mean']:.3f} ± "
            f"{test['final_power_std']:.3f} | {goal} | {paper} |"
        )
    return rows


def write_table(path: Path, models: list[dict]) -> None:
    text = path.read_text()
    head, rest = text.split(BEGIN, 1)
    tail = rest.split(END, 1)[1]
    path.write_text(head + BEGIN + "\n" + "\n".join(table_rows(models)) + "\n" + END + tail)
    print("wrote", path)


def main() -> int:
    fig, ax = plt.subplots(figsize=(9, 4.8))
    colors = {"easy": "tab:green", "medium": "tab:orange", "hard": "tab:red"}
    models = load_models()
    for m in models:
        cfg = m["meta"]["config"]
        minutes = [float(r["minutes"]) for r in m["curve"]]
        power = [float(r["test_final_power"]) for r in m["curve"]]
        history = m["meta"].get("obs_history", 0)
        label = f"{m['name']}: N = {cfg['stage']} {cfg['mode']}, memory k = {history}"
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
    write_table(REPO / "models" / "README.md", models)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
