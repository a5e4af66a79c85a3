"""``ros2 run ops_gym_bridge train``: train PPO / TD3 / SAC on the pulse stacker.

In-process (fast, default) or through the ROS 2 bridge against running simulators in lockstep
mode (``--backend ros``). Defaults are the paper's selected hyper-parameters
(``hyperparams/<algo>.yaml``), with 200-step episodes.

Output directory (``--out DIR``)::

    DIR/model.zip          the trained model (stable-baselines3)
    DIR/metadata.json      what the policy runner needs (ops_controller_ros.policy_io)
    DIR/logs/              progress.csv and TensorBoard events
    DIR/checkpoints/       model_<steps>_steps.zip on a schedule (+ metadata.json)
    DIR/replay_buffer.pkl  (TD3 / SAC) the replay buffer, for --resume
    DIR/vecnormalize.pkl   (normalize_obs=true) the normalization statistics, for --resume

Ctrl-C (or SIGTERM) stops training, saves a usable model and metadata, and exits with code 130.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import signal
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from . import hyperparams as hp
from .envs import BACKENDS, EPISODE_STEPS, final_powers, make_vec_env

MODES = ("easy", "medium", "hard")
EXIT_INTERRUPTED = 130


def strip_ros_args(argv: list[str]) -> list[str]:
    """Drop ``--ros-args ... [--]`` that ``ros2 run`` users may append."""
    out, skipping = [], False
    for a in argv:
        if a == "--ros-args":
            skipping = True
            continue
        if skipping:
            if a == "--":
                skipping = False
            continue
        out.append(a)
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ros2 run ops_gym_bridge train",
        description="Train a learned controller (stable-baselines3) for optical pulse stacking.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--algo", choices=hp.ALGOS, default="sac", help="RL algorithm")
    p.add_argument("--stage", type=int, default=5, help="number of stacking stages N")
    p.add_argument("--mode", choices=MODES, default="medium", help="difficulty mode")
    p.add_argument(
        "--split",
        choices=("train", "test"),
        default="train",
        help="noise variant to train on (the paper trains on 'train')",
    )
    p.add_argument(
        "--timesteps",
        type=int,
        default=100_000,
        help="environment steps to train (with --resume: additional steps)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument(
        "--backend",
        choices=BACKENDS,
        default="inprocess",
        help="inprocess: simulate in this process; ros: through running simulators",
    )
    p.add_argument("--n-envs", type=int, default=1, help="parallel environments")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument(
        "--hyperparams",
        nargs="+",
        action="extend",
        default=[],
        metavar="KEY=VALUE",
        help="override defaults from hyperparams/<algo>.yaml (YAML values)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue training the model in --out (step count continues)",
    )
    p.add_argument("--episode-steps", type=int, default=EPISODE_STEPS, help="steps per episode")
    p.add_argument(
        "--namespace",
        action="append",
        default=None,
        help="(ros) namespace of a simulator; repeat for several (one per env)",
    )
    p.add_argument(
        "--ros-timeout",
        type=float,
        default=5.0,
        help="(ros) seconds to wait for the simulator before failing",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--device", default="cpu", help="torch device")
    p.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        help="torch CPU threads (small networks train fastest on 1; 0: torch default)",
    )
    return p


class ProgressCallback:
    """Progress bar (tqdm) with mean return and final P_N/P_max; logs rollout/final_power."""

    def __new__(cls, *args, **kwargs):
        from stable_baselines3.common.callbacks import BaseCallback

        class _Progress(BaseCallback):
            def __init__(self, total: int, enabled: bool):
                super().__init__()
                self.total = total
                self.enabled = enabled
                self.bar = None
                self._last_post = 0.0
                self._last_log = 0

            def _on_training_start(self) -> None:
                from tqdm import tqdm

                start = self.model.num_timesteps
                self.bar = tqdm(
                    total=self.total,
                    initial=start,
                    unit="step",
                    dynamic_ncols=True,
                    disable=not self.enabled,
                    smoothing=0.05,
                    file=sys.stderr,
                    mininterval=0.5,
                )
                self._seen = start

            def _on_step(self) -> bool:
                n = self.model.num_timesteps
                if self.bar is not None:
                    self.bar.update(n - self._seen)
                self._seen = n
                now = time.monotonic()
                if now - self._last_post > 0.5:
                    self._last_post = now
                    buf = self.model.ep_info_buffer
                    if buf:
                        ret = float(np.mean([ep["r"] for ep in buf]))
                        powers = final_powers(buf)
                        post = {"return": f"{ret:.2f}"}
                        if powers.size:
                            post["P_N"] = f"{powers.mean():.3f}"
                        if self.bar is not None:
                            self.bar.set_postfix(post, refresh=False)
                if n - self._last_log >= 1000:
                    self._last_log = n
                    powers = final_powers(self.model.ep_info_buffer or [])
                    if powers.size:
                        self.logger.record("rollout/final_power_mean", float(powers.mean()))
                return True

            def _on_training_end(self) -> None:
                if self.bar is not None:
                    self.bar.close()

        return _Progress(*args, **kwargs)


def _sigterm_to_interrupt(signum, frame):
    raise KeyboardInterrupt


def _latest_checkpoint(out: Path) -> Path | None:
    ckpts = sorted(
        (out / "checkpoints").glob("model_*_steps.zip"),
        key=lambda p: int(p.stem.split("_")[1]) if p.stem.split("_")[1].isdigit() else -1,
    )
    return ckpts[-1] if ckpts else None


def _normalization_stats(venv) -> dict | None:
    from stable_baselines3.common.vec_env import VecNormalize

    if not isinstance(venv, VecNormalize):
        return None
    return {
        "obs_mean": venv.obs_rms.mean.tolist(),
        "obs_var": venv.obs_rms.var.tolist(),
        "clip_obs": float(venv.clip_obs),
        "epsilon": float(venv.epsilon),
    }


def build_metadata(
    args,
    params: dict,
    model,
    venv,
    argv: list[str],
    wall_s: float,
    interrupted: bool,
    previous: dict | None,
) -> dict[str, Any]:
    from ops_controller_ros.policy_io import library_versions

    from ops_sim_ros import OpsEnv

    ref = OpsEnv(
        stage=args.stage, mode=args.mode, split=args.split, max_episode_steps=args.episode_steps
    )
    history = list((previous or {}).get("history", []))
    history.append(
        {
            "command_line": argv,
            "timesteps": int(model.num_timesteps),
            "wall_s": round(wall_s, 2),
            "interrupted": interrupted,
            "finished": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        }
    )
    powers = final_powers(model.ep_info_buffer or [])
    return {
        "algo": args.algo,
        "stage": args.stage,
        "mode": args.mode,
        "split": args.split,
        "action_type": ref.action_type,
        "max_step_fs": float(ref.config.max_step_fs),
        "observation_spec": ref.obs_spec.to_dict(),
        "observation_shape": list(ref.observation_space.shape),
        "action_shape": list(ref.action_space.shape),
        "config": ref.config.to_dict(),
        "episode_steps": args.episode_steps,
        "normalization": _normalization_stats(venv),
        "versions": library_versions(),
        "command_line": argv,
        "timesteps": int(model.num_timesteps),
        "seed": args.seed,
        "backend": args.backend,
        "n_envs": args.n_envs,
        "hyperparams": params,
        "interrupted": interrupted,
        "train_final_power_mean": float(powers.mean()) if powers.size else None,
        "history": history,
    }


def _save(out: Path, args, params, model, venv, argv, wall_s, interrupted, previous) -> None:
    from ops_controller_ros.policy_io import save_metadata

    tmp = out / "model.tmp.zip"
    model.save(str(tmp))
    tmp.replace(out / "model.zip")
    if hasattr(model, "replay_buffer") and model.replay_buffer is not None:
        model.save_replay_buffer(str(out / "replay_buffer.pkl"))
    from stable_baselines3.common.vec_env import VecNormalize

    if isinstance(venv, VecNormalize):
        venv.save(str(out / "vecnormalize.pkl"))
    save_metadata(
        out, build_metadata(args, params, model, venv, argv, wall_s, interrupted, previous)
    )


def _fail(message: str, code: int = 2) -> int:
    print(f"[train] error: {message}", file=sys.stderr, flush=True)
    return code


def run(argv: list[str] | None = None) -> int:
    raw = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(strip_ros_args(raw))
    command_line = ["ros2", "run", "ops_gym_bridge", "train", *raw]
    out = Path(args.out).expanduser().resolve()
    previous = None

    from ops_controller_ros.policy_io import PolicyLoadError, algo_class, read_metadata

    if args.resume:
        try:
            previous = read_metadata(out)
        except PolicyLoadError as exc:
            return _fail(f"cannot resume from {out}: {exc}")
        # The run being resumed fixes what the model is; the command line may only repeat it.
        given = set(a.split("=")[0] for a in raw if a.startswith("--"))
        for key in ("algo", "stage", "mode", "split", "episode_steps", "n_envs"):
            flag = "--" + key.replace("_", "-")
            if flag in given and getattr(args, key) != previous.get(key, getattr(args, key)):
                return _fail(
                    f"--resume: {flag} {getattr(args, key)} differs from the model's "
                    f"{previous[key]} in {out}"
                )
            if key in previous:
                setattr(args, key, previous[key])
        if "--backend" not in given and previous.get("backend"):  # may change, if asked to
            args.backend = previous["backend"]
        params = hp.apply_overrides(
            previous.get("hyperparams") or hp.load(args.algo), args.hyperparams, args.algo
        )
    else:
        if (out / "model.zip").exists():
            return _fail(
                f"{out} already holds a model; use --resume to continue it or choose another --out"
            )
        try:
            params = hp.apply_overrides(hp.load(args.algo), args.hyperparams, args.algo)
        except ValueError as exc:
            return _fail(str(exc))
    if args.timesteps < 0:
        return _fail("--timesteps must be >= 0")

    import torch
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        venv = make_vec_env(
            args.backend,
            args.stage,
            args.mode,
            args.split,
            n_envs=args.n_envs,
            seed=args.seed,
            namespaces=args.namespace,
            timeout_s=args.ros_timeout,
            episode_steps=args.episode_steps,
        )
    except ValueError as exc:
        return _fail(str(exc))
    normalize = bool(params.get("normalize_obs", False))
    if normalize:
        vn_path = out / "vecnormalize.pkl"
        if args.resume and vn_path.exists():
            venv = VecNormalize.load(str(vn_path), venv)
            venv.training = True
        else:
            venv = VecNormalize(venv, norm_obs=True, norm_reward=False, clip_obs=10.0)

    if args.torch_threads > 0:
        torch.set_num_threads(args.torch_threads)
    out.mkdir(parents=True, exist_ok=True)
    cls = algo_class(args.algo)
    if args.resume:
        source = out / "model.zip"
        if not source.exists():
            source = _latest_checkpoint(out)
            if source is None:
                venv.close()
                return _fail(f"nothing to resume in {out}: no model.zip and no checkpoint")
        model = cls.load(str(source), env=venv, device=args.device)
        rb = out / "replay_buffer.pkl"
        if hasattr(model, "replay_buffer") and rb.exists():
            model.load_replay_buffer(str(rb))
        print(
            f"[train] resuming {args.algo} from {source.name} at step {model.num_timesteps}",
            flush=True,
        )
    else:
        action_dim = int(np.prod(venv.action_space.shape))
        try:
            kwargs = hp.sb3_kwargs(args.algo, params, action_dim)
            model = cls(env=venv, seed=args.seed, device=args.device, verbose=0, **kwargs)
        except (TypeError, ValueError) as exc:
            venv.close()
            return _fail(f"invalid hyper-parameters for {args.algo}: {exc}")
    model.set_logger(configure(str(out / "logs"), ["csv", "tensorboard"]))

    start_steps = int(model.num_timesteps)
    total = start_steps + args.timesteps
    ckpt_every = max(int(params.get("checkpoint_freq", 10000)) // max(args.n_envs, 1), 1)
    (out / "checkpoints").mkdir(exist_ok=True)
    callbacks = CallbackList(
        [
            ProgressCallback(total, enabled=not args.no_progress),
            CheckpointCallback(
                ckpt_every,
                str(out / "checkpoints"),
                name_prefix="model",
                save_vecnormalize=normalize,
            ),
        ]
    )
    # Checkpoints are loadable with policy_io too: they share this metadata (steps: planned).
    ckpt_meta = build_metadata(args, params, model, venv, command_line, 0.0, False, previous)
    from ops_controller_ros.policy_io import save_metadata

    save_metadata(out / "checkpoints", {**ckpt_meta, "checkpoint": True})

    previous_handler = signal.signal(signal.SIGTERM, _sigterm_to_interrupt)
    interrupted = False
    t0 = time.monotonic()
    print(
        f"[train] training started: {args.algo} stage={args.stage} mode={args.mode} "
        f"backend={args.backend} n_envs={args.n_envs} steps {start_steps} -> {total}, "
        f"out={out}",
        flush=True,
    )
    error: BaseException | None = None
    try:
        model.learn(
            total_timesteps=args.timesteps,
            callback=callbacks,
            reset_num_timesteps=not args.resume,
            log_interval=1,
        )
    except KeyboardInterrupt:
        interrupted = True
    except Exception as exc:  # e.g. the simulator died: keep what was learned, then report
        error = exc
    finally:
        # A second Ctrl-C must not corrupt the model being written.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        bar = getattr(callbacks.callbacks[0], "bar", None)
        if bar is not None:
            bar.close()
    wall = time.monotonic() - t0
    # A run that failed before its first step (e.g. no simulator) has nothing worth saving.
    saved = error is None or model.num_timesteps > start_steps
    try:
        if saved:
            _save(
                out,
                args,
                params,
                model,
                venv,
                command_line,
                wall,
                interrupted or error is not None,
                previous,
            )
    finally:
        with contextlib.suppress(Exception):  # closing must not hide the result
            venv.close()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, previous_handler)
    powers = final_powers(model.ep_info_buffer or [])
    summary = (
        f"{model.num_timesteps} steps ({model.num_timesteps - start_steps} new) in {wall:.1f} s"
    )
    if powers.size:
        summary += (
            f"; last {powers.size} episodes: return "
            f"{np.mean([ep['r'] for ep in model.ep_info_buffer]):.2f}, final P_N/P_max "
            f"{powers.mean():.3f}"
        )
    if error is not None:
        print(f"[train] error after {summary}: {type(error).__name__}: {error}", file=sys.stderr)
        if saved:
            print(f"[train] model so far saved to {out / 'model.zip'}", file=sys.stderr)
        sys.stderr.flush()
        return 1
    if interrupted:
        print(
            f"\n[train] interrupted after {summary}; model saved to {out / 'model.zip'} "
            "(continue with --resume)",
            flush=True,
        )
        return EXIT_INTERRUPTED
    print(f"[train] done: {summary}; model saved to {out / 'model.zip'}", flush=True)
    return 0


def main(argv: list[str] | None = None) -> None:
    try:
        code = run(argv)
    except KeyboardInterrupt:  # before training started: nothing to save
        print("\n[train] interrupted before training started; nothing saved", file=sys.stderr)
        code = EXIT_INTERRUPTED
    sys.exit(code)


if __name__ == "__main__":
    main()
