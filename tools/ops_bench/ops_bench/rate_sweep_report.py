"""The figure and the page of ``ops-bench rate-sweep``, from its stored cells (every group of
settings a table; the figure draws the group of the run that makes it).

Per controller and loop rate, over the seeds that locked (a seed that never reached 0.95 is
counted apart): the residual phase error pooled over seeds (rms of the seeds' rms) for all
stages and for the worst stage, P_N/P_max's mean and rms fluctuation, the fraction of readings
>= 0.95, the lock losses, and the steps per command the compute cost (its sustained rate is the
loop rate over them). Goals: LBNL's 50 mrad rms per stage and 1.5 % rms in P_N/P_max.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .rate_sweep import GOAL_MRAD, GOAL_RMS_PCT, GROUP_KEYS

REFERENCE = "oracle"  # ops_experiments.timed_loop.REFERENCE (not imported: no ROS needed here)


def pooled(values) -> float | None:
    """The rms of per-run rms figures (runs of equal length); None for none."""
    v = np.asarray([x for x in values if x is not None], dtype=np.float64)
    return None if v.size == 0 else float(np.sqrt(np.mean(v**2)))


def groups(cells: list[dict[str, Any]]) -> dict[tuple, list[dict[str, Any]]]:
    """Cells by their settings (GROUP_KEYS), the last stored cell of each controller, rate and
    seed kept (a cell stored again under other compute settings replaces the earlier)."""
    out: dict[tuple, dict[tuple, dict[str, Any]]] = {}
    for c in cells:
        key = tuple(c[k] for k in GROUP_KEYS)
        out.setdefault(key, {})[(c["controller"], c["rate_hz"], c["seed"])] = c
    return {k: list(v.values()) for k, v in out.items()}


def aggregate(cells: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per controller and rate (module docstring), in the order the cells came."""
    by: dict[tuple, list[dict[str, Any]]] = {}
    for c in cells:
        by.setdefault((c["controller"], c["rate_hz"]), []).append(c)
    rows = []
    for (controller, rate), runs in by.items():
        locked = [r for r in runs if r["residual_mrad"] is not None]
        stages = np.array([r["residual_mrad_stages"] for r in locked]) if locked else None
        k = float(np.median([r["steps_per_command_median"] for r in runs]))
        row = {
            "controller": controller,
            "rate_hz": rate,
            "seeds": len(runs),
            "never_locked": len(runs) - len(locked),
            "residual_mrad": pooled(r["residual_mrad"] for r in locked),
            "residual_min": min((r["residual_mrad"] for r in locked), default=None),
            "residual_max": max((r["residual_mrad"] for r in locked), default=None),
            "worst_stage_mrad": None if stages is None else float(pooled_cols(stages).max()),
            "power_mean": mean(r["power_mean"] for r in locked),
            "power_rms_pct": pooled(r["power_rms_pct"] for r in locked),
            "rms_min": min((r["power_rms_pct"] for r in locked), default=None),
            "rms_max": max((r["power_rms_pct"] for r in locked), default=None),
            "locked_pct": None if not locked else 100 * mean(r["locked_fraction"] for r in locked),
            "losses": sum(r["losses"] for r in runs),
            "steps_per_command": k,
            "sustained_hz": rate / k,
            "compute_ms": float(np.median([r["compute_ms_median"] for r in runs])),
            "compute": runs[0]["compute"],
            "latency_steps": runs[0]["latency_steps"],
        }
        row["meets"] = bool(
            row["never_locked"] == 0
            and row["worst_stage_mrad"] is not None
            and row["worst_stage_mrad"] <= GOAL_MRAD
            and row["power_rms_pct"] <= GOAL_RMS_PCT
        )
        rows.append(row)
    return rows


def pooled_cols(values: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.asarray(values) ** 2, axis=0))


def mean(values) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def _f(value, spec: str, none: str = "-") -> str:
    return none if value is None else format(value, spec)


def _range(row, key: str, low: str, high: str, spec: str) -> str:
    if row[key] is None:
        return "-"
    return f"{row[key]:{spec}} ({row[low]:{spec}}-{row[high]:{spec}})"


