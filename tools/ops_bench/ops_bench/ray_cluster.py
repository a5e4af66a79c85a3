"""A two-node Ray cluster on one machine: the head on host A and a worker node on host B of
ops_bench.hosts.TwoHosts (two network namespaces joined by a veth link), as docs/cluster.md sets one
up on real machines. Token authentication is on (the head's token copied to B's home), and the
worker node has nothing of the project: it starts from a folder of its own, with PYTHONPATH and
the ROS workspace variables cleared, so the project's packages cannot be imported there; only the
venv's Python with Ray and the third-party packages. Used by test/test_ray_cluster.py and
`ops-bench ray-cluster`. Every Ray process runs inside the namespaces, so closing the hosts
(``TwoHosts.close``: SIGKILL to every process in them) stops them all, and nothing else.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from ops_experiments.table1.ray_pool import PACKAGES  # the packages a task ships; none on B

PORT = 6379
#: Variables that would put the project on a node's path (setup.bash sets them).
PROJECT_VARS = ("PYTHONPATH", "AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH", "CMAKE_PREFIX_PATH")
PROBE = (
    "import importlib.util as u, json; print(json.dumps([bool(u.find_spec(p)) for p in {pkgs!r}]))"
)


def ray_exe() -> str:
    exe = Path(sys.executable).with_name("ray")
    return str(exe) if exe.exists() else (shutil.which("ray") or "ray")


class RayCluster:
    """``head`` and ``worker`` (processes.Process of ``ray start --block``) on ``hosts``."""

    def __init__(self, hosts, group, root: Path, cpus: int = 1):
        self.hosts, self.group, self.root, self.cpus = hosts, group, Path(root), cpus
        self.address = f"{hosts.a.address}:{PORT}"
        self.token = secrets.token_hex(32)
        self.home_a = self._home("home_a")
        self.home_b = self._home("home_b")
        self.worker_cwd = self.root / "worker_cwd"
        self.worker_cwd.mkdir(parents=True, exist_ok=True)
        self.head = self.worker = None
        # Ray's socket paths must fit in 107 bytes: its temp dirs go to a short folder.
        self.ray_tmp = Path(tempfile.mkdtemp(prefix="opsray"))
        for host in "ab":  # each node's TMPDIR (its runs' folders), removed with the rest
            (self.ray_tmp / f"tmp_{host}").mkdir()

    def close(self) -> None:
        """Remove Ray's folders (after the hosts are closed, which stops the nodes)."""
        shutil.rmtree(self.ray_tmp, ignore_errors=True)

    def __enter__(self) -> RayCluster:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _home(self, name: str) -> Path:
        home = self.root / name
        (home / ".ray").mkdir(parents=True, exist_ok=True)
        (home / ".ray" / "auth_token").write_text(self.token + "\n")
        return home

    def driver_env(self, **extra) -> dict:
        """Environment of the benchmark on host A: the project's, with A's home (the token)."""
        env = self.hosts.env(HOME=str(self.home_a), TMPDIR=str(self.ray_tmp / "tmp_a"), **extra)
        for var in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH", "RAY_ADDRESS"):
            env.pop(var, None)
        return env

    def worker_env(self) -> dict:
        env = {k: v for k, v in self.driver_env().items() if k not in PROJECT_VARS}
        env.update(HOME=str(self.home_b), RAY_AUTH_MODE="token", TMPDIR=str(self.ray_tmp / "tmp_b"))
        return env

    def _start(self, host, args, name, env, cwd=None):
        cmd = [ray_exe(), "start", "--block", "--disable-usage-stats", *args]
        cmd += [f"--num-cpus={self.cpus}", "--object-store-memory=100000000"]
        cmd += [f"--node-ip-address={host.address}", f"--temp-dir={self.ray_tmp / name}"]
        if cwd is None:
            return host.start(self.group, cmd, name=name, env=env)
        # ops_bench.processes.Process has no cwd: `env -C DIR` starts the node from DIR.
        return host.start(self.group, ["env", "-C", str(cwd), *cmd], name=name, env=env)

    def start_head(self, timeout: float = 120.0):
        env = self.driver_env(RAY_AUTH_MODE="token")
        self.head = self._start(self.hosts.a, ["--head", f"--port={PORT}"], "ray_head", env)
        self.head.wait_for(r"Ray runtime started", timeout=timeout)
        return self.head

    def start_worker(self, timeout: float = 120.0, without: str | None = None):
        """Start the worker node; ``without``: a third-party package its Python then lacks
        (a package of that name that fails to import comes first on its path)."""
        env = self.worker_env()
        if without:
            stub = self.root / "stubs" / without
            stub.mkdir(parents=True, exist_ok=True)
            (stub / "__init__.py").write_text(
                f"raise ImportError('{without} is not installed on this node')\n"
            )
            env["PYTHONPATH"] = str(stub.parent)
        self.worker = self._start(
            self.hosts.b, [f"--address={self.address}"], "ray_worker", env, cwd=self.worker_cwd
        )
        self.worker.wait_for(r"Ray runtime started", timeout=timeout)
        return self.worker

    def project_importable_on_worker(self) -> list[bool]:
        """Whether each of the project's packages can be imported where the worker node runs."""
        code = PROBE.format(pkgs=PACKAGES)
        out = subprocess.run(
            self.hosts.b.command(["env", "-C", str(self.worker_cwd), sys.executable, "-c", code]),
            capture_output=True,
            text=True,
            timeout=60,
            env=self.worker_env(),
        )
        return json.loads(out.stdout.strip() or "null")

    def kill_worker_node(self) -> int:
        """SIGKILL every process of host B (the worker node and its runs); how many."""
        pids = self.hosts.b.pids()
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        return len(pids)
