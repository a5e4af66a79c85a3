"""The shared CLI helper and the evaluate options built on it (--controller, --env, --detector)."""

from __future__ import annotations

import json

import pytest
from ops_contract.config import DETECTORS, MODES

from ops_experiments import cli_args, evaluate, train


def test_parse_key_values_types_and_errors():
    assert cli_args.parse_key_values(["a=1", "b=0.5", "c=[64, 64]", "d=true", "e=x"]) == {
        "a": 1,
        "b": 0.5,
        "c": [64, 64],
        "d": True,
        "e": "x",
    }
    with pytest.raises(ValueError, match="key=value"):
        cli_args.parse_key_values(["novalue"])
    with pytest.raises(ValueError, match="not a valid name"):
        cli_args.parse_key_values(["1x=2"])


@pytest.mark.parametrize("parser", [train.build_parser, evaluate.build_parser])
def test_env_choices_come_from_config_and_help_names_each_default_once(parser, capsys):
    p = parser()
    actions = {a.dest: a for a in p._actions}
    assert tuple(actions["mode"].choices) == MODES
    assert tuple(actions["detector"].choices) == DETECTORS
    with pytest.raises(SystemExit):
        p.parse_args(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: None)" not in text
    assert text.count("(default:") == text.count("default:")  # never "(default: x) (default: y)"
    for line in text.split("--"):
        assert line.count("default") <= 1, line


def _evaluate(tmp_path, *extra):
    out = tmp_path / "eval"
    argv = ["--stage", "2", "--mode", "easy", "--episodes", "1", "--seeds", "0", "--steps", "30"]
    code = evaluate.run([*argv, "--out", str(out), "--no-plot", "--quiet", *extra])
    return code, (json.loads((out / "evaluation.json").read_text()) if code == 0 else None)


def test_controller_spgd_equals_the_spgd_synonym(tmp_path):
    code_a, a = _evaluate(tmp_path / "a", "--controller", "spgd", "--controller-param", "gain=0.1")
    code_b, b = _evaluate(tmp_path / "b", "--spgd", "--spgd-param", "gain=0.1")
    assert code_a == code_b == 0
    assert a["controller"] == b["controller"] == "spgd"
    assert a["controller_params"] == {"gain": 0.1}
    assert a["splits"]["train"]["curve_mean"] == b["splits"]["train"]["curve_mean"]


def test_an_unknown_controller_names_the_controllers_and_where_a_model_goes(capsys):
    with pytest.raises(SystemExit) as exit_:
        evaluate.build_parser().parse_args(["--controller", "models/n5_hard"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "spgd, tracker" in err
    assert "without --controller" in err and "evaluate models/n5_hard" in err


def test_env_overrides_reach_the_simulator_not_the_controller(tmp_path, monkeypatch):
    from ops_experiments import rollouts

    seen = {}
    real = rollouts.controller_episodes

    def spy(env, controller, params, nominal, *args):
        seen["nominal"], seen["sim"] = nominal, env.config
        return real(env, controller, params, nominal, *args)

    monkeypatch.setattr(rollouts, "controller_episodes", spy)
    code, res = _evaluate(
        tmp_path,
        "--controller",
        "spgd",
        "--detector",
        "total",
        "--env",
        "detector_noise=0.01",
        "pulse_fwhm_fs=1200",
    )
    assert code == 0
    assert res["env_overrides"] == {"detector_noise": 0.01, "pulse_fwhm_fs": 1200}
    assert res["detector"] == "total"
    assert seen["sim"].detector_noise == 0.01 and seen["sim"].pulse_fwhm_fs == 1200.0
    assert seen["nominal"].detector_noise == 0.0 and seen["nominal"].pulse_fwhm_fs == 1000.0
    assert seen["nominal"].detector == seen["sim"].detector == "total"


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--env", "jitter_sigma_cycles=1e30"], "jitter_sigma_cycles must be from"),
        (["--env", "no_such_field=1"], "unknown parameter"),
        (["--env", "mode=hard"], "use --mode"),
        (["--controller-param", "no_such=1"], "bad spgd parameter"),
    ],
)
def test_bad_overrides_are_refused_with_a_reason(tmp_path, capsys, extra, message):
    code, _ = _evaluate(tmp_path, "--controller", "spgd", *extra)
    assert code == 2
    assert message in capsys.readouterr().err


def test_train_saves_the_detector(tmp_path):
    out = tmp_path / "m"
    argv = ["--algo", "td3", "--stage", "1", "--mode", "easy", "--detector", "total"]
    argv += ["--timesteps", "64", "--no-progress", "--out", str(out)]
    assert train.run([*argv, "--hyperparams", "learning_starts=32"]) == 0
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["detector"] == meta["config"]["detector"] == "total"
