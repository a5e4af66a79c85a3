"""``ros2 run ops_gym_bridge realism_sweep``: how the controllers hold on rigs that are not ideal.

One rig figure at a time away from the ideal stacker (latency, trace bits, piezo hysteresis,
pulse amplitude noise), then the ``lab`` preset with all of them, for the tracker, SPGD-PID and
the shipped learned models, in each mode asked for (N = 5, testing split). Each cell is one
``evaluate`` run on the same held-out seeds, told of the rig (``--rig`` / ``--realism``): the
controllers' nominal models know the figures; a learned model knows only what it was trained on.

Cells are stored as they finish (``OUT/cells/<subject>_<mode>_<case>/evaluation.json``) and
skipped when found, so an interrupted sweep resumes with the same command. At the end the sweep
writes ``OUT/summary.json``, the table ``OUT/index.md`` (mean and worst episode of every cell)
and the figure ``--figure``, and prints the table.
"""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from ops_contract.heap import freeze_after_heavy_imports

from . import cli_args

#: (case name, evaluate arguments): the ideal rig, one figure at a time, then the lab preset.
CASES: tuple[tuple[str, list[str]], ...] = (
    ("ideal", []),
    *((f"latency {k}", ["--rig", f"latency_steps={k}"]) for k in (1, 2, 4)),
    *((f"{b}-bit trace", ["--rig", f"trace_adc_bits={b}"]) for b in (12, 10, 8, 6)),
    *((f"hysteresis {h}%", ["--rig", f"actuator_hysteresis={h / 100}"]) for h in (5, 15)),
    *((f"amplitude noise {a}%", ["--rig", f"pulse_amplitude_noise={a / 100}"]) for a in (1, 3)),
    ("lab", ["--realism", "lab"]),
)
#: The figure's panels: (title, case-name prefix, x values of the cases, the ideal's x).
PANELS = (
    ("latency, steps", "latency ", (1, 2, 4), 0),
    ("trace digitizer, bits", "-bit trace", (12, 10, 8, 6), 16),
    ("piezo hysteresis, % of travel", "hysteresis ", (5, 15), 0),
    ("pulse energy noise, % rms", "amplitude noise ", (1, 3), 0),
)
CONTROLLERS = ("tracker", "spgd")
#: The learned models of each mode: the students the README names (the hard one trained on the
#: lab rig too; in easy mode the medium student, which holds it without the easy one's tail),
#: and the SAC models they replaced, for comparison.
MODELS = {
    "easy": ("models/n5_easy_dagger", "models/n5_medium_dagger"),
    "medium": ("models/n5_medium", "models/n5_medium_dagger"),
    "hard": (
        "models/n5_hard",
        "models/n5_hard_switch",
        "models/n5_hard_lab",
        "models/n5_hard_dagger",
        "models/n5_hard_lab_dagger",
    ),
}
DEFAULT_SEEDS = tuple(range(8301, 8321))  # never used for training or tuning


def build_parser():
    p = cli_args.make_parser(
        "realism_sweep", "Final P_N/P_max of the controllers against the rig's imperfections."
    )
    p.add_argument("--modes", nargs="+", default=["easy", "medium", "hard"], help="modes (N = 5)")
    p.add_argument(
        "--subjects",
        nargs="+",
        default=[*CONTROLLERS, "models"],
        help="tracker, spgd, models (the README's models of each mode) or model directories",
    )
    p.add_argument("--cases", nargs="+", help="case names (default: all; see --list)")
    p.add_argument("--seeds", type=int, nargs="+", default=list(DEFAULT_SEEDS))
    p.add_argument("--episodes", type=int, default=5, help="episodes per seed")
    p.add_argument("--jobs", type=int, default=1, help="evaluations at once")
    p.add_argument("--out", default="docs/results/realism_sweep", help="stored cells and table")
    p.add_argument("--figure", default="docs/figures/realism_sweep.png", help="the figure")
    p.add_argument("--list", action="store_true", help="print the cells and exit")
    return p


