"""ops-bench soak-steps: every step of the soak's loop logged, and the account of where locks
were lost (after which drift turn, at a knot or not) from those steps."""

from __future__ import annotations

import json

import numpy as np

from ops_bench import soak_steps


def _log(n=400, stage=5):
    """A made run: locked throughout, the drift reversing at step 200 on every stage."""
    drift = np.full((n, stage), 0.001, np.float32)
    drift[200:] *= -1.0
    return {
        "power": np.full(n, 0.99, np.float32),
        "true_drift": drift,
        "releases_all": np.zeros(n, np.int32),
        "releases_stage": np.zeros(n, np.int32),
        "releases_knot": np.zeros(n, np.int32),
        "knot_reading": np.zeros(n, np.int64),
    }


def test_a_lock_lost_is_placed_after_its_drift_turn():
    log = _log()
    log["power"][214:216] = [0.7, 0.75]  # one lock lost, two readings long
    log["power"][300] = 0.9  # low, not lost
    log["releases_all"][216:] = 1  # the memory let go 16 readings after the turn
    log["knot_reading"][210:] = 209  # a knot taken just before the loss
    got = soak_steps.account(log, rate_hz=10.0)
    assert got["drift_turns"] == 1 and got["locks_lost"] == 1
    assert got["losses"][0]["readings_after_turn"] == 14 and got["losses"][0]["knot_taken"]
    assert got["losses"][0]["lowest"] == 0.7
    assert got["releases_every_stage"] == 1 and got["release_delays_after_turn"] == [16]
    assert got["locks_lost_within_40_after_a_turn"] == 1
    assert got["readings_locked_pct"] == 100.0 * (400 - 3) / 400


def test_readings_before_the_first_lock_count_for_nothing():
    log = _log()
    log["power"][:50] = 0.1  # acquiring
    got = soak_steps.account(log, rate_hz=10.0)
    assert got["locks_lost"] == 0 and got["readings_after_first_lock"] == 350


def test_a_short_run_writes_its_steps_and_account(tmp_path, capsys):
    out = tmp_path / "steps.npz"
    argv = ["--hours", str(20 / 3600), "--vibration", "lab", "--seed", "11", "--out", str(out)]
    assert soak_steps.main(argv) == 0
    steps = np.load(out)
    assert steps["power"].shape == (200,) and steps["phase"].shape == (200, 5)
    assert np.all(np.abs(steps["phase"]) <= 0.5)
    account = json.loads(out.with_suffix(".json").read_text())
    assert account["command"].startswith("ops-bench soak-steps --hours")
    assert account["hours"] == round(20 / 3600, 4)
    assert json.loads(capsys.readouterr().out)["locks_lost"] == account["locks_lost"]


def test_bad_options_exit_2(tmp_path, capsys):
    assert soak_steps.main(["--hours", "0", "--out", str(tmp_path / "x.npz")]) == 2
    assert "--hours" in capsys.readouterr().err


def test_a_rig_figure_not_taken_exits_2(tmp_path, capsys):
    assert (
        soak_steps.main(["--hours", "0.01", "--rig", "step_s=1", "--out", str(tmp_path / "x.npz")])
        == 2
    )
    assert "--rig step_s: not taken here" in capsys.readouterr().err
    assert not (tmp_path / "x.npz").exists()
