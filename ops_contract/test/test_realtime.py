"""ops_contract.realtime in a real child process: every thread taken under SCHED_FIFO, threads
started afterwards inheriting it, and the way back; or, where the machine does not allow it, the
reason and nothing changed."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest
from ops_contract.realtime import MAX_PRIORITY, set_priority

pytestmark = pytest.mark.skipif(
    not hasattr(os, "sched_setscheduler"), reason="Linux scheduling only"
)

CHILD = """
import json, threading
from ops_contract.realtime import set_priority, thread_priorities
stop = threading.Event()
before = threading.Thread(target=stop.wait); before.start()
refused = set_priority(4)
after = threading.Thread(target=stop.wait); after.start()
taken = thread_priorities()
back = set_priority(0)
normal = thread_priorities()
stop.set(); before.join(); after.join()
print(json.dumps({"refused": refused, "taken": taken, "back": back, "normal": normal}))
"""


def run_child(*prefix: str) -> dict:
    done = subprocess.run(
        [*prefix, sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_every_thread_is_taken_and_given_back_or_the_reason_is_said():
    got = run_child()
    threads = len(got["taken"])  # the main thread, one started before, one after, rclpy's
    assert threads >= 3 and len(got["normal"]) == threads
    if got["refused"] is None:
        assert got["taken"] == [[1, 4]] * threads  # (SCHED_FIFO, 4), the later thread too
        assert got["back"] is None
    else:
        assert "CAP_SYS_NICE" in got["refused"] and "ulimit -r 4" in got["refused"]
        assert got["taken"] == [[0, 0]] * threads
    assert got["normal"] == [[0, 0]] * threads


@pytest.mark.parametrize("priority", [-1, MAX_PRIORITY + 1])
def test_a_priority_out_of_range_raises(priority):
    with pytest.raises(ValueError, match="realtime_priority must be in"):
        set_priority(priority)


@pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("capsh") is None,
    reason="needs root and capsh to take CAP_SYS_NICE away (without it the test above refuses)",
)
def test_a_process_without_the_right_is_told_how_to_get_it_and_stays_normal():
    got = run_child("capsh", "--drop=cap_sys_nice", "--", "-c", 'exec "$0" "$@"')
    assert "CAP_SYS_NICE" in got["refused"] and "ulimit -r 4" in got["refused"]
    assert all(t == [0, 0] for t in got["taken"] + got["normal"])
