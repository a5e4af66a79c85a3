"""``ops-bench spgd-attempts``: SPGD-PID's climbs and restarts attempt by attempt
(docs/results/spgd/notes.md, "Where the 0.04 goes"), on short runs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ops_bench import spgd_attempts as sa


def test_attempts_split_at_each_restart():
    power = np.array([0.1, 0.2, 0.3, 0.3, 0.5, 0.95, 0.97, 0.2, 0.3, 0.4])
    restarts = np.array([0, 0, 0, 1, 1, 1, 1, 2, 2, 2])  # decided on the readings of steps 3, 7
    assert sa.attempts_of(power, restarts) == [
        {"kind": "start", "reached": None, "ended": 4},
        {"kind": "restart", "reached": 2, "ended": 4},  # steps 4-7; 0.95 at step 5
        {"kind": "restart", "reached": None, "ended": None},  # cut short by the episode's end
    ]
    assert sa.attempts_of(np.full(5, 0.95), np.zeros(5, dtype=int)) == [
        {"kind": "start", "reached": 1, "ended": None}
    ]


def test_the_summary_counts_failed_attempts_that_ended_in_a_restart_only():
    rec = sa.RestartRecorder(2, 10)
    rec.power[0] = [0.1, 0.2, 0.3, 0.3, 0.5, 0.95, 0.97, 0.2, 0.3, 0.4]
    rec.restarts[0] = [0, 0, 0, 1, 1, 1, 1, 2, 2, 2]
    rec.power[1] = 0.95
    rec.restarts[1] = 0
    res = sa.summarize(rec, finals=[0.4, 0.95])
    assert res["restarts_per_episode"] == 1.0 and res["worst_final"] == 0.4
    assert res["start"]["attempts"] == 2 and res["start"]["reach_share"] == 0.5
    assert res["start"]["failed_ends_after_median"] == 4.0
    assert res["restart"]["attempts"] == 2 and res["restart"]["reach_share"] == 0.5
    assert res["restart"]["steps_to_reach_median"] == 2.0
    assert res["restart"]["failed_ends_after_median"] is None  # the failed one was cut short


def test_a_short_run_writes_its_figures_at_each_latency(tmp_path, capsys):
    out = tmp_path / "attempts.json"
    argv = ["--latencies", "0", "2", "--seeds", "8101", "8102", "--episodes", "3"]
    argv += ["--out", str(out)]
    assert sa.main(argv) == 0
    printed = capsys.readouterr().out
    assert "| | L = 0 | L = 2 |" in printed and "restarts per episode" in printed
    result = json.loads(out.read_text())
    assert result["command"] == "ops-bench spgd-attempts " + " ".join(argv)
    assert set(result["results"]) == {"0", "2"}
    for res in result["results"].values():
        assert res["episodes"] == 6 and 0 <= res["worst_final"] <= res["mean_final"] <= 1
        assert res["start"]["attempts"] == 6  # one start an episode
        assert res["restart"]["attempts"] == pytest.approx(6 * res["restarts_per_episode"])
        assert res["restarts_per_episode"] > 0  # hard: SPGD stalls on side peaks and restarts
        for kind in ("start", "restart"):
            assert 0 <= res[kind]["reach_share"] <= 1


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--latencies", "-1"], "--latencies"),
        (["--latencies", "one"], "--latencies"),
        (["--mode", "brutal"], "--mode"),
        (["--episodes", "0"], "--episodes"),
        (["--param", "no_such_param=1"], "--param"),
        (["--param", "restart_after=0"], "--param"),
    ],
)
def test_bad_input_exits_2_naming_the_option(argv, named, capsys):
    with pytest.raises(SystemExit) as done:
        sa.main(argv)
    assert done.value.code == 2
    assert named in capsys.readouterr().err
