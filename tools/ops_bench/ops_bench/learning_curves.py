"""``ops-bench learning-curves``: training recipes compared on their learning curves.

Each run is a folder with ``learning.csv`` (``minutes``, ``env_steps``, ``test_final_power``
and, from ``distill``, ``test_worst``: the periodic test evaluation of ``train --eval-freq`` or
``distill``) and ``metadata.json`` (its recipe: ``recipe``, else ``sac`` for a ``train`` run;
its mode). Draws P_N / P_max against wall minutes and against environment steps, with the
paper's TD3 budget (300,000 steps) marked, and writes a table: the best evaluation (mean and
worst episode), the first minute and environment step where the mean reached ``--reach``
(0.95), and, where the folder has ``eval/evaluation.json`` (``evaluate --out DIR/eval``), that
held-out evaluation's mean and worst episode.

``--run LABEL=DIR`` (repeatable); without it, the shipped students ``models/*_dagger`` and the
shipped fast-SAC models ``models/n5_{easy,medium,hard}``.
"""

from __future__ import annotations

import argparse
import csv
import json
import shlex
import sys
from pathlib import Path

from . import REPO

PAPER_TD3_STEPS = 300_000
DEFAULT_SAC = ("n5_easy", "n5_medium", "n5_hard")
COLORS = {"easy": "tab:green", "medium": "tab:orange", "hard": "tab:red", "extreme": "tab:purple"}
LAB_COLOR = "tab:brown"  # a run on the lab rig (whatever its mode)


def read_curve(folder: Path) -> list[dict]:
    rows = []
    with (folder / "learning.csv").open() as fh:
        for row in csv.DictReader(fh):
            rows.append(
                {
                    "minutes": float(row["minutes"]),
                    "env_steps": int(float(row["env_steps"])),
                    "mean": float(row["test_final_power"]),
                    "worst": float(row["test_worst"]) if row.get("test_worst") else None,
                }
            )
    return rows


def _rig_of(meta: dict) -> str:
    """The lab rig ("lab") for a run on it or on rigs drawn from it; "" for the ideal rig, also
    when only the latency was drawn (an ideal rig whose commands may come a step late)."""
    drawn = set(meta.get("rig_randomize") or {}) - {"latency_steps"}
    return "lab" if drawn or (meta.get("rig") or {}).get("realism") else ""


def describe(label: str, folder: Path) -> dict:
    """One run's curve and figures."""
    meta = json.loads((folder / "metadata.json").read_text())
    curve = read_curve(folder)
    best = max(curve, key=lambda r: ((r["worst"] or 0.0) >= 0.8, r["mean"]))
    item = {
        "label": label,
        "folder": str(folder.relative_to(REPO) if folder.is_relative_to(REPO) else folder),
        "recipe": meta.get("recipe", meta.get("algo", "?")),
        "mode": meta.get("mode", "?"),
        "rig": _rig_of(meta),
        "curve": curve,
        "best": best,
        "training_wall_s": meta.get("training_wall_s"),
        "episodes_per_point": meta.get("eval_episodes"),
    }
    ev = folder / "eval" / "evaluation.json"
    if ev.exists():
        test = json.loads(ev.read_text())["splits"].get("test", {})
        item["held_out"] = (test.get("final_power_mean"), test.get("final_power_min_episode"))
        item["held_out_episodes"] = len(test.get("final_power_per_episode", []))
    return item


def first_reach(curve: list[dict], level: float) -> tuple[float | None, int | None]:
    for r in curve:
        if r["mean"] >= level:
            return r["minutes"], r["env_steps"]
    return None, None


