"""ops-bench recipes: two tiny real recipes (a distilled student, SAC) trained side by side,
stored, not trained again, and drawn on one figure and table."""

from __future__ import annotations

import subprocess

import pytest

from ops_bench import recipes

pytestmark = pytest.mark.timeout(240)

TINY = """
student: [distill, --envs, "8", --rounds, "2", --eval-every, "1", --grad-steps, "20", --width, "32"]
sac: [train, --hyperparams-set, fast, --n-envs, "4", --timesteps, "400", --eval-freq, "200",
      --eval-episodes, "2", --no-progress, --hyperparams, learning_starts=100, "net_arch=[32,32]"]
"""


def bench(*argv) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["ops-bench", "recipes", *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=200,
        stdin=subprocess.DEVNULL,
    )


def test_the_shipped_recipes_are_distill_and_train_command_lines():
    shipped = recipes.read_recipes(recipes.RECIPES)
    named = {"dagger-oracle", "fast-sac", "ppo-parallel", "asymmetric-sac", "recurrent-ppo"}
    assert named <= set(shipped)
    assert {command[0] for command in shipped.values()} == {"distill", "train"}


def test_tiny_recipes_train_side_by_side_are_kept_and_drawn(tmp_path):
    (tmp_path / "recipes.yaml").write_text(TINY)
    argv = ["--recipes-file", tmp_path / "recipes.yaml", "--stage", 2, "--mode", "easy"]
    argv += ["--minutes", 2, "--out", tmp_path / "runs", "--figure", tmp_path / "fig.png"]
    argv += ["--results", tmp_path / "table"]
    done = bench(*argv)
    assert done.returncode == 0, done.stdout + done.stderr
    for name in ("student", "sac"):
        folder = tmp_path / "runs" / name
        assert recipes.finished(folder) and (folder / "model.zip").is_file()
        assert f"[recipes {name}] " in done.stdout  # its own output, under its name
    assert "--max-minutes 2 --out" in done.stdout and "--mode easy" in done.stdout
    assert (tmp_path / "fig.png").stat().st_size > 10_000
    table = (tmp_path / "table" / "table.md").read_text()
    assert "| student | dagger-oracle | easy |" in table and "| sac | sac | easy |" in table
    stamp = (tmp_path / "runs" / "sac" / "metadata.json").stat().st_mtime_ns
    again = bench(*argv, "--recipes", "sac")
    assert again.returncode == 0 and "sac: stored in" in again.stdout
    assert (tmp_path / "runs" / "sac" / "metadata.json").stat().st_mtime_ns == stamp


@pytest.mark.parametrize(
    "text, extra, message",
    [
        ("a: [sim]\n", [], "must be a list starting with distill or train"),
        ("a: [train]\n", ["--recipes", "b"], "unknown recipe(s) ['b']; recipes: a"),
        ("a: [train]\n", ["--minutes", "0"], "--minutes must be > 0"),
    ],
)
def test_bad_recipes_and_options_are_refused(tmp_path, capsys, text, extra, message):
    (tmp_path / "r.yaml").write_text(text)
    argv = ["--recipes-file", str(tmp_path / "r.yaml"), "--out", str(tmp_path / "runs"), *extra]
    assert recipes.main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()
