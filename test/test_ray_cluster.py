"""The benchmark on a real two-node Ray cluster: the head on host A, a worker node on host B
(two network namespaces on one link, ops_bench.ray_cluster), token authentication on, nothing of the
project on B. A subset of the smoke profile (10 runs: two seeds of each agent, so that a node B
that joins late still gets a second run; the whole profile is
`ops-bench ray-cluster`, docs/cluster.md) runs on both nodes, B joining while the benchmark
runs (its CPU is used from then on); node B is killed while a
training run is on it: that run is retried on A and everything is stored; the same command again
has nothing left to do. Needs root and `ip`; skipped with the reason otherwise."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ops_bench.hosts import make_two_hosts
from ops_bench.processes import assert_no_traceback
from ops_bench.ray_cluster import PACKAGES as RAY_PACKAGES
from ops_bench.ray_cluster import RayCluster

pytest.importorskip("ray")

pytestmark = [pytest.mark.integration, pytest.mark.timeout(600)]

SUBSET = ["--controllers", "spgd", "--algos", "ppo", "td3", "--modes", "easy", "hard"]
SUBSET += ["--seeds", "0", "1", "--extra-stages"]
RUNS = {f"n2_{m}_spgd" for m in ("easy", "hard")}
RUNS |= {f"n2_{m}_{a}_s{s}" for m in ("easy", "hard") for a in ("ppo", "td3") for s in (0, 1)}
ON_B = re.compile(r"\[benchmark\] (n2_\w+) running on node 10\.231\.0\.2 ")


def wait_for_victim(bench, timeout: float) -> tuple[str, bool]:
    """A training run in progress on B, and whether another run had finished there before.

    Preferably one once B has finished a run (so a result computed on B reaches the driver too);
    but how many runs B gets depends on the CPUs' speed: when every run of the plan has started
    and B is still on its first, that one is the victim."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        text = bench.output
        on_b = ON_B.findall(text)
        started = set(re.findall(r"\[benchmark\] start (n2_\w+)", text))
        done = set(re.findall(r"done (n2_\w+): final", text))
        live = [r for r in on_b if r not in done and re.search(r"_s\d+$", r)]
        finished_on_b = any(r in done for r in on_b)
        if live and (finished_on_b or started >= RUNS):
            return live[-1], finished_on_b
        if bench.popen.poll() is not None:
            break
        time.sleep(0.2)
    raise AssertionError(f"no training run in progress on B:\n{bench.output}")


@pytest.fixture
def cluster(hosts, procs, tmp_path):
    with RayCluster(hosts, procs, tmp_path / "cluster") as made:
        yield made
        hosts.close()  # stops every Ray process before its folders go


@pytest.fixture
def hosts():
    with make_two_hosts("the Ray cluster tests") as pair:
        yield pair


def bench_cmd(cluster, out) -> list[str]:
    # From a folder of its own: Ray puts the driver's folder on the workers' path.
    return [
        "env", "-C", str(Path(out).parent), sys.executable,
        "-m", "ops_experiments.table1.benchmark",
        "--profile", "smoke", "--out", str(out),
        "--ray-address", cluster.address, "--retry-delay", "1", "--status-every", "10", *SUBSET,
    ]  # fmt: skip


def test_smoke_runs_on_both_nodes_and_a_killed_node_costs_a_retry(cluster, hosts, procs, tmp_path):
    cluster.start_head()
    out = tmp_path / "out"
    bench = hosts.a.start(
        procs, bench_cmd(cluster, out), name="benchmark", env=cluster.driver_env()
    )
    bench.wait_for(r"Ray cluster: 1 node\(s\), 1 CPU\(s\)\n", timeout=120)
    # Node B joins while the benchmark runs: its CPU is used from then on.
    cluster.start_worker()
    assert cluster.project_importable_on_worker() == [False] * len(RAY_PACKAGES)
    bench.wait_for(r"Ray cluster: 2 node\(s\), 2 CPU\(s\) \(was 1\)", timeout=120)
    victim, finished_on_b = wait_for_victim(bench, timeout=400)
    assert cluster.kill_worker_node() > 0
    assert bench.wait_exit(400) == 0, bench.output
    text = bench.output
    assert_no_traceback(text)
    # Ray's own error, with its type, in the output and in the run's log; then a retry on A.
    error = re.search(rf"run {victim}: Ray error on node 10\.231\.0\.2 \(\w+\): (\w+Error)", text)
    assert error, text
    assert f"run {victim} failed (exit 1); retry 1/3" in text
    log = (out / "logs" / f"{victim}.log").read_text()
    assert error.group(1) in log
    attempts = re.findall(r"attempt on node (10\.231\.0\.\d)", log)
    assert attempts == ["10.231.0.2", "10.231.0.1"], log
    # Everything stored, by the driver, from both nodes.
    assert f"finished: {len(RUNS)}/{len(RUNS)} runs stored" in text
    stored = {p.parent.name for p in out.glob("runs/*/run.json")}
    assert stored == RUNS
    nodes = set()
    for rid in stored:
        rec = json.loads((out / "runs" / rid / "run.json").read_text())
        assert rec["spec"]["id"] == rid
        nodes.add(
            re.findall(r"attempt on node (\S+)", (out / "logs" / f"{rid}.log").read_text())[-1]
        )
    # B's CPU was used (the victim's first attempt); a run B finished was stored from there.
    assert nodes == ({"10.231.0.1", "10.231.0.2"} if finished_on_b else {"10.231.0.1"})
    assert not (out / "work").exists() or not list((out / "work").iterdir())
    # The same command again: nothing left to do.
    again = subprocess.run(
        hosts.a.command(bench_cmd(cluster, out)),
        capture_output=True,
        text=True,
        timeout=180,
        env=cluster.driver_env(),
    )
    assert again.returncode == 0, again.stdout + again.stderr
    assert f"{len(RUNS)} already stored" in again.stdout and "start " not in again.stdout


def test_a_node_that_cannot_import_is_reported_and_avoided(cluster, hosts, procs, tmp_path):
    """Node B lacks gymnasium (its metadata says otherwise, so the version check passes): the
    run's worker fails to import there. The cause reaches the output and the run's log, and
    the retry goes to A."""
    cluster.start_head()
    cluster.start_worker(without="gymnasium")
    out = tmp_path / "out"
    cmd = bench_cmd(cluster, out)
    cmd[cmd.index("--algos") :] = ["--algos", "ppo", "--modes", "easy", "--extra-stages"]
    bench = hosts.a.start(procs, cmd, name="benchmark", env=cluster.driver_env())
    assert bench.wait_exit(300) == 0, bench.output
    text = bench.output
    assert_no_traceback(text)
    failed = re.findall(r"run (n2_\w+) failed \(exit 1: (\w+Error): (.*)\); retry 1/3", text)
    assert failed, text
    for rid, kind, message in failed:
        assert kind == "ImportError" and "gymnasium is not installed on this node" in message
        log = (out / "logs" / f"{rid}.log").read_text()
        assert f"{kind}: gymnasium is not installed on this node" in log
        assert log.rstrip().splitlines()[-1].startswith(f"[run {rid}] done"), log
        # One failure on B, then A: the failed node is avoided on the retry.
        attempts = re.findall(r"attempt on node (\S+)", log)
        assert attempts == ["10.231.0.2", "10.231.0.1"], log
    assert {p.parent.name for p in out.glob("runs/*/run.json")} == {
        "n2_easy_spgd",
        "n2_easy_ppo_s0",
    }
