"""``ops-bench loop-rate``: the CPU it books per simulator step (each node's session, the child
that ``ros2 run`` starts in a process group of its own included) and the settings it passes."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest

from ops_bench.closed_loop import group_cpu_s, machine_times, start, steal_share, stop
from ops_bench.loop_rate import SECTION, commands, format_row, parse_args, section_title

# The parent waits; its child, in a process group of its own (as ``ros2 run`` starts a node),
# is busy: only the child's CPU can show.
CHILD_BUSY = """
import os, time
parent = os.getpid()
if os.fork() == 0:
    os.setpgid(0, 0)
    t = time.process_time()
    while time.process_time() - t < 30 and os.getppid() == parent:  # (ends with its parent)
        pass
else:
    os.wait()
"""


def test_a_session_is_booked_with_its_children_in_their_own_groups(tmp_path):
    proc = start([sys.executable, "-c", CHILD_BUSY], tmp_path / "busy.log")
    try:
        first = group_cpu_s(proc.pid)
        deadline = time.monotonic() + 30.0
        while group_cpu_s(proc.pid) - first < 0.5 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert group_cpu_s(proc.pid) - first >= 0.5  # the child's, in its own group
    finally:
        stop(proc)


def test_a_gone_session_books_nothing():
    assert group_cpu_s(2**22 + 12345) == 0.0


def test_the_steal_share_is_read_from_this_machine_and_is_a_share():
    before = machine_times()
    # Work until the kernel books a tick: /proc/stat's counts move in ticks of 10 ms, and an
    # idle core's are booked late (tickless idle), so a fixed amount of work may see none.
    deadline = time.monotonic() + 10.0
    after = machine_times()
    while after[1] == before[1] and time.monotonic() < deadline:
        sum(i * i for i in range(50_000))
        after = machine_times()
    assert after[1] > before[1] and after[0] >= before[0]
    assert 0.0 <= steal_share(before, after) <= 1.0
    assert steal_share((5, 100), (15, 300)) == 0.05
    assert steal_share((5, 100), (5, 100)) == 0.0  # (no time passed: no division by zero)


def test_the_table_row_shows_the_cpu_per_step():
    point = {"controller": "spgd", "executor": "events", "rate_hz": 500.0}
    point |= {"readings_per_s": 495.0, "missed": 0.036, "locked": 1.0, "held": False}
    point |= {"sim_cpu_us_per_step": 700.4, "controller_cpu_us_per_step": 616.2}
    row = "| spgd | events | 500 | 495 | 3.6 % | 100.0 % | 700 | 616 | — | no |"
    assert format_row(point) == row
    point["steal"] = 0.052
    assert "| 700 | 616 | 5.2 % | no |" in format_row(point)
    del point["steal"]
    del point["sim_cpu_us_per_step"]  # (a result file written before the column was added)
    assert "| — | 616 |" in format_row(point)


def test_physical_time_and_controller_parameters_reach_the_nodes_and_their_own_section():
    args = parse_args(["--controllers", "tracker", "--time-base", "seconds", "--vibration",
                       "lab", "--param", "answer_first:=true"])  # fmt: skip
    sim, ctl = commands(args, "tracker", "events", 500.0)
    assert {"time_base:=seconds", "vibration:=lab", "rate_hz:=500"} <= set(sim)
    # the tracker told the vibration at the loop's period, and the parameter given
    assert {"vibration:=lab", "step_s:=0.002", "answer_first:=true"} <= set(ctl)
    title = section_title(args)
    assert title == f"{SECTION}: tracker, time_base seconds, vibration lab, answer_first:=true"
    assert section_title(parse_args([])) == SECTION  # the default's: every controller
    assert section_title(parse_args(["--controllers", "spgd"])) == f"{SECTION}: spgd"


def test_a_vibration_in_steps_is_refused(capsys):
    with pytest.raises(SystemExit) as stop_:
        parse_args(["--controllers", "spgd", "--vibration", "lab"])
    assert stop_.value.code == 2
    assert "--time-base seconds" in capsys.readouterr().err


def test_a_realtime_priority_reaches_both_nodes_and_its_own_section():
    from ops_contract.realtime import set_priority

    if set_priority(7) is not None:
        pytest.skip("this machine does not allow SCHED_FIFO (parse_args refuses it: below)")
    set_priority(0)
    args = parse_args(["--controllers", "spgd", "--realtime-priority", "7", "--busy", "2"])
    sim, ctl = commands(args, "spgd", "events", 1000.0)
    assert "realtime_priority:=7" in sim and "realtime_priority:=7" in ctl
    assert section_title(args) == f"{SECTION}: spgd, realtime_priority 7, 2 busy processes"
    plain = commands(parse_args(["--controllers", "spgd"]), "spgd", "events", 1000.0)
    assert not any("realtime_priority" in p for p in plain[0] + plain[1])


@pytest.mark.parametrize(
    "option, why", [(["--realtime-priority", "99"], "0 to 98"), (["--busy", "-1"], ">= 0")]
)
def test_bad_priorities_and_loads_exit_2(capsys, option, why):
    with pytest.raises(SystemExit) as stop_:
        parse_args(["--controllers", "spgd", *option])
    assert stop_.value.code == 2
    assert why in capsys.readouterr().err


def test_busy_processes_keep_a_core_busy_and_are_gone_after():
    from ops_bench.processes import busy_processes

    def cpu_s(pid: int) -> float:  # utime + stime (/proc)
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    with busy_processes(2) as busy:
        assert [p.poll() for p in busy] == [None, None]
        deadline = time.monotonic() + 30.0
        while cpu_s(busy[0].pid) < 0.2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert cpu_s(busy[0].pid) >= 0.2
    assert all(p.poll() is not None for p in busy)