def table(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "| controller | loop rate | steps per command (sustained rate) | compute per reading | "
        "seeds (never locked) | residual, mrad rms (seeds' range) | worst stage, mrad | "
        "P_N/P_max mean | P_N/P_max rms, % (range) | readings >= 0.95 | losses | LBNL goals |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (r["controller"], r["rate_hz"])):
        compute = f"{r['compute_ms']:.2f} ms" + ("" if r["compute"] == "measured" else " (fixed)")
        lines.append(
            f"| {r['controller']} | {r['rate_hz']:g} Hz | {r['steps_per_command']:g} "
            f"({r['sustained_hz']:.4g} Hz) | {compute} | {r['seeds']} ({r['never_locked']}) | "
            f"{_range(r, 'residual_mrad', 'residual_min', 'residual_max', '.1f')} | "
            f"{_f(r['worst_stage_mrad'], '.1f')} | {_f(r['power_mean'], '.4f')} | "
            f"{_range(r, 'power_rms_pct', 'rms_min', 'rms_max', '.2f')} | "
            f"{_f(r['locked_pct'], '.2f', '-')}{'' if r['locked_pct'] is None else ' %'} | "
            f"{r['losses']} | "
            f"{'met' if r['meets'] else 'not met'} |"
        )
    return lines


def advice(rows: list[dict[str, Any]]) -> list[str]:
    """Which controller to run at each rate: the lowest residual among those that locked on
    every seed; and the best of all."""
    lines = []
    ok = [
        r
        for r in rows
        if r["never_locked"] == 0
        and r["residual_mrad"] is not None
        and r["controller"] != REFERENCE
    ]
    for rate in sorted({r["rate_hz"] for r in rows}):
        here = [r for r in ok if r["rate_hz"] == rate]
        if not here:
            lines.append(f"- **{rate:g} Hz**: no controller locked on every seed.")
            continue
        best = min(here, key=lambda r: r["residual_mrad"])
        lines.append(
            f"- **{rate:g} Hz**: {best['controller']} ({best['residual_mrad']:.1f} mrad, worst "
            f"stage {best['worst_stage_mrad']:.1f}; P_N/P_max {best['power_mean']:.4f}, rms "
            f"{best['power_rms_pct']:.2f} %"
            + (
                f"; it sustains {best['sustained_hz']:.4g} Hz"
                if best["steps_per_command"] > 1
                else ""
            )
            + f"): LBNL's goals {'met' if best['meets'] else 'not met'}."
        )
    floor = sorted(
        (r for r in rows if r["controller"] == REFERENCE and r["residual_mrad"] is not None),
        key=lambda r: r["rate_hz"],
    )
    if floor:
        lines.append(
            f"- **The reference** ({REFERENCE}: the true delay errors known at each reading, "
            "not a controller a rig can run) leaves "
            + ", ".join(
                f"{r['residual_mrad']:.0f} mrad / {r['power_rms_pct']:.2f} % at {r['rate_hz']:g} Hz"
                for r in floor
            )
            + ": what the rate and latency let the vibration do."
        )
    if ok:
        best = min(ok, key=lambda r: r["residual_mrad"])
        lines.append(
            f"- **Lowest residual of all**: {best['controller']} at {best['rate_hz']:g} Hz, "
            f"{best['residual_mrad']:.1f} mrad rms, P_N/P_max rms {best['power_rms_pct']:.2f} %."
        )
    return lines


def figure(rows: list[dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .docs import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.0), dpi=110)
    panels = (
        ("residual_mrad", "residual_min", "residual_max", GOAL_MRAD, "residual phase, mrad rms"),
        ("power_rms_pct", "rms_min", "rms_max", GOAL_RMS_PCT, "P_N/P_max rms, %"),
    )
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    for ax, (key, low, high, goal, ylabel) in zip(axes, panels, strict=True):
        for i, name in enumerate(controllers):
            color, style = (f"C{i}", "-") if name != REFERENCE else ("0.5", "--")
            for r in rows:  # never locked on any seed: an x at the top
                if r["controller"] == name and r[key] is None:
                    ax.plot(
                        r["rate_hz"], 0.97, "x", color=color, transform=ax.get_xaxis_transform()
                    )
            mine = sorted(
                (r for r in rows if r["controller"] == name and r[key] is not None),
                key=lambda r: r["rate_hz"],
            )
            if not mine:
                continue
            x = np.array([r["rate_hz"] for r in mine])
            y = np.array([r[key] for r in mine])
            err = np.array([[r[key] - r[low], r[high] - r[key]] for r in mine]).T
            name_shown = name if name != REFERENCE else f"{name} (true errors known: reference)"
            ax.errorbar(x, y, yerr=err, color=color, ls=style, lw=1.2, capsize=3, label=name_shown)
            capped = np.array([r["steps_per_command"] > 1 for r in mine])
            ax.plot(x[~capped], y[~capped], "o", color=color)
            ax.plot(x[capped], y[capped], "o", mfc="white", color=color)
            for r in mine:
                if r["never_locked"]:
                    ax.annotate(
                        f"{r['never_locked']}/{r['seeds']} never locked",
                        (r["rate_hz"], r[key]),
                        fontsize=6,
                        color=color,
                    )
        ax.axhline(goal, color="k", ls="--", lw=0.8)
        ax.text(
            0.01,
            goal,
            f" LBNL {goal:g}",
            transform=ax.get_yaxis_transform(),
            fontsize=7,
            va="bottom",
        )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("loop rate, Hz")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, which="both")
    if axes[1].get_legend_handles_labels()[0]:
        axes[1].legend(fontsize=7, loc="center right")
    fig.suptitle(
        title + ";\nopen markers: the controller's compute caps its rate; x at the top: never "
        "locked on any seed",
        fontsize=9,
    )
    save_figure(fig, path)
    print(f"wrote {path}", flush=True)


