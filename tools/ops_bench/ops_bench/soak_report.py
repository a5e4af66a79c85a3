"""The figure and the page of ``ops-bench soak`` (from its state: the figures so far)."""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

GOAL_MRAD = 50.0


def figure(state: dict[str, Any], result: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .docs import save_figure

    blocks, settings = state["blocks"], state["settings"]
    hours = (np.arange(len(blocks["p_mean"])) + 1) * settings["block_s"] / 3600.0
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 5.2), dpi=110, sharex=True)
    top.plot(hours, blocks["p_mean"], lw=0.8, label=f"mean per {settings['block_s']:g} s")
    top.plot(hours, blocks["p_min"], lw=0.6, alpha=0.7, label="lowest reading")
    top.axhline(0.95, color="k", ls="--", lw=0.7)
    top.set_ylabel("P_N / P_max")
    top.set_ylim(min(0.8, float(np.min(blocks["p_min"], initial=1.0))) - 0.02, 1.01)
    top.legend(fontsize=7, loc="lower left")
    top.grid(alpha=0.3)
    bottom.plot(hours, blocks["mrad"], lw=0.8, label="rms over the stages")
    bottom.plot(hours, blocks["mrad_worst"], lw=0.6, alpha=0.7, label="worst stage")
    bottom.axhline(GOAL_MRAD, color="k", ls="--", lw=0.7)
    bottom.text(0.0, GOAL_MRAD, " LBNL 50 mrad", fontsize=7, va="bottom")
    bottom.set_ylabel(f"residual phase per {settings['block_s']:g} s, mrad rms")
    bottom.set_xlabel("simulated hours")
    bottom.set_yscale("log")
    bottom.legend(fontsize=7, loc="upper left")
    bottom.grid(alpha=0.3, which="both")
    rms, locked = result["power_rms_pct"], result["locked_fraction"]
    fig.suptitle(
        f"{settings['controller']}, N = 5 {settings['mode']}, {rig_words(settings)}, "
        f"{settings['vibration']} vibration{turn_words(settings)}, {settings['rate_hz']:g} Hz, "
        f"{result['hours']:g} h\nP_N/P_max rms "
        + ("-" if rms is None else f"{rms:.2f} %")
        + ", readings >= 0.95 "
        + ("-" if locked is None else f"{100 * locked:.3f} %")
        + f", locks lost {result['losses']}",
        fontsize=9,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path)
    print(f"wrote {path}", flush=True)


def rig_words(settings: dict[str, Any], quote: str = "") -> str:
    """ "lab rig", or the preset and the figures ``--rig`` changed ("lab rig, trace_adc_bits=0")."""
    changed = "".join(f", {quote}{k}={v}{quote}" for k, v in settings["rig"].items())
    told = "".join(f", {quote}{k}={v}{quote}" for k, v in settings["params"].items())
    return f"{quote}{settings['realism']}{quote} rig{changed}" + (
        f" (the controller with{told[1:]})" if told else ""
    )


def turn_words(settings: dict[str, Any]) -> str:
    """The drift's turn in words (", the drift turning at its bound over 120 s"), or "" for
    the default turn in one step."""
    turn = settings.get("drift_turn_s", 0.0)
    return f", the drift turning at its bound over {turn:g} s" if turn else ""


def _f(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def page(result: dict[str, Any], figure_path: Path, out: Path) -> str:
    goals = result["goals"]
    locked = result["locked_fraction"]
    first = result["first_lock_step"]
    rel = Path(os.path.relpath(figure_path.resolve(), out.resolve()))
    lines = [
        "# Soak: the tracker for hours on the lab rig",
        "",
        "Written by `ops-bench soak` (tools/ops_bench/ops_bench/soak.py). In process, "
        f"`time_base` seconds at {result['rate_hz']:g} Hz, `{result['vibration']}` vibration, "
        f"the {rig_words(result, '`')} with a latency of {result['latency_ms']:g} ms and a "
        "delay-line "
        f"response of {result['lag_ms']:g} ms{turn_words(result)}, N = 5 {result['mode']} "
        "(testing split), seed "
        f"{result['seed']}; the controller's compute caps its rate "
        + (
            "(measured per reading, thread CPU time)"
            if result["compute_ms"] is None
            else f"(fixed at {result['compute_ms']:g} ms)"
        )
        + ". Figures over every simulator step from the first at P_N/P_max >= 0.95 on; a lock "
        "lost is a run of readings below 0.8 (ops_experiments.continuous).",
        "",
        "Commands (in turn; a run resumes from its checkpoint): "
        + ", ".join(f"`ops-bench soak {c}`" for c in result["commands"]),
        "",
        "| figure | value | goal |",
        "|---|---|---|",
        f"| simulated time | {result['hours']:g} h ({result['steps']:,} steps) | 30 h |",
        f"| first lock | {_f(None if first is None else first / result['rate_hz'], '.1f')} s | |",
        f"| P_N/P_max mean | {_f(result['power_mean'], '.4f')} | |",
        f"| P_N/P_max rms | {_f(result['power_rms_pct'], '.3f')} % | <= 1.5 % "
        f"({'met' if goals['power_rms_pct <= 1.5'] else 'not met'}) |",
        f"| readings >= 0.95 | {_f(None if locked is None else 100 * locked, '.4f')} % | "
        f">= 99.9 % ({'met' if goals['readings >= 0.95: >= 99.9 %'] else 'not met'}) |",
        f"| locks lost (runs below 0.8) | {result['losses']} (longest "
        f"{result['longest_loss']} readings) | 0 "
        f"({'met' if goals['no lock lost'] else 'not met'}) |",
        f"| lowest reading after the first lock | {_f(result['worst_after_lock'], '.4f')} | |",
        f"| residual phase, rms over stages | {_f(result['residual_mrad'], '.1f')} mrad | |",
        "| residual phase per stage | "
        + (
            "-"
            if result["residual_mrad_stages"] is None
            else ", ".join(f"{v:.1f}" for v in result["residual_mrad_stages"])
        )
        + " mrad | |",
        f"| the controller's compute per reading | median {result['compute_ms_median']:.2f} ms, "
        f"p99 {result['compute_ms_p99']:.2f} ms; {result['commands_late']:,} of "
        f"{result['readings']:,} answers a step late or more | |",
        f"| wall time | {result['wall_s'] / 3600:.2f} h | |",
        "",
        f"![soak]({rel})",
        "",
        "Per-block figures: [blocks.csv](blocks.csv); every figure: [summary.json](summary.json).",
    ]
    text = "\n".join(lines) + "\n"
    (out / "index.md").write_text(text)
    return text


def write_docs(state, result, figure_path: Path, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    figure(state, result, figure_path)
    (out / "summary.json").write_text(json.dumps(result, indent=2) + "\n")
    blocks, settings = state["blocks"], state["settings"]
    with open(out / "blocks.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["hours", "power_mean", "power_min", "residual_mrad", "worst_stage_mrad"])
        for i, row in enumerate(zip(*(blocks[k] for k in blocks), strict=True)):
            hours = (i + 1) * settings["block_s"] / 3600.0
            w.writerow([f"{hours:.4f}", *(f"{v:.6g}" for v in row)])
    page(result, figure_path, out)
    print(f"wrote {out / 'index.md'}", flush=True)
