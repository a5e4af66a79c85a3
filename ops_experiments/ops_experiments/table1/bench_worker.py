"""One run of the benchmark (``python -m ops_experiments.table1.bench_worker SPEC.json OUT``).

A run is a training run (an algorithm, a mode, a stage, a seed, a step budget) or a controller
run (a no-training controller of :data:`ops_controller_ros.controllers.CONTROLLERS`). Either way it
ends evaluated in the benchmark's protocol: ``eval.seeds`` x ``eval.episodes`` episodes of
``eval.steps`` steps on the training and on the testing environment, with the run's detector.
Trained models are also evaluated on the other modes' testing environments (``transfer``, the
paper's Figure 11) and, where asked (``traces``), one testing episode's output intensity traces are
kept at a handful of steps (the paper's Figure 17), so the report needs no model.

Training is ``ros2 run ops_gym_bridge train``'s own path (:func:`train_argv`: the run's
hyper-parameter set, one in-process env, the run's ``--observation`` and detector, built by
:func:`ops_experiments.build.build_model`), so the table measures what a user's
``train`` does. Evaluation is ``evaluate``'s (:class:`ops_experiments.subject.Subject`,
one summary schema: :mod:`ops_experiments.summary`), the agents on the very episodes
the controllers run (same initial errors, same noise draws).

Storage. The run works in ``OUT/work/<id>/`` (train's model directory: model, metadata, replay
buffer, training curve so far), saved by train when stopped; when it has finished training and
evaluation its small results (and the model) are moved in one ``os.replace`` to
``OUT/runs/<id>/``: a run is either absent there or complete. Files of a finished run::

    run.json          the spec, the outcome (final P_N per split), wall times
    metadata.json     (training runs) the model's metadata (ops_contract.policy_meta)
    model.zip         (training runs) the trained model (stable-baselines3)
    training.csv      (training runs) one row per training episode: step, return, length, P_N
    evaluation.json   the evaluation protocol (seeds, episodes, steps), per split and per
                      transfer mode the summary of ops_experiments.summary (final
                      P_N per seed and episode, worst episode, curves); traces

SIGINT / SIGTERM: training stops, the model, replay buffer and curve are saved in the work
directory, exit code 130; the next start resumes from there. The worker also asks the kernel for
SIGTERM when its parent dies, so a killed benchmark never leaves a training process behind.
"""

from __future__ import annotations

import csv
import ctypes
import json
import os
import shutil
import signal
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

EXIT_INTERRUPTED = 130
TRACE_STEPS = (0, 10, 20, 30, 40, 50)


# ------------------------------------------------------------------------------ small helpers
def write_json(path: Path, data: Any) -> None:
    """Write ``data`` as JSON atomically (temp file, then os.replace)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    os.replace(tmp, path)


def read_json(path: Path) -> Any | None:
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _die_with_parent() -> None:
    """SIGTERM this process when its parent exits (Linux; a no-op elsewhere)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _sigterm_to_interrupt(signum, frame):
    raise KeyboardInterrupt


def env_overrides(spec: dict) -> dict[str, Any]:
    """The evaluation environment's OpsConfig fields: the detector, the rig (which the
    controllers and the training runs know of) and the hidden overrides."""
    return {"detector": spec["detector"], **(spec.get("rig") or {}), **(spec.get("env") or {})}


# ------------------------------------------------------------------------------ evaluation
def observation_options(spec: dict) -> dict[str, Any]:
    """The observation of a run's models (the benchmark trains without memory)."""
    return {"observation": spec.get("observation", "rig")}


