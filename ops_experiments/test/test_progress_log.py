"""A resumed run's progress log: earlier parts kept in order, minutes counted from the start."""

from __future__ import annotations

from ops_experiments.progress_log import keep_earlier_parts, parts, read_progress

HEADER = "time/time_elapsed,time/total_timesteps,eval/final_power\n"


def write_part(logs, rows):
    (logs / "progress.csv").write_text(HEADER + "".join(f"{t},{s},{p}\n" for t, s, p in rows))


def test_parts_are_kept_in_order_and_minutes_add_up(tmp_path):
    assert keep_earlier_parts(tmp_path) is None  # nothing logged yet: nothing to keep
    write_part(tmp_path, [(60, 100, ""), (120, 200, 0.5)])
    assert keep_earlier_parts(tmp_path).name == "progress.part1.csv"
    write_part(tmp_path, [(30, 300, 0.6), (90, 400, "")])
    assert keep_earlier_parts(tmp_path).name == "progress.part2.csv"
    write_part(tmp_path, [(60, 500, 0.7)])
    for k in range(3, 11):  # part 10 sorts after part 9, not after part 1
        (tmp_path / f"progress.part{k}.csv").write_text(HEADER)
    (tmp_path / "progress.part10.csv").write_text(HEADER + "10,450,0.65\n")
    names = [p.name for p in parts(tmp_path)]
    assert names[:3] == ["progress.part1.csv", "progress.part2.csv", "progress.part3.csv"]
    assert names[-2:] == ["progress.part10.csv", "progress.csv"]
    rows = read_progress(tmp_path)
    assert [int(r["time/total_timesteps"]) for r in rows] == [100, 200, 300, 400, 450, 500]
    # part 1 ran 2 min, part 2 1.5 min, the empty parts nothing, part 10 10 s
    expected = [1.0, 2.0, 2.5, 3.5, 3.5 + 10 / 60, 3.5 + 10 / 60 + 1.0]
    assert [round(r["minutes"], 6) for r in rows] == [round(m, 6) for m in expected]


def test_an_empty_current_log_is_not_kept(tmp_path):
    (tmp_path / "progress.csv").write_text("")
    assert keep_earlier_parts(tmp_path) is None
    assert read_progress(tmp_path) == []
