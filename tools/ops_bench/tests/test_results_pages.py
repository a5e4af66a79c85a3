"""The results pages are what ``ops-bench results`` writes from the stored runs."""

from __future__ import annotations

import json
import re

import pytest

from ops_bench import results_pages, spgd_baseline


def test_committed_results_pages_are_what_the_command_writes():
    pages = results_pages.generate()
    stale = [
        results_pages.rel(path)
        for path, text in pages.items()
        if not path.exists() or path.read_text() != text
    ]
    assert not stale, (
        f"{', '.join(stale)}: edited by hand or out of date; edit the notes.md beside the page "
        "(or re-run the measurement) and run `ops-bench results`"
    )
    assert results_pages.generate() == pages  # deterministic


def test_no_commit_hash_beside_current_figures():
    assert results_pages.commits_beside_current(results_pages.generate()) == []
    assert results_pages.COMMIT.search("run of 5c28d78 kept")
    assert not results_pages.COMMIT.search("--timesteps 100000000, 3,848,848 steps")


def _evaluation(locked: list[float], never: int = 0) -> dict:
    per_seed = [{"locked_fraction": f} for f in locked]
    overall = {
        "locked_fraction": sum(locked) / len(locked),
        "runs_never_locked": never,
        "losses": 3,
        "longest_loss": 7,
        "worst_after_lock": 0.51234,
        "first_lock_step_median": 8.0,
    }
    return {
        "mode": "extreme",
        "continuous_steps": 2000,
        "seeds": [1000 + i for i in range(len(locked))],
        "splits": {"test": {"overall": overall, "per_seed": per_seed}},
    }


def test_continuous_table_renders_a_fixture(tmp_path, monkeypatch):
    root = tmp_path / "continuous"
    for name, data in {
        "tracker_extreme_30k": _evaluation([0.9768, 0.9780]),
        "spgd_extreme_5c28d78": _evaluation([0.0085, 0.0], never=1),
    }.items():
        (root / name).mkdir(parents=True)
        (root / name / "evaluation.json").write_text(json.dumps(data))
    monkeypatch.setattr(results_pages, "RESULTS", tmp_path)
    text = results_pages.expand(
        "before\n<!-- generated: continuous tracker_extreme_30k spgd_extreme_5c28d78 -->\nafter\n",
        tmp_path,
    )
    lines = text.splitlines()
    assert lines[0] == "before" and lines[-1] == "after"
    assert "`tracker_extreme_30k`, `spgd_extreme_5c28d78`" in lines[1]
    assert lines[3] == results_pages.CONTINUOUS_HEAD[0]
    assert lines[5] == (
        "| tracker | extreme | 2000 × 2 | 97.74 % (seeds: 97.68 %, 97.80 %) | 3 | 7 | 0.5123 | 8 |"
    )
    assert lines[6] == (
        "| SPGD-PID (defaults), commit 5c28d78 | extreme | 2000 × 2 | 0.43 % (one seed never "
        "locks) | 3 | 7 | 0.5123 | 8 |"
    )


def test_unknown_directive_is_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown directive"):
        results_pages.expand("<!-- generated: nothing a b -->\n", tmp_path)


def test_slug_is_githubs_anchor():
    assert results_pages.slug("SPGD-PID: the user's first run") == "spgd-pid-the-users-first-run"
    assert results_pages.slug("Table 1 at N = 5") == "table-1-at-n--5"


