"""A training run's ``logs/progress.csv`` across resumed parts.

SB3's CSV logger starts its file afresh, so a ``train --resume`` would overwrite the parts
before it (a run resumed every session kept only its last session's curve). Before a resumed
part opens its logger, :func:`keep_earlier_parts` moves the file to ``progress.partK.csv`` (K =
1, 2, ... in order); :func:`read_progress` reads every part back in order, with each row's
``minutes`` counted from the run's start (a part's ``time/time_elapsed`` restarts at 0).
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

CURRENT = "progress.csv"
_PART = re.compile(r"progress\.part(\d+)\.csv$")


def parts(logs: Path) -> list[Path]:
    """The run's progress files, oldest first (the current part last)."""
    logs = Path(logs)
    earlier = sorted(
        (p for p in logs.glob("progress.part*.csv") if _PART.search(p.name)),
        key=lambda p: int(_PART.search(p.name).group(1)),
    )
    current = logs / CURRENT
    return earlier + ([current] if current.is_file() else [])


def keep_earlier_parts(logs: Path) -> Path | None:
    """Move ``logs/progress.csv`` (if any, and not empty) to the next ``progress.partK.csv``;
    returns where it went."""
    current = Path(logs) / CURRENT
    if not current.is_file() or current.stat().st_size == 0:
        return None
    k = 1 + max((int(_PART.search(p.name).group(1)) for p in parts(logs)[:-1]), default=0)
    kept = current.with_name(f"progress.part{k}.csv")
    current.rename(kept)
    return kept


def read_progress(logs: Path) -> list[dict]:
    """Every row of every part, oldest first; each row gains ``minutes``: wall time since the
    run's first part started (the earlier parts' last ``time/time_elapsed`` added)."""
    rows: list[dict] = []
    offset_s = 0.0
    for path in parts(logs):
        last_s = 0.0
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                elapsed = row.get("time/time_elapsed") or ""
                if elapsed:
                    last_s = max(last_s, float(elapsed))
                row["minutes"] = (offset_s + (float(elapsed) if elapsed else last_s)) / 60.0
                rows.append(row)
        offset_s += last_s
    return rows
