"""``ros2 run ops_gym_bridge report RUNS_DIR --out DIR``: Table 1 and Figures 7-11 and 17 of the
paper from stored benchmark runs alone (``RUNS_DIR/runs/<id>/``, written by ``benchmark``; no
training, no model needed).

Writes ``table1.md`` / ``table1.csv`` (final P_N / P_max, mean ± std over training seeds, or over
evaluation seeds for the no-training controllers; training and testing environment; per mode and
controller, the paper's Table 1 beside ours), ``fig7_training.png`` (training reward per step vs
steps), ``fig8_control.png`` (P_N / P_max vs control step, testing environment),
``fig9_stages.png`` (hard mode, TD3, N = 1...6: training and testing curves),
``fig10_convergence.png`` (hard mode, TD3 and SAC: final P_N and steps to converge vs N),
``fig11_transfer.png`` (a policy trained on one mode evaluated on every mode's testing
environment) and ``fig17_traces.png`` (output traces of a trained agent on N = 5 hard mode from a
random start). Partial results are reported as such: every panel and table names what it covers.

Several run directories (``report A B --out DIR``, e.g. the same protocol with the authors' and
the rig's observation set): each one's table and figures go to ``DIR/<name of A>/`` ...,
and ``DIR/table1_sets.md`` puts their Table 1 cells side by side. With ``--pool`` they are
one set instead (one protocol whose seeds were stored in several directories): one report in
``DIR``, each cell over all their seeds.
"""

from __future__ import annotations

import csv
import io
import sys
from pathlib import Path
from typing import Any

import numpy as np

from .. import cli_args
from . import figures
from .runs import ALGO_ORDER, SPLITS, controller_order, load_runs, main_stage, pool_runs

#: The paper's Table 1 (N = 5): (mode, environment) -> algo -> (mean, std).
PAPER_TABLE1 = {
    ("easy", "train"): {"ppo": (0.7684, 0.0884), "td3": (0.9580, 0.0189), "sac": (0.9637, 0.0172)},
    ("easy", "test"): {"ppo": (0.7439, 0.0463), "td3": (0.9541, 0.0177), "sac": (0.9514, 0.0231)},
    ("medium", "train"): {
        "ppo": (0.6210, 0.0828),
        "td3": (0.9204, 0.0351),
        "sac": (0.8945, 0.0501),
    },
    ("medium", "test"): {
        "ppo": (0.6182, 0.0229),
        "td3": (0.9106, 0.0217),
        "sac": (0.8833, 0.0838),
    },
    ("hard", "train"): {"ppo": (0.5473, 0.0680), "td3": (0.8524, 0.0380), "sac": (0.8515, 0.0375)},
    ("hard", "test"): {"ppo": (0.4461, 0.0300), "td3": (0.8130, 0.0215), "sac": (0.8071, 0.0164)},
}


# ------------------------------------------------------------------------------ Table 1
def table1_rows(runs: list[dict]) -> list[dict[str, Any]]:
    stage = main_stage(runs)
    names = controller_order(runs)
    modes = [m for m in ("easy", "medium", "hard", "extreme") if any(r["mode"] == m for r in runs)]
    rows = []
    for mode in modes:
        for split in SPLITS:
            for name in names:
                rs = [r for r in runs if r["stage"] == stage and r["mode"] == mode]
                rs = [r for r in rs if r["name"] == name]
                if not rs:
                    continue
                if rs[0]["kind"] == "controller":  # spread over evaluation seeds
                    vals = np.array(rs[0]["eval"]["splits"][split]["final_power_per_seed"])
                    over = "evaluation seeds"
                else:
                    vals = np.array([r["eval"]["splits"][split]["final_power_mean"] for r in rs])
                    over = "training seeds"
                paper = PAPER_TABLE1.get((mode, split), {}).get(name) if stage == 5 else None
                rows.append(
                    {
                        "stage": stage,
                        "mode": mode,
                        "environment": "training" if split == "train" else "testing",
                        "controller": name,
                        "n": len(vals),
                        "over": over,
                        "timesteps": rs[0]["timesteps"] if rs[0]["kind"] == "train" else 0,
                        "mean": round(float(vals.mean()), 4),
                        "std": round(float(vals.std()), 4),
                        "paper_mean": paper[0] if paper else "",
                        "paper_std": paper[1] if paper else "",
                        "detector": rs[0]["detector"],
                        "observation": rs[0]["observation"],
                    }
                )
    return rows


