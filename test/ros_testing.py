"""Helpers of the integration tests: real processes started as a user would, and waiting on
their output instead of sleeping. The fixtures using them live in conftest.py."""

from __future__ import annotations

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
