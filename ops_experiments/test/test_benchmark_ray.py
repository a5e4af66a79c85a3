"""benchmark --ray-address: a cluster that cannot be used is one line naming the fix, exit 2,
before anything is written. Against a real Ray head with token authentication (a local instance
in a helper process of this test) and a port where nothing listens. The two-node cluster itself:
test/test_ray_cluster.py."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

pytestmark = pytest.mark.timeout(180)

# A Ray head with token authentication: its token lives in HOME/.ray/auth_token, HOME being a
# folder of this test; stdin closed = shut down.
HEAD = textwrap.dedent(
    """
    import sys, ray
    info = ray.init(address="local", num_cpus=0, include_dashboard=False, log_to_driver=False)
    print("GCS", info.address_info["gcs_address"], flush=True)
    sys.stdin.read()
    ray.shutdown()
    """
)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bench(out: Path, address: str, env: dict | None = None) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "ops_experiments.table1.benchmark", "--profile", "smoke"]
    cmd += ["--out", str(out), "--ray-address", address]
    return subprocess.run(
        cmd, capture_output=True, text=True, timeout=120, env=env, stdin=subprocess.DEVNULL
    )


def assert_refused(done: subprocess.CompletedProcess, out: Path, *words: str) -> str:
    """Exit 2, one line on stderr holding ``words``, nothing on stdout, nothing written."""
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    for word in words:
        assert word in lines[0], lines[0]
    assert done.stdout == ""
    assert not out.exists()
    return lines[0]


def test_nothing_listening_is_one_line_exit_2_nothing_written(tmp_path):
    port = free_port()
    out = tmp_path / "b"
    line = assert_refused(bench(out, f"127.0.0.1:{port}"), out, "cannot reach", str(port))
    assert f"ray start --head --port {port}" in line


def test_an_address_that_is_not_host_port_is_refused(tmp_path):
    out = tmp_path / "b"
    assert_refused(bench(out, "head-without-port"), out, "is not HOST:PORT")


@pytest.fixture(scope="module")
def token_head(tmp_path_factory):
    """(GCS address, token) of a Ray head that requires token authentication."""
    home = tmp_path_factory.mktemp("head_home")
    env = {**os.environ, "HOME": str(home), "RAY_AUTH_MODE": "token"}
    env.pop("RAY_AUTH_TOKEN", None)
    env.pop("RAY_AUTH_TOKEN_PATH", None)
    token_file = home / ".ray" / "auth_token"
    token_file.parent.mkdir()
    token_file.write_text("0123456789abcdef" * 4)
    log = home / "head.log"
    for _attempt in range(2):  # a loaded machine can time Ray's start-up out: once more
        with open(log, "w") as err:
            head = subprocess.Popen(
                [sys.executable, "-c", HEAD],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
                env=env,
            )
        line = head.stdout.readline()
        if line.startswith("GCS "):
            break
        head.wait(60)
    try:
        assert line.startswith("GCS "), f"the Ray head did not start:\n{log.read_text()}"
        yield line.split()[1], token_file.read_text().strip()
    finally:
        head.stdin.close()
        try:
            head.wait(60)
        except subprocess.TimeoutExpired:
            head.kill()
            head.wait()


def client_env(home: Path, **extra) -> dict:
    env = {**os.environ, "HOME": str(home), **extra}
    for var in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH", "RAY_ADDRESS"):
        if var not in extra:
            env.pop(var, None)
    return env


def test_without_the_token_one_line_names_the_fix(token_head, tmp_path):
    address, _ = token_head
    out = tmp_path / "b"
    line = assert_refused(
        bench(out, address, client_env(tmp_path)),
        out,
        "requires token authentication",
        "RAY_AUTH_MODE=token",
        str(tmp_path / ".ray" / "auth_token"),
    )
    assert "Traceback" not in line


def test_a_wrong_token_is_named(token_head, tmp_path):
    address, _ = token_head
    out = tmp_path / "b"
    (tmp_path / ".ray").mkdir()
    (tmp_path / ".ray" / "auth_token").write_text("f" * 64)
    assert_refused(
        bench(out, address, client_env(tmp_path, RAY_AUTH_MODE="token")),
        out,
        "refuses the token",
        str(tmp_path / ".ray" / "auth_token"),
    )


def test_auth_disabled_against_a_token_cluster_is_named(token_head, tmp_path):
    address, token = token_head
    out = tmp_path / "b"
    env = client_env(tmp_path, RAY_AUTH_MODE="disabled", RAY_AUTH_TOKEN=token)
    assert_refused(bench(out, address, env), out, "RAY_AUTH_MODE=token instead of disabled")


def test_the_right_token_passes_and_turns_token_mode_on(token_head, tmp_path, monkeypatch):
    """The head's token copied to this machine is enough: RAY_AUTH_MODE=token is set for Ray."""
    from ops_experiments.table1.ray_pool import check_address

    address, token = token_head
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    monkeypatch.delenv("RAY_AUTH_TOKEN", raising=False)
    path = tmp_path / "token"
    path.write_text(token + "\n")
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(path))
    check_address(address)
    assert os.environ["RAY_AUTH_MODE"] == "token"


