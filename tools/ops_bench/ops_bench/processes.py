"""Real processes started as a user would (``ros2 run ...``), and waiting on their output
instead of sleeping: the helpers of the integration tests (the fixtures using them live in the
repository's conftest.py) and of the benchmarks that start nodes."""

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

from ops_bench import REPO

__all__ = [
    "PYTHON",
    "REPO",
    "Process",
    "ProcessGroup",
    "assert_no_traceback",
    "busy_processes",
    "descendants",
    "executable",
    "ros2_command",
    "run_ros2",
    "sim_command",
    "start_sim",
]


def executable(package: str, name: str) -> list[str]:
    """Command line of ``ros2 run package name``, as a user types it."""
    return [*ros2_command(), "run", package, name]


def sim_command(*params: str) -> list[str]:
    """``ops_sim`` with parameters (``"stage:=3"``, ...) as a user runs it."""
    args = [*executable("ops_sim_ros", "sim"), "--ros-args"]
    for p in params:
        args += ["-p", p]
    return args


def start_sim(
    group: ProcessGroup,
    stage: int = 3,
    mode: str = "easy",
    namespace: str = "",
    lockstep: bool = True,
    seed: int = 1,
    name: str = "sim",
    env=None,
):
    """Start ``ops_sim`` and wait until it runs (``env``: its whole environment, as Popen's)."""
    args = sim_command(
        f"stage:={stage}",
        f"mode:={mode}",
        f"lockstep:={'true' if lockstep else 'false'}",
        f"seed:={seed}",
    )
    if namespace:
        args += ["-r", f"__ns:={namespace}"]
    proc = group.start(args, name=name, env=env)
    proc.wait_for(rf"stage={stage} mode={mode}", timeout=30)
    return proc


def ros2_command() -> list[str]:
    """The `ros2` a user has after `source setup.bash`."""
    exe = shutil.which("ros2")
    if exe is None:
        raise RuntimeError(
            "no `ros2` on PATH: run the tests after `source setup.bash` (make test does)"
        )
    return [exe]


def descendants(pid: int) -> list[int]:
    """The children of ``pid``, their children, ... (from /proc)."""
    parents: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = stat.read_text().rsplit(")", 1)[1].split()
            parents.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = [], [pid]
    while todo:
        kids = parents.get(todo.pop(), [])
        found += kids
        todo += kids
    return found


def log_tails(procs, chars: int = 3000) -> str:
    """The end of each process's output, headed by its command: what a wait that failed on
    them prints, so that a closed loop that did not get there says why."""
    return "".join(f"\n--- {' '.join(p.args)}\n{p.output[-chars:]}" for p in procs)


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

    def signal_tree(self, sig) -> None:
        """``sig`` to the process and every descendant: ``ros2 run`` starts the node in a
        session of its own and forwards SIGINT / SIGTERM only (SIGSTOP / SIGCONT need this)."""
        for pid in [*descendants(self.popen.pid), self.popen.pid]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)

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

    def node(self, package: str, exe: str, *params: str, name: str | None = None) -> Process:
        """``ros2 run package exe --ros-args -p P ...`` for each ``NAME:=VALUE`` of ``params``
        (its log named ``name``, or ``exe``)."""
        args = ["run", package, exe, "--ros-args"]
        for p in params:
            args += ["-p", p]
        return self.ros2(*args, name=name or exe)

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


#: What a process's output holds when an exception escaped: Python's traceback, and the events
#: executor's own report of an exception in a callback ("Exception in 'timers' callback: ...",
#: then "Error occurred at:" and the frames).
TRACEBACK_MARKS = ("Traceback", "Error occurred at:", "Exception in '")


def assert_no_traceback(text: str) -> None:
    found = [mark for mark in TRACEBACK_MARKS if mark in text]
    assert not found, f"{found}:\n{text}"


PYTHON = sys.executable


@contextlib.contextmanager
def busy_processes(count: int):
    """``count`` processes that keep a core busy each (at the normal priority) while the block
    runs: a machine that does other work beside a loop."""
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield busy
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
