"""freeze_after_heavy_imports: the heap is frozen once a heavy module has loaded (now, if it has),
and what is made afterwards is still collected: a cycle dropped later is finalized at exit (a
gc.freeze() at the end of the process would keep its finalizer from running).
Checked in fresh processes with a small standard module standing in for the heavy ones."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import gc, sys
from ops_contract import heap
heap.HEAVY_MODULES = ("colorsys",)
if sys.argv[1] == "loaded":
    import colorsys
heap.freeze_after_heavy_imports()
print("before", gc.get_freeze_count(), flush=True)
import colorsys
print("after", gc.get_freeze_count(), flush=True)

class Holder:  # in a cycle: only the collector frees it and runs its finalizer
    def __del__(self):
        with open(sys.argv[2], "w") as f:
            f.write("finalized")

h = Holder()
h.me = h
del h
"""


def _run(tmp_path, when: str) -> dict[str, int]:
    out = tmp_path / f"{when}.txt"
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, when, str(out)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert out.read_text() == "finalized"
    return {k: int(v) for k, v in (line.split() for line in done.stdout.splitlines())}


def test_the_heap_is_frozen_after_the_import_and_later_objects_are_still_collected(tmp_path):
    counts = _run(tmp_path, "later")
    assert counts["before"] == 0 and counts["after"] > 1000


def test_a_module_already_loaded_freezes_at_once(tmp_path):
    counts = _run(tmp_path, "loaded")
    assert counts["before"] > 1000 and counts["after"] == counts["before"]
