"""Helpers of the integration tests: real processes started as a user would, and waiting on
their output instead of sleeping. The fixtures using them live in conftest.py."""

from __future__ import annotations

import contextlib
import itertools
import json
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
):
    """Start ``ops_sim`` and wait until it runs."""
    args = sim_command(
        f"stage:={stage}",
        f"mode:={mode}",
        f"lockstep:={'true' if lockstep else 'false'}",
        f"seed:={seed}",
    )
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


# ---------------------------------------------------------------- two hosts on one machine
# Two Linux network namespaces joined by a veth pair stand for two computers on one Ethernet
# segment: each has its own address and loopback, so DDS between them goes over UDP on the link
# (as between two machines), and the link can be taken down and brought back.

_NETNS_COUNT = itertools.count()


class NetnsUnavailable(RuntimeError):
    """Network namespaces cannot be made here (the message says why)."""


def netns_unavailable_reason() -> str | None:
    """Why two-host tests cannot run on this machine, or None when they can (try TwoHosts())."""
    if not sys.platform.startswith("linux"):
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return "making network namespaces (ip netns add) needs root"
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2) on PATH"
    return None


def make_two_hosts(what: str) -> TwoHosts:
    """:class:`TwoHosts`, or skip the test saying why namespaces cannot be made here."""
    reason = netns_unavailable_reason()
    if reason:
        pytest.skip(f"{what} need network namespaces: {reason}")
    try:
        return TwoHosts()
    except NetnsUnavailable as exc:
        pytest.skip(f"{what}: cannot make network namespaces here: {exc}")


def _ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["ip", *args], capture_output=True, text=True, timeout=30, stdin=subprocess.DEVNULL
    )


class Host:
    """One network namespace on the link: a "host" with its own address."""

    def __init__(self, netns: str, device: str, address: str):
        self.netns = netns
        self.device = device
        self.address = address

    def command(self, args) -> list[str]:
        """``args`` run inside this host's namespace (``ip netns exec NETNS ...``)."""
        return ["ip", "netns", "exec", self.netns, *map(str, args)]

    def start(self, group: ProcessGroup, args, name: str | None = None, env=None) -> Process:
        """Start ``args`` on this host through ``group`` (stopped with the group's others)."""
        return group.start(self.command(args), name=name or Path(str(args[0])).name, env=env)

    def ros2(self, group: ProcessGroup, *args, name: str | None = None, env=None) -> Process:
        return self.start(group, [*ros2_command(), *args], name=name or f"ros2_{args[0]}", env=env)

    def set_link(self, up: bool) -> None:
        """Bring this host's end of the link up or down (down cuts the link both ways)."""
        done = _ip("-n", self.netns, "link", "set", self.device, "up" if up else "down")
        if done.returncode != 0:
            raise RuntimeError(f"ip link set {self.device}: {done.stderr.strip()}")

    def pids(self) -> list[int]:
        done = _ip("netns", "pids", self.netns)
        return [int(p) for p in done.stdout.split()] if done.returncode == 0 else []


