"""One run of the benchmark (``python -m ops_gym_bridge.bench_worker SPEC.json``).

A run is a training run (an algorithm, a mode, a stage, a seed, a step budget) or a controller
run (a no-training controller of :data:`ops_controller_ros.controllers.CONTROLLERS`). Either way it
ends evaluated in the benchmark's protocol: ``eval.seeds`` x ``eval.episodes`` episodes of
``eval.steps`` steps on the training and on the testing environment, with the run's detector.
Trained models are also evaluated on the other modes' testing environments (``transfer``, the
paper's Figure 11) and, where asked (``traces``), one testing episode's output intensity traces are
kept at a handful of steps (the paper's Figure 17), so the report needs no model.

Storage. The run works in ``OUT/work/<id>/`` (model, replay buffer, training curve so far) and is
saved there every ``save_every`` steps and when stopped; when it has finished training and
evaluation its small results (and the model) are moved in one ``os.replace`` to
``OUT/runs/<id>/``: a run is either absent there or complete. Files of a finished run::

    run.json          the spec, the outcome (final P_N per split), wall times
    metadata.json     (training runs) the model's metadata (ops_controller_ros.policy_io)
    model.zip         (training runs) the trained model (stable-baselines3)
    training.csv      (training runs) one row per training episode: step, return, length, P_N
    evaluation.json   per split: final P_N per evaluation seed and the P_N-vs-step curve;
                      transfer; traces

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
    return {"detector": spec["detector"], **(spec.get("env") or {})}


# ------------------------------------------------------------------------------ evaluation
def rollout_model(model, spec: dict, mode: str, split: str, seed: int) -> dict[str, np.ndarray]:
    """``episodes`` parallel episodes of ``model`` (deterministic) on one environment."""
    from ops_sim_ros.vec_env import OpsVectorEnv

    ev = spec["eval"]
    n, steps = int(ev["episodes"]), int(ev["steps"])
    env = OpsVectorEnv(
        num_envs=n,
        stage=spec["stage"],
        mode=mode,
        split=split,
        max_episode_steps=steps,
        **env_overrides(spec),
    )
    try:
        obs, info = env.reset(seed=seed)
        power = np.empty((n, steps + 1))
        power[:, 0] = np.asarray(info["power"], dtype=np.float64)
        for t in range(steps):
            actions, _ = model.predict(obs, deterministic=True)
            obs, _, _, _, info = env.step(actions)
            final = info.get("final_info") if t == steps - 1 else None
            src = final if final is not None and "power" in final else info
            power[:, t + 1] = np.asarray(src["power"], dtype=np.float64)
        return {"power": power}
    finally:
        env.close()


def rollout_controller(spec: dict, mode: str, split: str, seed: int) -> dict[str, np.ndarray]:
    """Episodes of a no-training controller, driven as its node drives the simulator
    (absolute set-points, one measurement per command)."""
    from ops_controller_ros.controllers import make_controller
    from ops_sim_ros.config import make_config

    from ops_sim_ros import OpsEnv

    ev = spec["eval"]
    n, steps = int(ev["episodes"]), int(ev["steps"])
    nominal = make_config(stage=spec["stage"], detector=spec["detector"])
    env = OpsEnv(
        stage=spec["stage"], mode=mode, split=split, max_episode_steps=steps, **env_overrides(spec)
    )
    power = np.empty((n, steps + 1))
    try:
        for e in range(n):
            _, info = env.reset(seed=seed * 1000 + e)
            ctl = make_controller(
                spec["controller"],
                nominal,
                spec.get("controller_params") or {},
                setpoints_fs=info["setpoints_fs"],
                seed=seed * 1000 + e,
            )
            power[e, 0] = info["power"]
            for t in range(steps):
                r = env.sim.step_setpoints(np.asarray(ctl.command(), dtype=np.float64)[None, :])
                ctl.observe(float(r.power[0]), np.asarray(r.pulse_energies[0]))
                power[e, t + 1] = float(r.power[0])
    finally:
        env.close()
    return {"power": power}


def summarize(per_seed: list[dict[str, np.ndarray]]) -> dict[str, Any]:
    """Per evaluation seed: mean final P_N over its episodes; curves averaged likewise."""
    final = np.array([r["power"][:, -1].mean() for r in per_seed])
    curves = np.stack([r["power"].mean(axis=0) for r in per_seed])
    return {
        "final_power_mean": float(final.mean()),
        "final_power_std": float(final.std()),
        "final_power_per_seed": [round(float(x), 6) for x in final],
        "curve_mean": [round(float(x), 5) for x in curves.mean(axis=0)],
        "curve_std": [round(float(x), 5) for x in curves.std(axis=0)],
    }


def record_traces(model, spec: dict) -> dict[str, Any]:
    """One testing-environment episode from a random start: the output intensity trace at
    :data:`TRACE_STEPS` (Figure 17)."""
    from ops_sim_ros import OpsEnv

    steps = max(TRACE_STEPS)
    env = OpsEnv(
        stage=spec["stage"],
        mode=spec["mode"],
        split="test",
        max_episode_steps=max(steps, 1),
        **env_overrides(spec),
    )
    try:
        obs, info = env.reset(seed=int(spec["eval"]["seeds"][0]))
        out = {"steps": [], "power": [], "trace": []}
        for t in range(steps + 1):
            if t in TRACE_STEPS:
                out["steps"].append(t)
                out["power"].append(round(float(info["power"]), 5))
                out["trace"].append([round(float(x), 5) for x in env.trace()])
            if t < steps:
                action, _ = model.predict(obs, deterministic=True)
                obs, _, _, _, info = env.step(action)
        return out
    finally:
        env.close()


def evaluate_run(spec: dict, model=None) -> dict[str, Any]:
    ev = spec["eval"]
    t0 = time.monotonic()

    def run(mode, split, seed):
        if model is None:
            return rollout_controller(spec, mode, split, seed)
        return rollout_model(model, spec, mode, split, seed)

    result: dict[str, Any] = {"splits": {}, "transfer": {}}
    for split in ("train", "test"):
        result["splits"][split] = summarize([run(spec["mode"], split, s) for s in ev["seeds"]])
    for mode in spec.get("transfer_modes") or []:
        if mode != spec["mode"]:
            result["transfer"][mode] = summarize([run(mode, "test", s) for s in ev["seeds"]])
    if model is not None and spec.get("traces"):
        result["traces"] = record_traces(model, spec)
    result["wall_s"] = round(time.monotonic() - t0, 2)
    return result


# ------------------------------------------------------------------------------ training
def _make_train_env(spec: dict):
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv

    from ops_sim_ros import OpsEnv

    def make():
        return Monitor(
            OpsEnv(
                stage=spec["stage"],
                mode=spec["mode"],
                split="train",
                max_episode_steps=int(spec["episode_steps"]),
                **env_overrides(spec),
            ),
            info_keywords=("power",),
        )

    return DummyVecEnv([make])


def _episode_callback(rows: list, work: Path, spec: dict, state: dict, save):
    from stable_baselines3.common.callbacks import BaseCallback

    class _Cb(BaseCallback):
        def _on_step(self) -> bool:
            n = self.model.num_timesteps
            for info in self.locals.get("infos", []):
                ep = info.get("episode")
                if ep is not None:
                    rows.append((n, float(ep["r"]), int(ep["l"]), float(info.get("power", np.nan))))
            if n - state["last_progress"] >= 1000:
                state["last_progress"] = n
                write_json(work / "progress.json", {"timesteps": n, "total": spec["timesteps"]})
            if n - state["last_save"] >= int(spec.get("save_every", 10_000)):
                state["last_save"] = n
                save(self.model)
            return True

    return _Cb()


def _save_training(work: Path, model, rows: list, spec: dict, wall_s: float, history: list):
    tmp = work / "model.tmp.zip"
    model.save(str(tmp))
    os.replace(tmp, work / "model.zip")
    if getattr(model, "replay_buffer", None) is not None:
        model.save_replay_buffer(str(work / "replay_buffer.tmp.pkl"))
        os.replace(work / "replay_buffer.tmp.pkl", work / "replay_buffer.pkl")
    tmp_csv = work / "training.csv.tmp"
    with open(tmp_csv, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["timesteps", "return", "length", "final_power"])
        for n, r, length, p in rows:
            w.writerow([n, f"{r:.5f}", length, f"{p:.5f}"])
    os.replace(tmp_csv, work / "training.csv")
    write_json(
        work / "state.json",
        {"timesteps": int(model.num_timesteps), "wall_s": round(wall_s, 2), "history": history},
    )


def _read_rows(path: Path) -> list:
    if not path.exists():
        return []
    with open(path) as f:
        return [
            (int(r["timesteps"]), float(r["return"]), int(r["length"]), float(r["final_power"]))
            for r in csv.DictReader(f)
        ]


def _metadata(spec: dict, model, params: dict, wall_s: float, history: list) -> dict:
    from ops_controller_ros.policy_io import library_versions

    from ops_sim_ros import OpsEnv

    ref = OpsEnv(
        stage=spec["stage"],
        mode=spec["mode"],
        split="train",
        max_episode_steps=int(spec["episode_steps"]),
        **env_overrides(spec),
    )
    return {
        "algo": spec["algo"],
        "stage": spec["stage"],
        "mode": spec["mode"],
        "split": "train",
        "action_type": ref.action_type,
        "max_step_fs": float(ref.config.max_step_fs),
        "observation_spec": ref.obs_spec.to_dict(),
        "observation_shape": list(ref.observation_space.shape),
        "action_shape": list(ref.action_space.shape),
        "config": ref.config.to_dict(),
        "episode_steps": int(spec["episode_steps"]),
        "normalization": None,
        "versions": library_versions(),
        "command_line": ["python", "-m", "ops_gym_bridge.bench_worker", spec["id"]],
        "timesteps": int(model.num_timesteps),
        "seed": spec["seed"],
        "backend": "inprocess",
        "n_envs": 1,
        "hyperparams": params,
        "interrupted": False,
        "train_wall_s": round(wall_s, 2),
        "history": history,
        "benchmark_run": spec["id"],
    }


def train(spec: dict, work: Path):
    """Train (or resume) in ``work``; returns (model, params, wall_s, history) or raises
    KeyboardInterrupt after saving."""
    import torch
    from ops_controller_ros.policy_io import algo_class

    from . import hyperparams as hp

    torch.set_num_threads(1)
    algo = spec["algo"]
    params = hp.apply_overrides(hp.load(algo), spec.get("hyperparams") or [], algo)
    if params.get("normalize_obs"):
        raise ValueError("the benchmark trains without observation normalization")
    venv = _make_train_env(spec)
    cls = algo_class(algo)
    state = read_json(work / "state.json") if (work / "model.zip").exists() else None
    if state:
        model = cls.load(str(work / "model.zip"), env=venv, device="cpu")
        if (
            getattr(model, "replay_buffer", None) is not None
            and (work / "replay_buffer.pkl").exists()
        ):
            model.load_replay_buffer(str(work / "replay_buffer.pkl"))
        rows = [r for r in _read_rows(work / "training.csv") if r[0] <= model.num_timesteps]
        wall0, history = float(state["wall_s"]), list(state["history"])
        print(f"[run {spec['id']}] resuming at step {model.num_timesteps}", flush=True)
    else:
        kwargs = hp.sb3_kwargs(algo, params, int(np.prod(venv.action_space.shape)))
        model = cls(env=venv, seed=int(spec["seed"]), device="cpu", verbose=0, **kwargs)
        rows, wall0, history = [], 0.0, []
    start = int(model.num_timesteps)
    remaining = int(spec["timesteps"]) - start
    t0 = time.monotonic()
    cb_state = {"last_progress": start, "last_save": start}

    def save(m, interrupted=False):
        wall = wall0 + time.monotonic() - t0
        hist = [*history, {"from": start, "to": int(m.num_timesteps), "interrupted": interrupted}]
        _save_training(work, m, rows, spec, wall, hist)

    interrupted = False
    if remaining > 0:
        try:
            model.learn(
                total_timesteps=remaining,
                callback=_episode_callback(rows, work, spec, cb_state, save),
                reset_num_timesteps=start == 0,
            )
        except KeyboardInterrupt:
            interrupted = True
        finally:
            signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second signal must not corrupt
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
        save(model, interrupted)
        if interrupted:
            print(
                f"[run {spec['id']}] stopped at step {model.num_timesteps}; saved in {work}",
                flush=True,
            )
            raise KeyboardInterrupt
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, _sigterm_to_interrupt)
    state = read_json(work / "state.json") or {"wall_s": 0.0, "history": []}
    venv.close()
    return model, params, float(state["wall_s"]), state["history"]


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
        model, params, wall, history = train(spec, work)
        record["train_wall_s"] = round(wall, 1)
        record["timesteps"] = int(model.num_timesteps)
        from ops_controller_ros.policy_io import save_metadata

        save_metadata(work, _metadata(spec, model, params, wall, history))
        evaluation = evaluate_run(spec, model)
    else:
        evaluation = evaluate_run(spec, None)
    write_json(work / "evaluation.json", evaluation)
    record["eval_wall_s"] = evaluation["wall_s"]
    record["final_power"] = {s: v["final_power_mean"] for s, v in evaluation["splits"].items()}
    record["wall_s"] = round(time.monotonic() - t0, 1)
    for name in ("replay_buffer.pkl", "state.json", "progress.json", "worker.pid"):
        (work / name).unlink(missing_ok=True)
    write_json(work / "run.json", record)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    if final.exists():  # a leftover without run.json (never complete): replace it
        shutil.rmtree(final)
    os.replace(work, final)
    return record


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) != 2:
        print("usage: python -m ops_gym_bridge.bench_worker SPEC.json OUT", file=sys.stderr)
        sys.exit(2)
    _die_with_parent()
    signal.signal(signal.SIGTERM, _sigterm_to_interrupt)
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
