"""The ``executor`` parameter of the simulator and the controller nodes, as real processes over
DDS: a bad value is refused naming the allowed ones; with each executor the simulator and SPGD
close the loop and exit cleanly on SIGINT and SIGTERM; under the events executor the simulator's
timers, parameter services, diagnostics and command inbox work."""

from __future__ import annotations

import re
import signal

import numpy as np
import pytest
from ops_bench.processes import assert_no_traceback, run_ros2
from ops_contract.executors import EXECUTORS

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


@pytest.mark.parametrize(
    "package, exe", [("ops_sim_ros", "sim"), ("ops_controller_ros", "spgd")], ids=["sim", "spgd"]
)
def test_a_bad_executor_is_refused_naming_the_allowed_ones(procs, package, exe):
    proc = procs.node(package, exe, "executor:=threads")
    assert proc.wait_exit(60) == 2, proc.output
    assert "executor must be one of default, events (got 'threads')" in proc.output
    assert_no_traceback(proc.output)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("executor", EXECUTORS)
def test_sim_and_spgd_close_the_loop_and_exit_cleanly(procs, observer, executor, sig):
    """At 500 Hz the simulator is publishing most of the time, so the signal that shuts the
    context down comes in a callback's publish: that is quiet too
    (ops_contract.executors.guarded)."""
    sim = procs.node(
        "ops_sim_ros",
        "sim",
        "stage:=2",
        "mode:=easy",
        "seed:=3",
        "rate_hz:=500.0",
        f"executor:={executor}",
    )
    spgd = procs.node("ops_controller_ros", "spgd", f"executor:={executor}")
    spgd.wait_for("closing the loop", timeout=60)
    # Closed: the simulator took SPGD's commands (its inbox) and SPGD its readings.
    observer.wait_closed(0.9, timeout=60, logs=(sim, spgd))
    for proc in (spgd, sim):
        proc.signal(sig)
        assert proc.wait_exit(20) == 0, proc.output
        assert_no_traceback(proc.output)


def test_the_events_executor_runs_timers_parameters_and_the_inbox(procs, observer):
    sim = procs.node(
        "ops_sim_ros",
        "sim",
        "stage:=3",
        "rate_hz:=50.0",
        "seed:=5",
        "executor:=events",
    )
    observer.wait_count("power", 20, timeout=60)

    def rate(n: int = 60) -> float:
        start = observer.count("power")
        observer.wait_count("power", start + n, timeout=30)
        with observer.lock:
            t = [m[0] for m in observer.messages["power"][start : start + n]]
        return (n - 1) / (t[-1] - t[0])

    assert 35.0 < rate() < 60.0  # the step timer, at rate_hz
    done = run_ros2("param", "set", "/ops_sim", "rate_hz", "100.0")
    assert "Set parameter successful" in done.stdout, done.stdout + done.stderr
    observer.wait_until(lambda: rate() > 75.0, timeout=30, what="steps at the new rate_hz")
    done = run_ros2("param", "set", "/ops_sim", "executor", "default")
    assert "executor cannot change while the node runs" in done.stdout + done.stderr
    got = run_ros2("param", "get", "/ops_sim", "executor")
    assert "events" in got.stdout, got.stdout + got.stderr
    # The inbox: a command sent is applied at a step
    observer.wait_for_subscriber()
    command = [0.25, -0.5, 0.75]
    observer.send(command)
    observer.wait_until(
        lambda: np.allclose(observer.last("delays"), command, atol=1e-5),
        timeout=10,
        what="the command applied",
    )
    # The diagnostics timer, with the count of steps that took no new command
    diag = run_ros2("topic", "echo", "--once", "/diagnostics", timeout=60)
    counts = re.search(r"key: steps_without_command\s+value: '(\d+)'", diag.stdout)
    assert counts and int(counts.group(1)) > 20, diag.stdout
    sim.signal(signal.SIGINT)
    assert sim.wait_exit(20) == 0, sim.output
    assert_no_traceback(sim.output)