class TwoHosts:
    """Hosts ``a`` and ``b``: two network namespaces joined by a veth pair, addresses
    10.231.0.1/24 and 10.231.0.2/24 (private to the namespaces, so parallel pairs do not meet),
    loopback up and a multicast route (224.0.0.0/4) on the link for DDS discovery. Names are
    unique per process and pair. ``close()`` (or leaving the ``with`` block) kills whatever
    still runs in the namespaces and deletes them, which removes the link too.

    Raises :class:`NetnsUnavailable` when the namespaces cannot be made; see also
    :func:`netns_unavailable_reason`.
    """

    def __init__(self):
        reason = netns_unavailable_reason()
        if reason:
            raise NetnsUnavailable(reason)
        tag = f"{os.getpid()}x{next(_NETNS_COUNT)}"  # device names have at most 15 characters
        self._made: list[str] = []
        self.a = Host(f"ops_{tag}_a", f"o{tag}a", "10.231.0.1")
        self.b = Host(f"ops_{tag}_b", f"o{tag}b", "10.231.0.2")
        try:
            for host in (self.a, self.b):
                self._run("netns", "add", host.netns)
                self._made.append(host.netns)
            self._run("link", "add", self.a.device, "type", "veth", "peer", "name", self.b.device)
            for host in (self.a, self.b):
                self._run("link", "set", host.device, "netns", host.netns)
                self._run("-n", host.netns, "addr", "add", f"{host.address}/24", "dev", host.device)
                self._run("-n", host.netns, "link", "set", "lo", "up")
                self._run("-n", host.netns, "link", "set", host.device, "up")
                self._run("-n", host.netns, "route", "add", "224.0.0.0/4", "dev", host.device)
            # `ip netns exec` also needs a mount namespace of its own: try it once.
            probe = subprocess.run(
                self.a.command(["true"]), capture_output=True, text=True, timeout=30
            )
            if probe.returncode != 0:
                raise NetnsUnavailable(f"ip netns exec failed: {probe.stderr.strip()}")
        except BaseException:
            self.close()
            raise

    def _run(self, *args: str) -> None:
        done = _ip(*args)
        if done.returncode != 0:
            raise NetnsUnavailable(f"ip {' '.join(args)}: {done.stderr.strip()}")

    def env(self, **extra) -> dict:
        """Environment of a process on either host: this process's (ROS_DOMAIN_ID included),
        discovery over the subnet (conftest's LOCALHOST would stay inside one namespace) and
        unbuffered Python output, so the tests can read it as it comes."""
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", PYTHONUNBUFFERED="1")
        env.pop("ROS_STATIC_PEERS", None)
        env.update({k: str(v) for k, v in extra.items()})
        return env

    def close(self) -> None:
        for netns in self._made:
            host = self.a if netns == self.a.netns else self.b
            for pid in host.pids():  # only what was started in our own namespaces
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        for netns in self._made:
            _ip("netns", "del", netns)  # removes the veth pair with it
        if self._made:  # a veth made but not yet moved into a namespace
            _ip("link", "del", self.a.device)
        self._made = []

    def __enter__(self) -> TwoHosts:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class RelayedHosts(TwoHosts):
    """Hosts ``a`` and ``b`` as in :class:`TwoHosts`, but joined through a third namespace in
    which scripts/fault_relay.py forwards every frame, so the link can lose, delay and cut them
    (``set(loss=0.05, delay_ms=20, down=False)``; this kernel has no netem). The relay's counts
    are in ``self.relay.output``."""

    def __init__(self, tmp_path: Path, seed: int = 0, relay_nice: int = 0):
        """``relay_nice``: the relay's niceness (it stands in for a network, which takes no CPU
        of the hosts; a benchmark that raises the loop's priority raises the relay's too)."""
        reason = netns_unavailable_reason()
        if reason:
            raise NetnsUnavailable(reason)
        tag = f"{os.getpid()}x{next(_NETNS_COUNT)}"
        self._made: list[str] = []
        self.a = Host(f"ops_{tag}_a", f"o{tag}a", "10.231.0.1")
        self.b = Host(f"ops_{tag}_b", f"o{tag}b", "10.231.0.2")
        self.r = Host(f"ops_{tag}_r", "", "")
        self.control = Path(tmp_path) / f"relay_{tag}.json"
        self.relay: Process | None = None
        try:
            for host in (self.a, self.b, self.r):
                self._run("netns", "add", host.netns)
                self._made.append(host.netns)
            self._run("-n", self.r.netns, "link", "set", "lo", "up")
            ports = []
            for host in (self.a, self.b):
                port = host.device[:-1] + "r" + host.device[-1]  # its end in the relay
                self._run("link", "add", host.device, "type", "veth", "peer", "name", port)
                self._run("link", "set", host.device, "netns", host.netns)
                self._run("link", "set", port, "netns", self.r.netns)
                self._run("-n", self.r.netns, "link", "set", port, "promisc", "on", "up")
                self._run("-n", host.netns, "addr", "add", f"{host.address}/24", "dev", host.device)
                self._run("-n", host.netns, "link", "set", "lo", "up")
                self._run("-n", host.netns, "link", "set", host.device, "up")
                self._run("-n", host.netns, "route", "add", "224.0.0.0/4", "dev", host.device)
                ports.append(port)
            self.set()
            log = Path(tmp_path) / f"relay_{tag}.log"
            prio = ["nice", "-n", str(relay_nice)] if relay_nice else []
            self.relay = Process(
                self.r.command(
                    [
                        *prio,
                        PYTHON,
                        REPO / "scripts" / "fault_relay.py",
                        *ports,
                        *("--control", self.control, "--seed", seed, "--report-s", 5),
                    ]
                ),
                log,
                env=dict(os.environ, PYTHONUNBUFFERED="1"),
            )
            self.relay.wait_for(r"\[relay\] loss", timeout=30)
        except BaseException:
            self.close()
            raise

    def set(self, loss: float = 0.0, delay_ms: float = 0.0, down: bool = False) -> None:
        """New link conditions (the relay picks them up within 0.1 s)."""
        tmp = self.control.with_suffix(".tmp")
        tmp.write_text(json.dumps({"loss": loss, "delay_ms": delay_ms, "down": down}))
        tmp.replace(self.control)

    def close(self) -> None:
        if self.relay is not None:
            self.relay.stop(timeout=5)
            self.relay = None
        super().close()
