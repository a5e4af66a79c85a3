"""The benchmark's protocol: agents and controllers on the same episodes, training through
``train``'s own steps (what a user's ``ros2 run ops_gym_bridge train`` does)."""

from __future__ import annotations

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_experiments.rollouts import controller_episodes, episode_seed, policy_episodes
from ops_experiments.summary import summarize
from ops_experiments.table1 import bench_worker

from ops_experiments import learn
from ops_sim_ros import OpsEnv

pytestmark = pytest.mark.timeout(180)


def test_agents_and_controllers_run_the_same_episodes():
    """A policy that holds still sees exactly what holding the set-points with absolute commands
    (a controller's way) sees: same initial delay errors, same noise and drift draws."""
    cfg = make_config(stage=3, mode="hard", split="test", episode_steps=30)
    held = policy_episodes(lambda obs: np.zeros((len(obs), 3)), cfg, 4, 30, seed=2)["power"]
    for e in range(4):
        env = OpsEnv.from_config(cfg, max_episode_steps=30)
        _, info = env.reset(seed=episode_seed(2, e))
        powers = [info["power"]]
        for _ in range(30):
            powers.append(float(env.step_setpoints(np.zeros(3)).power[0]))
        np.testing.assert_array_equal(held[e], powers)
    assert len(set(held[:, 0])) == 4  # four different episodes
    assert not np.allclose(held[:, 0], held[:, -1])  # the drift moved them
    nominal = make_config(stage=3)
    env = OpsEnv.from_config(cfg, max_episode_steps=30)
    spgd = controller_episodes(env, "spgd", {}, nominal, 4, 30, seed=2)["power"]
    np.testing.assert_array_equal(spgd[:, 0], held[:, 0])  # the same starts


def test_benchmark_trains_through_train(tmp_path, monkeypatch):
    """bench_worker.train builds through experiments.build.build_model and trains with
    learn_and_save, as train does (no loop of its own): the model directory is train's, with the
    run's observation set."""
    calls = []
    learn_and_save = learn.learn_and_save

    def counted(run):
        calls.append(run.args)
        return learn_and_save(run)

    monkeypatch.setattr(learn, "learn_and_save", counted)
    spec = {
        "id": "n2_easy_td3_s0", "kind": "train", "algo": "td3", "stage": 2, "mode": "easy",
        "seed": 0, "timesteps": 300, "episode_steps": 50, "detector": "total",
        "observation": "authors", "save_every": 10_000,
        "hyperparams": ["learning_starts=100", "batch_size=32", "net_arch=[16,16]"],
        "eval": {"seeds": [0], "episodes": 2, "steps": 10},
    }  # fmt: skip
    policy = bench_worker.train(spec, tmp_path)
    model, meta = policy.model, policy.metadata
    assert len(calls) == 1 and calls[0].observation == "authors"
    assert meta["command_line"][:4] == ["ros2", "run", "ops_gym_bridge", "train"]
    assert meta["hyperparams_set"] == "paper" and meta["observation"] == "authors"
    assert meta["config"]["detector"] == "total" and meta["timesteps"] == 300
    assert model.observation_space.shape == (1 + 3 + 2,)
    rows = (tmp_path / "training.csv").read_text().splitlines()
    assert len(rows) == 1 + 300 // 50  # a row per finished training episode
    # Resuming a finished run trains nothing more.
    bench_worker.train(spec, tmp_path)
    assert len(calls) == 1


def test_benchmark_trains_with_the_named_hyperparameter_set(tmp_path):
    """--hyperparams-set authors reaches train: the run's metadata names the set and holds the
    authors' code's values (SAC: lr 3e-4, 100k buffer, no gSDE, three layers), overrides on top."""
    from ops_experiments.table1 import benchmark

    args = benchmark.build_parser().parse_args(
        ["--profile", "smoke", "--algos", "sac", "--modes", "easy", "--controllers",
         "--extra-stages", "--observation", "authors", "--hyperparams-set", "authors"]
    )  # fmt: skip
    (spec,) = benchmark.plan(args)
    assert spec["hyperparams_set"] == "authors"
    spec = {**spec, "timesteps": 150, "hyperparams": ["learning_starts=50", "batch_size=16"]}
    argv = bench_worker.train_argv(spec, tmp_path, resume=False, remaining=150)
    assert argv[argv.index("--hyperparams-set") + 1] == "authors"
    meta = bench_worker.train(spec, tmp_path).metadata
    hp = meta["hyperparams"]
    assert meta["hyperparams_set"] == "authors"
    assert hp["learning_rate"] == 3e-4 and hp["buffer_size"] == 100_000
    assert hp["use_sde"] is False and hp["net_arch"] == [256, 256, 256]
    assert hp["batch_size"] == 16  # the profile's override on top of the set


