"""benchmark: a tiny grid through the real train and evaluate command lines; resumable."""

from __future__ import annotations

import json
import subprocess

import pytest
from ros_testing import executable

pytestmark = pytest.mark.timeout(180)


def bench(out, timesteps, *extra):
    cmd = [
        *executable("ops_gym_bridge", "benchmark"),
        "--stage",
        "2",
        "--algos",
        "sac",
        "--modes",
        "easy",
        "--seeds",
        "1",
        "--timesteps",
        str(timesteps),
        "--eval-seeds",
        "0",
        "--eval-episodes",
        "2",
        "--out",
        str(out),
        "--hyperparams",
        "learning_starts=100",
        "net_arch=[16,16]",
        "batch_size=32",
        *extra,
    ]
    return subprocess.run(
        cmd, capture_output=True, text=True, timeout=150, stdin=subprocess.DEVNULL
    )


def test_benchmark_grid_table_and_resume(tmp_path):
    out = tmp_path / "grid"
    done = bench(out, 300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "[benchmark] (1/1) sac easy seed 1: test P_N/P_max" in done.stdout
    table = (out / "results.md").read_text()
    assert "| SAC | easy | 1 |" in table and "Stage 2, 300 training steps" in table
    (rec,) = json.loads((out / "results.json").read_text())
    assert rec["timesteps"] == 300 and 0.0 <= rec["test_final_power"] <= 1.0
    # Same command again: nothing to train or evaluate, same numbers.
    again = bench(out, 300)
    assert again.returncode == 0, again.stderr
    assert "training started" not in again.stdout + again.stderr
    assert json.loads((out / "results.json").read_text())[0] == rec
    # More steps: the run continues from where it stopped.
    more = bench(out, 500)
    assert more.returncode == 0, more.stderr
    assert "resuming at step 300" in more.stdout
    assert json.loads((out / "results.json").read_text())[0]["timesteps"] == 500
