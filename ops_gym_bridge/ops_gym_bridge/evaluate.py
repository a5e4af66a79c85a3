"""``ros2 run ops_gym_bridge evaluate``: evaluate a trained model or the SPGD-PID baseline.

Runs ``--episodes`` episodes for each of ``--seeds`` on the training and the testing environment
(``--splits train test``; the testing environment of hard mode has the shifted noise of the paper's
section 2.2), in-process. Reports, per split, the final normalized P_N / P_max (mean +- std over
seeds of each seed's mean over its episodes), the final return (P_N at the last step, the paper's
"final return"), the episode return (sum of rewards) and the P_N-vs-step curve.

Writes ``OUT/evaluation.json`` (summary + curves), ``OUT/curve.csv`` (step, split, mean, std) and
``OUT/curve.png``. ``--mode`` / ``--stage`` evaluate on another environment than the model was
trained on (the transfer experiment of section 4.2); a stage whose observation shape differs from
the model's is refused with a clear error.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from .envs import EPISODE_STEPS
from .recording import new_bag_path

MODES = ("easy", "medium", "hard")
SPLITS = ("train", "test")


class EvaluationError(RuntimeError):
    pass


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ros2 run ops_gym_bridge evaluate",
        description="Evaluate a trained model (DIR from train --out) or the SPGD-PID baseline.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("model", nargs="?", help="model directory (or its model.zip)")
    p.add_argument("--spgd", action="store_true", help="evaluate the SPGD-PID baseline instead")
    p.add_argument("--stage", type=int, help="stage to evaluate on (default: the model's)")
    p.add_argument("--mode", choices=MODES, help="mode to evaluate on (default: the model's)")
    p.add_argument(
        "--splits",
        nargs="+",
        choices=SPLITS,
        default=list(SPLITS),
        help="environments: train and/or test (shifted noise in hard mode)",
    )
    p.add_argument("--episodes", type=int, default=5, help="episodes per seed and split")
    p.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[0, 1, 2, 3, 4],
        help="evaluation seeds (the mean +- std is over seeds)",
    )
    p.add_argument("--steps", type=int, default=EPISODE_STEPS, help="steps per episode")
    p.add_argument("--out", help="output directory (default: MODEL/eval, or ./eval_spgd)")
    p.add_argument(
        "--record", metavar="DIR", type=new_bag_path, help="also record a bag of episodes"
    )
    p.add_argument(
        "--spgd-param",
        nargs="+",
        action="extend",
        default=[],
        metavar="KEY=VALUE",
        help="SpgdParams overrides for --spgd (e.g. gain=0.1)",
    )
    p.add_argument("--no-plot", action="store_true", help="do not write curve.png")
    p.add_argument("--torch-threads", type=int, default=1, help="torch CPU threads (0: default)")
    p.add_argument("--quiet", action="store_true", help="print only the summary table")
    return p


# ---------------------------------------------------------------------------------- rollouts
def rollout_policy(
    predict, stage: int, mode: str, split: str, episodes: int, steps: int, seed: int
) -> dict[str, np.ndarray]:
    """``episodes`` parallel episodes with a batched ``predict(obs) -> actions``.

    Returns ``power`` (episodes, steps + 1): P_N/P_max after reset and after each step, and
    ``returns`` (episodes,): the sum of rewards.
    """
    from ops_sim_ros.vec_env import OpsVectorEnv

    env = OpsVectorEnv(
        num_envs=episodes, stage=stage, mode=mode, split=split, max_episode_steps=steps
    )
    try:
        obs, info = env.reset(seed=seed)
        power = np.empty((episodes, steps + 1))
        power[:, 0] = np.asarray(info["power"], dtype=np.float64)
        returns = np.zeros(episodes)
        for t in range(steps):
            actions = predict(obs)
            obs, rewards, _, _, info = env.step(actions)
            returns += rewards
            if t == steps - 1:
                final = info.get("final_info") if isinstance(info, dict) else None
                if final is not None and "power" in final:
                    power[:, t + 1] = np.asarray(final["power"], dtype=np.float64)
                    continue
            power[:, t + 1] = np.asarray(info["power"], dtype=np.float64)
        return {"power": power, "returns": returns}
    finally:
        env.close()


def rollout_spgd(
    params_overrides: dict, stage: int, mode: str, split: str, episodes: int, steps: int, seed: int
) -> dict[str, np.ndarray]:
    """SPGD-PID episodes, driven exactly as its node drives the simulator (absolute set-points,
    one measurement per command)."""
    from ops_controller_ros.spgd import SpgdParams, SpgdPid

    from ops_sim_ros import OpsEnv

    params = SpgdParams(**params_overrides)
    power = np.empty((episodes, steps + 1))
    returns = np.zeros(episodes)
    env = OpsEnv(stage=stage, mode=mode, split=split, max_episode_steps=steps)
    for e in range(episodes):
        _, info = env.reset(seed=seed * 1000 + e)
        ctl = SpgdPid(stage, params, setpoints_fs=info["setpoints_fs"], seed=seed * 1000 + e)
        power[e, 0] = info["power"]
        for t in range(steps):
            r = env.sim.step_setpoints(ctl.command()[None, :])
            ctl.observe(float(r.power[0]))
            power[e, t + 1] = float(r.power[0])
            returns[e] += float(r.reward[0])
    env.close()
    return {"power": power, "returns": returns}


# ---------------------------------------------------------------------------------- summary
def summarize(per_seed: list[dict[str, np.ndarray]]) -> dict[str, Any]:
    """Mean +- std over seeds of the per-seed means."""
    final = np.array([r["power"][:, -1].mean() for r in per_seed])
    ret = np.array([r["returns"].mean() for r in per_seed])
    curves = np.stack([r["power"].mean(axis=0) for r in per_seed])  # (seeds, steps + 1)
    all_final = np.concatenate([r["power"][:, -1] for r in per_seed])
    return {
        "final_power_mean": float(final.mean()),
        "final_power_std": float(final.std()),
        "final_power_per_seed": final.tolist(),
        "final_power_min_episode": float(all_final.min()),
        "episode_return_mean": float(ret.mean()),
        "episode_return_std": float(ret.std()),
        "initial_power_mean": float(curves[:, 0].mean()),
        "curve_mean": curves.mean(axis=0).tolist(),
        "curve_std": curves.std(axis=0).tolist(),
    }


def _parse_kv(items: list[str]) -> dict[str, Any]:
    import yaml

    out = {}
    for item in items:
        if "=" not in item:
            raise EvaluationError(f"{item!r} must look like key=value")
        k, v = item.split("=", 1)
        out[k.strip()] = yaml.safe_load(v)
    return out


def load_for_evaluation(model_path: str, stage: int | None):
    """(LoadedPolicy, stage) or EvaluationError for a model that cannot run on ``stage``."""
    from ops_controller_ros.policy_io import PolicyLoadError, load_policy
    from ops_sim_ros.config import make_config
    from ops_sim_ros.observation import ObservationSpec

    try:
        loaded = load_policy(model_path)
    except PolicyLoadError as exc:
        raise EvaluationError(str(exc)) from None
    stage = loaded.stage if stage is None else stage
    if stage != loaded.stage:
        spec = ObservationSpec.from_dict(loaded.observation_spec)
        target = ObservationSpec.from_config(
            make_config(stage=stage),
            **{k: v for k, v in loaded.observation_spec.items() if k.startswith("include_")},
        )
        if target.dim != spec.dim:
            raise EvaluationError(
                f"cannot evaluate a stage-{loaded.stage} model on stage {stage}: its observation "
                f"has {target.dim} values and its action {stage}, the model expects "
                f"{spec.dim} and {loaded.stage} (stage transfer needs equal shapes)"
            )
    return loaded, stage


def evaluate(args) -> dict[str, Any]:
    if args.spgd == bool(args.model):
        raise EvaluationError("give a model directory or --spgd (exactly one)")
    if args.episodes < 1 or args.steps < 1 or not args.seeds:
        raise EvaluationError("--episodes and --steps must be >= 1 and --seeds non-empty")
    if args.spgd:
        stage = args.stage or 5
        mode = args.mode or "medium"
        overrides = _parse_kv(args.spgd_param)
        name = "spgd"
        meta = {"controller": "spgd", "spgd_params": overrides}

        def run(split, seed):
            return rollout_spgd(overrides, stage, mode, split, args.episodes, args.steps, seed)
    else:
        loaded, stage = load_for_evaluation(args.model, args.stage)
        mode = args.mode or loaded.mode
        name = loaded.algo
        meta = {
            "controller": loaded.algo,
            "model": str(loaded.path),
            "trained_stage": loaded.stage,
            "trained_mode": loaded.mode,
            "trained_timesteps": loaded.metadata.get("timesteps"),
        }

        def run(split, seed):
            return rollout_policy(
                loaded.predict, stage, mode, split, args.episodes, args.steps, seed
            )

    results: dict[str, Any] = {
        **meta,
        "stage": stage,
        "mode": mode,
        "episodes_per_seed": args.episodes,
        "seeds": list(args.seeds),
        "steps": args.steps,
        "splits": {},
    }
    t0 = time.monotonic()
    for split in args.splits:
        per_seed = []
        for seed in args.seeds:
            per_seed.append(run(split, seed))
            if not args.quiet:
                print(
                    f"[evaluate] {name} stage={stage} mode={mode} split={split} seed={seed}: "
                    f"final P_N/P_max {per_seed[-1]['power'][:, -1].mean():.4f}",
                    flush=True,
                )
        results["splits"][split] = summarize(per_seed)
    results["wall_s"] = round(time.monotonic() - t0, 2)
    return results


def write_outputs(results: dict[str, Any], out: Path, plot: bool = True) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "evaluation.json"]
    (out / "evaluation.json").write_text(json.dumps(results, indent=2) + "\n")
    with open(out / "curve.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "split", "power_mean", "power_std"])
        for split, s in results["splits"].items():
            for t, (m, sd) in enumerate(zip(s["curve_mean"], s["curve_std"], strict=True)):
                w.writerow([t, split, f"{m:.6f}", f"{sd:.6f}"])
    written.append(out / "curve.csv")
    if plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.6), dpi=110)
        for split, s in results["splits"].items():
            m, sd = np.asarray(s["curve_mean"]), np.asarray(s["curve_std"])
            steps = np.arange(m.size)
            ax.plot(steps, m, label=f"{split}: final {s['final_power_mean']:.3f}")
            ax.fill_between(steps, m - sd, m + sd, alpha=0.25)
        ax.set_xlabel("step")
        ax.set_ylabel("P_N / P_max")
        ax.set_ylim(0, 1.02)
        ax.set_title(f"{results['controller']} on stage {results['stage']}, {results['mode']}")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right")
        fig.tight_layout()
        fig.savefig(out / "curve.png")
        plt.close(fig)
        written.append(out / "curve.png")
    return written


def format_table(results: dict[str, Any]) -> str:
    lines = [
        f"{results['controller']} on stage {results['stage']}, {results['mode']} mode "
        f"({len(results['seeds'])} seeds x {results['episodes_per_seed']} episodes, "
        f"{results['steps']} steps)",
        f"{'split':<6} {'final P_N/P_max':>20} {'episode return':>20} {'initial P_N':>12}",
    ]
    for split, s in results["splits"].items():
        lines.append(
            f"{split:<6} {s['final_power_mean']:>11.4f} ± {s['final_power_std']:<6.4f} "
            f"{s['episode_return_mean']:>11.2f} ± {s['episode_return_std']:<6.2f} "
            f"{s['initial_power_mean']:>12.4f}"
        )
    return "\n".join(lines)


def run(argv: list[str] | None = None) -> int:
    from .train import strip_ros_args

    args = build_parser().parse_args(strip_ros_args(list(sys.argv[1:] if argv is None else argv)))
    if args.torch_threads > 0:
        import torch

        torch.set_num_threads(args.torch_threads)
    try:
        results = evaluate(args)
    except (EvaluationError, ValueError) as exc:
        print(f"[evaluate] error: {exc}", file=sys.stderr, flush=True)
        return 2
    if args.out:
        out = Path(args.out)
    elif args.model:
        from ops_controller_ros.policy_io import resolve_paths

        out = resolve_paths(args.model)[0].parent / "eval"
    else:
        out = Path("eval_spgd")
    written = write_outputs(results, out, plot=not args.no_plot)
    if args.record:
        from .recording import record_episodes

        written.append(record_episodes(args, results["stage"], results["mode"], Path(args.record)))
    print(format_table(results))
    print(f"[evaluate] wrote {', '.join(str(p) for p in written)}", flush=True)
    return 0


def main(argv: list[str] | None = None) -> None:
    try:
        code = run(argv)
    except KeyboardInterrupt:
        print("\n[evaluate] interrupted", file=sys.stderr)
        code = 130
    sys.exit(code)


if __name__ == "__main__":
    main()
