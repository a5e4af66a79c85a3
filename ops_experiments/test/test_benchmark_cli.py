"""benchmark and report: the smoke profile end to end, resume after an interruption, SIGINT and
SIGTERM from a script, Ray, and the committed results reproduced by ``report``."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ops_bench.processes import executable
from ops_controller_ros.controllers import CONTROLLERS
from ops_experiments.table1.report import FILES

pytestmark = pytest.mark.timeout(300)

ROOT = Path(__file__).resolve().parents[2]
COMMITTED = ROOT / "docs" / "results" / "n5_quick"


def bench_cmd(out, *extra) -> list[str]:
    return [
        sys.executable,
        "-m",
        "ops_experiments.table1.benchmark",
        "--profile",
        "smoke",
        "--out",
        str(out),
        "--status-every",
        "2",
        *extra,
    ]


def run_bench(out, *extra, timeout=240):
    return subprocess.run(
        bench_cmd(out, *extra),
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def stored(out) -> dict[str, float]:
    """run id -> mtime of its run.json."""
    return {p.parent.name: p.stat().st_mtime for p in Path(out).glob("runs/*/run.json")}


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = tmp_path_factory.mktemp("smoke")
    done = run_bench(out, "--detector", "total")
    assert done.returncode == 0, done.stdout + done.stderr
    return out, done


def test_smoke_profile_writes_every_table_and_figure(smoke, tmp_path):
    out, done = smoke
    n = 11 + 3 * len(CONTROLLERS)  # 9 (mode, algo) + 2 (N = 1) + one per controller and mode
    assert f"{n}/{n} runs done" in done.stdout and "time left" in done.stdout
    # Every registered no-training controller is a row; every stored run is complete.
    runs = stored(out)
    assert {"n2_easy_spgd", "n2_hard_td3_s0", "n1_hard_sac_s0"} <= set(runs)
    assert not list((out / "work").iterdir())
    for rid in runs:
        d = out / "runs" / rid
        assert (d / "evaluation.json").exists()
        if json.loads((d / "run.json").read_text())["spec"]["kind"] == "train":
            assert (d / "model.zip").exists() and (d / "training.csv").exists()
            assert json.loads((d / "metadata.json").read_text())["config"]["detector"] == "total"
    rep = subprocess.run(
        [*executable("ops_gym_bridge", "report"), str(out), "--out", str(tmp_path / "r")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert rep.returncode == 0, rep.stdout + rep.stderr
    for name in FILES:
        assert (tmp_path / "r" / name).stat().st_size > 100, name
    rows = list(csv.DictReader((tmp_path / "r" / "table1.csv").read_text().splitlines()))
    assert {r["controller"] for r in rows} == {"ppo", "td3", "sac", *CONTROLLERS}
    assert {(r["mode"], r["environment"]) for r in rows} == {
        (m, e) for m in ("easy", "medium", "hard") for e in ("training", "testing")
    }
    # Nothing to do the second time.
    again = run_bench(out, "--detector", "total")
    assert again.returncode == 0 and f"{n} already stored" in again.stdout
    assert "start " not in again.stdout
    # Another detector in the same directory is refused.
    other = run_bench(out, "--detector", "polarizer")
    assert other.returncode == 2 and "--detector total" in other.stderr


def _wait_for(pred, timeout, proc=None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        if proc is not None and proc.poll() is not None:
            return False
        time.sleep(0.2)
    return False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie is dead for our purpose.
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def test_signal_stops_every_run_saves_and_resumes(tmp_path):
    """SIGTERM (SIGINT: test_benchmark_ray) stops both runs, each saves; the next start resumes
    them; the one after finds everything stored and starts nothing."""
    sig = signal.SIGTERM
    out = tmp_path / "b"
    base = ["--algos", "sac", "--modes", "easy", "--seeds", "0", "1", "--controllers"]
    base += ["--extra-stages", "--jobs", "2", "--save-every", "100000"]
    proc = subprocess.Popen(
        bench_cmd(out, *base, "--timesteps", "50000"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    works = [out / "work" / f"n2_easy_sac_s{s}" for s in (0, 1)]
    ok = _wait_for(lambda: all((w / "progress.json").exists() for w in works), 150, proc)
    assert ok, "runs did not start training"
    pids = [int((w / "worker.pid").read_text()) for w in works]
    proc.send_signal(sig)
    text = proc.communicate(timeout=150)[0]
    assert proc.returncode == 130, text
    assert "stopping 2 run(s)" in text
    # Every run stopped (none left training on its own) and saved its model.
    assert _wait_for(lambda: not any(_alive(p) for p in pids), 10)
    steps = []
    for w in works:
        assert (w / "model.zip").exists() and (w / "replay_buffer.pkl").exists()
        state = json.loads((w / "metadata.json").read_text())  # train's own save
        assert state["timesteps"] >= 1000
        steps.append(state["timesteps"])
    assert not stored(out)
    # The next start resumes both from where they stopped (a budget they have already reached:
    # evaluation only, fast).
    again = run_bench(out, *base, "--timesteps", "1000")
    assert again.returncode == 0, again.stdout + again.stderr
    assert again.stdout.count("(resuming)") == 2
    for s, n in zip((0, 1), steps, strict=True):
        rec = json.loads((out / "runs" / f"n2_easy_sac_s{s}" / "run.json").read_text())
        assert rec["timesteps"] == n
    # Stored runs are never redone.
    before = stored(out)
    third = run_bench(out, *base, "--timesteps", "1000")
    assert third.returncode == 0, third.stdout + third.stderr
    assert "2 already stored" in third.stdout and "start " not in third.stdout
    assert stored(out) == before


def _committed_runs() -> list[str]:
    try:
        files = subprocess.run(
            ["git", "ls-files", "docs/results/n5_quick/runs"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        files = []
    if not files:
        return sorted(p.name for p in (COMMITTED / "runs").iterdir())
    return sorted({Path(f).parts[4] for f in files})


@pytest.mark.skipif(not (COMMITTED / "table1.csv").exists(), reason="no committed results")
def test_report_reproduces_committed_table1(tmp_path):
    runs = tmp_path / "n5" / "runs"
    runs.mkdir(parents=True)
    for rid in _committed_runs():
        src = COMMITTED / "runs" / rid
        if (src / "run.json").exists():
            shutil.copytree(src, runs / rid, ignore=shutil.ignore_patterns("model.zip"))
    from ops_experiments.table1.report import write_report

    write_report(tmp_path / "n5", tmp_path / "out")
    assert (tmp_path / "out" / "table1.csv").read_text() == (COMMITTED / "table1.csv").read_text()


@pytest.mark.parametrize(
    ("stored", "option", "message"),
    [
        ({"observation": "authors"}, [], "holds runs with --observation authors"),
        ({"hyperparams_set": "authors"}, [], "holds runs with --hyperparams-set authors"),
        ({}, ["--hyperparams-set", "authors"], "holds runs with --hyperparams-set paper"),
        ({"detector": "total"}, [], "holds runs with --detector total"),
    ],
)
def test_a_folder_holds_one_protocol(tmp_path, capsys, stored, option, message):
    """Runs of another observation set, hyper-parameter set or detector are refused before
    anything runs or is written (a folder without the key holds the old default)."""
    from ops_experiments.table1 import benchmark

    settings = {"detector": "polarizer", **stored}
    (tmp_path / "benchmark.json").write_text(json.dumps(settings))
    argv = ["--profile", "smoke", "--algos", "sac", "--controllers", "--out", str(tmp_path)]
    assert benchmark.run(argv + option) == 2
    assert message in capsys.readouterr().err
    assert json.loads((tmp_path / "benchmark.json").read_text()) == settings
    assert not (tmp_path / "runs").exists()
