#!/usr/bin/env python3
"""Training speed and learning against wall time of candidate hyper-parameter sets (issue 11).

For each candidate (an algorithm, a hyper-parameter set of ``ops_gym_bridge/hyperparams``, a
number of environments, an observation memory) this trains in-process, exactly as ``ros2 run
ops_gym_bridge train`` builds its model and environments (torch on ``--torch-threads`` threads),
for ``--minutes`` of wall time, and every ``--eval-every`` seconds evaluates the deterministic
policy on the testing environment (``--eval-episodes`` parallel 200-step episodes, evaluation seed
0; evaluation time is not counted as training time). It prints and writes:

* env-steps/s and gradient-steps/s of each candidate (training time only),
* the evaluation P_N / P_max reached against training wall time.

    python scripts/bench_training.py --stage 5 --mode medium --minutes 3 \
        --json runs/bench_training.json

Candidates: ``--candidates paper-sac fast-sac fast-tqc fast-crossq fast-sac-h2`` (see
CANDIDATES). The machine's load matters: report it with the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

#: name -> (algo, hyper-parameter set, n_envs, obs_history, hyper-parameter overrides)
CANDIDATES = {
    "paper-sac": ("sac", "paper", 1, 0, []),
    "paper-td3": ("td3", "paper", 1, 0, []),
    "fast-sac": ("sac", "fast", 16, 0, []),
    "fast-sac-256": ("sac", "fast", 16, 0, ["net_arch=[256,256]"]),
    "fast-sac-64": ("sac", "fast", 16, 0, ["net_arch=[64,64]"]),
    "fast-sac-h2": ("sac", "fast", 16, 2, []),
    "fast-sac-h4": ("sac", "fast", 16, 4, []),
    "fast-sac-64env": ("sac", "fast", 64, 0, ["gradient_steps=8"]),
    "fast-tqc": ("tqc", "fast", 16, 0, []),
    "fast-crossq": ("crossq", "fast", 16, 0, []),
    "fast-td3": ("td3", "fast", 16, 0, []),
}


def evaluate_policy(model, stage, mode, detector, history, episodes, seed=0) -> float:
    """Mean final P_N / P_max of ``episodes`` deterministic test-environment episodes."""
    from ops_gym_bridge.rollouts import rollout_policy
    from ops_sim_ros.config import make_config

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
    """(model, venv, params) of a candidate, as ``train`` builds them."""
    import torch
    from ops_controller_ros.policy_io import algo_class
    from ops_gym_bridge.envs import make_vec_env

    from ops_gym_bridge import hyperparams as hp

    algo, hp_set, n_envs, history, overrides = CANDIDATES[name]
    torch.set_num_threads(args.torch_threads)
    params = hp.apply_overrides(hp.load(algo, hp_set), [*overrides, *args.hyperparams], algo)
    venv = make_vec_env(
        "inprocess",
        args.stage,
        args.mode,
        "train",
        n_envs=n_envs,
        seed=args.seed,
        overrides={"detector": args.detector},
        observation_options={"history": history},
    )
    kwargs = hp.sb3_kwargs(algo, params, int(np.prod(venv.action_space.shape)))
    model = algo_class(algo)(env=venv, seed=args.seed, device="cpu", verbose=0, **kwargs)
    return model, venv, params


def throughput(name: str, args) -> dict:
    """Raw rates of a candidate: acting (policy forward + one batched env step, no learning) in
    env-steps/s, learning (``model.train`` on a filled buffer) in gradient-steps/s, and what the
    two give together at the candidate's update ratio (gradient steps per env step)."""
    model, venv, params = build(name, args)
    _, _, n_envs, _, _ = CANDIDATES[name]
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

    algo, hp_set, n_envs, history, overrides = CANDIDATES[name]
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
        "algo": algo,
        "hyperparams_set": hp_set,
        "n_envs": n_envs,
        "obs_history": history,
        "overrides": overrides,
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
        choices=sorted(CANDIDATES),
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
