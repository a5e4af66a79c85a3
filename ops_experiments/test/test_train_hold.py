"""Training with held decisions (``train --hold-steps``, ops_contract.held): each env step is one
decision, the action on the first of k simulator steps and k - 1 held ones after it, the
observation and its memory built from the decisions' readings alone: exactly what
``evaluate --hold-steps`` (ops_controller_ros.policy_hold.HeldRunner) gives a policy. The model's
metadata records the hold, and evaluate holds it so by default. Each test takes seconds."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_contract.observation import ObservationBuilder
from ops_controller_ros.policy_hold import HeldRunner
from ops_controller_ros.policy_io import (
    PolicyLoadError,
    load_policy,
    observation_spec_of,
    read_metadata,
)
from ops_controller_ros.runner_factory import build_runner
from ops_experiments.rollouts import rollout_policy, rollout_runner
from ops_sim_ros.env import OpsEnv
from ops_sim_ros.vec_env import OpsVectorEnv

from ops_experiments import evaluate, train

pytestmark = pytest.mark.timeout(60)

MODELS = Path(__file__).resolve().parents[2] / "models"
STAGE = 5
# Small network and early learning: a few hundred steps take seconds.
FAST = ["learning_starts=50", "net_arch=[32,32]", "batch_size=32", "checkpoint_freq=500"]


def _spy(env):
    """Record every simulator step of ``env`` (its increments and the result)."""
    sim, steps = env.sim, []
    step = sim.step_increments

    def recorded(actions):
        r = step(actions)
        steps.append((np.array(actions, dtype=np.float64).reshape(-1), r))
        return r

    sim.step_increments = recorded
    return steps


def test_a_held_env_moves_the_set_points_on_decisions_only_and_keeps_the_episode_length():
    k = 3
    env = OpsEnv.from_config(make_config(STAGE, "hard", "test", latency_steps=2), hold_steps=k)
    env.reset(seed=8301)
    steps = _spy(env)
    decisions = 0
    while True:
        before = env.sim.setpoints_fs.copy()
        _, reward, _, truncated, info = env.step(np.full(STAGE, 0.5, dtype=np.float32))
        decisions += 1
        mine = steps[-(k if not truncated else 200 - (decisions - 1) * k) :]
        assert np.all(mine[0][0] == 0.5) and all(not a.any() for a, _ in mine[1:])  # held: 0
        assert np.allclose(mine[0][1].setpoints_fs - before, 0.5 * env.config.max_step_fs)
        assert all(np.array_equal(r.setpoints_fs, mine[0][1].setpoints_fs) for _, r in mine)
        assert info["power"] == mine[-1][1].power[0] and reward == mine[-1][1].reward[0]
        if truncated:
            break
    # 200 simulator steps per episode, as without a hold: 66 decisions of 3 and one of 2.
    assert len(steps) == 200 and decisions == 67 and int(env.sim.step_count[0]) == 200


def test_the_batched_training_env_holds_all_its_envs_together():
    """The batched SB3 env (train's default with --n-envs > 1): one step is one decision of k
    simulator steps for every env, the episode still 200 simulator steps."""
    from ops_sim_ros.vec_env import OpsSb3VecEnv

    venv = OpsSb3VecEnv(num_envs=3, stage=STAGE, mode="hard", seed=0, hold_steps=0, realism="lab")
    assert venv.hold_steps == 2  # auto: lab's latency 1 + 1
    venv.reset()
    for decision in range(1, 101):
        venv.step_async(np.full((3, STAGE), 0.1, dtype=np.float32))
        _, _, dones, infos = venv.step_wait()
        if decision < 100:
            assert not dones.any() and np.all(venv.sim.step_count == 2 * decision)
    assert dones.all() and all("terminal_observation" in info for info in infos)
    assert np.all(venv.sim.step_count == 0)  # new episodes


def test_the_observation_memory_holds_the_decisions_readings_alone():
    k, spec_options = 2, {"history": 4}
    env = OpsEnv.from_config(
        make_config(STAGE, "hard", "test", latency_steps=1),
        hold_steps=k,
        observation_options=spec_options,
    )
    obs, _ = env.reset(seed=3)
    steps = _spy(env)
    builder = ObservationBuilder(env.obs_spec)
    r0 = env.sim.last
    assert np.array_equal(obs, builder.reset(r0.pulse_energies[0], r0.power[0], r0.setpoints_fs[0]))
    rng = np.random.default_rng(0)
    for d in range(10):
        action = rng.uniform(-1, 1, STAGE).astype(np.float32)
        obs, *_ = env.step(action)
        r = steps[-1][1]  # the decision's last reading, after k simulator steps
        assert len(steps) == (d + 1) * k
        expected = builder.step(r.pulse_energies[0], r.power[0], r.setpoints_fs[0], action)
        assert np.array_equal(obs, expected)


def test_auto_holds_each_episode_for_its_own_drawn_latency():
    env = OpsEnv(
        stage=STAGE,
        mode="hard",
        realism="lab",
        rig_randomize={"latency_steps": (0, 2)},
        hold_steps=0,
    )
    seen = set()
    for seed in range(12):
        env.reset(seed=seed)
        latency = env.rig["latency_steps"]
        assert env.hold_steps == latency + 1 and env.sim.config.latency_steps == latency
        env.step(np.zeros(STAGE, dtype=np.float32))
        assert int(env.sim.step_count[0]) == latency + 1
        seen.add(latency)
    assert seen == {0, 1, 2}


def test_the_trained_env_and_the_held_runner_give_the_policy_the_same_observations():
    """n5_hard (history 4) on the lab rig, hold auto (latency 1: 2 readings per decision): the
    held vector env (training's view) and HeldRunner on every reading (evaluate's and the
    node's view) give the same observations, hence the same actions, on the same seed."""
    loaded = load_policy(MODELS / "n5_hard")
    cfg = make_config(STAGE, "hard", "test", realism="lab", episode_steps=200)
    options = observation_spec_of(loaded.metadata).options()
    n, k = 4, 2
    held_env = OpsVectorEnv.from_config(
        cfg, num_envs=n, max_episode_steps=200, observation_options=options, hold_steps=0
    )
    assert held_env.hold_steps == k
    every = OpsVectorEnv.from_config(cfg, num_envs=n, max_episode_steps=200)
    runner = build_runner(loaded, num_envs=n, hold_steps=k)
    assert isinstance(runner, HeldRunner)
    obs, _ = held_env.reset(seed=8301)
    every.reset(seed=8301)
    runner.restart()
    for t in range(200):
        r = every.sim.last
        action = runner.act(r.pulse_energies, r.power, r.setpoints_fs, r.applied_fs)
        if t % k == 0:  # a decision: the env's observation is the runner's
            assert np.array_equal(runner.runner.last_observation, obs)
            mine = loaded.predict(obs)
            assert np.array_equal(action, mine)
            obs, *_ = held_env.step(mine)
        every.step(action)
    assert np.array_equal(held_env.sim.last.power, every.sim.last.power)
    # The two rollouts of evaluation agree to the last reading.
    via_env = rollout_policy(loaded.predict, cfg, n, 200, 8302, options, hold_steps=k)
    via_runner = rollout_runner(build_runner(loaded, num_envs=n, hold_steps=k), cfg, n, 200, 8302)
    assert via_env["power"].shape == (n, 101) and via_runner["power"].shape == (n, 201)
    assert np.array_equal(via_env["power"], via_runner["power"][:, ::k])


def _model_with_hold(tmp_path: Path, hold) -> Path:
    """models/n5_hard copied, with ``hold_steps`` in its metadata."""
    out = tmp_path / f"held_{hold}"
    out.mkdir()
    shutil.copy2(MODELS / "n5_hard" / "model.zip", out / "model.zip")
    meta = json.loads((MODELS / "n5_hard" / "metadata.json").read_text())
    (out / "metadata.json").write_text(json.dumps({**meta, "hold_steps": hold}))
    return out


EVAL = ["--mode", "hard", "--splits", "test", "--seeds", "8301", "--episodes", "4"]
EVAL += ["--no-plot", "--quiet", "--steps", "60"]


def _evaluate(model: Path, out: Path, *extra: str) -> dict:
    assert evaluate.run([str(model), *EVAL, "--out", str(out), *extra]) == 0
    return json.loads((out / "evaluation.json").read_text())


def test_evaluate_holds_a_model_as_its_metadata_says_unless_told_otherwise(tmp_path):
    fixed = _model_with_hold(tmp_path, 2)
    default = _evaluate(fixed, tmp_path / "default", "--realism", "lab")
    told = _evaluate(MODELS / "n5_hard", tmp_path / "told", "--realism", "lab", "--hold-steps", "2")
    assert default["hold_steps"] == 2
    finals = [r["splits"]["test"]["final_power_per_episode"] for r in (default, told)]
    assert finals[0] == finals[1]
    bare = _evaluate(fixed, tmp_path / "bare", "--realism", "lab", "--hold-steps", "1")
    assert "hold_steps" not in bare  # an explicit value overrides the model's
    auto = _model_with_hold(tmp_path, 0)  # auto: the told latency + 1
    assert _evaluate(auto, tmp_path / "auto", "--realism", "lab")["hold_steps"] == 2
    assert _evaluate(auto, tmp_path / "ideal")["hold_steps"] == 1  # ideal rig: every reading
    assert "hold_steps" not in _evaluate(MODELS / "n5_hard", tmp_path / "old")  # no entry: 1
    bad = _model_with_hold(tmp_path, -3)
    with pytest.raises(PolicyLoadError, match=r"hold_steps must be 0 \(auto"):
        read_metadata(bad)


def _train(*args) -> int:
    return train.run([*map(str, args)])


def test_train_saves_the_hold_and_resume_and_init_from_keep_it(tmp_path, capsys):
    out = tmp_path / "held"
    code = _train(
        "--algo", "sac", "--stage", 2, "--mode", "hard", "--timesteps", 120, "--n-envs", 2,
        "--realism", "lab", "--rig-randomize", "latency_steps=0:2", "--hold-steps", "auto",
        "--eval-freq", 100, "--eval-episodes", 2, "--out", out, "--no-progress",
        "--hyperparams", *FAST,
    )  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "hold_steps=auto" in printed and "(use --obs-history" not in printed
    assert "evaluation (test, 2 episodes)" in printed
    meta = read_metadata(out)
    assert meta["hold_steps"] == 0 and read_metadata(out / "best")["hold_steps"] == 0
    assert meta["timesteps"] == 120  # decisions
    assert _train("--resume", "--out", out, "--timesteps", 20, "--no-progress") == 0
    assert read_metadata(out)["hold_steps"] == 0
    code = _train("--resume", "--out", out, "--hold-steps", 3, "--timesteps", 10)
    assert code == 2 and "--hold-steps 3 differs from the model's 0" in capsys.readouterr().err
    tuned = tmp_path / "tuned"
    assert _train("--init-from", out, "--out", tuned, "--timesteps", 20, "--no-progress") == 0
    assert read_metadata(tuned)["hold_steps"] == 0  # the task's hold, by default the model's
    fixed = tmp_path / "fixed"
    code = _train(
        "--init-from", out, "--out", fixed, "--hold-steps", 3, "--timesteps", 20, "--no-progress",
        "--hyperparams", "learning_rate=0.0002", "--eval-freq", 1000, "--eval-episodes", 1,
    )  # fmt: skip
    assert code == 0 and read_metadata(fixed)["hold_steps"] == 3
    # A fine-tune is evaluated before its first step (DIR/best: never worse than its start)
    # and learns at the rate it is given (SB3's load kept the stored one).
    assert "[train] step 140: evaluation (test, 1 episodes)" in capsys.readouterr().out
    assert read_metadata(fixed / "best")["timesteps"] == 140
    assert load_policy(fixed).model.learning_rate == pytest.approx(0.0002)
    plain = tmp_path / "plain"
    code = _train(
        "--algo", "sac", "--stage", 2, "--mode", "easy", "--timesteps", 20, "--out", plain,
        "--no-progress", "--hyperparams", *FAST,
    )  # fmt: skip
    assert code == 0 and read_metadata(plain)["hold_steps"] == 1


def test_bad_hold_steps_are_refused_with_a_clear_message(tmp_path, capsys):
    for bad in ("-1", "1002", "1.5", "some"):
        with pytest.raises(SystemExit) as exc:
            _train("--out", tmp_path / "bad", "--hold-steps", bad)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "--hold-steps must be auto (or 0" in err and "from 1 to 1001" in err
    code = _train("--out", tmp_path / "ros", "--backend", "ros", "--hold-steps", 2)
    assert code == 2
    assert "--hold-steps holds each decision in the simulator" in capsys.readouterr().err
    assert not (tmp_path / "ros" / "model.zip").exists()
