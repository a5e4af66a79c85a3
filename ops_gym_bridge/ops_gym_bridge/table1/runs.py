"""The stored runs of a benchmark (``OUT/runs/<id>/``: run.json, evaluation.json, training.csv),
read for the report: every ``evaluation.json`` in the one summary schema
(:func:`ops_gym_bridge.experiments.summary.read_evaluation`, which also reads runs stored before
it).
"""

from __future__ import annotations

import csv
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from ..experiments.summary import read_evaluation
from .bench_worker import read_json

ALGO_ORDER = ("ppo", "td3", "sac")
SPLITS = ("train", "test")


def load_runs(root: Path) -> list[dict[str, Any]]:
    """Every stored run under ``root/runs`` (or ``root`` itself holding run directories)."""
    base = root / "runs" if (root / "runs").is_dir() else root
    runs = []
    for d in sorted(p for p in base.iterdir() if p.is_dir()):
        rec = read_json(d / "run.json")
        ev = read_evaluation(d / "evaluation.json")
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
