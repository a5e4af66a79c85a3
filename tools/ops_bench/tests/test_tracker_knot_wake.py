"""``ops-bench tracker-knot-wake``: what a knot costs the tracker, reading by reading
(docs/tracker.md, "What a knot costs, reading by reading"), on short runs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ops_bench import tracker_knot_wake as kw


def test_a_knot_acts_from_the_step_after_the_one_it_was_drawn_in():
    slope = np.zeros((60, 5))
    slope[45:, 2] = 0.01  # drawn during step 45: the slope after step 45 is the new one
    slope[50:, 0] = -0.02
    slope[10:, 1] = 0.03  # before --from-step
    assert kw.knots_of(slope, from_step=40) == [(46, 2), (51, 0)]
    assert kw.knots_of(slope, from_step=47) == [(51, 0)]


def test_the_wake_reads_each_figure_at_its_reading():
    steps = 60
    rec = kw.WakeRecorder(1, steps, period_fs=3.44)
    rec.power[:] = 0.99
    rec.slope[:] = 0.0
    rec.slope[0, 45:, 2] = 0.01  # acts from step 46
    rec.drift[:] = 0.0
    rec.drift[0, 49:, 2] = 0.01  # the tracker has the new slope from step 49 on
    rec.taken[:] = 3
    rec.taken[0, 48:] = 4  # and took the knot at step 48
    rec.power[0, 46 + 2] = 0.8
    out = kw.wake(rec, from_step=40, readings=(0, 2, 3, 20))
    assert out["knots"] == 1
    rows = out["by_readings"]
    assert rows["2"]["power"] == pytest.approx(0.8) and rows["0"]["power"] == pytest.approx(0.99)
    assert rows["0"]["drift_error_over_change"] == pytest.approx(1.0)
    assert rows["3"]["drift_error_over_change"] == pytest.approx(0.0)
    assert rows["0"]["knot_taken"] == 0.0 and rows["2"]["knot_taken"] == 1.0
    assert rows["20"]["knots"] == 0 and rows["20"]["power"] is None  # past the episode's end


def test_a_short_run_writes_the_wake_and_the_tracker_learns_the_new_slope(tmp_path, capsys):
    out = tmp_path / "wake.json"
    argv = ["--realism", "ideal", "--seeds", "8101", "--episodes", "2", "--out", str(out)]
    argv += ["--readings", "0", "4", "16"]
    assert kw.main(argv) == 0
    printed = capsys.readouterr().out
    assert "| `ideal`: P_N/P_max |" in printed and "| `ideal`: knot taken |" in printed
    result = json.loads(out.read_text())
    assert result["command"] == "ops-bench tracker-knot-wake " + " ".join(argv)
    assert result["settings"]["mode"] == "extreme" and result["settings"]["seeds"] == [8101]
    res = result["results"]["ideal"]
    assert res["episodes"] == 2 and res["knots"] >= 5  # a stage turns every 40-120 steps
    rows = res["by_readings"]
    assert set(rows) == {"0", "4", "16"}
    assert all(0 <= rows[k]["power"] <= 1 and 0 <= rows[k]["knot_taken"] <= 1 for k in rows)
    # the estimate holds the old slope at the knot and has learned most of the new one later
    assert rows["0"]["drift_error_over_change"] > 0.5
    assert rows["16"]["drift_error_over_change"] < 0.5 * rows["0"]["drift_error_over_change"]
    assert rows["16"]["knot_taken"] >= rows["0"]["knot_taken"]


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--mode", "brutal"], "--mode"),
        (["--realism", "real"], "--realism"),
        (["--readings", "200"], "--readings"),
        (["--readings", "-1"], "--readings"),
        (["--from-step", "1"], "--from-step"),
        (["--episodes", "0"], "--episodes"),
        (["--param", "no_such_param=1"], "--param"),
    ],
)
def test_bad_input_exits_2_naming_the_option(argv, named, capsys):
    with pytest.raises(SystemExit) as done:
        kw.main(argv)
    assert done.value.code == 2
    assert named in capsys.readouterr().err
