"""Training speed and learning against wall time of candidate hyper-parameter sets.

For each candidate (an algorithm, a hyper-parameter set of ``ops_experiments/yaml``, a
number of environments, an observation memory) this trains in-process, exactly as ``ros2 run
ops_gym_bridge train`` builds its model and environments (torch on ``--torch-threads`` threads),
for ``--minutes`` of wall time, and every ``--eval-every`` seconds evaluates the deterministic
policy on the testing environment (``--eval-episodes`` parallel 200-step episodes, evaluation seed
0; evaluation time is not counted as training time). It prints and writes:

* env-steps/s and gradient-steps/s of each candidate (training time only),
* the evaluation P_N / P_max reached against training wall time.

    ops-bench training --stage 5 --mode medium --minutes 3 \\
        --json runs/bench_training.json

Candidates: ``--candidates paper-sac fast-sac fast-tqc fast-crossq fast-sac-h2`` (see
ops_experiments/yaml/candidates.yaml). The machine's load matters: report it with the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path


def candidates() -> dict[str, dict]:
    """name -> algo, hyperparams_set, n_envs, obs_history, overrides (the YAML beside the
    hyper-parameters, ``ops_experiments/ops_experiments/yaml/candidates.yaml``)."""
    from ops_experiments import hyperparams as hp

    return hp.candidates()


def evaluate_policy(model, stage, mode, detector, history, episodes, seed=0) -> float:
    """Mean final P_N / P_max of ``episodes`` deterministic test-environment episodes."""
    from ops_contract.config import make_config
    from ops_experiments.rollouts import rollout_policy

    cfg = make_config(stage, mode, "test", detector=detector, episode_steps=200)
    res = rollout_policy(
        lambda obs: model.predict(obs, deterministic=True)[0],
        cfg,
        episodes,
        200,
        seed,
        {"history": history},
    )
    return float(res["power"][:, -1].mean())


def build(name: str, args):
    """(model, venv, params) of a candidate, built by ``train``'s own path
    (``ops_experiments.build.build_model``) in a scratch run directory."""
    import tempfile

    from ops_experiments.build import build_model

    c = candidates()[name]
    overrides = [*c["overrides"], *args.hyperparams]
    options = ["--algo", c["algo"], "--hyperparams-set", c["hyperparams_set"]]
    options += ["--n-envs", str(c["n_envs"]), "--obs-history", str(c["obs_history"])]
    options += ["--reward", "paper", "--stage", str(args.stage), "--mode", args.mode]
    options += ["--detector", args.detector, "--seed", str(args.seed)]
    options += ["--torch-threads", str(args.torch_threads)]
    options += ["--hyperparams", *overrides] if overrides else []
    run = build_model(options, out=tempfile.mkdtemp(prefix="ops_bench_training_"))
    return run.model, run.venv, run.params


def throughput(name: str, args) -> dict:
    """Raw rates of a candidate: acting (policy forward + one batched env step, no learning) in
    env-steps/s, learning (``model.train`` on a filled buffer) in gradient-steps/s, and what the
    two give together at the candidate's update ratio (gradient steps per env step)."""
    model, venv, params = build(name, args)
    n_envs = candidates()[name]["n_envs"]
    batch = int(params.get("batch_size", 256))
    model.learn(total_timesteps=max(2 * batch, int(params.get("learning_starts", 0))) + n_envs)
    obs = venv.reset()
    t0, steps = time.perf_counter(), 0
    while time.perf_counter() - t0 < args.throughput_s:
        actions, _ = model.predict(obs, deterministic=False)
        obs, _, _, _ = venv.step(actions)
        steps += n_envs
    env_rate = steps / (time.perf_counter() - t0)
    model._setup_learn(1, None)  # a logger for train()
    t0, grads = time.perf_counter(), 0
    while time.perf_counter() - t0 < args.throughput_s:
        model.train(gradient_steps=10, batch_size=batch)
        grads += 10
    grad_rate = grads / (time.perf_counter() - t0)
    utd = float(params.get("gradient_steps", 1)) / (n_envs * float(params.get("train_freq", 1)))
    if isinstance(params.get("train_freq"), int) and params.get("gradient_steps", 1) == -1:
        utd = 1.0
    combined = 1.0 / (1.0 / env_rate + utd / grad_rate)
    venv.close()
    return {
        "name": name,
        "act_env_steps_per_s": round(env_rate, 1),
        "gradient_steps_per_s": round(grad_rate, 1),
        "update_ratio": utd,
        "training_env_steps_per_s": round(combined, 1),
    }