def _stored_run(root, observation, kind, name, final, seed=0, timesteps=100):
    """A stored run as benchmark writes it (run.json + evaluation.json), final P_N given."""
    rid = f"n5_easy_{name}" + (f"_s{seed}" if kind == "train" else "")
    d = root / "runs" / rid
    d.mkdir(parents=True)
    spec = {"id": rid, "kind": kind, "stage": 5, "mode": "easy", "detector": "total",
            "observation": observation, "seed": seed if kind == "train" else None}  # fmt: skip
    spec["algo" if kind == "train" else "controller"] = name
    spec["timesteps"] = timesteps
    power = np.full((3, 11), final)
    returns = np.zeros(3)
    split = summarize([{"power": power, "returns": returns}, {"power": power, "returns": returns}])
    ev = {"splits": {"train": split, "test": split}, "transfer": {}}
    bench_worker.write_json(d / "run.json", {"spec": spec, "timesteps": timesteps})
    bench_worker.write_json(d / "evaluation.json", ev)


def test_report_puts_two_observation_sets_side_by_side(tmp_path):
    from ops_experiments.table1 import report

    for label, observation, td3 in (("authors", "authors", 0.9), ("rig", "rig", 0.2)):
        _stored_run(tmp_path / label, observation, "train", "td3", td3)
        _stored_run(tmp_path / label, observation, "controller", "spgd", 0.5)
    out = tmp_path / "out"
    assert report.run([str(tmp_path / "authors"), str(tmp_path / "rig"), "--out", str(out)]) == 0
    for label in ("authors", "rig"):
        assert (out / label / "table1.csv").exists() and (out / label / "fig8_control.png").exists()
        assert f"observation set of the agents `{label}`" in (out / label / "table1.md").read_text()
    text = (out / "table1_sets.md").read_text()
    assert "| authors (authors) | rig (rig) |" in text
    td3_test = [ln for ln in text.splitlines() if ln.startswith("| easy | testing | TD3 |")]
    assert td3_test == ["| easy | testing | TD3 | 0.9541 ± 0.0177 | 0.9000 ± 0.0000 (n=1) | "
                        "0.2000 ± 0.0000 (n=1) |"]  # fmt: skip


def test_report_pools_one_protocols_seeds_from_several_directories(tmp_path):
    """--pool: seeds of one cell stored in two directories make one cell over all of them; a
    repeated run id, or a cell whose runs differ in protocol, is refused (exit 2)."""
    from ops_experiments.table1 import report

    _stored_run(tmp_path / "first", "authors", "train", "td3", 0.9, seed=0)
    _stored_run(tmp_path / "first", "authors", "train", "td3", 0.8, seed=1)
    _stored_run(tmp_path / "more", "authors", "train", "td3", 0.4, seed=2)
    dirs = [str(tmp_path / "first"), str(tmp_path / "more")]
    assert report.run([*dirs, "--pool", "--out", str(tmp_path / "out")]) == 0
    text = (tmp_path / "out" / "table1.md").read_text()
    assert "| easy | testing | 0.7000 ± 0.2160 (n=3) | 0.9541 ± 0.0177 |" in text
    assert not (tmp_path / "out" / "table1_sets.md").exists()

    _stored_run(tmp_path / "again", "authors", "train", "td3", 0.5, seed=1)
    argv = [dirs[0], str(tmp_path / "again"), "--pool", "--out", str(tmp_path / "o2")]
    assert report.run(argv) == 2  # n5_easy_td3_s1 twice
    _stored_run(tmp_path / "longer", "authors", "train", "td3", 0.5, seed=3, timesteps=900)
    argv = [dirs[0], str(tmp_path / "longer"), "--pool", "--out", str(tmp_path / "o3")]
    assert report.run(argv) == 2  # 100 and 900 steps in one cell


