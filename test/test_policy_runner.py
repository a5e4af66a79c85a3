"""The learned-policy runner against a real simulator process, with a model really trained by
stable-baselines3 through the training command line."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
from ops_bench.processes import REPO, assert_no_traceback, ros2_command

pytestmark = [pytest.mark.integration, pytest.mark.timeout(300)]


@pytest.fixture(scope="module")
def trained_model(tmp_path_factory):
    """A small PPO model for stage 2, easy mode: a thousand real training steps (it need not be
    good, only real: the runner's job is to load it and close the loop with it)."""
    out = tmp_path_factory.mktemp("model") / "ppo_n2"
    cmd = [
        *ros2_command(),
        "run",
        "ops_gym_bridge",
        "train",
        "--algo",
        "ppo",
        "--stage",
        "2",
        "--mode",
        "easy",
        "--timesteps",
        "1024",
        "--seed",
        "3",
        "--out",
        str(out),
        "--no-progress",
        "--hyperparams",
        "n_steps=256",
        "batch_size=64",
        "n_epochs=2",
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=200)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (out / "model.zip").is_file() and (out / "metadata.json").is_file()
    return out


def policy(procs, model, name="policy"):
    return procs.ros2(
        "run", "ops_controller_ros", "policy", "--ros-args", "-p", f"model:={model}", name=name
    )


def wait_for_moved_setpoints(observer):
    """Until the runner's commands have moved the simulator's set-points."""
    first = observer.last("delays")
    observer.wait_until(
        lambda: (
            observer.last("delays") is not None
            and not np.allclose(observer.last("delays"), first or [0, 0])
        ),
        timeout=20,
        what="set-points moved by the policy",
    )


def test_policy_runner_closes_the_loop(procs, observer, trained_model):
    procs.ros2(
        "run",
        "ops_sim_ros",
        "sim",
        "--ros-args",
        "-p",
        "stage:=2",
        "-p",
        "mode:=easy",
        "-p",
        "seed:=11",
        "-p",
        "rate_hz:=100.0",
        name="sim",
    )
    runner = policy(procs, trained_model)
    runner.wait_for("loaded PPO model for stage 2")
    runner.wait_for("running the policy", timeout=30)
    runner.wait_for(r"step \d+: P_N/P_max", timeout=30)
    # The runner moves the set-points: commands arrive and the sim applies them.
    wait_for_moved_setpoints(observer)
    assert_no_traceback(runner.output)


def test_model_for_another_stage_is_refused(procs, trained_model):
    procs.ros2("run", "ops_sim_ros", "sim", "--ros-args", "-p", "stage:=3", name="sim")
    runner = policy(procs, trained_model)
    assert runner.wait_exit(60) == 1
    assert f"model {trained_model} was trained for stage 2, the simulator runs stage 3" in (
        runner.output
    )
    assert_no_traceback(runner.output)


def test_a_model_set_while_running_is_refused_or_taken(procs, observer, trained_model, tmp_path):
    """``ros2 param set /ops_policy model``: a model for another stage is refused with why and
    the node goes on with its old one; a good one takes over."""
    procs.ros2(
        "run", "ops_sim_ros", "sim", "--ros-args", "-p", "stage:=2", "-p", "mode:=easy", name="sim"
    )
    runner = policy(procs, trained_model)
    runner.wait_for(r"step \d+: P_N/P_max", timeout=60)

    def param_set(model) -> str:
        cmd = [*ros2_command(), "param", "set", "/ops_policy", "model", str(model)]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
        return done.stdout + done.stderr

    said = param_set(REPO / "models" / "n3_easy")
    assert "was trained for stage 3, the simulator runs stage 2" in said, said
    runner.wait_for(f"the node goes on with {trained_model}", timeout=10)
    copy = tmp_path / "again"
    shutil.copytree(trained_model, copy)
    assert "Set parameter successful" in param_set(copy)
    runner.wait_for(f"loaded PPO model for stage 2 .* from {copy}", timeout=30)
    runner.wait_for(r"step \d+: P_N/P_max", timeout=30)
    wait_for_moved_setpoints(observer)
    assert_no_traceback(runner.output)


@pytest.mark.parametrize("problem", ["missing", "corrupt", "no_param"])
def test_missing_or_corrupt_model_is_a_clear_error(procs, tmp_path, trained_model, problem):
    if problem == "missing":
        runner = policy(procs, tmp_path / "nowhere")
        expect = "not found"
    elif problem == "corrupt":
        bad = tmp_path / "bad"
        bad.mkdir()
        (bad / "model.zip").write_bytes(b"not a zip at all")
        (bad / "metadata.json").write_text((trained_model / "metadata.json").read_text())
        runner = policy(procs, bad)
        expect = "corrupt model file"
    else:
        runner = procs.ros2("run", "ops_controller_ros", "policy", name="policy")
        expect = "model must be the path of a trained model"
    assert runner.wait_exit(60) == 2
    assert expect in runner.output, runner.output
    assert_no_traceback(runner.output)


def test_memory_model_closes_the_loop(procs, observer, tmp_path):
    """A model trained with observation memory (--obs-history 2, the fast set, sb3-contrib TQC)
    runs in the policy node against a simulator over DDS."""
    out = tmp_path / "tqc_h2"
    cmd = [*ros2_command(), "run", "ops_gym_bridge", "train", "--hyperparams-set", "fast"]
    cmd += ["--algo", "tqc", "--stage", "2", "--mode", "easy", "--n-envs", "4"]
    cmd += ["--obs-history", "2", "--timesteps", "160", "--out", str(out), "--no-progress"]
    cmd += ["--hyperparams", "learning_starts=64", "batch_size=32", "net_arch=[16,16]"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=200)
    assert done.returncode == 0, done.stdout + done.stderr
    procs.ros2(
        "run", "ops_sim_ros", "sim", "--ros-args", "-p", "stage:=2", "-p", "mode:=easy", name="sim"
    )
    runner = policy(procs, out)
    runner.wait_for(r"loaded TQC model for stage 2 \(easy mode, observation stage 2, 16 values")
    runner.wait_for("history=2")
    runner.wait_for(r"step \d+: P_N/P_max", timeout=30)
    wait_for_moved_setpoints(observer)
    assert_no_traceback(runner.output)


def test_shipped_model_stacks_over_dds(procs, observer):
    """A shipped model (models/n3_easy, the one the README runs) loaded by the policy node closes
    the loop with a simulator over DDS and stacks: P_N/P_max held high, well above a random
    start's (the model's held-out evaluation: 0.95)."""
    model = REPO / "models" / "n3_easy"
    procs.ros2(
        "run", "ops_sim_ros", "sim", "--ros-args", "-p", "stage:=3", "-p", "mode:=easy", name="sim"
    )
    runner = policy(procs, model)
    runner.wait_for(r"loaded SAC model for stage 3 \(easy mode")
    runner.wait_for(r"step \d+: P_N/P_max", timeout=30)

    def stacked() -> bool:
        recent = observer.values("power")[-50:]
        return len(recent) == 50 and float(np.mean(recent)) >= 0.85

    observer.wait_until(stacked, timeout=60, what="mean P_N/P_max of 50 readings >= 0.85")
    assert_no_traceback(runner.output)


def test_authors_observation_model_runs_on_the_oracle_topic(procs, observer, tmp_path):
    """A model trained on the authors' observation set (the applied delays in it) runs in the
    policy node only with -p observation:=authors, on the simulator's ops/delays_actual (it acts
    on no reading without it); on the default rig set it stops with a message that says why."""
    out = tmp_path / "td3_authors"
    cmd = [*ros2_command(), "run", "ops_gym_bridge", "train", "--algo", "td3", "--stage", "2"]
    cmd += ["--mode", "easy", "--observation", "authors", "--timesteps", "200"]
    cmd += ["--out", str(out), "--no-progress"]
    cmd += ["--hyperparams", "learning_starts=64", "batch_size=32", "net_arch=[16,16]"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=200)
    assert done.returncode == 0, done.stdout + done.stderr
    procs.ros2(
        "run", "ops_sim_ros", "sim", "--ros-args", "-p", "stage:=2", "-p", "mode:=easy", name="sim"
    )
    refused = policy(procs, out, name="policy_rig")
    assert refused.wait_exit(60) == 2
    assert "trained on the 'authors' observation set" in refused.output, refused.output
    assert "-p observation:=authors" in refused.output
    runner = procs.ros2(
        "run", "ops_controller_ros", "policy", "--ros-args", "-p", f"model:={out}",
        "-p", "observation:=authors", name="policy",
    )  # fmt: skip
    runner.wait_for(r"loaded TD3 model for stage 2 .*authors observation", timeout=120)
    runner.wait_for(r"step \d+: P_N/P_max", timeout=30)
    wait_for_moved_setpoints(observer)
    assert_no_traceback(runner.output)


def test_switching_model_hands_over_to_its_holder_over_dds(procs, observer, tmp_path):
    """A switching model (`ops-bench switch-model`; here the shipped hard models: n5_hard
    acquires, n5_hard_long holds) in the policy node: both parts load, the log says which acts,
    and once the readings stay >= 0.95 the holder takes over."""
    from ops_controller_ros.policy_switch import write_switch_model

    model = write_switch_model(
        tmp_path / "switch", REPO / "models" / "n5_hard_long", REPO / "models" / "n5_hard"
    )
    procs.ros2(
        "run", "ops_sim_ros", "sim", "--ros-args", "-p", "stage:=5", "-p", "mode:=hard",
        "-p", "seed:=12", name="sim",
    )  # fmt: skip
    runner = procs.ros2(
        "run", "ops_controller_ros", "policy", "--ros-args", "-p", f"model:={model}",
        "-p", "log_period_s:=0.2", name="policy",
    )  # fmt: skip
    runner.wait_for(r"switching model: .*acquire acquires", timeout=120)
    runner.wait_for(r"step \d+: P_N/P_max = [\d.]+ \(acquiring policy acts", timeout=30)
    runner.wait_for(r"\(holding policy acts; [1-9]\d* hand-overs since start\)", timeout=90)
    assert_no_traceback(runner.output)
