"""train / evaluate command lines with real stable-baselines3 training, in-process backend."""

from __future__ import annotations

import contextlib
import csv
import importlib
import io
import json
import re
import shutil
import signal
import subprocess

import numpy as np
import pytest
from ops_bench.processes import executable
from ops_controller_ros.policy_io import PolicyLoadError, check_stage, load_policy, read_metadata
from ops_experiments.progress_log import read_progress

from ops_sim_ros import OpsEnv

pytestmark = pytest.mark.timeout(180)

# Small network and early learning so that a few thousand steps take seconds on 2 cores.
FAST = ["learning_starts=200", "net_arch=[64,64]", "batch_size=64", "checkpoint_freq=500"]


_COMMANDS = {"train": "ops_experiments.train", "evaluate": "ops_experiments.evaluate"}


def run_command(exe: str, *args, timeout=150) -> subprocess.CompletedProcess:
    """``ros2 run ops_gym_bridge EXE ARGS`` as a user types it, in a new process."""
    return subprocess.run(
        [*executable("ops_gym_bridge", exe), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def run(exe: str, *args) -> subprocess.CompletedProcess:
    """The same command's ``run(argv)`` (what its ``main`` calls) in this process, its output
    captured: no new interpreter importing torch and stable-baselines3 again (3-5 s each). The
    command lines themselves run in new processes in ``trained`` and the Ctrl-C test."""
    module = importlib.import_module(_COMMANDS[exe])
    argv = list(map(str, args))
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = module.run(argv)
        except SystemExit as exc:  # argparse's refusals
            code = exc.code if isinstance(exc.code, int) else 1
    return subprocess.CompletedProcess([exe, *argv], code, out.getvalue(), err.getvalue())


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("train") / "sac_n3"
    done = run_command(
        "train",
        "--algo",
        "sac",
        "--stage",
        3,
        "--mode",
        "easy",
        "--timesteps",
        1500,
        "--seed",
        5,
        "--out",
        out,
        "--no-progress",
        "--hyperparams",
        *FAST,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "Traceback" not in done.stderr
    assert "[train] done: 1500 steps" in done.stdout
    return out


def test_output_directory_and_metadata(trained):
    assert (trained / "model.zip").is_file()
    assert (trained / "replay_buffer.pkl").is_file()
    assert (trained / "logs" / "progress.csv").is_file()
    assert list((trained / "logs").glob("events.out.tfevents.*"))
    ckpts = sorted((trained / "checkpoints").glob("model_*_steps.zip"))
    assert [c.name for c in ckpts] == [
        "model_1000_steps.zip",
        "model_1500_steps.zip",
        "model_500_steps.zip",
    ]
    meta = read_metadata(trained)
    env = OpsEnv(stage=3, mode="easy")
    assert meta["algo"] == "sac" and meta["stage"] == 3 and meta["mode"] == "easy"
    assert meta["split"] == "train" and meta["action_type"] == "increment"
    assert meta["timesteps"] == 1500 and meta["seed"] == 5 and meta["backend"] == "inprocess"
    assert meta["max_step_fs"] == pytest.approx(env.config.max_step_fs)
    assert meta["observation_spec"] == env.obs_spec.to_dict()
    assert meta["config"] == env.config.to_dict()
    assert meta["normalization"] is None
    assert meta["hyperparams"]["learning_starts"] == 200
    assert meta["hyperparams"]["net_arch"] == [64, 64]
    assert meta["hyperparams"]["gamma"] == 0.98  # the paper's value, not overridden
    assert meta["command_line"][:4] == ["ros2", "run", "ops_gym_bridge", "train"]
    assert "--timesteps" in meta["command_line"]
    assert set(meta["versions"]) >= {"python", "numpy", "torch", "stable_baselines3", "gymnasium"}
    # The checkpoints load with the same reader, each with its own step count.
    checkpoint = trained / "checkpoints" / "model_500_steps.zip"
    assert load_policy(checkpoint).stage == 3
    assert read_metadata(checkpoint)["timesteps"] == 500
    assert read_metadata(trained / "checkpoints" / "model_1000_steps.zip")["timesteps"] == 1000


def test_model_loads_and_runs_and_stage_is_checked(trained):
    loaded = load_policy(trained)
    assert loaded.model.num_timesteps == 1500
    env = OpsEnv(stage=3, mode="easy")
    obs, _ = env.reset(seed=0)
    for _ in range(20):
        action = loaded.predict(obs)
        assert action.shape == (3,) and np.all(np.abs(action) <= 1)
        obs, *_ = env.step(action)
    check_stage(loaded, 3)
    with pytest.raises(
        PolicyLoadError, match=r"model .*sac_n3 was trained for stage 3, the simulator runs stage 5"
    ):
        check_stage(loaded, 5)


def test_evaluate_writes_json_csv_png(trained, tmp_path):
    out = tmp_path / "eval"
    done = run("evaluate", trained, "--seeds", 0, 1, "--episodes", 3, "--steps", 40, "--out", out)
    assert done.returncode == 0, done.stdout + done.stderr
    assert re.search(r"train\s+0\.\d{4} ± 0\.\d{4}", done.stdout), done.stdout
    res = json.loads((out / "evaluation.json").read_text())
    assert res["controller"] == "sac" and res["stage"] == 3 and res["mode"] == "easy"
    for split in ("train", "test"):
        s = res["splits"][split]
        assert len(s["curve_mean"]) == 41 and len(s["final_power_per_seed"]) == 2
        assert 0.0 <= s["final_power_mean"] <= 1.0
        # (curves stored to 5 decimals, per-seed values to 6: experiments.summary)
        assert s["final_power_mean"] == pytest.approx(s["curve_mean"][-1], abs=1e-5)
        assert s["final_power_std"] == pytest.approx(np.std(s["final_power_per_seed"]), abs=1e-5)
        worst = min(s["final_power_per_episode"])  # the worst episode beside the mean
        assert len(s["final_power_per_episode"]) == 6
        assert s["final_power_min_episode"] == pytest.approx(worst, abs=1e-6)
    rows = list(csv.DictReader((out / "curve.csv").read_text().splitlines()))
    assert len(rows) == 2 * 41 and rows[0]["step"] == "0"
    assert (out / "curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_evaluate_transfer_to_another_mode_and_refused_stage(trained, tmp_path):
    done = run(
        "evaluate",
        trained,
        "--mode",
        "hard",
        "--splits",
        "test",
        "--seeds",
        0,
        "--episodes",
        2,
        "--steps",
        20,
        "--out",
        tmp_path / "hard",
        "--no-plot",
    )
    assert done.returncode == 0, done.stderr
    res = json.loads((tmp_path / "hard" / "evaluation.json").read_text())
    assert res["mode"] == "hard" and res["trained_mode"] == "easy"
    assert list(res["splits"]) == ["test"]
    done = run("evaluate", trained, "--stage", 4, "--out", tmp_path / "s4")
    assert done.returncode == 2
    assert "sac_n3 was trained for stage 3, the evaluation's simulator" in done.stderr
    assert "runs stage 4" in done.stderr
    assert "Traceback" not in done.stderr


def test_evaluate_spgd_baseline(tmp_path):
    done = run(
        "evaluate",
        "--spgd",
        "--stage",
        2,
        "--mode",
        "medium",
        "--seeds",
        0,
        1,
        "--episodes",
        2,
        "--out",
        tmp_path / "spgd",
        "--no-plot",
    )
    assert done.returncode == 0, done.stdout + done.stderr
    res = json.loads((tmp_path / "spgd" / "evaluation.json").read_text())
    assert res["controller"] == "spgd"
    s = res["splits"]["train"]
    assert s["final_power_mean"] > s["initial_power_mean"]  # SPGD climbs


def test_resume_continues_the_step_count(trained, tmp_path):
    """A resumed run continues its step count and its learning curve (the first part's log is
    kept, not overwritten), and --hyperparams' learning rate applies from the resume on."""
    out = tmp_path / "resumed"
    shutil.copytree(trained, out)
    first_part = (out / "logs" / "progress.csv").read_text()
    done = run(
        "train", "--resume", "--out", out, "--timesteps", 400, "--no-progress",
        "--hyperparams", "learning_rate=0.00012",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "resuming sac from model.zip at step 1500" in done.stdout
    assert "[train] done: 1900 steps (400 new)" in done.stdout
    meta = read_metadata(out)
    assert meta["timesteps"] == 1900 and len(meta["history"]) == 2
    assert meta["stage"] == 3 and meta["hyperparams"]["net_arch"] == [64, 64]
    assert meta["hyperparams"]["learning_rate"] == pytest.approx(0.00012)
    model = load_policy(out).model
    assert model.num_timesteps == 1900
    assert model.lr_schedule(1.0) == pytest.approx(0.00012)
    assert (out / "logs" / "progress.part1.csv").read_text() == first_part
    rows = [r for r in read_progress(out / "logs") if r.get("time/total_timesteps")]
    steps = [int(float(r["time/total_timesteps"])) for r in rows]
    minutes = [r["minutes"] for r in rows]
    assert steps[0] <= 1500 < steps[-1] == 1900 and steps == sorted(steps)
    assert minutes == sorted(minutes)
    # A resume cannot change what the model is.
    done = run("train", "--resume", "--out", out, "--stage", 5, "--timesteps", 10)
    assert done.returncode == 2 and "--stage 5 differs from the model's 3" in done.stderr


def test_init_from_fine_tunes_with_another_task(trained, tmp_path):
    """--init-from: the weights and what the model is (algo, stage, observation, hyper-
    parameters) come from the initial model; the task may change (here: mode and episode
    length); the initial model is left as it was."""
    before = (trained / "model.zip").read_bytes()
    out = tmp_path / "tuned"
    done = run(
        "train", "--init-from", trained, "--out", out, "--mode", "hard", "--episode-steps", 100,
        "--timesteps", 300, "--no-progress",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "fine-tuning sac from" in done.stdout and "step 1500" in done.stdout
    meta = read_metadata(out)
    assert meta["mode"] == "hard" and meta["episode_steps"] == 100
    assert meta["stage"] == 3 and meta["hyperparams"]["net_arch"] == [64, 64]
    assert meta["timesteps"] >= 1800  # the step count continues
    assert meta["history"][-2]["init_from"] == str(trained.resolve())
    assert (trained / "model.zip").read_bytes() == before
    # What the model is cannot change; nor can a fine-tune start from nothing.
    done = run("train", "--init-from", trained, "--out", tmp_path / "x", "--stage", 5)
    assert done.returncode == 2 and "--stage 5 differs from the model's 3" in done.stderr
    done = run("train", "--init-from", tmp_path / "nothing", "--out", tmp_path / "y")
    assert done.returncode == 2 and "--init-from" in done.stderr
    assert "Traceback" not in done.stderr


def test_ship_model_ships_a_checkpoint_and_the_curve_of_the_model_it_started_from(
    trained, tmp_path
):
    """`ops-bench ship-model --checkpoint STEPS --after LEARNING_CSV`: the checkpoint becomes a
    model folder whose metadata gives its own step count, and the learning curve starts with
    the earlier model's evaluations before the fine-tune's first step."""
    out = tmp_path / "tuned"
    done = run(
        "train", "--init-from", trained, "--out", out, "--timesteps", 400, "--eval-freq", 200,
        "--eval-episodes", 1, "--no-progress", "--hyperparams", "checkpoint_freq=200",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    earlier = tmp_path / "earlier.csv"
    earlier.write_text(
        "minutes,env_steps,test_final_power\n"
        "1.00,500,0.1000\n2.00,1000,0.2000\n3.00,1400,0.3000\n9.00,1600,0.9000\n"
    )
    ship = [shutil.which("ops-bench"), "ship-model", out, tmp_path / "model"]
    ship += ["--seeds", 100, "--episodes", 1]
    done = subprocess.run(
        [*map(str, ship), "--checkpoint", "1700", "--after", str(earlier)],
        capture_output=True, text=True, timeout=150, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    dest = tmp_path / "model"
    assert (dest / "model.zip").read_bytes() == (
        out / "checkpoints" / "model_1700_steps.zip"
    ).read_bytes()
    meta = read_metadata(dest)
    assert meta["timesteps"] == 1700 and "checkpoint" not in meta and meta["mode"] == "easy"
    assert load_policy(dest).model.num_timesteps == 1700
    with open(dest / "learning.csv", newline="") as f:
        rows = [(float(r["minutes"]), int(r["env_steps"])) for r in csv.DictReader(f)]
    assert rows[:3] == [(1.0, 500), (2.0, 1000), (3.0, 1400)]  # the earlier curve, to step 1500
    own = rows[3:]
    assert [steps for _, steps in own] == [1500, 1700, 1900]  # at the start, then every 200
    assert all(minutes >= 3.0 for minutes, _ in own)  # counted on from the earlier curve
    assert (dest / "eval" / "evaluation.json").is_file()
    # A checkpoint the run does not have is named, with the ones it has.
    done = subprocess.run(
        [*map(str, ship), "--checkpoint", "1234"], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 2 and "model_1234_steps.zip" in done.stderr
    assert "1700, 1900" in done.stderr and "Traceback" not in done.stderr


def test_a_fine_tune_fills_its_new_buffer_with_its_own_actions_before_updating(trained, tmp_path):
    """A fine-tune starts with an empty replay buffer: for learning_starts steps it acts with
    the model it starts from and makes no update (the weights stay the initial ones), then
    learns with the model's own number of gradient steps."""
    from stable_baselines3 import SAC

    out = tmp_path / "warm"
    done = run(
        "train", "--init-from", trained, "--out", out, "--timesteps", 300, "--no-progress",
        "--hyperparams", "learning_starts=300",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "fine-tune: 300 steps of the model's own actions" in done.stdout
    before, after = SAC.load(trained / "model.zip"), SAC.load(out / "model.zip")
    for name, value in before.policy.state_dict().items():
        assert np.array_equal(value.numpy(), after.policy.state_dict()[name].numpy()), name
    assert after.gradient_steps == before.gradient_steps == 1
    after.load_replay_buffer(out / "replay_buffer.pkl")
    assert after.replay_buffer.size() == 300
    # Past the warm-up it learns: the weights move.
    done = run(
        "train", "--init-from", trained, "--out", tmp_path / "learns", "--timesteps", 400,
        "--no-progress", "--hyperparams", "learning_starts=300",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    moved = SAC.load(tmp_path / "learns" / "model.zip").policy.state_dict()
    initial = before.policy.state_dict()
    assert any(not np.array_equal(v.numpy(), moved[k].numpy()) for k, v in initial.items())


def test_a_fine_tune_with_critic_warmup_keeps_the_actor_while_the_critic_learns(trained, tmp_path):
    """--hyperparams critic_warmup=K: after the warm buffer only the critic learns for K steps
    (the actor's weights and SAC's entropy coefficient stay the initial ones); the step that
    ends it is stored, so a resumed run keeps it, and past it the actor learns."""
    from stable_baselines3 import SAC

    out = tmp_path / "critic"
    done = run(
        "train", "--init-from", trained, "--out", out, "--timesteps", 400, "--no-progress",
        "--hyperparams", "learning_starts=100", "critic_warmup=1000",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "critic warm-up: the actor stays as it is until step 2600" in done.stdout
    before, after = SAC.load(trained / "model.zip"), SAC.load(out / "model.zip")
    actor0, actor1 = before.actor.state_dict(), after.actor.state_dict()
    assert all(np.array_equal(v.numpy(), actor1[k].numpy()) for k, v in actor0.items())
    critic0, critic1 = before.critic.state_dict(), after.critic.state_dict()
    assert any(not np.array_equal(v.numpy(), critic1[k].numpy()) for k, v in critic0.items())
    # SAC's entropy coefficient is held with the actor (left free, it grew against the frozen
    # actor and, released, drove it to a random policy)
    assert after.log_ent_coef.item() == before.log_ent_coef.item()
    assert read_metadata(out)["hyperparams"]["actor_frozen_until"] == 2600
    # Resumed past the warm-up's end, the actor learns.
    done = run(
        "train", "--resume", "--out", out, "--timesteps", 800, "--no-progress",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "critic warm-up done at step 2600" in done.stdout
    moved = SAC.load(out / "model.zip").actor.state_dict()
    assert any(not np.array_equal(v.numpy(), moved[k].numpy()) for k, v in actor0.items())


def test_long_run_training_options_are_saved_and_checked(trained, tmp_path):
    """--continue-prob (episodes that carry on the same run) and --setpoint-window (set-points
    re-centred by whole cycles) reach the envs and the metadata; a fine-tune keeps them unless
    told otherwise; impossible values are refused before training."""
    out = tmp_path / "long"
    done = run(
        "train", "--init-from", trained, "--out", out, "--n-envs", 4, "--episode-steps", 50,
        "--continue-prob", 0.5, "--setpoint-window", 1, "--timesteps", 400, "--no-progress",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "setpoint_window=1 continue_prob=0.5" in done.stdout
    meta = read_metadata(out)
    assert meta["continue_prob"] == 0.5 and meta["n_envs"] == 4
    assert meta["observation_spec"]["setpoint_window_cycles"] == 1.0
    loaded = load_policy(out)
    assert loaded.observation_spec["setpoint_window_cycles"] == 1.0
    again = run(
        "train", "--init-from", out, "--out", tmp_path / "again", "--timesteps", 200,
        "--no-progress",
    )  # fmt: skip
    assert again.returncode == 0, again.stdout + again.stderr
    meta = read_metadata(tmp_path / "again")
    assert meta["continue_prob"] == 0.5 and meta["observation_spec"]["setpoint_window_cycles"] == 1
    done = run("train", "--resume", "--out", out, "--setpoint-window", 2, "--timesteps", 10)
    assert done.returncode == 2 and "--setpoint-window 2 differs from the model's 1" in done.stderr
    for extra, message in (
        (["--continue-prob", 0.5, "--backend", "ros"], "--continue-prob carries a run on"),
        (["--continue-prob", 1.0, "--n-envs", 2], "--continue-prob must be in [0, 1)"),
        (["--setpoint-window", 0.2], "setpoint_window_cycles must be 0 (off) or >= 0.5"),
    ):
        done = run("train", "--out", tmp_path / "bad", "--timesteps", 10, *extra)
        assert done.returncode == 2 and message in done.stderr, done.stderr
        assert "Traceback" not in done.stderr


def test_refuses_to_overwrite_and_bad_hyperparameters(trained, tmp_path):
    done = run("train", "--out", trained, "--timesteps", 10)
    assert done.returncode == 2 and "already holds a model" in done.stderr
    done = run("train", "--out", tmp_path / "x", "--hyperparams", "no_such_knob=3")
    assert done.returncode == 2 and "unknown hyper-parameter 'no_such_knob'" in done.stderr
    assert "Traceback" not in done.stderr


def test_ctrl_c_saves_a_loadable_model(procs, tmp_path):
    out = tmp_path / "interrupted"
    proc = procs.start(
        [
            *executable("ops_gym_bridge", "train"),
            "--algo",
            "td3",
            "--stage",
            "2",
            "--mode",
            "easy",
            "--timesteps",
            "100000",
            "--out",
            str(out),
            "--hyperparams",
            "learning_starts=200",
            "train_freq=10",
            "gradient_steps=10",
            "net_arch=[32,32]",
        ],
        name="train",
    )
    proc.wait_for(r"\[train\] training started", timeout=60)
    # Wait until the progress bar shows learning under way (past learning_starts).
    proc.wait_for(r"\b([3-9]\d\d|\d{4,})/100000\b", timeout=90)
    proc.signal(signal.SIGINT)
    assert proc.wait_exit(60) == 130
    text = proc.output
    assert "Traceback" not in text, text
    assert re.search(r"\[train\] interrupted after \d+ steps", text), text
    meta = read_metadata(out)
    assert meta["interrupted"] is True and 300 <= meta["timesteps"] < 100000
    loaded = load_policy(out)
    assert loaded.model.num_timesteps == meta["timesteps"]
    obs, _ = OpsEnv(stage=2, mode="easy").reset(seed=0)
    assert loaded.predict(obs).shape == (2,)


def test_inprocess_n_envs_uses_the_batched_vector_env():
    from ops_experiments.envs import make_vec_env
    from ops_sim_ros.vec_env import OpsSb3VecEnv
    from stable_baselines3.common.vec_env import VecMonitor

    venv = make_vec_env("inprocess", 3, "easy", n_envs=4, seed=0)
    assert isinstance(venv, VecMonitor) and isinstance(venv.venv, OpsSb3VecEnv)
    assert venv.num_envs == 4
    venv.reset()
    for _ in range(200):
        _, _, dones, infos = venv.step(np.zeros((4, 3), np.float32))
    assert dones.all() and all("episode" in i and "power" in i["episode"] for i in infos)
    venv.close()


def test_authors_observation_is_saved_and_refused_on_the_rig_set(tmp_path):
    """train --observation authors: the set is in the metadata, the model sees the applied delays,
    and evaluate refuses to run it on the rig's observation with a message that says why."""
    out = tmp_path / "td3_authors"
    done = run(
        "train", "--algo", "td3", "--stage", 2, "--mode", "easy", "--timesteps", 300,
        "--observation", "authors", "--out", out, "--no-progress",
        "--hyperparams", "learning_starts=100", "net_arch=[16,16]", "batch_size=32",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    meta = read_metadata(out)
    assert meta["observation"] == "authors"
    assert meta["observation_spec"]["observation"] == "authors"
    refused = run("evaluate", out, "--observation", "rig", "--episodes", 1, "--steps", 5,
                  "--seeds", 0, "--out", tmp_path / "ev_rig")  # fmt: skip
    assert refused.returncode == 2
    assert "trained on the 'authors' observation set" in refused.stderr
    assert "--observation authors" in refused.stderr
    assert not (tmp_path / "ev_rig" / "evaluation.json").exists()
    ok = run("evaluate", out, "--episodes", 1, "--steps", 5, "--seeds", 0,
             "--out", tmp_path / "ev")  # fmt: skip
    assert ok.returncode == 0, ok.stdout + ok.stderr


def test_the_rig_reaches_the_training_environments_and_a_resumed_run_keeps_it(tmp_path):
    """--realism / --rig set the training environments' rig, are printed and saved in the
    metadata (config and rig); --resume without them keeps the model's; a bad figure is
    refused before training."""
    out = tmp_path / "lab"
    done = run(
        "train", "--algo", "td3", "--stage", 2, "--mode", "easy", "--timesteps", 100,
        "--realism", "lab", "--rig", "latency_steps=2", "--out", out, "--no-progress",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "latency_steps=2 realism=lab" in done.stdout
    meta = read_metadata(out)
    assert meta["rig"] == {"latency_steps": 2, "realism": "lab"}
    assert meta["config"]["latency_steps"] == 2 and meta["config"]["trace_adc_bits"] == 8
    again = run("train", "--resume", "--out", out, "--timesteps", 100, "--no-progress")
    assert again.returncode == 0, again.stdout + again.stderr
    assert read_metadata(out)["config"]["latency_steps"] == 2
    bad = run("train", "--out", tmp_path / "bad", "--timesteps", 10, "--rig", "dac_bits=40")
    assert bad.returncode == 2 and "dac_bits must be 0 (an ideal DAC) or from 1 to 32" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_a_resumed_run_keeps_the_physical_time_its_rig_was_given(tmp_path):
    """--rig time_base=seconds step_s=... vibration=lab: the training environments' time, saved
    in the metadata, and kept by --resume without --rig."""
    out = tmp_path / "seconds"
    done = run(
        "train", "--algo", "td3", "--stage", 2, "--mode", "easy", "--timesteps", 100,
        "--rig", "time_base=seconds", "step_s=0.01", "vibration=lab", "--out", out,
        "--no-progress",
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    time_keys = {"time_base": "seconds", "step_s": 0.01, "vibration": "lab"}
    config = read_metadata(out)["config"]
    assert {k: config[k] for k in time_keys} == time_keys
    again = run("train", "--resume", "--out", out, "--timesteps", 100, "--no-progress")
    assert again.returncode == 0, again.stdout + again.stderr
    meta = read_metadata(out)
    assert {k: meta["config"][k] for k in time_keys} == time_keys
    assert {k: meta["rig"][k] for k in time_keys} == time_keys
    assert "step_s=0.01" in again.stdout and "vibration=lab" in again.stdout


def test_a_rig_drawn_per_episode_is_saved_resumed_and_the_model_evaluates_on_lab(tmp_path):
    """--rig-randomize (training on the rig): each training env draws its rig at
    every reset; the ranges are printed and saved in the metadata (rig_randomize, beside the
    fixed rig); --resume keeps them; the model evaluates on the fixed lab rig; a range outside
    the figure's limits is refused (exit 2) naming it and what it may be."""
    out = tmp_path / "lab_random"
    done = run(
        "train", "--algo", "sac", "--stage", 2, "--mode", "hard", "--timesteps", 300,
        "--n-envs", 2, "--obs-history", 2, "--realism", "lab",
        "--rig-randomize", "lab", "latency_steps=0:2", "--out", out, "--no-progress",
        "--hyperparams", *FAST,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "rig_randomize=[actuator_hysteresis=0:0.15" in done.stdout
    assert "latency_steps=0:2" in done.stdout
    assert "(use --obs-history 3 or more)" in done.stdout  # the memory is short of latency 2
    meta = read_metadata(out)
    assert meta["rig_randomize"]["latency_steps"] == [0, 2]
    assert meta["rig_randomize"]["trace_adc_bits"] == [6, 12]
    assert meta["rig"] == {"realism": "lab"} and meta["config"]["latency_steps"] == 1
    again = run("train", "--resume", "--out", out, "--timesteps", 100, "--no-progress")
    assert again.returncode == 0, again.stdout + again.stderr
    assert "latency_steps=0:2" in again.stdout
    assert read_metadata(out)["rig_randomize"] == meta["rig_randomize"]
    assert load_policy(out).model.num_timesteps == 400
    ev = run(
        "evaluate", out, "--realism", "lab", "--mode", "hard", "--splits", "test",
        "--seeds", 0, "--episodes", 1, "--steps", 30, "--out", tmp_path / "eval",
    )  # fmt: skip
    assert ev.returncode == 0, ev.stdout + ev.stderr
    res = json.loads((tmp_path / "eval" / "evaluation.json").read_text())
    assert res["rig"] == {"realism": "lab"}
    assert len(res["splits"]["test"]["final_power_per_episode"]) == 1
    bad = run(
        "train", "--out", tmp_path / "bad", "--timesteps", 10,
        "--rig-randomize", "actuator_hysteresis=0:1.2",
    )  # fmt: skip
    assert bad.returncode == 2, bad.stdout + bad.stderr
    assert "actuator_hysteresis=0:1.2: actuator_hysteresis must be from 0.0 to 0.99" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_a_rig_drawn_per_episode_trains_with_runs_that_carry_on(tmp_path):
    """--rig-randomize with --continue-prob (the recipe that held long runs, on the rig): each
    env carries its run on, with its rig, at some episode ends; both are saved."""
    out = tmp_path / "lab_long"
    done = run(
        "train", "--algo", "sac", "--stage", 2, "--mode", "hard", "--timesteps", 300,
        "--n-envs", 2, "--episode-steps", 20, "--realism", "lab", "--rig-randomize", "lab",
        "--hold-steps", "auto", "--continue-prob", 0.5, "--out", out, "--no-progress",
        "--hyperparams", *FAST,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "continue_prob=0.5" in done.stdout
    meta = read_metadata(out)
    assert meta["continue_prob"] == 0.5 and meta["rig_randomize"]["latency_steps"] == [0, 2]