def subject_of(spec: dict, policy=None):
    """The run as an evaluation :class:`~ops_experiments.subject.Subject`: its
    controller (told of the nominal rig: stage, detector and the run's rig, as its node is) or
    its trained model (``policy``: a ``ModelStack`` of :mod:`ops_controller_ros.runner_factory`,
    or a loaded policy it is built from; on the controllers' very episodes, holding its
    decisions as its metadata's ``hold_steps`` says, as ``evaluate`` does), on the run's mode."""
    from ops_contract.config import make_config

    from ..evaluate import with_hold
    from ..subject import Subject

    rig = dict(spec.get("rig") or {})
    common = {
        "stage": int(spec["stage"]),
        "mode": spec["mode"],
        "detector": spec["detector"],
        "env_overrides": dict(spec.get("env") or {}),
        "rig": rig,
    }
    if policy is not None:
        model = _model_stack(policy)
        return with_hold(Subject(name=spec["algo"], model=model, paired=True, **common))
    nominal = make_config(stage=spec["stage"], detector=spec["detector"], **rig)
    return Subject(
        name=spec["controller"],
        controller=spec["controller"],
        controller_params=dict(spec.get("controller_params") or {}),
        nominal=nominal,
        **common,
    )


def _model_stack(policy):
    """A ``ModelStack`` (:mod:`ops_controller_ros.runner_factory`) of ``policy`` (one already,
    or a ``LoadedPolicy``: its metadata not read again)."""
    from ops_controller_ros.runner_factory import ModelStack, load_model

    return policy if isinstance(policy, ModelStack) else load_model(policy)


def record_traces(policy, spec: dict, hold_steps: int = 1) -> dict[str, Any]:
    """One testing-environment episode from a random start, on the run's rig: the output
    intensity trace at :data:`TRACE_STEPS` (Figure 17). A model that holds its decisions
    (``hold_steps`` k, resolved) decides on one reading in k, as it is evaluated; its traces are
    those of the first decision at or after each of the steps (``steps`` says which)."""
    from ops_sim_ros import OpsEnv

    steps = max(TRACE_STEPS)
    env = OpsEnv(
        stage=spec["stage"],
        mode=spec["mode"],
        split="test",
        max_episode_steps=max(steps, 1),
        observation_options=observation_options(spec),
        hold_steps=hold_steps,
        **env_overrides(spec),
    )
    predict = _model_stack(policy).predictor()
    try:
        obs, info = env.reset(seed=int(spec["eval"]["seeds"][0]))
        out = {"steps": [], "power": [], "trace": []}
        wanted = sorted(TRACE_STEPS)
        t = 0  # simulator steps taken
        while wanted:
            if t >= wanted[0]:
                while wanted and t >= wanted[0]:
                    wanted.pop(0)
                out["steps"].append(t)
                out["power"].append(round(float(info["power"]), 5))
                out["trace"].append([round(float(x), 5) for x in env.trace()])
            if wanted:
                obs, _, _, _, info = env.step(predict(obs))
                t = min(t + env.hold_steps, steps)
        return out
    finally:
        env.close()


def evaluate_run(spec: dict, policy=None) -> dict[str, Any]:
    """The run's ``evaluation.json``: per split and per transfer mode the one summary of
    :mod:`ops_experiments.summary`; (``traces``) Figure 17's traces; ``hold_steps``
    where the model holds its decisions (:func:`subject_of`)."""
    ev = spec["eval"]
    seeds, episodes, steps = list(ev["seeds"]), int(ev["episodes"]), int(ev["steps"])
    subject = subject_of(spec, policy)
    t0 = time.monotonic()
    result: dict[str, Any] = {
        "seeds": seeds,
        "episodes_per_seed": episodes,
        "steps": steps,
        "splits": subject.evaluate(("train", "test"), seeds, episodes, steps),
        "transfer": {},
    }
    if subject.hold_steps != 1:  # (a model trained with train --hold-steps)
        result["hold_steps"] = subject.hold_steps
    for mode in spec.get("transfer_modes") or []:
        if mode != spec["mode"]:
            transfer = subject.with_mode(mode).evaluate(("test",), seeds, episodes, steps)
            result["transfer"][mode] = transfer["test"]
    if policy is not None and spec.get("traces"):
        result["traces"] = record_traces(policy, spec, subject.hold_steps)
    result["wall_s"] = round(time.monotonic() - t0, 2)
    return result