def test_every_relative_link_of_the_pages_resolves():
    broken = []
    for path, text in results_pages.generate().items():
        for match in re.finditer(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
            target = match.group(1)
            if not target.startswith("http") and not (path.parent / target).exists():
                broken.append(f"{results_pages.rel(path)}: {target}")
    assert broken == []


def test_held_out_table_renders_a_fixture_in_a_block_quote(tmp_path, monkeypatch):
    finals = {"n5_easy": [[0.99, 0.5], [0.97, 0.98]], "n5_hard": [[0.9, 0.95, 0.7]]}
    for name, per_seed in finals.items():
        (tmp_path / name / "eval").mkdir(parents=True)
        flat = [x for row in per_seed for x in row]
        test = {
            "final_power_mean": sum(flat) / len(flat),
            "final_power_std": 0.0123,
            "final_power_per_episode": per_seed,
        }
        data = {
            "seeds": [100 + i for i in range(len(per_seed))],
            "episodes_per_seed": len(per_seed[0]),
            "splits": {"test": test},
        }
        (tmp_path / name / "eval" / "evaluation.json").write_text(json.dumps(data))
    monkeypatch.setattr(results_pages, "MODELS", tmp_path)
    text = results_pages.expand(
        "> before\n> <!-- generated: held-out n5_hard n5_easy -->\n> after\n", tmp_path
    )
    lines = text.splitlines()
    assert lines[0] == "> before" and lines[-1] == "> after"
    assert lines[1].startswith("> *From `models/NAME/eval/evaluation.json` (NAME: `n5_hard`, `n5_")
    assert "ros2 run ops_gym_bridge evaluate models/NAME --splits test" in lines[1]
    assert "(each model's seeds and episodes)" in lines[1]  # the two differ here
    assert lines[2] == ">"  # the blank line stays inside the quote
    assert lines[3] == "> " + results_pages.HELD_OUT_HEAD[0]
    assert lines[5] == "> | n5_hard | 0.850 ± 0.012 | 0.900 | 0.700 | 1 / 3 |"
    assert lines[6] == "> | n5_easy | 0.860 ± 0.012 | 0.975 | 0.500 | 1 / 4 |"


def test_seeds_are_written_as_the_docs_write_them():
    assert results_pages.seeds_text(list(range(100, 120))) == "100 ... 119"
    assert results_pages.seeds_text([7, 9]) == "7 9"


def _baseline(final_test: float) -> dict:
    cell = {
        "initial_power_mean": 0.20581,
        "final_power_mean": 0.88704,
        "final_power_std": 0.14271,
        "episode_return_mean": -50.94,
        "episode_return_std": 26.61,
    }
    return {
        "command_line": ["ops-bench", "spgd-baseline", "--stage", "5", "--store", "b.json"],
        "seeds": [0, 1, 2],
        "episodes_per_seed": 4,
        "steps": 200,
        "modes": {"easy": {"train": cell, "test": {**cell, "final_power_mean": final_test}}},
    }


def test_spgd_baseline_table_is_rendered_from_its_json(tmp_path, monkeypatch):
    (tmp_path / "b.json").write_text(json.dumps(_baseline(0.5)))
    monkeypatch.setattr(results_pages, "REPO", tmp_path)
    lines = results_pages.expand("<!-- generated: spgd-baseline b.json -->\n", tmp_path)
    lines = lines.splitlines()
    assert lines[0] == (
        "*From `b.json` (3 seeds × 4 episodes of 200 steps per cell), stored by "
        "`ops-bench spgd-baseline --stage 5 --store b.json`.*"
    )
    assert lines[2:] == [
        *spgd_baseline.TABLE_HEAD,
        "| easy | train | 0.206 | 0.8870 ± 0.1427 | -50.9 ± 26.6 |",
        "| easy | test | 0.206 | 0.5000 ± 0.1427 | -50.9 ± 26.6 |",
    ]


def test_the_spgd_page_takes_the_baseline_table_from_the_stored_json():
    """No hand-kept copy in notes.md: the page's rows are those of baseline.json."""
    notes = (results_pages.RESULTS / "spgd" / "notes.md").read_text()
    assert "<!-- generated: spgd-baseline docs/results/spgd/baseline.json -->" in notes
    assert spgd_baseline.TABLE_HEAD[0] not in notes
    stored = json.loads((results_pages.RESULTS / "spgd" / "baseline.json").read_text())
    assert set(stored["modes"]) == {"easy", "medium", "hard", "extreme"}
    spgd = next(page for page in results_pages.TOPICS if page.name == "spgd")
    page = results_pages.render_page(spgd)
    assert "\n".join(spgd_baseline.table_lines(stored)) in page
