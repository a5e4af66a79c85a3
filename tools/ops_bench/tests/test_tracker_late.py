"""``ops-bench tracker-late``: the tracker in process with late commands (docs/tracker.md, "A knot
test cut short on a noisy detector takes no knot"), on short runs."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from ops_experiments.continuous import lock_figures

from ops_bench import tracker_late


def harness_figures(power: np.ndarray) -> tuple[float, int]:
    """The figures as the scratch harness the docs' numbers came from computed them."""
    first = np.argmax(power >= 0.95) if (power >= 0.95).any() else len(power)
    after = power[first:]
    low = after < 0.8
    losses = int(np.sum(low[1:] & ~low[:-1]) + (low[0] if low.size else 0))
    return (float(np.mean(after >= 0.95)) if after.size else 0.0), losses


@pytest.mark.parametrize(
    "power",
    [
        [0.5, 0.96, 0.97, 0.7, 0.6, 0.96, 0.9, 0.79, 0.99],
        [0.5, 0.6],
        [0.99, 0.5],
        [0.96, 0.97],
    ],
)
def test_figures_are_the_harness_figures(power):
    f = lock_figures(power)
    assert (f["locked_fraction"], f["losses"]) == harness_figures(np.array(power))


def test_a_short_run_writes_its_figures_and_settings(tmp_path, capsys):
    out = tmp_path / "late.json"
    argv = ["--seeds", "1001", "--steps", "300", "--mode", "easy", "--realism", "ideal"]
    argv += ["--p-late", "0", "--param", "knot_budget_ms=4.0", "--out", str(out)]
    assert tracker_late.main(argv) == 0
    printed = capsys.readouterr().out
    assert "seed 1001 p_late 0.0:" in printed and "1 seeds: mean" in printed
    result = json.loads(out.read_text())
    assert result["command"] == "ops-bench tracker-late " + " ".join(argv)
    settings = result["settings"]
    assert settings["mode"] == "easy" and settings["realism"] == "ideal"
    assert settings["p_late"] == 0.0 and settings["steps"] == 300 and settings["seeds"] == [1001]
    assert settings["tracker_params"] == {"knot_budget_ms": 4.0}
    (run,) = result["per_seed"]
    assert run["seed"] == 1001 and 0 <= run["percent_locked"] <= 100 and run["losses"] >= 0
    assert run["percent_locked"] > 90  # no late command, an ideal rig, easy: locked
    assert result["summary"]["worst_percent_locked"] == run["percent_locked"]


def test_late_commands_step_the_rig_once_more_on_the_old_setpoints(monkeypatch):
    steps = []
    real = tracker_late.OpsEnv.step_setpoints
    monkeypatch.setattr(
        tracker_late.OpsEnv,
        "step_setpoints",
        lambda env, sp: steps.append(np.array(sp)) or real(env, sp),
    )
    power = tracker_late.run(7, steps=200, p_late=0.3, mode="hard", realism="lab")
    assert power.shape == (200,) and np.all(np.isfinite(power))
    late = len(steps) - 200
    assert 30 <= late <= 90  # ~60 of 200 come a step late
    # each late step holds the set-points of the step before (the first: the reset's)
    repeats = sum(np.array_equal(a, b) for a, b in itertools.pairwise(steps))
    assert repeats >= late - 1
    f = lock_figures(power)
    assert 0 <= f["locked_fraction"] <= 1 and f["losses"] >= 0


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--p-late", "1"], "--p-late"),
        (["--p-late", "-0.1"], "--p-late"),
        (["--p-late", "often"], "--p-late"),
        (["--mode", "brutal"], "--mode"),
        (["--realism", "real"], "--realism"),
        (["--steps", "0"], "--steps"),
        (["--param", "no_such_param=1"], "--param"),
        (["--param", "knot_budget_ms=-1"], "--param"),
    ],
)
def test_bad_input_exits_2_naming_the_option(argv, named, capsys):
    with pytest.raises(SystemExit) as done:
        tracker_late.main(argv)
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert named in err
    if named == "--mode":
        assert "easy" in err and "extreme" in err
    if named == "--p-late":
        assert "[0, 1)" in err