# ------------------------------------------------------------------------------ training
def train_argv(spec: dict, work: Path, resume: bool, remaining: int) -> list[str]:
    """The ``ros2 run ops_gym_bridge train`` arguments of a training run of the benchmark: the
    run's hyper-parameter set (the paper's unless the spec names one), one in-process env, the
    run's observation set."""
    argv = [
        "--algo", spec["algo"],
        "--stage", str(spec["stage"]),
        "--mode", spec["mode"],
        "--split", "train",
        "--detector", spec["detector"],
        "--observation", spec.get("observation", "rig"),
        "--episode-steps", str(int(spec["episode_steps"])),
        "--seed", str(int(spec["seed"])),
        "--timesteps", str(int(remaining)),
        "--hyperparams-set", spec.get("hyperparams_set", "paper"),
        "--n-envs", "1",
        "--obs-history", "0",
        "--reward", "paper",
        "--backend", "inprocess",
        "--torch-threads", "1",
        "--no-progress",
        "--out", str(work),
    ]  # fmt: skip
    overrides = [
        *(spec.get("hyperparams") or []),
        f"checkpoint_freq={spec.get('save_every', 10_000)}",
    ]
    rig = dict(spec.get("rig") or {})
    if "realism" in rig:
        argv += ["--realism", str(rig.pop("realism"))]
    if rig:
        argv += ["--rig", *(f"{k}={v}" for k, v in rig.items())]
    argv += ["--hyperparams", *overrides]
    return [*argv, "--resume"] if resume else argv


