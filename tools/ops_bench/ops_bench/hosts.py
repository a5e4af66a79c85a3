"""Two hosts on one machine: Linux network namespaces joined by a veth pair (TwoHosts), or
through a third namespace in which ops_bench.relay forwards, loses, delays and cuts frames
(RelayedHosts). Used by the two-host and lossy-link tests and benchmarks."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

from ops_bench.processes import PYTHON, Process, ProcessGroup, ros2_command

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
    import pytest  # a test's helper: the only one here that needs pytest

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
    which ops_bench.relay forwards every frame, so the link can lose, delay and cut them
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
                        "-m",
                        "ops_bench.relay",
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

    def set(
        self, loss: float = 0.0, delay_ms: float = 0.0, down: bool = False, stuck: bool = False
    ) -> None:
        """New link conditions (the relay picks them up within 0.1 s; ``stuck``: the DDS links
        open now stay dead, ops_bench.relay)."""
        tmp = self.control.with_suffix(".tmp")
        conditions = {"loss": loss, "delay_ms": delay_ms, "down": down, "stuck": stuck}
        tmp.write_text(json.dumps(conditions))
        tmp.replace(self.control)

    def close(self) -> None:
        if self.relay is not None:
            self.relay.stop(timeout=5)
            self.relay = None
        super().close()