def describe(group: dict[str, Any]) -> str:
    return (
        f"{group['seconds']:g} s of simulated time per cell, N = 5 {group['mode']} (testing "
        f"split), `{group['vibration']}` vibration, `lab` rig with a latency of "
        f"{group['latency_ms']:g} ms and a delay-line response of {group['lag_ms']:g} ms"
    )


INTRO = """# Rate sweep: which controller holds, at which loop rate, under vibration

Written by `ops-bench rate-sweep` (tools/ops_bench/ops_bench/rate_sweep.py) from the cells in
`cells.jsonl` (one JSON line per controller, loop rate and seed). The simulator runs in process
under `time_base` seconds (a simulated second holds the same random walk, drift and vibration at
any rate; docs/physics.md) on the `lab` rig, the rig's latency and delay-line response given in
ms. A controller's compute caps its rate: a reading whose answer costs more than a loop period
is answered that many whole periods later, the set-points holding in between, and the controller
reads next the first reading that shows its answer; the work it does once the command is out
(the tracker's `think()`: a deferred knot test, or the fit of `tracker-answer-first`) keeps it
from that reading until the work ends, and a command it revised is taken then
(ops_experiments/timed_loop.py). Compute (per reading, both parts) is
the controller's thread CPU time per reading on this 2-core machine (others' load excluded),
unless fixed (`--compute-ms`). Figures are taken over every simulator step from the first at
P_N/P_max >= 0.95 on: residual phase = 2 pi x (delay error to the nearest whole optical period)
/ optical period, rms per stage; P_N/P_max rms = standard deviation over mean; losses: runs
below 0.8. LBNL's goals: <= 50 mrad rms per stage (the worst stage is compared) and <= 1.5 %
rms in P_N/P_max. `oracle` is a reference, not a controller a rig can run: it knows the lines'
walk and drift at each reading and predicts their vibration from its value then
(`TrueErrorReference` in ops_experiments/timed_loop.py), so what it leaves is roughly what the
loop's rate and latency let the vibration do.
"""


def write_report(cells, out: Path, figure_path: Path | None, group: dict) -> None:
    """``out/index.md`` (every group) and the figure of ``group`` (if it has cells)."""
    lines = [INTRO]
    if (out / "notes.md").exists():
        lines.append("What the figures say, and what a lab should run: [notes.md](notes.md).\n")
    current = tuple(group[k] for k in GROUP_KEYS)
    for key, members in sorted(groups(cells).items(), key=lambda kv: kv[0] != current):
        g = dict(zip(GROUP_KEYS, key, strict=True))
        rows = aggregate(members)
        commands = sorted({c.get("command", "") for c in members} - {""})
        lines += [f"## {describe(g)}", ""]
        lines += [f"Command: `ops-bench rate-sweep {c}`" for c in commands]
        lines += ["", *table(rows), "", "Which controller to run at each loop rate:", ""]
        lines += [*advice(rows), ""]
        if key == current and figure_path is not None:
            figure(rows, figure_path, describe(g))
            rel = Path("../../figures") / figure_path.name
            lines += [f"![rate sweep]({rel})", ""]
    out.mkdir(parents=True, exist_ok=True)
    (out / "index.md").write_text("\n".join(lines).rstrip("\n") + "\n")
    print(f"wrote {out / 'index.md'}", flush=True)