def table1_csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    fields = [
        "stage",
        "mode",
        "environment",
        "controller",
        "n",
        "over",
        "timesteps",
        "mean",
        "std",
        "paper_mean",
        "paper_std",
        "detector",
    ]
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (f"{r[k]:.4f}" if k in ("mean", "std") else r[k]) for k in fields})
    return buf.getvalue()


def table1_md(rows: list[dict]) -> str:
    if not rows:
        return "No stored runs.\n"
    names = list(dict.fromkeys(r["controller"] for r in rows))
    head = ["mode", "environment"]
    for n in names:
        head.append(f"{n.upper()} (ours)")
        if n in ALGO_ORDER:
            head.append(f"{n.upper()} (paper)")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    by = {(r["mode"], r["environment"], r["controller"]): r for r in rows}
    for mode, env in dict.fromkeys((r["mode"], r["environment"]) for r in rows):
        cells = [mode, env]
        for n in names:
            r = by.get((mode, env, n))
            cells.append(f"{r['mean']:.4f} ± {r['std']:.4f} (n={r['n']})" if r else "—")
            if n in ALGO_ORDER:
                p = PAPER_TABLE1.get((mode, "train" if env == "training" else "test"), {}).get(n)
                cells.append(f"{p[0]:.4f} ± {p[1]:.4f}" if p and rows[0]["stage"] == 5 else "—")
        lines.append("| " + " | ".join(cells) + " |")
    steps = {r["controller"]: r["timesteps"] for r in rows if r["timesteps"] and r["controller"]}
    notes = [
        "",
        f"N = {rows[0]['stage']}, detector `{rows[0]['detector']}`, observation set of the agents "
        f"`{_observation_of(rows)}`. Final P_N/P_max after the last "
        "step of each evaluation episode; mean ± std over training seeds (n) for the trained "
        "agents, over evaluation seeds (n) for the no-training controllers.",
        "Training steps per run: "
        + (", ".join(f"{k.upper()} {v:,}" for k, v in steps.items()) or "none")
        + "; the paper trained 300,000 steps (its Figures 7-8) with 10 seeds.",
    ]
    return "\n".join(lines + notes) + "\n"


def _observation_of(rows: list[dict]) -> str:
    sets = {r["observation"] for r in rows if r["over"] == "training seeds"}
    return ", ".join(sorted(sets)) or "none (no trained agent stored)"


def table1_sets_md(tables: dict[str, list[dict]]) -> str:
    """Table 1 cells of several run directories (label -> rows of :func:`table1_rows`) side by
    side: one line per mode, environment and controller."""
    labels = list(tables)
    head = ["mode", "environment", "controller", "paper"]
    head += [f"{lab} ({_observation_of(tables[lab])})" for lab in labels]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    keys = []
    for rows in tables.values():
        keys += [(r["mode"], r["environment"], r["controller"]) for r in rows]
    order = {m: i for i, m in enumerate(("easy", "medium", "hard", "extreme"))}
    keys = sorted(dict.fromkeys(keys), key=lambda k: (order.get(k[0], 9), k[1] != "training"))
    by = {
        lab: {(r["mode"], r["environment"], r["controller"]): r for r in tables[lab]}
        for lab in labels
    }
    paper_stage = all(r["stage"] == 5 for rows in tables.values() for r in rows)
    for mode, env, name in keys:
        p = PAPER_TABLE1.get((mode, "train" if env == "training" else "test"), {}).get(name)
        p = p if paper_stage else None
        cells = [mode, env, name.upper(), f"{p[0]:.4f} ± {p[1]:.4f}" if p else "—"]
        for lab in labels:
            r = by[lab].get((mode, env, name))
            cells.append(f"{r['mean']:.4f} ± {r['std']:.4f} (n={r['n']})" if r else "not run yet")
        lines.append("| " + " | ".join(cells) + " |")
    notes = [
        "",
        "Final P_N/P_max, mean ± std over training seeds (n) for the agents, over evaluation "
        "seeds for the no-training controllers; each column is one run directory "
        "(`ros2 run ops_gym_bridge report " + " ".join(labels) + " --out DIR`).",
    ]
    return "\n".join(lines + notes) + "\n"