def draw(items: list[dict], path: Path, reach: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), sharey=True)
    # One mode and rig for all (a side-by-side run of the recipes): a colour per run; else a
    # colour per mode (the lab rig its own), the recipe told by the line.
    one_kind = len({(it["mode"], bool(it["rig"])) for it in items}) == 1
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, it in enumerate(items):
        style = "-" if it["recipe"].startswith("dagger") else ":"
        if one_kind:
            color = cycle[k % len(cycle)]
        else:
            color = LAB_COLOR if it["rig"] else COLORS.get(it["mode"], "gray")
        xs_m = [r["minutes"] for r in it["curve"]]
        xs_s = [max(r["env_steps"], 1) for r in it["curve"]]
        ys = [r["mean"] for r in it["curve"]]
        for ax, xs in zip(axes, (xs_m, xs_s), strict=True):
            ax.plot(xs, ys, style, color=color, marker=".", ms=3, label=it["label"])
    axes[0].set_xscale("log")
    axes[1].set_xscale("log")
    axes[1].axvline(PAPER_TD3_STEPS, color="k", lw=0.8, ls="--")
    axes[1].text(PAPER_TD3_STEPS * 1.05, 0.05, "paper's TD3\nbudget (300k)", fontsize=8)
    for ax in axes:
        ax.axhline(reach, color="gray", lw=0.6, ls="--")
        ax.set_ylim(0, 1.01)
        ax.grid(alpha=0.3)
    axes[0].set_xlabel("wall minutes (one core, shared machine)")
    axes[1].set_xlabel("environment steps (every simulated step)")
    axes[0].set_ylabel("test final P_N / P_max (mean)")
    axes[1].legend(fontsize=7, loc="lower right")
    modes = sorted({it["mode"] for it in items})
    fig.suptitle(
        f"Rig-view students (DAgger, solid) against training by reward (dotted), {', '.join(modes)}"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(x, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def table(items: list[dict], reach: float) -> list[str]:
    lines = [
        f"| run | recipe | mode | best test mean | its worst | minutes to {reach} | "
        f"env steps to {reach} | held-out mean | held-out worst | folder |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for it in items:
        minutes, steps = first_reach(it["curve"], reach)
        held = it.get("held_out", (None, None))
        mode = it["mode"] + (", lab rig" if it["rig"] else "")
        lines.append(
            f"| {it['label']} | {it['recipe']} | {mode} | {it['best']['mean']:.4f} | "
            f"{_fmt(it['best']['worst'], '.4f')} | {_fmt(minutes, '.1f')} | "
            f"{_fmt(steps, ',')} | {_fmt(held[0], '.4f')} | {_fmt(held[1], '.4f')} | "
            f"`{it['folder']}` |"
        )
    return lines


def default_runs() -> list[tuple[str, Path]]:
    runs = [(p.name, p) for p in sorted((REPO / "models").glob("*_dagger")) if _usable(p)]
    runs += [(f"{n} (fast SAC)", REPO / "models" / n) for n in DEFAULT_SAC]
    return [(label, p) for label, p in runs if _usable(p)]


def _usable(folder: Path) -> bool:
    return (folder / "learning.csv").exists() and (folder / "metadata.json").exists()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ops-bench learning-curves", description=__doc__)
    p.add_argument("--run", action="append", default=[], metavar="LABEL=DIR")
    p.add_argument("--reach", type=float, default=0.95, help="the level whose cost is tabled")
    p.add_argument("--figure", default="docs/figures/learned_recipes.png")
    p.add_argument("--results", default="docs/results/learned_recipes")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    runs = [(s.split("=", 1)[0], Path(s.split("=", 1)[1])) for s in args.run] or default_runs()
    items = [describe(label, (REPO / p).resolve()) for label, p in runs]
    if not items:
        print("learning-curves: no run with learning.csv and metadata.json", file=sys.stderr)
        return 2
    draw(items, REPO / args.figure, args.reach)
    lines = table(items, args.reach)
    out = REPO / args.results
    out.mkdir(parents=True, exist_ok=True)
    command = "ops-bench learning-curves " + shlex.join(sys.argv[1:] if argv is None else argv)
    (out / "table.md").write_text(
        f"Command: `{command.strip()}`\n\n" + "\n".join(lines) + "\n", encoding="utf-8"
    )
    print("\n".join(lines))
    print(f"[learning-curves] {args.figure}, {args.results}/table.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
