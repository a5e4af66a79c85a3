"""Physical time on the command line: --env / --rig time_base, step_s, vibration."""

from __future__ import annotations

import json

import pytest
from ops_contract.config import TIME_KEYS
from ops_experiments.table1 import benchmark

from ops_experiments import cli_args, evaluate, train


def _evaluate(tmp_path, *extra):
    out = tmp_path / "eval"
    argv = ["--controller", "spgd", "--stage", "2", "--mode", "easy", "--episodes", "1"]
    argv += ["--seeds", "0", "--steps", "20", "--out", str(out), "--no-plot", "--quiet"]
    code = evaluate.run([*argv, *extra])
    return code, (json.loads((out / "evaluation.json").read_text()) if code == 0 else None)


BAD = [
    ("time_base=minutes", "time_base must be one of step, seconds (got 'minutes')"),
    ("step_s=0", "step_s must be from 1e-05 to 10.0 (got 0.0)"),
    ("step_s=nan", "step_s must be a finite number from 1e-05 to 10.0"),
    ("step_s=-0.01", "step_s must be from 1e-05 to 10.0"),
    ("step_s=fast", "step_s must be a number (got 'fast')"),
    ("vibration=loud", "vibration must be one of none, lab, open (got 'loud')"),
]


@pytest.mark.parametrize("option", ["--env", "--rig"])
@pytest.mark.parametrize("item, message", BAD)
def test_evaluate_refuses_bad_physical_time_with_exit_2(tmp_path, capsys, option, item, message):
    code, _ = _evaluate(tmp_path, option, item)
    assert code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("item, message", BAD)
def test_the_rig_option_of_every_cli_says_the_same(item, message):
    """train and benchmark resolve --rig with cli_args.resolve_rig, as evaluate does."""
    with pytest.raises(ValueError) as err:
        cli_args.resolve_rig(None, [item])
    assert message in str(err.value)


def test_train_and_benchmark_exit_2_on_a_bad_time_base(tmp_path, capsys):
    argv = ["--out", str(tmp_path / "b"), "--rig", "time_base=minutes", "--list"]
    assert benchmark.run(argv) == 2
    assert "time_base must be one of step, seconds" in capsys.readouterr().err
    argv = ["--algo", "td3", "--stage", "1", "--timesteps", "64", "--out", str(tmp_path / "m")]
    assert train.run([*argv, "--no-progress", "--rig", "step_s=20"]) == 2
    assert "step_s must be from 1e-05 to 10.0 (got 20.0)" in capsys.readouterr().err


def test_rig_takes_the_keys_of_physical_time_and_tells_the_controller(tmp_path):
    rig = cli_args.resolve_rig("lab", ["time_base=seconds", "step_s=0.01", "vibration=lab"])
    assert rig == {"time_base": "seconds", "step_s": 0.01, "vibration": "lab", "realism": "lab"}
    assert set(TIME_KEYS) <= set(cli_args.RIG_OPTION_KEYS)
    code, res = _evaluate(tmp_path, "--rig", "time_base=seconds", "step_s=0.01", "vibration=lab")
    assert code == 0 and res["rig"]["step_s"] == 0.01
    assert (res["time_base"], res["step_s"], res["steps"], res["episode_s"]) == (
        "seconds",
        0.01,
        20,
        0.2,
    )
    code, res = _evaluate(tmp_path / "default")
    assert code == 0 and (res["time_base"], res["episode_s"]) == ("step", 2.0)


def test_episode_time_counts_seconds_beside_steps():
    from ops_contract.config import make_config
    from ops_experiments.summary import episode_time

    assert episode_time(200, make_config()) == {
        "time_base": "step",
        "step_s": 0.1,
        "episode_s": 20.0,
    }
    fast = make_config(time_base="seconds", step_s=0.001)
    assert episode_time(2000, fast)["episode_s"] == 2.0
