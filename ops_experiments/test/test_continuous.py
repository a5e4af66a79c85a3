"""`evaluate --continuous STEPS`: one long run per seed, lock fraction and lock losses."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from ops_sim_ros.env import OpsEnv

from ops_experiments import continuous, evaluate


def test_lock_figures_count_runs_after_the_first_lock():
    p = np.array([0.1, 0.5, 0.96, 0.97, 0.7, 0.6, 0.99, 0.9, 0.5, 0.96, 0.3])
    f = continuous.lock_figures(p)
    assert f["first_lock_step"] == 2
    assert f["readings_after_lock"] == 9
    assert f["locked_readings"] == 4
    assert f["locked_fraction"] == pytest.approx(4 / 9)
    assert f["losses"] == 3 and f["loss_lengths"] == [2, 1, 1]
    assert f["worst_after_lock"] == pytest.approx(0.3)
    assert f["worst"] == pytest.approx(0.1)
    never = continuous.lock_figures([0.2, 0.9])
    assert never["first_lock_step"] is None and never["locked_fraction"] == 0.0
    both = continuous.overall([f, never])
    assert both["runs_never_locked"] == 1 and both["losses"] == 3 and both["longest_loss"] == 2
    with pytest.raises(ValueError, match="finite"):
        continuous.lock_figures([0.5, float("nan")])


class FrozenSubject(evaluate.Subject):
    """A controller that lets go: it starts on the stacking point (hidden errors placed at 0)
    and never moves its set-points again, while the rig's drift runs on."""

    def run(self, split, episodes, steps, seed):
        env = OpsEnv.from_config(self.sim_config(split, steps), max_episode_steps=steps)
        _, info = env.reset(seed=seed, options={"delay_errors_fs": np.zeros(self.stage)})
        power = [info["power"]]
        for _ in range(steps):
            power.append(float(env.step_setpoints(np.zeros(self.stage)).power[0]))
        return {"power": np.array([power]), "returns": np.zeros(1)}


def _args(**kw):
    base = dict(continuous=2000, seeds=[1001, 1002], splits=["test"], record=None, quiet=True)
    return SimpleNamespace(**{**base, **kw})


def test_a_controller_that_lets_go_is_reported_as_losing_lock():
    subject = FrozenSubject(
        name="frozen",
        stage=5,
        mode="hard",
        detector="polarizer",
        env_overrides={},
        meta={"controller": "frozen"},
    )
    results = continuous.evaluate(_args(), subject)
    s = results["splits"]["test"]
    for run in s["per_seed"]:
        # locked at the start (the errors were placed at 0); the test split's drift of at least
        # 0.0005 cycles per step moves every stage by a cycle in 2000 steps
        assert run["first_lock_step"] == 0
        assert run["losses"] >= 1 and run["worst_after_lock"] < 0.5
        assert run["locked_fraction"] < 0.5
    assert s["overall"]["losses"] >= 2 and s["overall"]["runs_with_losses"] == 2
    table = continuous.format_table(results)
    assert "seed 1001" in table and "overall" in table


def test_evaluate_continuous_tracker_holds_hard_mode(tmp_path):
    """The tracker through the CLI: 1500 steps of hard mode's test split (drift running)."""
    out = tmp_path / "cont"
    argv = ["--controller", "tracker", "--mode", "hard", "--splits", "test", "--seeds", "1003"]
    argv += ["--continuous", "1500", "--out", str(out), "--no-plot", "--quiet"]
    assert evaluate.run(argv) == 0
    result = json.loads((out / "evaluation.json").read_text())
    assert result["continuous_steps"] == 1500
    run = result["splits"]["test"]["per_seed"][0]
    assert run["readings"] == 1501
    assert run["first_lock_step"] is not None and run["first_lock_step"] <= 40
    assert run["locked_fraction"] >= 0.98, run
    assert run["losses"] == 0, run


def test_evaluate_continuous_refuses_record(tmp_path):
    argv = ["--controller", "tracker", "--continuous", "10", "--record", str(tmp_path / "bag")]
    assert evaluate.run([*argv, "--out", str(tmp_path / "o"), "--quiet"]) == 2


def test_a_switching_model_of_one_policy_runs_the_plain_models_episodes(tmp_path):
    """A switching model whose two parts are the same shipped policy is that policy: evaluated
    through the runner path (rollouts.rollout_runner, each reading observed by the runner) it
    gives the episodes of the plain model's batched path (rollout_policy), reading for reading.
    And `evaluate --continuous` runs a switching model."""
    from ops_controller_ros.policy_switch import write_switch_model

    shipped = Path(__file__).resolve().parents[2] / "models" / "n5_medium"
    same = write_switch_model(tmp_path / "same", shipped, shipped)
    finals = []
    for model, out in ((shipped, tmp_path / "plain"), (same, tmp_path / "switch")):
        argv = [str(model), "--splits", "test", "--seeds", "7", "--episodes", "6"]
        assert evaluate.run([*argv, "--out", str(out), "--no-plot", "--quiet"]) == 0
        result = json.loads((out / "evaluation.json").read_text())
        finals.append(result["splits"]["test"]["final_power_per_episode"])
    np.testing.assert_allclose(finals[0], finals[1], atol=1e-5)
    out = tmp_path / "cont"
    argv = [str(same), "--splits", "test", "--seeds", "1004", "--continuous", "400"]
    assert evaluate.run([*argv, "--out", str(out), "--no-plot", "--quiet"]) == 0
    run = json.loads((out / "evaluation.json").read_text())["splits"]["test"]["per_seed"][0]
    assert run["readings"] == 401
