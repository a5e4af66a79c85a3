"""The one reduction of evaluation episodes, and the one schema of every ``evaluation.json``.

``evaluate`` (per split) and the benchmark (per split and per transfer mode) reduce the episodes of
several evaluation seeds with :func:`summarize`. A summary holds:

==========================  ===================================================================
``final_power_mean``        mean over evaluation seeds of each seed's mean final P_N / P_max
``final_power_std``         their std (over seeds)
``final_power_per_seed``    each seed's mean final P_N / P_max (6 decimals)
``final_power_min_episode`` the worst episode's final P_N / P_max (over all seeds)
``final_power_per_episode`` every episode's final P_N / P_max, seed by seed (6 decimals)
``episode_return_mean/std`` the episode return (sum of rewards), mean and std over seeds
``initial_power_mean``      P_N / P_max after reset, mean over seeds
``curve_mean/std``          P_N / P_max after reset and after each step, mean and std over seeds
                            of each seed's mean curve (5 decimals)
==========================  ===================================================================

Runs the benchmark stored before this schema hold only the mean, std, per-seed values and the
curves; :func:`read_summary` (and :func:`read_evaluation` for a whole file) fills what they lack:
``initial_power_mean`` from the curve, the rest as None (not measured).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

#: The keys of a summary, in the order they are written.
SUMMARY_KEYS = (
    "final_power_mean",
    "final_power_std",
    "final_power_per_seed",
    "final_power_min_episode",
    "final_power_per_episode",
    "episode_return_mean",
    "episode_return_std",
    "initial_power_mean",
    "curve_mean",
    "curve_std",
)


def summarize(per_seed: list[dict[str, np.ndarray]]) -> dict[str, Any]:
    """Mean +- std over evaluation seeds of the per-seed means; ``per_seed``: one rollout result
    per seed (``power`` (episodes, steps + 1) and ``returns`` (episodes,), as
    :mod:`ops_experiments.rollouts` returns them)."""
    final = np.array([r["power"][:, -1].mean() for r in per_seed])
    ret = np.array([r["returns"].mean() for r in per_seed])
    curves = np.stack([r["power"].mean(axis=0) for r in per_seed])  # (seeds, steps + 1)
    all_final = np.concatenate([r["power"][:, -1] for r in per_seed])
    return {
        "final_power_mean": float(final.mean()),
        "final_power_std": float(final.std()),
        "final_power_per_seed": _rounded(final, 6),
        "final_power_min_episode": float(all_final.min()),
        "final_power_per_episode": _rounded(all_final, 6),
        "episode_return_mean": float(ret.mean()),
        "episode_return_std": float(ret.std()),
        "initial_power_mean": float(curves[:, 0].mean()),
        "curve_mean": _rounded(curves.mean(axis=0), 5),
        "curve_std": _rounded(curves.std(axis=0), 5),
    }


def episode_time(steps: int, config) -> dict[str, Any]:
    """The episodes' length in physical time beside their steps (keys added to an
    ``evaluation.json``; docs/physics.md, "Physical time and vibration"): ``time_base``,
    ``step_s`` (the control period; the paper's 0.1 s under ``step``) and ``episode_s``."""
    return {
        "time_base": config.time_base,
        "step_s": config.step_s,
        "episode_s": round(int(steps) * config.step_s, 9),
    }


def _rounded(values: np.ndarray, digits: int) -> list[float]:
    return [round(float(v), digits) for v in values]


def read_summary(summary: dict[str, Any]) -> dict[str, Any]:
    """A stored summary in this schema: one of :func:`summarize` as it is, one of a benchmark run
    stored before it (no episodes, returns or initial power) completed with None where it was
    not measured and ``initial_power_mean`` from its curve."""
    out = {key: summary.get(key) for key in SUMMARY_KEYS}
    if out["initial_power_mean"] is None and summary.get("curve_mean"):
        out["initial_power_mean"] = float(summary["curve_mean"][0])
    out.update({k: v for k, v in summary.items() if k not in SUMMARY_KEYS})
    return out


def read_evaluation(path: Path) -> dict[str, Any] | None:
    """``evaluation.json`` (of ``evaluate`` or of a benchmark run, in this schema or the
    benchmark's older one) with every summary (``splits``, ``transfer``) in this schema; None for
    a missing or unreadable file."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError):
        return None
    for group in ("splits", "transfer"):
        if isinstance(data.get(group), dict):
            data[group] = {k: read_summary(v) for k, v in data[group].items()}
    return data
