"""Helpers of the integration tests: real processes started as a user would, and waiting on
their output instead of sleeping. The fixtures using them live in conftest.py."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def executable(package: str, name: str) -> list[str]:
    """Command line of ``ros2 run package name``, as a user types it."""
    return [*ros2_command(), "run", package, name]


def start_sim(
    group: ProcessGroup,
    stage: int = 3,
    mode: str = "easy",
    namespace: str = "",
    lockstep: bool = True,
    seed: int = 1,
    name: str = "sim",
):
    """Start ``ops_sim`` and wait until it runs."""
    args = [
        *executable("ops_sim_ros", "sim"),
        "--ros-args",
        "-p",
        f"stage:={stage}",
        "-p",
        f"mode:={mode}",
        "-p",
        f"lockstep:={'true' if lockstep else 'false'}",
        "-p",
        f"seed:={seed}",
    ]
    if namespace:
        args += ["-r", f"__ns:={namespace}"]
    proc = group.start(args, name=name)
    proc.wait_for(rf"stage={stage} mode={mode}", timeout=30)
    return proc


def ros2_command() -> list[str]:
    """The `ros2` a user has after `source setup.bash`."""
    exe = shutil.which("ros2")
    if exe is None:
        pytest.fail("no `ros2` on PATH: run the tests after `source setup.bash` (make test does)")
    return [exe]


class Process:
    """A started command with its output in a file."""

    def __init__(self, args, log_path: Path, env=None):
        self.args = [str(a) for a in args]
        self.log_path = log_path
        self._log = open(log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.popen = subprocess.Popen(
            self.args,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=env,
            start_new_session=True,  # our signals reach it only when we send them
        )

    @property
    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_for(self, pattern: str, timeout: float = 30.0, count: int = 1) -> re.Match:
        """Poll the output until ``pattern`` (a regex) has matched ``count`` times."""
        deadline = time.monotonic() + timeout
        rx = re.compile(pattern)
        while True:
            matches = list(rx.finditer(self.output))
            if len(matches) >= count:
                return matches[count - 1]
            if self.popen.poll() is not None:
                matches = list(rx.finditer(self.output))
                if len(matches) >= count:
                    return matches[count - 1]
                raise AssertionError(
                    f"{' '.join(self.args)} exited ({self.popen.returncode}) before printing "
                    f"{pattern!r}:\n{self.output}"
                )
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"timed out after {timeout} s waiting for {pattern!r} from "
                    f"{' '.join(self.args)}:\n{self.output}"
                )
            time.sleep(0.05)

    def wait_exit(self, timeout: float = 30.0) -> int:
        try:
            return self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(
                f"{' '.join(self.args)} did not exit within {timeout} s:\n{self.output}"
            ) from None

    def signal(self, sig=signal.SIGINT) -> None:
        if self.popen.poll() is None:
            os.killpg(self.popen.pid, sig)

    def stop(self, timeout: float = 10.0) -> int | None:
        """SIGINT, then SIGKILL after ``timeout``; returns the exit code."""
        if self.popen.poll() is None:
            self.signal(signal.SIGINT)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(self.popen.pid, signal.SIGKILL)
                self.popen.wait(5)
        self._log.close()
        return self.popen.returncode


class ProcessGroup:
    def __init__(self, tmp_path: Path):
        self.tmp_path = tmp_path
        self.started: list[Process] = []

    def start(self, args, name: str | None = None, env=None) -> Process:
        name = name or Path(str(args[0])).name
        log = self.tmp_path / f"{len(self.started):02d}_{name}.log"
        proc = Process(args, log, env=env)
        self.started.append(proc)
        return proc

    def ros2(self, *args, name: str | None = None, env=None) -> Process:
        return self.start([*ros2_command(), *args], name=name or f"ros2_{args[0]}", env=env)

    def stop_all(self):
        for proc in reversed(self.started):
            proc.stop()


def run_ros2(*args, timeout: float = 60.0, env=None) -> subprocess.CompletedProcess:
    """Run a short `ros2 ...` command to completion and capture its output."""
    return subprocess.run(
        [*ros2_command(), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        stdin=subprocess.DEVNULL,
    )


def assert_no_traceback(text: str) -> None:
    assert "Traceback" not in text, text


PYTHON = sys.executable


class TopicObserver:
    """An rclpy node in the test process: records the simulator's outputs, sends commands.

    Spins in a background thread on its own context (so each test starts clean); ``close()``
    stops it. Messages are kept as (monotonic time, value) per topic.
    """

    def __init__(self, namespace: str = "/"):
        import threading

        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float32, Float32MultiArray

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("test_observer", namespace=namespace, context=self.context)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.lock = threading.Lock()
        self.messages: dict[str, list] = {"delays": [], "intensity": [], "power": [], "reward": []}
        self.order: list[str] = []
        for name, mtype in (
            ("delays", Float32MultiArray),
            ("intensity", Float32MultiArray),
            ("power", Float32),
            ("reward", Float32),
        ):
            self.node.create_subscription(mtype, f"ops/{name}", self._recorder(name), qos)
        self.cmd_pub = self.node.create_publisher(Float32MultiArray, "ops/delay_cmd", qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        from rclpy.executors import ExternalShutdownException

        # close() shuts the executor down from another thread.
        with contextlib.suppress(ExternalShutdownException):
            self.executor.spin()

    def _recorder(self, name):
        def record(msg):
            value = list(msg.data) if hasattr(msg.data, "__len__") else float(msg.data)
            with self.lock:
                self.messages[name].append((time.monotonic(), value, msg))
                self.order.append(name)

        return record

    def count(self, name: str) -> int:
        with self.lock:
            return len(self.messages[name])

    def values(self, name: str) -> list:
        with self.lock:
            return [v for _, v, _ in self.messages[name]]

    def last(self, name: str):
        with self.lock:
            return self.messages[name][-1][1] if self.messages[name] else None

    def wait_until(self, condition, timeout: float = 30.0, what: str = "condition"):
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            time.sleep(0.02)

    def wait_count(self, name: str, n: int, timeout: float = 30.0):
        self.wait_until(lambda: self.count(name) >= n, timeout, f"{n} messages on ops/{name}")

    def send(self, values):
        from std_msgs.msg import Float32MultiArray

        self.cmd_pub.publish(Float32MultiArray(data=[float(v) for v in values]))

    def wait_for_subscriber(self, timeout: float = 30.0):
        """Until the simulator's command subscription has matched our publisher."""
        self.wait_until(
            lambda: self.cmd_pub.get_subscription_count() > 0, timeout, "a delay_cmd subscriber"
        )

    def close(self):
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)
        self._thread.join(timeout=5.0)
