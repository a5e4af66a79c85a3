"""The benchmark's runs as Ray tasks (``benchmark --ray-address``), on any node of a cluster.

What a node needs: Ray and the driver's Python version with the third-party packages a run uses
(:data:`WORKER_DISTRIBUTIONS`) at the driver's versions; a task checks them first and fails
with a line naming what differs. Nothing of the project: its packages (:data:`PACKAGES`)
travel with every task in its ``runtime_env`` (``py_modules``), and nothing is read from or
written to a shared file system. A task runs the worker (:mod:`.bench_worker`) in a temporary
directory of its node and returns the finished run (packed) with its log; the driver stores it
in ``OUT`` atomically. A run that stops (Ctrl-C of the benchmark) or fails returns its work
directory, which the driver keeps in ``OUT/work/<id>/`` and sends with the next attempt, so the
run resumes where it stopped.

Errors reach the user: a run whose worker fails is named with the last exception of its log
(``ImportError: ...``); a task that fails outside the worker (cannot import, runtime environment,
node lost, worker killed) is reported with Ray's error type and message on stderr and in the
run's log, and the node it failed on is avoided on the retry (a soft affinity to a live node the
run has not failed on: it waits for a CPU there, and goes anywhere if that node leaves). Runs go
to whatever CPUs the cluster has: as many runs are in flight as the cluster has CPUs now, read
again as nodes come and go.

:func:`check_address` checks the cluster address before anything is written: an address that
cannot be reached, or a cluster that refuses this machine's token, is one line naming the fix.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

#: The project's packages, shipped to every node with each task.
PACKAGES = (
    "ops_contract",
    "ops_sim_ros",
    "ops_controller_ros",
    "ops_gym_bridge",
    "ops_experiments",
)
#: The third-party distributions a run imports; a node must have the driver's versions.
WORKER_DISTRIBUTIONS = ("numpy", "gymnasium", "stable-baselines3", "sb3-contrib", "torch", "pyyaml")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_REFRESH_S = 5.0


class RayAddressError(RuntimeError):
    """The cluster cannot be used from here; the message (one line) says what to do."""


# ------------------------------------------------------------------------------ before anything
def _token() -> tuple[str | None, str]:
    """The Ray authentication token this machine has, and where it came from (Ray's order)."""
    if os.environ.get("RAY_AUTH_TOKEN"):
        return os.environ["RAY_AUTH_TOKEN"].strip(), "RAY_AUTH_TOKEN"
    path = Path(os.environ.get("RAY_AUTH_TOKEN_PATH") or Path.home() / ".ray" / "auth_token")
    try:
        return path.read_text().strip() or None, str(path)
    except OSError:
        return None, str(path)


def _resolve(address: str) -> tuple[str, int]:
    if address == "auto":
        from ray._private.services import get_ray_address_from_environment

        try:
            address = get_ray_address_from_environment("auto", None)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise RayAddressError(
                "no Ray cluster found for --ray-address auto: start one (`ray start --head`) "
                f"or give its HOST:PORT ({exc})"
            ) from None
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise RayAddressError(
            f"--ray-address {address!r} is not HOST:PORT (e.g. 10.0.0.1:6379), auto or local"
        )
    return host, int(port)


def _cluster_id_call(host: str, port: int, token: str | None, timeout: float):
    """The first call Ray's own client makes to the head (GCS), GetClusterId: None when it is
    answered, else gRPC's status code."""
    import grpc
    from ray.core.generated import gcs_service_pb2, gcs_service_pb2_grpc

    metadata = [("authorization", f"Bearer {token}")] if token else None
    with grpc.insecure_channel(f"{host}:{port}") as channel:
        stub = gcs_service_pb2_grpc.NodeInfoGcsServiceStub(channel)
        try:
            stub.GetClusterId(
                gcs_service_pb2.GetClusterIdRequest(), timeout=timeout, metadata=metadata
            )
        except grpc.RpcError as exc:
            return exc.code()
    return None


def _use_token_auth() -> None:
    """``RAY_AUTH_MODE=token`` for this process and its children, as Ray itself does for a
    cluster it finds by itself (Ray reads its configuration once: read it again)."""
    os.environ["RAY_AUTH_MODE"] = "token"
    from ray._raylet import Config

    Config.initialize("")


def check_address(address: str, timeout: float = 5.0) -> None:
    """Raise :class:`RayAddressError` unless the Ray cluster at ``address`` answers and accepts
    this machine. Where it wants the token this machine has, ``RAY_AUTH_MODE=token`` is set for
    the benchmark (Ray's driver then sends it)."""
    if address == "local":
        return
    import grpc

    host, port = _resolve(address)
    where = f"the Ray cluster at {host}:{port}"
    token, source = _token()
    mode = os.environ.get("RAY_AUTH_MODE", "").lower()
    send = token if mode == "token" else None
    code = _cluster_id_call(host, port, send, timeout)
    if code == grpc.StatusCode.UNAUTHENTICATED and send is None and token and not mode:
        send = token  # Ray 2.60 turns token auth on where this machine has a token: try it
        code = _cluster_id_call(host, port, send, timeout)
        if code is None:
            _use_token_auth()
    if code is None:
        return
    if code != grpc.StatusCode.UNAUTHENTICATED:
        raise RayAddressError(
            f"cannot reach {where} (gRPC: {code.name.lower()}): start the head "
            f"there (`ray start --head --port {port}`) or correct --ray-address"
        )
    if mode == "disabled":
        raise RayAddressError(
            f"{where} requires token authentication: set RAY_AUTH_MODE=token instead of disabled"
            f" and copy the head's ~/.ray/auth_token to {source}"
        )
    if token is None:
        raise RayAddressError(
            f"{where} requires token authentication: copy the head's ~/.ray/auth_token to "
            f"{source} (or set RAY_AUTH_TOKEN) and set RAY_AUTH_MODE=token"
        )
    raise RayAddressError(
        f"{where} refuses the token of {source}: copy the head's ~/.ray/auth_token there "
        "(or set RAY_AUTH_TOKEN) and set RAY_AUTH_MODE=token"
    )


def runtime_env() -> dict[str, Any]:
    """What every task takes with it: the project's packages and one thread per run."""
    import importlib

    modules = [str(Path(importlib.import_module(p).__file__).resolve().parent) for p in PACKAGES]
    return {
        "py_modules": modules,
        "excludes": ["__pycache__", "*.pyc"],
        "env_vars": {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"},
    }


def versions() -> dict[str, str]:
    """Python's and :data:`WORKER_DISTRIBUTIONS`' versions here (local labels such as ``+cpu``
    dropped: a build for another accelerator is fine); "missing" where one is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    found = {"python": ".".join(map(str, sys.version_info[:2]))}
    for dist in WORKER_DISTRIBUTIONS:
        try:
            found[dist] = version(dist).split("+")[0]
        except PackageNotFoundError:
            found[dist] = "missing"
    return found


def check_versions(driver: dict[str, str]) -> None:
    """Raise RuntimeError naming every package whose version here differs from the driver's."""
    here = versions()
    wrong = [
        f"{k} {here.get(k, 'missing')} (driver {v})" for k, v in driver.items() if here.get(k) != v
    ]
    if wrong:
        pins = " ".join(f"{k}=={v}" for k, v in driver.items() if k != "python")
        raise RuntimeError(
            f"this node's Python differs from the driver's: {', '.join(wrong)}; "
            f"install the driver's versions here (pip install {pins})"
        )


# ------------------------------------------------------------------------------ on the node
def _pack(directory: Path) -> bytes | None:
    if not directory.is_dir():
        return None
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        tar.add(directory, arcname=".")
    return buf.getvalue()


def _unpack(data: bytes, directory: Path) -> None:
    """Unpack next to ``directory``, then replace it in one rename."""
    incoming = directory.with_name(f".{directory.name}.incoming")
    shutil.rmtree(incoming, ignore_errors=True)
    incoming.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        if hasattr(tarfile, "data_filter"):
            tar.extractall(incoming, filter="data")
        else:  # Python before 3.11.4 (e.g. Debian 12's 3.11.2) has no extraction filters
            for member in tar.getmembers():
                name = Path(member.name)
                plain = member.isfile() or member.isdir()
                if name.is_absolute() or ".." in name.parts or not plain:
                    raise ValueError(f"refusing to unpack {member.name!r} from a run's archive")
            tar.extractall(incoming)  # every member checked above
    if directory.exists():
        shutil.rmtree(directory)
    os.replace(incoming, directory)


def run_task(spec: dict, work: bytes | None, stop_flag, driver_versions: dict[str, str]):
    """Body of the Ray task (a generator): first where it runs, then the outcome of the run."""
    check_versions(driver_versions)
    import ray
    from ray.util import get_node_ip_address

    yield {"node": ray.get_runtime_context().get_node_id(), "host": get_node_ip_address()}
    tmp = Path(tempfile.mkdtemp(prefix=f"ops_bench_{spec['id']}_"))
    try:  # the node's folder goes before the outcome is handed over
        spec_path = tmp / "spec.json"
        spec_path.write_text(json.dumps(spec))
        if work is not None:
            _unpack(work, tmp / "work" / spec["id"])
        log_path = tmp / "run.log"
        worker = [sys.executable, "-m", "ops_experiments.table1.bench_worker"]
        with open(log_path, "w") as log:
            proc = subprocess.Popen(
                [*worker, str(spec_path), str(tmp)],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True,
            )  # fmt: skip
            code = _wait(proc, stop_flag)
        outcome = {
            "code": code,
            "log": log_path.read_text(errors="replace"),
            "run": _pack(tmp / "runs" / spec["id"]) if code == 0 else None,
            "work": None if code == 0 else _pack(tmp / "work" / spec["id"]),
        }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    yield outcome


def _wait(proc: subprocess.Popen, stop_flag) -> int:
    """The worker's exit code; one SIGTERM to it (it saves) once the driver's flag is set."""
    import ray

    signalled = False
    while True:
        try:
            return proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            try:
                stop = signalled or bool(ray.get(stop_flag.is_set.remote(), timeout=10))
            except Exception:  # the flag's actor is gone: so is the driver
                stop = True
        except KeyboardInterrupt:  # ray.cancel
            stop = True
        if stop and not signalled:
            proc.send_signal(signal.SIGTERM)
            signalled = True


class _StopFlag:
    """Set by the driver when the benchmark stops; every task asks it every few seconds."""

    def __init__(self):
        self.value = False

    def set(self) -> None:
        self.value = True

    def is_set(self) -> bool:
        return self.value


# ------------------------------------------------------------------------------ on the driver
def describe_error(exc: BaseException) -> str:
    """Ray's error as type and message, one line (the full text goes to the run's log)."""
    text = _ANSI.sub("", str(exc)).strip()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    last = lines[-1] if lines else ""
    return f"{type(exc).__name__}: {last}"[:400]


class RayPool:
    """Runs as Ray tasks of one CPU each, on whatever nodes the cluster has (see the module)."""

    def __init__(self, address: str, jobs: int, out: Path, log_dir: Path):
        import ray

        self.ray = ray
        self.versions = versions()
        env = runtime_env()
        if address == "local":
            # address="local": a new instance of our own, whatever RAY_ADDRESS or the address a
            # cluster left in Ray's temp folder says (without it, ray.init joined that cluster
            # and refused num_cpus).
            ray.init(
                address="local",
                num_cpus=jobs,
                include_dashboard=False,
                log_to_driver=False,
                runtime_env=env,
            )
        else:
            ray.init(address=address, log_to_driver=False, runtime_env=env)
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        here = ray.get_runtime_context().get_node_id()
        self.flag = (
            ray.remote(num_cpus=0)(_StopFlag)
            .options(scheduling_strategy=NodeAffinitySchedulingStrategy(here, soft=False))
            .remote()
        )
        self.task = ray.remote(num_cpus=1, max_retries=0)(run_task)
        self.out, self.log_dir = out, log_dir
        self.running: dict[Any, str] = {}  # generator -> run id
        self.where: dict[str, dict] = {}  # run id -> node of its current attempt
        self.avoid: dict[str, set[str]] = {}  # run id -> nodes it failed on
        self.jobs, self._refreshed = 0, 0.0
        self._refresh()

    def _refresh(self) -> None:
        """The cluster's CPUs now (nodes come and go)."""
        if time.monotonic() - self._refreshed < _REFRESH_S:
            return
        self._refreshed = time.monotonic()
        cpus = int(self.ray.cluster_resources().get("CPU", 0))
        nodes = sum(1 for n in self.ray.nodes() if n.get("Alive"))
        if cpus != self.jobs:
            was = f" (was {self.jobs})" if self.jobs else ""
            print(f"[benchmark] Ray cluster: {nodes} node(s), {cpus} CPU(s){was}", flush=True)
        self.jobs = cpus

    def free(self) -> bool:
        self._refresh()
        return len(self.running) < max(self.jobs, 1)

    def submit(self, spec: dict, spec_path: Path) -> None:
        rid = spec["id"]
        work = _pack(self.out / "work" / rid)
        task = self.task
        elsewhere = self._elsewhere(rid)
        if elsewhere is not None:
            task = task.options(scheduling_strategy=elsewhere)
        self.running[task.remote(spec, work, self.flag, self.versions)] = rid
        self.where.pop(rid, None)

    def _elsewhere(self, rid: str):
        """For a run that failed on some nodes: a soft affinity to a live node it has not failed
        on (the one with most CPUs). The retry waits for a CPU there, and goes anywhere if that
        node leaves; where the run has failed on every node, None (anywhere)."""
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        avoid = self.avoid.get(rid)
        if not avoid:
            return None
        good = [
            n
            for n in self.ray.nodes()
            if n.get("Alive")
            and n["NodeID"] not in avoid
            and n.get("Resources", {}).get("CPU", 0) >= 1
        ]
        if not good:
            return None
        node = max(good, key=lambda n: n["Resources"]["CPU"])
        return NodeAffinitySchedulingStrategy(node["NodeID"], soft=True)

    def _log(self, rid: str, text: str) -> None:
        with open(self.log_dir / f"{rid}.log", "a") as f:
            f.write(text if text.endswith("\n") else text + "\n")

    def _node_text(self, rid: str) -> str:
        node = self.where.get(rid)
        return f"node {node['host']} ({node['node'][:12]})" if node else "an unknown node"

    def _failed(self, rid: str, exc: BaseException) -> tuple[str, int]:
        node = self.where.get(rid)
        if node is None:
            node = self._node_of_error(exc)
            if node:
                self.where[rid] = node
        if node:
            self.avoid.setdefault(rid, set()).add(node["node"])
        line = f"Ray error on {self._node_text(rid)}: {describe_error(exc)}"
        print(f"[benchmark] run {rid}: {line}", file=sys.stderr, flush=True)
        self._log(rid, f"[benchmark] {line}\n{_ANSI.sub('', str(exc))}")
        return rid, 1

    def _node_of_error(self, exc: BaseException) -> dict | None:
        """The node a task failed on before it said where it ran (Ray's text names the IP)."""
        found = re.search(r"ip=([0-9a-fA-F.:]+)\)", _ANSI.sub("", str(exc)))
        if not found:
            return None
        nodes = [n for n in self.ray.nodes() if n.get("NodeManagerAddress") == found.group(1)]
        if len(nodes) != 1:
            return None
        return {"node": nodes[0]["NodeID"], "host": found.group(1)}

    def _outcome(self, rid: str, result: dict) -> tuple[str, int]:
        code = int(result["code"])
        self._log(rid, result["log"])
        if result.get("run") is not None:
            (self.out / "runs").mkdir(parents=True, exist_ok=True)
            _unpack(result["run"], self.out / "runs" / rid)
            shutil.rmtree(self.out / "work" / rid, ignore_errors=True)
        elif result.get("work") is not None:
            (self.out / "work").mkdir(parents=True, exist_ok=True)
            _unpack(result["work"], self.out / "work" / rid)
        if code not in (0, 130):
            self.avoid.setdefault(rid, set()).add(self.where[rid]["node"])
        return rid, code

    def _advance(self, gen) -> tuple[str, int] | None:
        """The next item of a task: where it started (None), or its end (run id, exit code)."""
        rid = self.running[gen]
        try:
            item = self.ray.get(next(gen))
        except StopIteration:
            del self.running[gen]
            return self._failed(rid, RuntimeError("the task ended without a result"))
        except Exception as exc:  # Ray's errors: import, runtime env, node or worker lost
            del self.running[gen]
            return self._failed(rid, exc)
        if "node" in item:
            self.where[rid] = item
            self._log(rid, f"[benchmark] attempt on {self._node_text(rid)}")
            print(f"[benchmark] {rid} running on {self._node_text(rid)}", flush=True)
            return None
        del self.running[gen]
        return self._outcome(rid, item)

    def poll(self, timeout: float) -> list[tuple[str, int]]:
        if not self.running:
            return []
        try:
            ready, _ = self.ray.wait(list(self.running), num_returns=1, timeout=timeout)
        except SystemError as exc:  # Ray wraps what a signal handler raised during the wait
            if exc.__cause__ is None:
                raise
            raise exc.__cause__ from None
        finished = []
        for gen in ready:
            done = self._advance(gen)
            if done is not None:
                finished.append(done)
        return finished

    def stop(self, grace_s: float) -> None:
        """Every task stops its run, which saves; what they return is stored as usual."""
        self.flag.set.remote()
        deadline = time.monotonic() + grace_s
        while self.running and time.monotonic() < deadline:
            self.poll(timeout=min(1.0, max(deadline - time.monotonic(), 0.01)))
        for gen in self.running:
            with contextlib.suppress(Exception):
                self.ray.cancel(gen, force=True)
        self.running.clear()
        self.ray.shutdown()
