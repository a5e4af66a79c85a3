"""The realism sweep: its cells, a small real sweep that stores, resumes and draws."""

from __future__ import annotations

import json

import pytest

from ops_experiments import realism_sweep


def _args(*argv):
    return realism_sweep.build_parser().parse_args(list(argv))


def test_the_cells_cover_every_figure_of_the_issue_and_tell_the_controller():
    todo = realism_sweep.cells(_args())
    cases = {c["case"] for c in todo}
    for case in ("ideal", "latency 1", "latency 2", "latency 4", "6-bit trace", "8-bit trace",
                 "10-bit trace", "12-bit trace", "hysteresis 5%", "hysteresis 15%",
                 "amplitude noise 1%", "amplitude noise 3%", "lab"):  # fmt: skip
        assert case in cases
    assert {c["mode"] for c in todo} == {"easy", "medium", "hard"}
    subjects = {(c["subject"], c["mode"]) for c in todo}
    for name in ("easy_dagger", "medium_dagger", "hard_dagger", "hard_lab_dagger"):
        assert (f"n5_{name}", name.split("_")[0]) in subjects  # the README's models
    assert {("tracker", "easy"), ("spgd", "hard"), ("n5_hard", "hard")} <= subjects
    lab = next(c for c in todo if c["case"] == "lab" and c["subject"] == "tracker")
    assert lab["argv"][lab["argv"].index("--realism") + 1] == "lab"
    lat = next(c for c in todo if c["case"] == "latency 2" and c["subject"] == "spgd")
    assert "latency_steps=2" in lat["argv"] and "test" in lat["argv"]
    assert len({c["name"] for c in todo}) == len(todo)
    with pytest.raises(ValueError, match="unknown case"):
        realism_sweep.cells(_args("--cases", "latency 3"))


def test_a_small_sweep_stores_its_cells_resumes_and_writes_table_and_figure(tmp_path, capsys):
    argv = ["--modes", "easy", "--subjects", "spgd", "--cases", "ideal", "latency 2",
            "--seeds", "5", "--episodes", "1", "--out", str(tmp_path / "sweep"),
            "--figure", str(tmp_path / "fig.png")]  # fmt: skip
    assert realism_sweep.run(argv) == 0
    summary = json.loads((tmp_path / "sweep" / "summary.json").read_text())
    rows = {r["case"]: r for r in summary["cells"]}
    assert set(rows) == {"ideal", "latency 2"}
    for r in rows.values():
        assert 0.0 <= r["worst"] <= r["mean"] + 1e-6 <= 1.0 + 1e-6 and r["episodes"] == 1
    page = (tmp_path / "sweep" / "index.md").read_text()
    assert "| latency 2 |" in page and "realism_sweep --modes easy" in page
    assert (tmp_path / "fig.png").stat().st_size > 10_000
    cell = tmp_path / "sweep" / "cells" / "spgd_easy_latency_2" / "evaluation.json"
    stamp = cell.stat().st_mtime_ns
    assert realism_sweep.run(argv) == 0  # stored cells are not run again
    assert cell.stat().st_mtime_ns == stamp
    assert "| ideal |" in capsys.readouterr().out
    # a run of one more part: the page and the summary keep every stored cell
    part = [a if a != "latency 2" else "latency 4" for a in argv]
    part.remove("ideal")
    assert realism_sweep.run(part) == 0
    summary = json.loads((tmp_path / "sweep" / "summary.json").read_text())
    assert {r["case"] for r in summary["cells"]} == {"ideal", "latency 2", "latency 4"}
    page = (tmp_path / "sweep" / "index.md").read_text()
    assert "| ideal |" in page and "| latency 2 |" in page and "| latency 4 |" in page
