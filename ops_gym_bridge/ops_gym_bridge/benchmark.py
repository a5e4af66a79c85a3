"""``ros2 run ops_gym_bridge benchmark``: the paper's benchmark grid (algorithms x modes at a stage,
several seeds), by running ``train`` and ``evaluate`` for every cell, then a markdown table.

Resumable: each run lives in ``OUT/<algo>_<mode>_s<seed>/``; a run whose model has all its steps
and an evaluation is skipped, an interrupted one continues with ``train --resume``. Ctrl-C stops
the grid after saving the current model; run the same command again to go on.

The paper's grid (section 3, Table 1): stage 5, PPO / TD3 / SAC, easy / medium / hard, ten seeds,
evaluated on the training and the testing environment. ``--quick`` is a small configuration
(stage 2, SAC and TD3, easy, one seed, 3000 steps) to check the pipeline in a few minutes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ALGOS = ("ppo", "td3", "sac")
MODES = ("easy", "medium", "hard")
QUICK = {
    "stage": 2,
    "algos": ["sac", "td3"],
    "modes": ["easy"],
    "seeds": [1],
    "timesteps": 3000,
    "eval_seeds": [0, 1],
    "eval_episodes": 3,
}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ros2 run ops_gym_bridge benchmark",
        description="Run the benchmark grid (train + evaluate) and write a markdown table.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--stage", type=int, default=5)
    p.add_argument("--algos", nargs="+", choices=ALGOS, default=list(ALGOS))
    p.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    p.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=list(range(10)),
        help="training seeds (the paper uses ten)",
    )
    p.add_argument("--timesteps", type=int, default=300_000, help="training steps per run")
    p.add_argument("--eval-seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--eval-episodes", type=int, default=5)
    p.add_argument(
        "--hyperparams",
        nargs="+",
        action="extend",
        default=[],
        metavar="KEY=VALUE",
        help="overrides passed to every training run",
    )
    p.add_argument("--n-envs", type=int, default=1)
    p.add_argument("--out", default="runs/benchmark", help="directory of the runs and the table")
    p.add_argument(
        "--quick",
        action="store_true",
        help="small grid: " + ", ".join(f"{k}={v}" for k, v in QUICK.items()),
    )
    p.add_argument("--progress", action="store_true", help="show each run's progress bar")
    return p


def _cli(module: str) -> list[str]:
    return [sys.executable, "-m", f"ops_gym_bridge.{module}"]


def _run_child(cmd: list[str]) -> int:
    """Run a CLI to completion. On Ctrl-C (which reaches the child too) let it save and exit."""
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL)
    try:
        return proc.wait()
    except KeyboardInterrupt:
        try:
            proc.wait(120)
        except subprocess.TimeoutExpired:
            proc.kill()
        raise


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def run_cell(args, algo: str, mode: str, seed: int, out: Path, log) -> dict[str, Any]:
    """Train (or resume) and evaluate one run; returns its record."""
    run_dir = out / f"{algo}_{mode}_s{seed}"
    meta = _read_json(run_dir / "metadata.json") if (run_dir / "model.zip").exists() else None
    done_steps = int(meta["timesteps"]) if meta else 0
    if done_steps < args.timesteps:
        cmd = [
            *_cli("train"),
            "--algo",
            algo,
            "--stage",
            str(args.stage),
            "--mode",
            mode,
            "--seed",
            str(seed),
            "--out",
            str(run_dir),
            "--n-envs",
            str(args.n_envs),
        ]
        if meta:
            cmd += ["--resume", "--timesteps", str(args.timesteps - done_steps)]
            log(f"resuming at step {done_steps}")
        else:
            cmd += ["--timesteps", str(args.timesteps)]
        if args.hyperparams:
            cmd += ["--hyperparams", *args.hyperparams]
        if not args.progress:
            cmd.append("--no-progress")
        code = _run_child(cmd)
        if code == 130:
            raise KeyboardInterrupt
        if code != 0:
            raise RuntimeError(f"training failed ({code}): {' '.join(cmd)}")
        meta = _read_json(run_dir / "metadata.json")
        (run_dir / "eval" / "evaluation.json").unlink(missing_ok=True)
    evaluation = _read_json(run_dir / "eval" / "evaluation.json")
    if evaluation is None:
        cmd = [
            *_cli("evaluate"),
            str(run_dir),
            "--seeds",
            *map(str, args.eval_seeds),
            "--episodes",
            str(args.eval_episodes),
            "--quiet",
        ]
        code = _run_child(cmd)
        if code != 0:
            raise RuntimeError(f"evaluation failed ({code}): {' '.join(cmd)}")
        evaluation = _read_json(run_dir / "eval" / "evaluation.json")
    train_wall = sum(h.get("wall_s", 0.0) for h in meta.get("history", []))
    return {
        "algo": algo,
        "mode": mode,
        "seed": seed,
        "timesteps": meta["timesteps"],
        "train_wall_s": round(train_wall, 1),
        "train_final_power": evaluation["splits"]["train"]["final_power_mean"],
        "test_final_power": evaluation["splits"]["test"]["final_power_mean"],
        "train_return": evaluation["splits"]["train"]["episode_return_mean"],
        "test_return": evaluation["splits"]["test"]["episode_return_mean"],
        "dir": str(run_dir),
    }


def table(records: list[dict], args) -> str:
    lines = [
        f"Stage {args.stage}, {args.timesteps} training steps per run, final P_N/P_max after "
        f"200 steps (mean ± std over training seeds; each seed evaluated on "
        f"{len(args.eval_seeds)} seeds x {args.eval_episodes} episodes).",
        "",
        "| algo | mode | seeds | train env P_N | test env P_N | test episode return | "
        "train wall time / run |",
        "|---|---|---|---|---|---|---|",
    ]
    for algo in args.algos:
        for mode in args.modes:
            rs = [r for r in records if r["algo"] == algo and r["mode"] == mode]
            if not rs:
                continue
            tr = np.array([r["train_final_power"] for r in rs])
            te = np.array([r["test_final_power"] for r in rs])
            ret = np.array([r["test_return"] for r in rs])
            wall = np.mean([r["train_wall_s"] for r in rs])
            lines.append(
                f"| {algo.upper()} | {mode} | {len(rs)} | {tr.mean():.4f} ± {tr.std():.4f} | "
                f"{te.mean():.4f} ± {te.std():.4f} | {ret.mean():.2f} ± {ret.std():.2f} | "
                f"{wall:.0f} s |"
            )
    return "\n".join(lines) + "\n"


def run(argv: list[str] | None = None) -> int:
    from .train import strip_ros_args

    args = build_parser().parse_args(strip_ros_args(list(sys.argv[1:] if argv is None else argv)))
    if args.quick:
        for k, v in QUICK.items():
            setattr(args, k, v)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cells = [(a, m, s) for a in args.algos for m in args.modes for s in args.seeds]
    records: list[dict] = []
    t0 = time.monotonic()
    try:
        for i, (algo, mode, seed) in enumerate(cells, 1):
            prefix = f"[benchmark] ({i}/{len(cells)}) {algo} {mode} seed {seed}"

            def log(msg, prefix=prefix):
                print(f"{prefix}: {msg}", flush=True)

            t = time.monotonic()
            rec = run_cell(args, algo, mode, seed, out, log)
            records.append(rec)
            log(
                f"test P_N/P_max {rec['test_final_power']:.4f}, train P_N/P_max "
                f"{rec['train_final_power']:.4f} (training {rec['train_wall_s']:.0f} s; this "
                f"cell {time.monotonic() - t:.0f} s; elapsed {time.monotonic() - t0:.0f} s)"
            )
    except KeyboardInterrupt:
        print(
            f"\n[benchmark] interrupted after {len(records)}/{len(cells)} runs; run the same "
            "command again to continue",
            file=sys.stderr,
        )
        return 130
    except RuntimeError as exc:
        print(f"[benchmark] error: {exc}", file=sys.stderr)
        return 1
    text = table(records, args)
    (out / "results.md").write_text(text)
    (out / "results.json").write_text(json.dumps(records, indent=2) + "\n")
    print(text)
    print(f"[benchmark] wrote {out / 'results.md'} and {out / 'results.json'}")
    return 0


def main(argv: list[str] | None = None) -> None:
    try:
        code = run(argv)
    except KeyboardInterrupt:
        code = 130
    sys.exit(code)


if __name__ == "__main__":
    main()