FILES = (
    "table1.md",
    "table1.csv",
    "fig7_training.png",
    "fig8_control.png",
    "fig9_stages.png",
    "fig10_convergence.png",
    "fig11_transfer.png",
    "fig17_traces.png",
)


def write_report(root: Path, out: Path) -> list[Path]:
    return write_runs_report(load_runs(root), out)


def write_runs_report(runs: list[dict], out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    rows = table1_rows(runs)
    (out / "table1.csv").write_text(table1_csv(rows))
    (out / "table1.md").write_text(table1_md(rows))
    modes = [m for m in ("easy", "medium", "hard", "extreme") if any(r["mode"] == m for r in runs)]
    modes = modes or ["easy", "medium", "hard"]
    figures.fig7(runs, out / "fig7_training.png", modes)
    figures.fig8(runs, out / "fig8_control.png", modes)
    figures.fig9(runs, out / "fig9_stages.png")
    figures.fig10(runs, out / "fig10_convergence.png")
    figures.fig11(runs, out / "fig11_transfer.png", modes)
    figures.fig17(runs, out / "fig17_traces.png")
    return [out / f for f in FILES]


def build_parser():
    p = cli_args.make_parser("report", "Table 1 and Figures 7-11, 17 from stored benchmark runs.")
    p.add_argument(
        "runs_dir",
        nargs="+",
        help="the benchmark's --out directory (or its runs/); several: each one's report in "
        "OUT/<its name>/ and their Table 1 side by side in OUT/table1_sets.md",
    )
    p.add_argument("--out", required=True, help="directory for the table and figures")
    p.add_argument(
        "--pool",
        action="store_true",
        help="the run directories are one set (one protocol's seeds stored in several "
        "directories): one report in OUT, each cell over all their runs",
    )
    return p


def run(argv: list[str] | None = None) -> int:
    args = cli_args.parse_args(build_parser(), argv)
    roots = [Path(d) for d in args.runs_dir]
    for root in roots:
        if not root.is_dir():
            print(f"[report] error: {root} is not a directory", file=sys.stderr)
            return 2
    out = Path(args.out)
    if args.pool:
        try:
            runs = pool_runs(roots)
        except ValueError as err:
            print(f"[report] error: {err}", file=sys.stderr)
            return 2
        written = write_runs_report(runs, out)
        print((out / "table1.md").read_text(), flush=True)
    elif len(roots) == 1:
        written = write_report(roots[0], out)
        print((out / "table1.md").read_text(), flush=True)
    else:
        if len({r.resolve().name for r in roots}) < len(roots):
            print("[report] error: the run directories need different names", file=sys.stderr)
            return 2
        written, tables = [], {}
        for root in roots:
            name = root.resolve().name
            written += write_report(root, out / name)
            tables[name] = table1_rows(load_runs(root))
        (out / "table1_sets.md").write_text(table1_sets_md(tables))
        written.append(out / "table1_sets.md")
        print((out / "table1_sets.md").read_text(), flush=True)
    print(f"[report] wrote {', '.join(str(p) for p in written)}")
    return 0


def main(argv: list[str] | None = None) -> None:
    sys.exit(run(argv))


if __name__ == "__main__":
    main()