def cells(args) -> list[dict[str, Any]]:
    """Every (subject, mode, case) of the sweep, with its evaluate arguments."""
    cases = [c for c in CASES if not args.cases or c[0] in args.cases]
    unknown = set(args.cases or ()) - {c[0] for c in CASES}
    if unknown:
        raise ValueError(f"unknown case(s) {sorted(unknown)}; allowed: {[c[0] for c in CASES]}")
    out = []
    for mode in args.modes:
        subjects = []
        for s in args.subjects:
            subjects += list(MODELS.get(mode, ())) if s == "models" else [s]
        for subject in subjects:
            base = ["--controller", subject] if subject in CONTROLLERS else [subject]
            for case, extra in cases:
                name = f"{Path(subject).name}_{mode}_{case}".replace(" ", "_").replace("%", "pc")
                argv = [*base, "--stage", "5", "--mode", mode, "--splits", "test"]
                argv += ["--seeds", *map(str, args.seeds), "--episodes", str(args.episodes)]
                argv += [*extra, "--quiet", "--no-plot"]
                out.append(dict(name=name, subject=Path(subject).name, mode=mode, case=case,
                                argv=argv))  # fmt: skip
    return out


def _run_cell(cell: dict, root: Path) -> dict:
    out = root / "cells" / cell["name"]
    if not (out / "evaluation.json").exists():
        cmd = [
            sys.executable,
            "-m",
            "ops_experiments.evaluate",
            *cell["argv"],
            "--out",
            str(out),
        ]
        done = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL)
        if done.returncode != 0:
            raise RuntimeError(f"{cell['name']}: evaluate failed:\n{done.stderr[-2000:]}")
    row = _stored_row(cell, root)
    figures = f"{row['mean']:.4f} (worst {row['worst']:.4f})"
    print(f"[realism_sweep] {cell['name']}: {figures}", flush=True)
    return row


def _stored_row(cell: dict, root: Path) -> dict | None:
    """The figures of a cell stored under ``root`` (None: not stored)."""
    path = root / "cells" / cell["name"] / "evaluation.json"
    if not path.exists():
        return None
    ev = json.loads(path.read_text())["splits"]["test"]
    finals = ev["final_power_per_episode"]
    return {
        **{k: cell[k] for k in ("subject", "mode", "case")},
        "mean": ev["final_power_mean"],
        "worst": min(finals),
        "below_0_8": sum(f < 0.8 for f in finals),
        "episodes": len(finals),
    }


def stored_rows(args, todo: list[dict], root: Path) -> list[dict]:
    """Every stored cell of the whole sweep (every case of the default subjects and modes and
    of this run's), in the sweep's order: the page and the figure show all of them, whichever
    part a run (re)made."""
    whole = build_parser().parse_args(["--seeds", *map(str, args.seeds)])
    whole.episodes = args.episodes
    whole.modes = list(dict.fromkeys([*whole.modes, *args.modes]))
    whole.subjects = list(dict.fromkeys([*whole.subjects, *args.subjects]))
    plan = {c["name"]: c for c in cells(whole)}
    plan.update({c["name"]: c for c in todo if c["name"] not in plan})
    rows = [_stored_row(c, root) for c in plan.values()]
    return [r for r in rows if r is not None]


def table(rows: list[dict]) -> str:
    """Markdown: a row per case, a column per (subject, mode): mean (worst)."""
    columns = list(dict.fromkeys((r["subject"], r["mode"]) for r in rows))
    cases = list(dict.fromkeys(r["case"] for r in rows))
    by = {(r["subject"], r["mode"], r["case"]): r for r in rows}
    lines = [
        "| rig | " + " | ".join(f"{s}, {m}" for s, m in columns) + " |",
        "|---|" + "---|" * len(columns),
    ]
    for case in cases:
        cells_ = []
        for s, m in columns:
            r = by.get((s, m, case))
            cells_.append("" if r is None else f"{r['mean']:.3f} ({r['worst']:.3f})")
        lines.append(f"| {case} | " + " | ".join(cells_) + " |")
    return "\n".join(lines)


def write_page(root: Path, rows: list[dict], argv: list[str], figure: Path) -> None:
    episodes = rows[0]["episodes"] if rows else 0
    rel = Path("..", "..", *figure.parts[1:]) if figure.parts[:1] == ("docs",) else figure
    command = " ".join(["ros2 run ops_gym_bridge realism_sweep", *map(shlex.quote, argv)])
    text = (
        "# Realism sweep\n\n"
        "Final P_N / P_max, mean over the episodes (worst episode in brackets), N = 5, testing "
        f"split, {episodes} episodes per cell on held-out seeds. Each controller is told of the "
        "rig (`evaluate --rig` / `--realism`); a learned model knows only its training "
        'environment. Cases are described in docs/physics.md, "Rig imperfections".\n\n'
        f"Command (the last run): `{command}`. "
        "A cell stored under `cells/` is not run again (delete its folder to re-run it), and "
        "this page and the figure show every stored cell, whichever run made it; "
        "`ros2 run ops_gym_bridge realism_sweep` alone makes the whole default sweep.\n\n"
        f"{table(rows)}\n\n![realism sweep]({rel})\n"
    )
    (root / "index.md").write_text(text)


