"""The continuous-operation table over DDS beside the in-process one.

Reads the JSON files `ops-bench continuous-dds --out` wrote (default
docs/results/continuous_dds/CELL.json, CELL = tracker_MODE_600s, model_NAME_600s (NAME: the
folder under models/) or spgd_MODE_300s) and the in-process `evaluate --continuous --out`
results of the same controller and mode (docs/results/continuous/CELL/evaluation.json, the
longest run stored), and prints a markdown table: readings >= 0.95 after the first lock, lock
losses (< 0.8), the longest, the worst reading after the lock, the difference of the locked
fractions and the file (a suffix names the commit of an older run: CELL_<commit>.json).

Usage (after `source setup.bash`):
  ops-bench continuous-table [--dds docs/results/continuous_dds]
      [--inprocess docs/results/continuous]
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

from ops_bench import REPO

# CELL: tracker_MODE, spgd_MODE or model_NAME (NAME: the folder under models/, e.g. n5_hard_long;
# the mode is the run's), then the seconds and an optional suffix (nice, commit)
CELL = re.compile(r"^(tracker|spgd|model)_([a-z0-9_]+?)_(\d+)s(_[\w-]+)?$")
MODES = ("easy", "medium", "hard", "extreme")


def inprocess_figures(root: Path, kind: str, mode: str) -> tuple[str, dict] | None:
    """The longest stored in-process run of ``kind`` (tracker, spgd: in ``mode``; a model:
    model_NAME) in ``mode``: (its folder, overall)."""
    best = None
    prefix = kind if kind.startswith("model_") else f"{kind}_{mode}"
    for path in sorted(root.glob(f"{prefix}*/evaluation.json")):
        if kind.startswith("model_") and not re.fullmatch(rf"{prefix}(_\d+k)?", path.parent.name):
            continue  # another model whose name starts the same (n5_hard, n5_hard_long)
        data = json.loads(path.read_text())
        steps = int(data.get("continuous_steps", 0)) * len(data.get("seeds", []))
        overall = data["splits"]["test"]["overall"]
        if best is None or steps > best[0]:
            best = (steps, path.parent.name, overall, data)
    if best is None:
        return None
    _, name, overall, data = best
    return f"{name} ({data['continuous_steps']} × {len(data['seeds'])})", overall


#: a stored file or folder whose name ends in a commit (``_5c28d78``) is an older controller's run,
#: kept for the record: the results pages put it on the history page, not beside current figures.
COMMIT_SUFFIX = re.compile(r"_[0-9a-f]{7,40}$")


def superseded(name: str) -> bool:
    """Whether a stored run (file stem or folder name) is an older controller's, named by commit."""
    return bool(COMMIT_SUFFIX.search(name))


HEADER = [
    "| controller | mode | DDS: time, readings | locked after first lock | losses | longest | "
    "worst after lock | nice | load at the end | in process (run) | in process locked | "
    "difference | stored as |",
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
]


def table_lines(dds: Path, inprocess: Path, select=lambda stem: True, link: str = "") -> list[str]:
    """The markdown table of the runs in ``dds`` whose file stem ``select`` accepts, each beside
    the in-process run of ``inprocess``; ``link``: a path prefix that makes "stored as" a link."""
    rows = []
    for path in Path(dds).glob("*.json"):
        match = CELL.match(path.stem)
        if not match or not select(path.stem):
            continue
        kind, name, seconds, _ = match.groups()
        data = json.loads(path.read_text())
        mode = data["args"]["mode"]
        if kind == "model" and data["args"].get("model"):  # the model's folder, not the file's
            name = Path(data["args"]["model"]).name  # name (model_n5_sac300k_authors_hard_600s)
        cell = f"{kind}_{name}" if kind == "model" else kind  # the in-process run's prefix
        rows.append((("tracker", "model", "spgd").index(kind), MODES.index(mode), cell, mode,
                     int(seconds), data, path.name))  # fmt: skip
    lines = list(HEADER)
    for _, _, kind, mode, seconds, data, stored in sorted(
        rows, key=lambda r: (*r[:2], r[5]["args"].get("nice", 0), r[6])
    ):
        o = data["overall"]
        readings = sum(int(r.get("readings", 0)) for r in data.get("per_seed", []))
        name = "SPGD-PID" if kind == "spgd" else kind.replace("model_", "models/")
        load = data.get("load_average_end", ["?"])[0]  # 1-min load average at the end
        ref = inprocess_figures(Path(inprocess), kind, mode)
        ref_cells = ["—", "—", "—"]
        if ref is not None:
            diff = 100 * (o["locked_fraction"] - ref[1]["locked_fraction"])
            ref_cells = [ref[0], f"{100 * ref[1]['locked_fraction']:.2f} %", f"{diff:+.2f} points"]
        stored_cell = f"[{stored}]({link}{stored})" if link else stored
        lines.append(
            f"| {name} | {mode} | {seconds} s, {readings} | {100 * o['locked_fraction']:.2f} % | "
            f"{o['losses']} | {o['longest_loss']} | {o['worst_after_lock']:.4f} | "
            f"{data['args'].get('nice', 0)} | {load} | "
            + " | ".join(ref_cells)
            + f" | {stored_cell} |"
        )
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--dds", default=str(REPO / "docs/results/continuous_dds"))
    ap.add_argument("--inprocess", default=str(REPO / "docs/results/continuous"))
    args = ap.parse_args(argv)
    print("\n".join(table_lines(Path(args.dds), Path(args.inprocess))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