def _episode_recorder(rows: list, work: Path, spec: dict):
    """An SB3 callback: one row per finished training episode (step, return, length, final
    P_N/P_max) and ``progress.json`` every 1000 steps (the benchmark's time estimate)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class _Recorder(BaseCallback):
        last_progress = 0

        def _on_step(self) -> bool:
            n = self.model.num_timesteps
            for info in self.locals.get("infos", []):
                ep = info.get("episode")
                if ep is not None:
                    rows.append((n, float(ep["r"]), int(ep["l"]), float(info.get("power", np.nan))))
            if n - self.last_progress >= 1000:
                self.last_progress = n
                write_json(work / "progress.json", {"timesteps": n, "total": spec["timesteps"]})
            return True

    return _Recorder()


def _write_rows(path: Path, rows: list) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["timesteps", "return", "length", "final_power"])
        for n, r, length, p in rows:
            w.writerow([n, f"{r:.5f}", length, f"{p:.5f}"])
    os.replace(tmp, path)


def _read_rows(path: Path) -> list:
    if not path.exists():
        return []
    with open(path) as f:
        return [
            (int(r["timesteps"]), float(r["return"]), int(r["length"]), float(r["final_power"]))
            for r in csv.DictReader(f)
        ]


def train(spec: dict, work: Path):
    """Train (or resume) in ``work`` as ``ros2 run ops_gym_bridge train`` does
    (:func:`~ops_experiments.build.build_model` with :func:`train_argv`, then
    :func:`~ops_experiments.learn.learn_and_save`); returns the stored model (a
    :class:`~ops_controller_ros.policy_io.LoadedPolicy`, its metadata read once: the runner
    factory builds on it without reading it again) or raises KeyboardInterrupt after saving."""
    from ops_contract.policy_meta import PolicyLoadError, read_meta
    from ops_controller_ros.policy_io import load_policy

    from .. import learn
    from ..build import build_model
    from ..training_run import TrainError

    previous = None
    if (work / "model.zip").exists():
        try:
            previous = read_meta(work).to_dict()
        except PolicyLoadError:  # killed before its first save: start again
            previous = None
    if previous is None:
        for name in ("model.zip", "metadata.json", "replay_buffer.pkl", "training.csv"):
            (work / name).unlink(missing_ok=True)
        shutil.rmtree(work / "checkpoints", ignore_errors=True)
    done = int(previous["timesteps"]) if previous else 0
    remaining = max(int(spec["timesteps"]) - done, 0)
    rows = [r for r in _read_rows(work / "training.csv") if r[0] <= done]
    if previous is not None:
        print(f"[run {spec['id']}] resuming at step {done}", flush=True)
    if previous is None or remaining > 0:
        try:
            run = build_model(train_argv(spec, work, previous is not None, remaining))
        except TrainError as exc:
            raise RuntimeError(f"train refused the run: {exc}") from None
        run.extra_callbacks.append(_episode_recorder(rows, work, spec))
        interrupted, error, _ = learn.learn_and_save(run)
        _write_rows(work / "training.csv", rows)
        if error is not None:
            raise error
        if interrupted:
            print(f"[run {spec['id']}] stopped; saved in {work}", flush=True)
            raise KeyboardInterrupt
        signal.signal(signal.SIGTERM, _sigterm_to_interrupt)
    return load_policy(work)  # the stored model, as the report's readers will load it


# ------------------------------------------------------------------------------ one run
def execute(spec: dict, out: Path) -> dict:
    """Run ``spec`` to completion and store it under ``out/runs/<id>``; returns run.json."""
    final = out / "runs" / spec["id"]
    if (final / "run.json").exists():
        return read_json(final / "run.json")
    work = out / "work" / spec["id"]
    work.mkdir(parents=True, exist_ok=True)
    (work / "worker.pid").write_text(str(os.getpid()))
    t0 = time.monotonic()
    record: dict[str, Any] = {"spec": spec}
    if spec["kind"] == "train":
        from ops_contract.policy_meta import write_meta

        policy = train(spec, work)
        history = policy.meta.entries.get("history", [])
        record["train_wall_s"] = round(sum(float(h.get("wall_s", 0.0)) for h in history), 1)
        record["timesteps"] = int(policy.model.num_timesteps)
        write_meta(work, {**policy.meta.entries, "benchmark_run": spec["id"]})
        evaluation = evaluate_run(spec, policy)
    else:
        evaluation = evaluate_run(spec, None)
    write_json(work / "evaluation.json", evaluation)
    record["eval_wall_s"] = evaluation["wall_s"]
    record["final_power"] = {s: v["final_power_mean"] for s, v in evaluation["splits"].items()}
    record["wall_s"] = round(time.monotonic() - t0, 1)
    for name in ("replay_buffer.pkl", "state.json", "progress.json", "worker.pid"):
        (work / name).unlink(missing_ok=True)
    for name in ("checkpoints", "logs"):  # train's checkpoints and logs: not results
        shutil.rmtree(work / name, ignore_errors=True)
    write_json(work / "run.json", record)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    if final.exists():  # a leftover without run.json (never complete): replace it
        shutil.rmtree(final)
    os.replace(work, final)
    return record


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) != 2:
        print("usage: python -m ops_experiments.table1.bench_worker SPEC.json OUT", file=sys.stderr)
        sys.exit(2)
    _die_with_parent()
    signal.signal(signal.SIGTERM, _sigterm_to_interrupt)
    from ops_contract.heap import freeze_after_heavy_imports

    freeze_after_heavy_imports()
    spec = json.loads(Path(argv[0]).read_text())
    try:
        rec = execute(spec, Path(argv[1]))
    except KeyboardInterrupt:
        sys.exit(EXIT_INTERRUPTED)
    fp = rec["final_power"]
    print(
        f"[run {spec['id']}] done: final P_N/P_max train {fp['train']:.4f}, test {fp['test']:.4f}",
        flush=True,
    )
    sys.exit(0)


if __name__ == "__main__":
    main()