@pytest.mark.timeout(480)
def test_ctrl_c_brings_the_work_back_and_the_same_command_resumes(tmp_path):
    """On a local Ray instance: SIGINT stops the run on its node, which saves; its work folder
    comes back to OUT/work and the next start sends it with the run, which resumes."""
    import glob
    import json
    import shutil
    import signal
    import tempfile
    import time

    out = tmp_path / "b"
    rid = "n2_easy_sac_s0"
    base = [sys.executable, "-m", "ops_experiments.table1.benchmark", "--profile", "smoke"]
    base += ["--out", str(out), "--ray-address", "local", "--jobs", "1", "--algos", "sac"]
    base += ["--modes", "easy", "--controllers", "--extra-stages", "--save-every", "100000"]
    # The local node's TMPDIR (its tasks' folders; short: Ray's sockets go there too). A foreign
    # cluster's address in the environment must not capture a local instance.
    node_tmp = Path(tempfile.mkdtemp(prefix="opsn"))
    env = {**os.environ, "TMPDIR": str(node_tmp), "RAY_ADDRESS": "127.0.0.1:9"}
    proc = subprocess.Popen(
        [*base, "--timesteps", "50000"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    # The run's folder on its node (this machine): its progress file says how far it trained.
    pattern = f"{node_tmp}/ops_bench_{rid}_*/work/{rid}/progress.json"

    def trained() -> int:
        for path in glob.glob(pattern):
            try:
                return int(json.loads(Path(path).read_text())["timesteps"])
            except (OSError, ValueError, KeyError):
                pass
        return 0

    try:
        deadline = time.monotonic() + 300
        while trained() < 1000:  # progress is written every 1000 steps
            assert proc.poll() is None and time.monotonic() < deadline, "no progress"
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        text = proc.communicate(timeout=120)[0]
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(60)
        shutil.rmtree(node_tmp / "ray", ignore_errors=True)
    assert proc.returncode == 130, text
    assert (out / "work" / rid / "model.zip").exists()
    assert not list(node_tmp.glob("ops_bench_*"))  # the node's folder is gone
    assert not (out / "runs" / rid).exists()
    try:
        again = subprocess.run(
            [*base, "--timesteps", "500"], capture_output=True, text=True, timeout=240, env=env
        )
    finally:
        shutil.rmtree(node_tmp, ignore_errors=True)
    assert again.returncode == 0, again.stdout + again.stderr
    assert f"start {rid} (resuming)" in again.stdout
    rec = json.loads((out / "runs" / rid / "run.json").read_text())
    assert rec["timesteps"] >= 1000  # a fresh start would have stopped at 500
