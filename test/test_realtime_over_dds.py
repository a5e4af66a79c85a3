"""The ``realtime_priority`` parameter of the nodes that loop (ops_contract.realtime), as real
processes over DDS: a value out of range stops the node naming the allowed ones; a loop whose
nodes ask for a priority closes, and each node's threads are all under SCHED_FIFO at that
priority, or the node said why not (a machine that does not allow it) and left them all under
the normal scheduler; either way it exits cleanly."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
from ops_bench.processes import assert_no_traceback, descendants
from ops_contract.realtime import thread_priorities

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

SCHED_OTHER, SCHED_FIFO = 0, 1
TAKEN = "every thread under SCHED_FIFO"
REFUSED = "not taken, the node runs under the normal scheduler"


def node_threads(proc, exe: str) -> list[tuple[int, int]]:
    """(policy, priority) of every thread of the node's process: the one of ``ros2 run``'s
    tree that runs the executable ``exe`` (``ros2 run`` starts it as a child)."""
    for pid in [proc.popen.pid, *descendants(proc.popen.pid)]:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        if any(part.endswith(f"/{exe}".encode()) for part in cmdline):
            return thread_priorities(pid)
    raise AssertionError(f"no process runs {exe} under {proc.popen.pid}")


@pytest.mark.parametrize(
    "package, exe",
    [("ops_sim_ros", "sim"), ("ops_controller_ros", "spgd"), ("ops_controller_ros", "tracker")],
    ids=["sim", "spgd", "tracker"],
)
def test_a_priority_out_of_range_is_refused_naming_the_allowed_ones(procs, package, exe):
    proc = procs.node(package, exe, "realtime_priority:=99")
    assert proc.wait_exit(60) == 2, proc.output
    assert "realtime_priority must be int in [0, 98]" in proc.output
    assert_no_traceback(proc.output)


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="Linux scheduling only")
def test_a_loop_at_a_realtime_priority_runs_under_fifo_or_says_why(procs, observer):
    sim = procs.node(
        "ops_sim_ros",
        "sim",
        "stage:=2",
        "mode:=easy",
        "seed:=4",
        "rate_hz:=200.0",
        "realtime_priority:=3",
    )
    spgd = procs.node("ops_controller_ros", "spgd", "realtime_priority:=3")
    spgd.wait_for("closing the loop", timeout=60)
    observer.wait_closed(0.9, timeout=60, logs=(sim, spgd))
    for proc, exe in ((sim, "sim"), (spgd, "spgd")):
        found = proc.wait_for(f"realtime_priority 3: ({TAKEN}|{REFUSED})").group(1)
        threads = node_threads(proc, exe)
        assert len(threads) >= 3, threads  # Python's, the executor's, the DDS library's
        want = (SCHED_FIFO, 3) if found == TAKEN else (SCHED_OTHER, 0)
        assert all(t == want for t in threads), (found, threads)
    for proc in (spgd, sim):
        proc.signal(signal.SIGTERM)
        assert proc.wait_exit(20) == 0, proc.output
        assert_no_traceback(proc.output)
