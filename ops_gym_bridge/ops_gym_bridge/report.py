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
and ``DIR/table1_sets.md`` puts their Table 1 cells side by side.
"""

from __future__ import annotations

import csv
import io
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from . import cli_args
from .bench_worker import read_json

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
ALGO_ORDER = ("ppo", "td3", "sac")
SPLITS = ("train", "test")
COLORS = {"ppo": "tab:green", "td3": "tab:blue", "sac": "tab:orange"}


# ------------------------------------------------------------------------------ loading
def load_runs(root: Path) -> list[dict[str, Any]]:
    """Every stored run under ``root/runs`` (or ``root`` itself holding run directories)."""
    base = root / "runs" if (root / "runs").is_dir() else root
    runs = []
    for d in sorted(p for p in base.iterdir() if p.is_dir()):
        rec = read_json(d / "run.json")
        ev = read_json(d / "evaluation.json")
        if not rec or not ev:
            continue
        spec = rec["spec"]
        run = {
            "id": spec["id"],
            "kind": spec["kind"],
            "name": spec.get("algo") or spec.get("controller"),
            "stage": int(spec["stage"]),
            "mode": spec["mode"],
            "seed": spec.get("seed"),
            "detector": spec["detector"],
            "observation": spec.get("observation", "rig"),
            "timesteps": rec.get("timesteps"),
            "eval": ev,
            "spec": spec,
            "training": _read_training(d / "training.csv"),
        }
        runs.append(run)
    return runs


def _read_training(path: Path) -> np.ndarray | None:
    if not path.exists():
        return None
    with open(path) as f:
        rows = [
            (float(r["timesteps"]), float(r["return"]), float(r["length"]), float(r["final_power"]))
            for r in csv.DictReader(f)
        ]
    return np.array(rows) if rows else None


def main_stage(runs: list[dict]) -> int:
    """The stage of Table 1: the one with runs on more than one mode (N = 5 in the profiles)."""
    stages = defaultdict(set)
    for r in runs:
        stages[r["stage"]].add(r["mode"])
    return max(stages, key=lambda s: (len(stages[s]), s == 5, s)) if stages else 5


def controller_order(runs: list[dict]) -> list[str]:
    algos = [a for a in ALGO_ORDER if any(r["name"] == a for r in runs)]
    others = sorted({r["name"] for r in runs if r["kind"] == "controller"})
    extra = sorted({r["name"] for r in runs if r["kind"] == "train"} - set(ALGO_ORDER))
    return algos + extra + others


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


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _kilo(ax, axis: str = "x") -> None:
    """Step axes in thousands (300k, not 300000: the labels would overlap)."""
    from matplotlib.ticker import FuncFormatter

    fmt = FuncFormatter(lambda v, _: f"{v / 1000:g}k" if v else "0")
    (ax.xaxis if axis == "x" else ax.yaxis).set_major_formatter(fmt)


def _empty(ax, text="no stored runs"):
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="gray")


def _binned(runs: list[dict], column: int, per_step: bool, bins: int = 40):
    """Mean and std over runs of a training-curve column, binned on a common step grid."""
    curves = [r["training"] for r in runs if r["training"] is not None and len(r["training"])]
    if not curves:
        return None
    top = max(float(c[:, 0].max()) for c in curves)
    edges = np.linspace(0, top, bins + 1)
    centers = 0.5 * (edges[1:] + edges[:-1])
    per_run = []
    for c in curves:
        vals = c[:, column] / c[:, 2] if per_step else c[:, column]
        idx = np.clip(np.digitize(c[:, 0], edges) - 1, 0, bins - 1)
        row = np.full(bins, np.nan)
        for b in range(bins):
            sel = vals[idx == b]
            if sel.size:
                row[b] = sel.mean()
        per_run.append(row)
    arr = np.array(per_run)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return centers, np.nanmean(arr, axis=0), np.nanstd(arr, axis=0), len(curves)


def _coverage(runs: list[dict]) -> str:
    seeds = sorted({r["seed"] for r in runs if r["kind"] == "train"})
    det = sorted({r["detector"] for r in runs})
    return f"stored runs: {len(runs)}; training seeds {seeds}; detector {', '.join(det)}"


def fig7(runs, path: Path, modes) -> None:
    plt = _plt()
    stage = main_stage(runs)
    fig, axes = plt.subplots(1, len(modes), figsize=(4.2 * len(modes), 3.4), squeeze=False)
    for ax, mode in zip(axes[0], modes, strict=True):
        any_ = False
        for algo in ALGO_ORDER:
            rs = [
                r
                for r in runs
                if r["name"] == algo and r["mode"] == mode and r["stage"] == stage
                and r["kind"] == "train"
            ]  # fmt: skip
            b = _binned(rs, 1, per_step=True)
            if b is None:
                continue
            x, m, s, n = b
            ax.plot(x, m, color=COLORS[algo], label=f"{algo.upper()} (n={n})")
            ax.fill_between(x, m - s, m + s, color=COLORS[algo], alpha=0.2)
            any_ = True
        if not any_:
            _empty(ax)
        ax.set_title(f"N = {stage}, {mode}")
        ax.set_xlabel("training step")
        _kilo(ax)
        ax.set_ylabel("training reward per step")
        ax.grid(alpha=0.3)
        if any_:
            ax.legend(loc="lower right", fontsize=8)
    fig.suptitle("Training curves (mean ± std over seeds); " + _coverage(runs), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _curves(rs: list[dict], split: str, key: str = "splits", mode: str | None = None):
    if not rs:
        return None
    if rs[0]["kind"] == "controller":
        e = rs[0]["eval"][key][mode] if mode else rs[0]["eval"][key][split]
        return np.array(e["curve_mean"]), np.array(e["curve_std"]), len(e["final_power_per_seed"])
    cs = []
    for r in rs:
        e = r["eval"][key].get(mode) if mode else r["eval"][key][split]
        if e:
            cs.append(np.array(e["curve_mean"]))
    if not cs:
        return None
    arr = np.array(cs)
    return arr.mean(axis=0), arr.std(axis=0), len(cs)


def fig8(runs, path: Path, modes) -> None:
    plt = _plt()
    stage = main_stage(runs)
    names = controller_order(runs)
    fig, axes = plt.subplots(1, len(modes), figsize=(4.2 * len(modes), 3.4), squeeze=False)
    for ax, mode in zip(axes[0], modes, strict=True):
        any_ = False
        for i, name in enumerate(names):
            rs = [
                r for r in runs if r["name"] == name and r["mode"] == mode and r["stage"] == stage
            ]
            c = _curves(rs, "test")
            if c is None:
                continue
            m, s, n = c
            color = COLORS.get(name, f"C{i + 3}")
            style = "--" if rs[0]["kind"] == "controller" else "-"
            what = "eval seeds" if rs[0]["kind"] == "controller" else "n"
            ax.plot(np.arange(m.size), m, style, color=color, label=f"{name.upper()} ({what}={n})")
            ax.fill_between(np.arange(m.size), m - s, m + s, color=color, alpha=0.15)
            any_ = True
        if not any_:
            _empty(ax)
        ax.set_ylim(0, 1.02)
        ax.set_title(f"N = {stage}, {mode}, testing environment")
        ax.set_xlabel("control step")
        ax.set_ylabel("P_N / P_max")
        ax.grid(alpha=0.3)
        if any_:
            ax.legend(loc="lower right", fontsize=8)
    fig.suptitle("Control from a random start (mean over seeds); " + _coverage(runs), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _hard_train(runs, algo: str) -> dict[int, list[dict]]:
    out: dict[int, list[dict]] = defaultdict(list)
    for r in runs:
        if r["kind"] == "train" and r["name"] == algo and r["mode"] == "hard":
            out[r["stage"]].append(r)
    return dict(sorted(out.items()))


def fig9(runs, path: Path) -> None:
    plt = _plt()
    by_stage = _hard_train(runs, "td3")
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    cmap = plt.get_cmap("viridis")
    for i, (st, rs) in enumerate(by_stage.items()):
        color = cmap(i / max(len(by_stage) - 1, 1))
        t = _binned(rs, 3, per_step=False)
        if t is not None:
            x, m, _, n = t
            a.plot(x, m, color=color, label=f"N={st} (n={n})")
        c = _curves(rs, "test")
        if c is not None:
            m, _, n = c
            b.plot(np.arange(m.size), m, color=color, label=f"N={st} (n={n})")
    for ax, title, xl in (
        (a, "(a) training: final P_N of training episodes", "training step"),
        (b, "(b) testing environment: P_N vs control step", "control step"),
    ):
        if not by_stage:
            _empty(ax)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(xl)
        ax.set_ylabel("P_N / P_max")
        ax.set_ylim(0, 1.02)
        if ax is a:
            _kilo(ax)
        ax.grid(alpha=0.3)
        if by_stage:
            ax.legend(fontsize=8, loc="lower right")
    stages = sorted(by_stage)
    fig.suptitle(f"TD3, hard mode, N = {stages} (n = seeds per N); " + _coverage(runs), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def convergence_step(training: np.ndarray | None, window: int = 20) -> float | None:
    """First training step at which the moving average (``window`` episodes) of the episodes'
    final P_N covers 90 % of its rise from the first window to the last 10 % of training."""
    if training is None or len(training) < 2 * window:
        return None
    p = training[:, 3]
    smooth = np.convolve(p, np.ones(window) / window, mode="valid")
    start, final = smooth[0], p[-max(len(p) // 10, window) :].mean()
    if final <= start:
        return float(training[window - 1, 0])
    hit = np.nonzero(smooth >= start + 0.9 * (final - start))[0]
    return float(training[hit[0] + window - 1, 0]) if hit.size else None


def fig10(runs, path: Path) -> None:
    plt = _plt()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    any_ = have_conv = False
    for k, algo in enumerate(("td3", "sac")):
        by_stage = _hard_train(runs, algo)
        if not by_stage:
            continue
        any_ = True
        xs = np.array(list(by_stage)) + (k - 0.5) * 0.12
        fin = [
            [r["eval"]["splits"]["test"]["final_power_mean"] for r in rs]
            for rs in by_stage.values()
        ]
        conv = [
            [c for r in rs if (c := convergence_step(r["training"])) is not None]
            for rs in by_stage.values()
        ]
        ns = [len(rs) for rs in by_stage.values()]
        a.errorbar(
            xs, [np.mean(f) for f in fin], [np.std(f) for f in fin], fmt="o-", capsize=3,
            color=COLORS[algo], label=f"{algo.upper()} (seeds per N: {ns})",
        )  # fmt: skip
        have_conv = have_conv or any(conv)
        cm = [np.mean(c) if c else np.nan for c in conv]
        cs = [np.std(c) if c else np.nan for c in conv]
        b.errorbar(xs, cm, cs, fmt="s-", capsize=3, color=COLORS[algo], label=algo.upper())
    stages = sorted({st for algo in ("td3", "sac") for st in _hard_train(runs, algo)})
    if any_ and not have_conv:
        _empty(b, "training curves too short to tell")
    for ax in (a, b):
        if stages:
            ax.set_xticks(stages)
    a.set_title("(a) final P_N, hard mode, testing environment", fontsize=10)
    a.set_ylabel("P_N / P_max")
    a.set_ylim(0, 1.05)
    b.set_title("(b) training steps to converge (90 % of the rise)", fontsize=10)
    b.set_ylabel("training steps")
    _kilo(b, "y")
    for ax in (a, b):
        ax.set_xlabel("stages N")
        ax.grid(alpha=0.3)
        if any_:
            ax.legend(fontsize=8)
        else:
            _empty(ax)
    fig.suptitle("TD3 and SAC across N (mean ± std over seeds); " + _coverage(runs), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def fig11(runs, path: Path, modes) -> None:
    plt = _plt()
    stage = main_stage(runs)
    train_modes = [m for m in ("hard", "medium", "easy") if m in modes]
    fig, axes = plt.subplots(
        1, len(train_modes), figsize=(4.2 * len(train_modes), 3.4), squeeze=False
    )
    for ax, tm in zip(axes[0], train_modes, strict=True):
        any_ = False
        width = 0.8 / len(ALGO_ORDER)
        for k, algo in enumerate(ALGO_ORDER):
            rs = [
                r for r in runs
                if r["kind"] == "train" and r["name"] == algo and r["mode"] == tm
                and r["stage"] == stage
            ]  # fmt: skip
            if not rs:
                continue
            means, stds = [], []
            for em in modes:
                vals = [
                    r["eval"]["splits"]["test"]["final_power_mean"]
                    if em == tm
                    else r["eval"]["transfer"].get(em, {}).get("final_power_mean", np.nan)
                    for r in rs
                ]
                means.append(np.nanmean(vals))
                stds.append(np.nanstd(vals))
            x = np.arange(len(modes)) + (k - 1) * width
            ax.bar(x, means, width, yerr=stds, color=COLORS[algo], capsize=2,
                   label=f"{algo.upper()} (n={len(rs)})")  # fmt: skip
            any_ = True
        ax.set_xticks(np.arange(len(modes)), [f"{m} test" for m in modes])
        ax.set_ylim(0, 1.05)
        ax.set_ylabel("final P_N / P_max")
        ax.set_title(f"trained on {tm} (N = {stage})")
        ax.grid(alpha=0.3, axis="y")
        if any_:
            ax.legend(fontsize=8, loc="upper right")
        else:
            _empty(ax)
    fig.suptitle("Transfer between modes; " + _coverage(runs), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def fig17(runs, path: Path) -> None:
    plt = _plt()
    with_traces = [r for r in runs if r["kind"] == "train" and r["eval"].get("traces")]
    with_traces.sort(key=lambda r: (r["stage"] != 5, r["mode"] != "hard", r["name"] != "td3",
                                    r["seed"]))  # fmt: skip
    fig, axes = plt.subplots(1, 6, figsize=(15, 2.6), sharey=True)
    if not with_traces:
        for ax in axes:
            _empty(ax)
        title = "no stored run with traces"
    else:
        r = with_traces[0]
        tr = r["eval"]["traces"]
        top = max(max(t) for t in tr["trace"]) or 1.0
        for ax, step, p, t in zip(axes, tr["steps"], tr["power"], tr["trace"], strict=False):
            ax.plot(np.arange(len(t)), np.array(t) / top, color="tab:red", lw=0.9)
            ax.set_title(f"step {step}: P_N = {p:.3f}", fontsize=9)
            ax.set_xlabel("sample")
        axes[0].set_ylabel("intensity (norm.)")
        title = (
            f"{r['name'].upper()} (seed {r['seed']}, {r['timesteps']:,} steps) controlling "
            f"N = {r['stage']} {r['mode']} mode, testing environment, random start; "
            f"detector {r['detector']}"
        )
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


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
    runs = load_runs(root)
    out.mkdir(parents=True, exist_ok=True)
    rows = table1_rows(runs)
    (out / "table1.csv").write_text(table1_csv(rows))
    (out / "table1.md").write_text(table1_md(rows))
    modes = [m for m in ("easy", "medium", "hard", "extreme") if any(r["mode"] == m for r in runs)]
    modes = modes or ["easy", "medium", "hard"]
    fig7(runs, out / "fig7_training.png", modes)
    fig8(runs, out / "fig8_control.png", modes)
    fig9(runs, out / "fig9_stages.png")
    fig10(runs, out / "fig10_convergence.png")
    fig11(runs, out / "fig11_transfer.png", modes)
    fig17(runs, out / "fig17_traces.png")
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
    return p


def run(argv: list[str] | None = None) -> int:
    args = cli_args.parse_args(build_parser(), argv)
    roots = [Path(d) for d in args.runs_dir]
    for root in roots:
        if not root.is_dir():
            print(f"[report] error: {root} is not a directory", file=sys.stderr)
            return 2
    out = Path(args.out)
    if len(roots) == 1:
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