def run_candidate(name: str, args) -> dict:
    from stable_baselines3.common.callbacks import BaseCallback

    c = candidates()[name]
    history = c["obs_history"]
    model, venv, _ = build(name, args)
    budget = args.minutes * 60.0
    points: list[dict] = []

    class Clock(BaseCallback):
        def __init__(self):
            super().__init__()
            self.train_s = 0.0
            self.next_eval = 0.0

        def _on_training_start(self):
            self.t0 = time.monotonic()

        def _eval(self):
            t = time.monotonic()
            p = evaluate_policy(
                self.model,
                args.stage,
                args.mode,
                args.detector,
                history,
                args.eval_episodes,
            )
            updates = int(getattr(self.model, "_n_updates", 0))
            points.append(
                {
                    "train_s": round(self.train_s, 1),
                    "env_steps": int(self.model.num_timesteps),
                    "gradient_steps": updates,
                    "eval_power": round(p, 4),
                }
            )
            print(
                f"[bench_training] {name}: {self.train_s:6.0f} s, {self.model.num_timesteps:8d} "
                f"env steps, {updates:7d} gradient steps: test P_N/P_max {p:.4f}",
                flush=True,
            )
            self.t0 += time.monotonic() - t  # evaluation time is not training time

        def _on_step(self) -> bool:
            self.train_s = time.monotonic() - self.t0
            if self.train_s >= self.next_eval:
                self._eval()
                self.next_eval += args.eval_every
            if self.train_s >= budget:
                self._eval()
                return False
            return True

    clock = Clock()
    model.learn(total_timesteps=10**9, callback=clock)
    venv.close()
    last = points[-1]
    train_s = max(last["train_s"], 1e-9)
    # Throughput over the training after learning_starts (gradient steps exist only there).
    return {
        "name": name,
        "algo": c["algo"],
        "hyperparams_set": c["hyperparams_set"],
        "n_envs": c["n_envs"],
        "obs_history": history,
        "overrides": c["overrides"],
        "train_s": last["train_s"],
        "env_steps": last["env_steps"],
        "gradient_steps": last["gradient_steps"],
        "env_steps_per_s": round(last["env_steps"] / train_s, 1),
        "gradient_steps_per_s": round(last["gradient_steps"] / train_s, 1),
        "best_eval_power": max(p["eval_power"] for p in points),
        "final_eval_power": last["eval_power"],
        "curve": points,
    }


def markdown(results: list[dict], args, load: tuple[float, float, float]) -> str:
    lines = [
        f"N = {args.stage}, {args.mode} mode, {args.detector} detector; {args.minutes} min of "
        f"training per candidate, torch {args.torch_threads} thread(s); evaluation: "
        f"{args.eval_episodes} deterministic 200-step episodes of the testing environment "
        f"(seed 0) every {args.eval_every} s of training. Load average at the start: "
        f"{load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}.",
        "",
        "| candidate | algo | set | n_envs | memory | env-steps/s | gradient-steps/s | "
        "env steps | test P_N/P_max: best | final |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r['name']} | {r['algo']} | {r['hyperparams_set']} | {r['n_envs']} | "
            f"{r['obs_history']} | {r['env_steps_per_s']:.0f} | {r['gradient_steps_per_s']:.0f} | "
            f"{r['env_steps']:,} | {r['best_eval_power']:.4f} | {r['final_eval_power']:.4f} |"
        )
    lines += ["", "P_N/P_max against training wall time (s):", ""]
    for r in results:
        curve = ", ".join(f"{p['train_s']:.0f} s: {p['eval_power']:.3f}" for p in r["curve"])
        lines.append(f"- {r['name']}: {curve}")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument(
        "--candidates",
        nargs="+",
        default=["paper-sac", "fast-sac", "fast-tqc", "fast-crossq"],
        choices=sorted(candidates()),
    )
    p.add_argument("--stage", type=int, default=5)
    p.add_argument("--mode", default="medium")
    p.add_argument("--detector", default="polarizer")
    p.add_argument("--minutes", type=float, default=3.0, help="training wall time per candidate")
    p.add_argument("--eval-every", type=float, default=30.0, help="seconds of training")
    p.add_argument("--eval-episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--torch-threads", type=int, default=1)
    p.add_argument("--hyperparams", nargs="*", default=[], help="key=value for every candidate")
    p.add_argument("--json", help="write the results here")
    p.add_argument(
        "--throughput-only",
        action="store_true",
        help="only the raw rates (acting, gradient steps; --throughput-s each), no learning runs",
    )
    p.add_argument("--throughput-s", type=float, default=10.0)
    args = p.parse_args(argv)
    load = os.getloadavg()
    if args.throughput_only:
        rows = [throughput(name, args) for name in args.candidates]
        print(
            f"N = {args.stage}, {args.mode}, {args.detector}; torch {args.torch_threads} "
            f"thread(s); load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}\n\n"
            "| candidate | acting: env-steps/s | gradient-steps/s | gradient steps per env step "
            "| training env-steps/s at that ratio |\n|---|---|---|---|---|"
        )
        for r in rows:
            print(
                f"| {r['name']} | {r['act_env_steps_per_s']:,.0f} "
                f"| {r['gradient_steps_per_s']:,.0f}"
                f" | {r['update_ratio']:.3g} | {r['training_env_steps_per_s']:,.0f} |"
            )
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(
                json.dumps({"argv": sys.argv, "load": load, "throughput": rows}, indent=1)
            )
        return 0
    results = []
    for name in args.candidates:
        results.append(run_candidate(name, args))
        if args.json:  # after every candidate: a long run that is stopped keeps what it has
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(
                json.dumps({"argv": sys.argv, "load": load, "results": results}, indent=1)
            )
    print(markdown(results, args, load))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
