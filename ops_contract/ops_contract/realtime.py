"""Real-time scheduling for a node that loops: the ``realtime_priority`` parameter of the
simulator, the controller nodes and the rig node (:func:`~ops_contract.ros_interface.run_node`).

A free-running loop over DDS has one period for a round trip: the simulator's reading out, the
controller's answer back. On a machine that runs anything else beside the loop, the kernel's
fair scheduler hands the loop's threads a core when their turn comes, which can be a few ms
late; a step whose command comes late is a step without a command. Under ``SCHED_FIFO`` a
woken thread of the loop takes a core from any normal process at once. ``ops-bench loop-rate
--busy 2`` measures it (docs/benchmarks.md, docs/loop_rate.md, "Over DDS").

``realtime_priority``: 0 (the default) leaves the node under the normal scheduler; 1-98 puts
every thread of the process (Python's, rclpy's and the DDS library's, and those they start
later, which inherit it) under ``SCHED_FIFO`` at that priority, as ros2_control's
``thread_priority`` does for its control loop. 99 is left to the kernel's own threads (the
priority of its watchdogs, which a loop must not block).

Linux allows it to a process with ``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO`` at least the
priority (``ulimit -r``; ``rtprio`` in ``/etc/security/limits.conf`` for a user or group). A
node refused it logs a warning with what to set and runs under the normal scheduler: the loop
works the same, with the late wake-ups a busy machine gives. The kernel keeps 5 % of each
second for normal processes while real-time threads want a core (``sched_rt_runtime_us``), so
a loop at a real-time priority cannot lock a machine up.
"""

from __future__ import annotations

import os

from .node_params import ParamSpec

#: The highest priority a node may ask for (99 is the kernel's watchdogs').
MAX_PRIORITY = 98

REALTIME_PRIORITY_SPEC = ParamSpec(
    "realtime_priority",
    0,
    "0: the normal scheduler; 1-98: every thread of the node under SCHED_FIFO at this priority, "
    "so that the loop's round trip is not delayed by other processes (needs CAP_SYS_NICE or an "
    "rtprio limit; refused, the node warns and runs normally)",
    low=0,
    high=MAX_PRIORITY,
    read_only=True,
)

HOW_TO_ALLOW = (
    "allow it with CAP_SYS_NICE (e.g. `sudo setcap cap_sys_nice+ep $(readlink -f $(which "
    "python3))`) or a real-time limit for the user (`ulimit -r {priority}` in the launching "
    "shell; `@group - rtprio {priority}` in /etc/security/limits.conf)"
)


def thread_ids() -> list[int]:
    """The ids of this process's threads (Linux's /proc/self/task)."""
    return [int(tid) for tid in os.listdir("/proc/self/task")]


def set_priority(priority: int) -> str | None:
    """Put every thread of this process under ``SCHED_FIFO`` at ``priority`` (1 to
    :data:`MAX_PRIORITY`), or back under the normal scheduler (``priority`` 0).

    Returns None once done, or why it could not be done: Linux refuses it for every thread
    alike, so a refusal comes at the first one and nothing has changed."""
    if not 0 <= priority <= MAX_PRIORITY:
        raise ValueError(f"realtime_priority must be in [0, {MAX_PRIORITY}] (got {priority})")
    if not hasattr(os, "sched_setscheduler"):
        return "this platform has no SCHED_FIFO (os.sched_setscheduler)"
    policy = os.SCHED_FIFO if priority else os.SCHED_OTHER
    param = os.sched_param(priority)
    for tid in thread_ids():
        try:
            os.sched_setscheduler(tid, policy, param)  # a thread id names that thread alone
        except ProcessLookupError:
            continue  # the thread ended meanwhile
        except PermissionError:
            return "this process may not use SCHED_FIFO: " + HOW_TO_ALLOW.format(priority=priority)
    return None


def thread_priorities(pid: int | str = "self") -> list[tuple[int, int]]:
    """(policy, real-time priority) of each thread of process ``pid`` (Linux's /proc: fields
    40 and 41 of each task's stat), for checking what :func:`set_priority` did."""
    found = []
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
        except OSError:
            continue  # (ended meanwhile)
        # fields after the name start at field 3 (state): rt_priority is 40, policy is 41
        found.append((int(fields[38]), int(fields[37])))
    return found
