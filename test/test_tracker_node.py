"""The tracker node over DDS: ``sim`` (stage 5, medium) + ``tracker`` as real processes."""

from __future__ import annotations

import signal
import time

import numpy as np
import pytest
from ros_testing import assert_no_traceback

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def start(procs, name, pkg, exe, *params):
    args = ["run", pkg, exe, "--ros-args"]
    for p in params:
        args += ["-p", p]
    return procs.ros2(*args, name=name)


@pytest.mark.parametrize("lockstep", ["false", "true"])
def test_tracker_locks_a_medium_n5_stacker_within_10_s(procs, observer, lockstep):
    start(
        procs,
        "sim",
        "ops_sim_ros",
        "sim",
        "stage:=5",
        "mode:=medium",
        "seed:=3",
        f"lockstep:={lockstep}",
    )
    observer.wait_for_subscriber()
    tracker = start(procs, "tracker", "ops_controller_ros", "tracker", "seed:=3")
    tracker.wait_for("closing the loop", timeout=30)
    started = time.monotonic()
    observer.wait_until(
        lambda: (
            len(observer.values("power")) > 20 and np.mean(observer.values("power")[-10:]) >= 0.95
        ),
        timeout=10,
        what="P_N/P_max >= 0.95 over the last 10 readings within 10 s of the tracker's start",
    )
    assert time.monotonic() - started <= 10.0
    tracker.wait_for(r"reading \d+ \(locked\): P_N/P_max = 0\.9", timeout=10)
    tracker.signal(signal.SIGTERM)
    assert tracker.wait_exit(15) == 0  # a clean exit on SIGTERM
    assert_no_traceback(tracker.output)


def test_bad_parameter_stops_the_tracker_before_it_spins(procs):
    tracker = start(procs, "tracker", "ops_controller_ros", "tracker", "detector:=camera")
    assert tracker.wait_exit(30) == 2
    assert "detector" in tracker.output and "polarizer, total" in tracker.output
    assert_no_traceback(tracker.output)
