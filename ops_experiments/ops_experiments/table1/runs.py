"""The stored runs of a benchmark (``OUT/runs/<id>/``: run.json, evaluation.json, training.csv),
read for the report: every ``evaluation.json`` in the one summary schema
(:func:`ops_experiments.summary.read_evaluation`, which also reads runs stored before
it).
"""

from __future__ import annotations

import csv
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from ..summary import read_evaluation
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


def pool_runs(roots: list[Path]) -> list[dict[str, Any]]:
    """The stored runs of several directories as one set: one protocol whose seeds were run into
    more than one ``--out`` (e.g. seeds 0-2, then 3-9 of one cell). Raises ``ValueError`` when a
    run id repeats, or when the runs of one cell (stage, mode, controller) differ in detector,
    observation set, planned training steps, hyperparameters or rig, so no cell mixes two
    protocols."""
    runs, where = [], {}
    for root in roots:
        for run in load_runs(root):
            if run["id"] in where:
                raise ValueError(f"run {run['id']} is stored in both {where[run['id']]} and {root}")
            where[run["id"]] = root
            runs.append(run)
    cells: dict[tuple, dict] = {}
    for run in runs:
        cell = (run["stage"], run["mode"], run["name"])
        setting = _protocol(run)
        first = cells.setdefault(cell, setting)
        if first != setting:
            diff = {k: (first[k], setting[k]) for k in setting if first[k] != setting[k]}
            raise ValueError(
                f"the runs of N = {cell[0]} {cell[1]} {cell[2]} differ in {diff}; pool only one "
                "protocol's runs"
            )
    return runs


def _protocol(run: dict[str, Any]) -> dict[str, Any]:
    """What a cell's runs must share to be pooled (the planned steps: a resumed run may stop a
    few steps past them)."""
    spec = run["spec"]
    return {
        "detector": run["detector"],
        "observation": run["observation"],
        "timesteps": spec.get("timesteps", run["timesteps"]),
        "hyperparams_set": spec.get("hyperparams_set"),
        "hyperparams": sorted(spec.get("hyperparams") or []),
        "rig": spec.get("rig") or {},
    }


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