def test_the_rig_of_a_benchmark_reaches_training_evaluation_and_controllers(tmp_path):
    """benchmark --realism / --rig: every run's spec holds the rig; training runs get it on
    their command line, evaluations and the controllers' nominal model in their config."""
    from ops_experiments.table1 import benchmark

    args = benchmark.build_parser().parse_args(
        ["--profile", "smoke", "--algos", "td3", "--modes", "hard", "--controllers", "tracker",
         "--extra-stages", "--realism", "lab", "--rig", "latency_steps=2"]
    )  # fmt: skip
    specs = benchmark.plan(args)
    assert specs and all(s["rig"] == {"latency_steps": 2, "realism": "lab"} for s in specs)
    train = next(s for s in specs if s["kind"] == "train")
    argv = bench_worker.train_argv(train, tmp_path, resume=False, remaining=100)
    assert argv[argv.index("--realism") + 1] == "lab"
    assert argv[argv.index("--rig") + 1] == "latency_steps=2"
    overrides = bench_worker.env_overrides(train)
    assert overrides["latency_steps"] == 2 and overrides["realism"] == "lab"
    assert benchmark.run(["--list", "--rig", "trace_adc_bits=0.5", "--out", str(tmp_path)]) == 2


def test_the_benchmark_evaluates_a_held_model_with_its_hold(tmp_path):
    """A model trained with ``train --hold-steps 2`` decides on one reading in two in the
    benchmark's evaluation, as ``evaluate`` holds it (one resolution: evaluate.with_hold); one
    without the entry decides on every reading, as before."""
    import dataclasses

    from ops_controller_ros.policy_io import load_policy

    from ops_experiments import train

    out = tmp_path / "held"
    code = train.run(
        ["--algo", "sac", "--stage", "2", "--mode", "hard", "--timesteps", "60", "--seed", "0",
         "--hold-steps", "2", "--out", str(out), "--no-progress",
         "--hyperparams", "learning_starts=40", "batch_size=32", "net_arch=[16,16]"]
    )  # fmt: skip
    assert code == 0
    held = load_policy(out)
    assert held.metadata["hold_steps"] == 2
    spec = {
        "algo": "sac", "stage": 2, "mode": "hard", "detector": held.metadata["config"]["detector"],
        "transfer_modes": ["medium"], "eval": {"seeds": [0], "episodes": 2, "steps": 20},
    }  # fmt: skip
    result = bench_worker.evaluate_run(spec, held)
    assert result["hold_steps"] == 2
    subject = bench_worker.subject_of(spec, held)
    assert subject.hold_steps == 2 and subject.with_mode("medium").hold_steps == 2
    # The very episodes of the held subject, and not those of the bare policy.
    again = subject.evaluate(("test",), [0], 2, 20)["test"]
    assert result["splits"]["test"]["curve_mean"] == again["curve_mean"]
    bare = dataclasses.replace(subject, hold_steps=1).evaluate(("test",), [0], 2, 20)["test"]
    assert bare["curve_mean"] != again["curve_mean"]
    # Without the entry (every model from before the option): every reading, no hold_steps.
    from ops_contract.policy_meta import PolicyMeta

    entries = {k: v for k, v in held.metadata.items() if k != "hold_steps"}
    old = dataclasses.replace(held, meta=PolicyMeta.from_dict(entries, path=held.path))
    plain = bench_worker.evaluate_run(spec, old)
    assert "hold_steps" not in plain and bench_worker.subject_of(spec, old).hold_steps == 1
    assert plain["splits"]["test"]["curve_mean"] == bare["curve_mean"]
    # Figure 17's traces: the held model holds there too, and on the run's rig.
    traced = bench_worker.evaluate_run({**spec, "traces": True}, held)["traces"]
    assert traced["steps"] == sorted(bench_worker.TRACE_STEPS)  # every one even: a decision
    assert traced != bench_worker.record_traces(held, spec, hold_steps=1)
    coarse = bench_worker.record_traces(
        held, {**spec, "rig": {"trace_adc_bits": 3, "trace_full_scale": 1.25}}, hold_steps=2
    )
    levels = np.unique(np.round(np.concatenate(coarse["trace"]), 4))
    assert 1 < levels.size <= 2**3  # the run's 3-bit digitizer drew them
