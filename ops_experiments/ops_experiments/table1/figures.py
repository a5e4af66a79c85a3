"""The report's figures (the paper's Figures 7-11 and 17) from stored runs
(:func:`.runs.load_runs`): each panel names what it covers.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from .runs import ALGO_ORDER, controller_order, main_stage

COLORS = {"ppo": "tab:green", "td3": "tab:blue", "sac": "tab:orange"}


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


def _label(ax, any_: bool, title: str, xlabel: str, ylabel: str) -> None:
    """Title, axis labels, grid, and the legend of a panel (or "no stored runs")."""
    if not any_:
        _empty(ax)
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if any_:
        ax.legend(loc="lower right", fontsize=8)


def _save(fig, path: Path, title: str) -> None:
    """The figure's title (what it covers), saved and closed."""
    plt = _plt()
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


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
        _label(ax, any_, f"N = {stage}, {mode}", "training step", "training reward per step")
        _kilo(ax)
    _save(fig, path, "Training curves (mean ± std over seeds); " + _coverage(runs))


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
        ax.set_ylim(0, 1.02)
        _label(ax, any_, f"N = {stage}, {mode}, testing environment", "control step", "P_N / P_max")
    _save(fig, path, "Control from a random start (mean over seeds); " + _coverage(runs))


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
    _save(fig, path, f"TD3, hard mode, N = {stages} (n = seeds per N); " + _coverage(runs))


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
    _save(fig, path, "TD3 and SAC across N (mean ± std over seeds); " + _coverage(runs))


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
    _save(fig, path, "Transfer between modes; " + _coverage(runs))


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
    _save(fig, path, title)
