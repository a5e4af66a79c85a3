"""``evaluate`` builds a model through the runner factory (ops_controller_ros.runner_factory): a
model it cannot run exits with status 2 and a message naming what differs or what is missing;
a recurrent model (sb3-contrib RecurrentPPO) is evaluated with its state carried through each
episode, bare and inside the runner's layers. Real files: shipped models (copied and edited
where a bad one is needed) and a tiny recurrent model, built, not trained."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from ops_experiments import evaluate

MODELS = Path(__file__).resolve().parents[2] / "models"
QUICK = ["--seeds", "5", "--episodes", "2", "--steps", "12", "--no-plot", "--quiet"]


def _run(capsys, *argv) -> tuple[int, str]:
    code = evaluate.run([*map(str, argv), *QUICK])
    return code, capsys.readouterr().err


def _copy(tmp_path: Path, name: str, **entries) -> Path:
    out = tmp_path / name
    shutil.copytree(MODELS / name, out, ignore=shutil.ignore_patterns("eval*", "*.csv"))
    meta = json.loads((out / "metadata.json").read_text())
    (out / "metadata.json").write_text(json.dumps({**meta, **entries}))
    return out


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["--stage", "5"],
            "model {m} was trained for stage 3, the evaluation's simulator (--stage, --detector) "
            "runs stage 5",
        ),
        (["--detector", "total"], "model {m} was trained with the 'polarizer' detector"),
        (["--observation", "authors"], "set --observation rig (the authors' set"),
    ],
)
def test_a_model_asked_for_what_it_was_not_trained_for_exits_2(capsys, tmp_path, argv, message):
    model = MODELS / "n3_easy"
    code, err = _run(capsys, model, *argv, "--out", tmp_path)
    assert code == 2 and message.format(m=model) in err, err


@pytest.mark.parametrize(
    "entries, message",
    [
        ({"recipe": "evolution"}, "recipe 'evolution', which this runner does not know"),
        ({"recurrent": {"kind": "gru", "hidden": 64}}, "recurrent state of kind 'gru'"),
        ({"algo": "recurrent_ppo"}, "'recurrent' is null"),
    ],
)
def test_a_model_the_runner_does_not_know_exits_2_naming_it(capsys, tmp_path, entries, message):
    model = _copy(tmp_path, "n3_easy", **entries)
    code, err = _run(capsys, model, "--out", tmp_path / "out")
    assert code == 2 and message in err and str(model) in err, err


def test_missing_files_exit_2_saying_what_is_missing(capsys, tmp_path):
    model = _copy(tmp_path, "n3_easy")
    (model / "model.zip").unlink()
    code, err = _run(capsys, model, "--out", tmp_path / "out")
    assert code == 2 and f"model file missing: {model / 'model.zip'} not found" in err, err
    (model / "metadata.json").unlink()
    code, err = _run(capsys, model, "--out", tmp_path / "out")
    assert code == 2 and f"metadata missing: {model / 'metadata.json'} not found" in err, err
    switch = _copy(tmp_path, "n5_hard_switch")
    (switch / "acquire" / "model.zip").unlink()
    code, err = _run(capsys, switch, "--out", tmp_path / "out")
    assert code == 2 and f"the acquiring policy {switch / 'acquire' / 'model.zip'}" in err, err


@pytest.fixture(scope="module")
def recurrent(tmp_path_factory) -> Path:
    """A stage-2 RecurrentPPO model (an LSTM of 8), built and saved with its metadata."""
    sb3_contrib = pytest.importorskip("sb3_contrib")
    from ops_contract.policy_meta import write_meta

    from ops_sim_ros import OpsEnv

    env = OpsEnv(stage=2, mode="easy")
    model = sb3_contrib.RecurrentPPO(
        "MlpLstmPolicy", env, n_steps=16, policy_kwargs={"lstm_hidden_size": 8}, seed=0
    )
    out = tmp_path_factory.mktemp("rppo") / "rppo"
    out.mkdir()
    model.save(str(out / "model.zip"))
    write_meta(
        out,
        {
            "algo": "recurrent_ppo",
            "recipe": "recurrent_ppo",
            "recurrent": {"kind": "lstm", "hidden": 8, "layers": 1},
            "training_wall_s": 0.0,
            "stage": 2,
            "mode": "easy",
            "action_type": "increment",
            "max_step_fs": env.config.max_step_fs,
            "observation_spec": env.obs_spec.to_dict(),
            "config": env.config.to_dict(),
        },
    )
    return out


def test_a_recurrent_model_is_evaluated_with_its_state(recurrent, tmp_path):
    """Bare (env-built observations, the state carried by the rollout's predictor) and inside
    the layers (held decisions: the runner on every reading): deterministic, and the state
    matters (the episodes differ from a policy that starts afresh at every step)."""
    from ops_experiments.rollouts import rollout_policy
    from ops_experiments.subject import Subject

    args = evaluate.build_parser().parse_args([str(recurrent), *QUICK])
    subject = evaluate.resolve_subject(args)
    assert not subject.model.layered and subject.policy.recurrent
    first = evaluate.evaluate(args, subject)
    again = evaluate.evaluate(args, evaluate.resolve_subject(args))
    assert first["splits"] == again["splits"]
    sim = subject.sim_config("test", 12)
    stateless = rollout_policy(subject.policy.predict, sim, 2, 12, 5)["power"]
    assert not np.array_equal(subject.run("test", 2, 12, 5)["power"], stateless)
    assert isinstance(subject, Subject)
    held = evaluate.run([str(recurrent), *QUICK, "--hold-steps", "2", "--out", str(tmp_path)])
    assert held == 0
    results = json.loads((tmp_path / "evaluation.json").read_text())
    assert results["hold_steps"] == 2 and results["controller"] == "recurrent_ppo"
