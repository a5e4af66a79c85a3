"""The README's main job, run as a user would: `bash scripts/demo.sh` (what `make demo` runs)."""

import os
import re
import subprocess

import pytest
from ops_bench.processes import REPO, assert_no_traceback

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def test_demo_closes_the_loop_and_saves_the_picture(tmp_path):
    env = dict(os.environ, DEMO_OUT=str(tmp_path), DEMO_SECONDS="3")
    done = subprocess.run(
        ["bash", "scripts/demo.sh"], cwd=REPO, env=env, capture_output=True, text=True, timeout=100
    )
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    assert_no_traceback(out)
    before = float(re.search(r"before control: first trace received: P_N/P_max = ([\d.]+)", out)[1])
    powers = [float(p) for p in re.findall(r"iteration \d+: P_N/P_max = ([\d.]+)", out)]
    assert powers and powers[-1] >= 0.95 > before
    picture = tmp_path / "monitor.png"
    assert picture.stat().st_size > 10_000
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_rig_drives_the_simulated_lab_and_saves_the_picture(tmp_path):
    """`make demo-rig`: simlab, calibrate, rig and tracker (its optics from the rig YAML), the
    piezos parked at the end."""
    env = dict(os.environ, DEMO_OUT=str(tmp_path), DEMO_SECONDS="6")
    done = subprocess.run(
        ["bash", "scripts/demo_rig.sh"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=110,
    )
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    assert_no_traceback(out)
    assert f"nominal model from {tmp_path}/rig.yaml: stage 5" in out
    powers = [float(p) for p in re.findall(r"\): P_N/P_max = ([\d.]+)", out)]
    assert powers and powers[-1] >= 0.9, out
    assert "rig: parked the piezos" in out
    picture = tmp_path / "monitor.png"
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