def _panel_case(panel: tuple, x) -> str:
    """The case name of value ``x`` on a panel of :data:`PANELS`."""
    title, key, _, _ = panel
    case = f"{x}{key}" if key.startswith("-") else f"{key}{x}"
    return case + "%" if "%" in title else case


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    modes = list(dict.fromkeys(r["mode"] for r in rows))
    subjects = list(dict.fromkeys(r["subject"] for r in rows))
    by = {(r["subject"], r["mode"], r["case"]): r for r in rows}
    shown = {r["case"] for r in rows}  # panels with no stored case are left out
    panels = [pn for pn in PANELS if any(_panel_case(pn, x) in shown for x in pn[2])]
    fig, axes = plt.subplots(
        len(modes), len(panels) + 1, figsize=(max(3.2 * (len(panels) + 1), 6.5), 3.0 * len(modes)),
        squeeze=False, sharey=True,
    )  # fmt: skip
    colors = dict(zip(subjects, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
    for i, mode in enumerate(modes):
        here = [s for s in subjects if any(k[:2] == (s, mode) for k in by)]
        for j, panel in enumerate(panels):
            title, _, xs, x0 = panel
            ax = axes[i, j]
            for s in here:
                pts = [(x0, by.get((s, mode, "ideal")))]
                pts += [(x, by.get((s, mode, _panel_case(panel, x)))) for x in xs]
                pts = [(x, r) for x, r in pts if r is not None]
                if not pts:
                    continue
                x = [p[0] for p in pts]
                ax.plot(x, [p[1]["mean"] for p in pts], "o-", color=colors[s], label=s)
                ax.plot(x, [p[1]["worst"] for p in pts], "x:", color=colors[s], alpha=0.6)
            ax.set_title(f"{mode}: {title}", fontsize=9)
            ax.set_ylim(0.0, 1.02)
            ax.grid(alpha=0.3)
        ax = axes[i, -1]
        for k, s in enumerate(here):
            r = by.get((s, mode, "lab"))
            if r is not None:
                ax.bar(k, r["mean"], color=colors[s])
                ax.plot(k, r["worst"], "kx")
        ax.set_xticks(range(len(here)), here, rotation=20, fontsize=7)
        ax.set_title(f"{mode}: lab preset", fontsize=9)
        axes[i, 0].set_ylabel("final P_N / P_max")
        if panels:
            axes[i, 0].legend(fontsize=7, loc="center right")
    fig.suptitle(
        "Mean (o, bars) and worst episode (x) against the rig's imperfections", fontsize=10
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(argv: list[str] | None = None) -> int:
    raw = list(sys.argv[1:] if argv is None else argv)
    args = cli_args.parse_args(build_parser(), raw)
    try:
        todo = cells(args)
    except ValueError as exc:
        print(f"[realism_sweep] error: {exc}", file=sys.stderr)
        return 2
    if args.list:
        print("\n".join(c["name"] for c in todo))
        return 0
    root = Path(args.out)
    print(f"[realism_sweep] {len(todo)} cells, {args.jobs} at a time, into {root}", flush=True)
    with ThreadPoolExecutor(max_workers=max(args.jobs, 1)) as pool:
        list(pool.map(lambda c: _run_cell(c, root), todo))
    rows = stored_rows(args, todo, root)
    (root / "summary.json").write_text(json.dumps({"command_line": raw, "cells": rows}, indent=1))
    figure = Path(args.figure)
    plot(rows, figure)
    write_page(root, rows, raw, figure)
    print(table(rows))
    print(f"[realism_sweep] wrote {root / 'index.md'}, {root / 'summary.json'}, {figure}")
    return 0


def main(argv: list[str] | None = None) -> None:
    freeze_after_heavy_imports()
    try:
        code = run(argv)
    except KeyboardInterrupt:
        code = 130
    except RuntimeError as exc:
        print(f"[realism_sweep] error: {exc}", file=sys.stderr)
        code = 1
    sys.exit(code)


if __name__ == "__main__":
    main()
