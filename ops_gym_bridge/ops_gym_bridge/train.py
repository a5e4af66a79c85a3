"""``ros2 run ops_gym_bridge train``: train PPO / TD3 / SAC (or sb3-contrib's TQC / CrossQ) on
the pulse stacker.

In-process (fast, default) or through the ROS 2 bridge against running simulators in lockstep
mode (``--backend ros``). Defaults are the paper's selected hyper-parameters
(``hyperparams/<algo>.yaml``), with 200-step episodes; ``--hyperparams-set fast``
(``hyperparams/fast.yaml``) trains on many batched environments with fewer gradient steps per
environment step, and chooses the algorithm, ``--n-envs`` and ``--obs-history`` unless given.
``--obs-history K`` gives the policy memory: each observation holds the last K observations and
the actions that led to them (``ops_sim_ros.observation``; saved in the metadata).
``--observation authors`` trains on the authors' observation set (their ``CPS_env`` default, with
the actual delay-line lengths, a simulator-only oracle) instead of the rig's (the default).

Output directory (``--out DIR``)::

    DIR/model.zip          the trained model (stable-baselines3)
    DIR/metadata.json      what the policy runner needs (ops_controller_ros.policy_io)
    DIR/logs/              progress.csv and TensorBoard events
    DIR/checkpoints/       model_<steps>_steps.zip on a schedule (+ metadata.json)
    DIR/replay_buffer.pkl  (TD3 / SAC) the replay buffer, for --resume
    DIR/vecnormalize.pkl   (normalize_obs=true) the normalization statistics, for --resume
    DIR/best/              (--eval-freq) the model that evaluated best during training
                           (model.zip + metadata.json with eval_final_power; a model directory)

Ctrl-C (or SIGTERM) stops training, saves a usable model and metadata, and exits with code 130.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from ops_sim_ros.config import RIG_KEYS, make_config
from ops_sim_ros.observation import OBSERVATION_SETS
from ops_sim_ros.threads import limit_blas_threads

from . import cli_args
from . import hyperparams as hp
from .cli_args import strip_ros_args  # noqa: F401  (kept importable from here)
from .envs import BACKENDS, EPISODE_STEPS, final_powers, make_vec_env
from .rewards import REWARDS, wrap_training_reward

EXIT_INTERRUPTED = 130
#: What a model is: a resumed run keeps these (the command line may only repeat them).
RUN_KEYS = (
    "algo",
    "stage",
    "mode",
    "split",
    "detector",
    "episode_steps",
    "n_envs",
    "obs_history",
    "observation",
    "reward",
    "hyperparams_set",
    "continue_prob",
)


#: What a fine-tuned run (``--init-from``) keeps of its initial model; the task (mode, split,
#: episode length, reward, environments) may change.
INIT_KEYS = ("algo", "stage", "detector", "obs_history", "observation", "hyperparams_set")


class TrainError(RuntimeError):
    """A run that cannot start; the message says why (exit code 2)."""


def build_parser():
    p = cli_args.make_parser(
        "train", "Train a learned controller (stable-baselines3) for optical pulse stacking."
    )
    _add_algorithm_arguments(p)
    cli_args.add_env_arguments(p)
    cli_args.add_rig_arguments(p, "the policy (its training environments)")
    _add_budget_arguments(p)
    _add_run_arguments(p)
    return p


def _add_algorithm_arguments(p) -> None:
    """The algorithm, its named hyper-parameter set, the observation memory."""
    p.add_argument(
        "--algo",
        choices=hp.ALL_ALGOS,
        default=None,
        help="RL algorithm (default: the hyper-parameter set's; sac for paper)",
    )
    p.add_argument(
        "--hyperparams-set",
        choices=hp.SETS,
        default="paper",
        help="named defaults: paper (hyperparams/<algo>.yaml, the paper's tables), authors "
        "(hyperparams/authors.yaml, the authors' code's values) or fast (hyperparams/fast.yaml: "
        "many batched envs, fewer gradient steps per env step)",
    )
    p.add_argument(
        "--obs-history",
        type=int,
        default=None,
        metavar="K",
        help="observation memory: the last K observations and the actions that led to them "
        "(default: the set's; 0, the paper's memoryless observation, for paper)",
    )
    p.add_argument(
        "--reward",
        choices=REWARDS,
        default=None,
        help="what the learner is paid: paper (eq. 3, -(1 - P)^2) or nines (-log10(1 - P) / 3, "
        "steep near the optimum; ops_gym_bridge.rewards). Evaluations always measure P_N/P_max "
        "(default: the set's; paper for paper)",
    )
    p.add_argument(
        "--observation",
        choices=OBSERVATION_SETS,
        default=None,
        help="observation set: rig (what a real stacker measures) or authors (the authors' "
        "CPS_env: power, trace and the actual delay-line lengths, a simulator-only oracle); "
        "saved in the model's metadata (default: rig; --resume: the model's)",
    )
    p.add_argument(
        "--setpoint-window",
        type=cli_args.non_negative_float,
        default=None,
        metavar="CYCLES",
        help="observe each set-point relative to a whole number of optical cycles that follows "
        "it (re-centred when it leaves +- CYCLES; >= 0.5), so that a long run, whose drift "
        "carries the delays cycles away, looks like the training episodes; 0: absolute "
        "set-points (default: 0; --resume and --init-from: the model's)",
    )
    cli_args.add_key_value_argument(
        p, "--hyperparams", help="override defaults from hyperparams/<algo>.yaml (YAML values)"
    )


def _add_budget_arguments(p) -> None:
    """How long to train and how to evaluate on the way."""
    p.add_argument(
        "--timesteps",
        type=int,
        default=100_000,
        help="environment steps to train (with --resume: additional steps)",
    )
    p.add_argument(
        "--max-minutes",
        type=float,
        default=None,
        help="stop training after this many minutes of wall time (the model is saved as after "
        "--timesteps; exit code 0)",
    )
    p.add_argument(
        "--eval-freq",
        type=int,
        default=0,
        metavar="STEPS",
        help="every STEPS environment steps, evaluate the deterministic policy on the testing "
        "environment (--eval-episodes parallel episodes) and keep the best in DIR/best "
        "(0: never)",
    )
    p.add_argument(
        "--eval-episodes", type=int, default=20, help="episodes of each --eval-freq evaluation"
    )
    p.add_argument("--seed", type=int, default=0, help="random seed")


def _add_run_arguments(p) -> None:
    """Where the environments run, where the run is stored, and the process."""
    p.add_argument(
        "--backend",
        choices=BACKENDS,
        default="inprocess",
        help="inprocess: simulate in this process; ros: through running simulators",
    )
    p.add_argument(
        "--n-envs",
        type=int,
        default=None,
        help="parallel environments (default: the set's; 1 for paper)",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue training the model in --out (step count continues)",
    )
    p.add_argument(
        "--init-from",
        metavar="MODEL_DIR",
        help="start from a trained model's weights (fine-tuning, e.g. with longer episodes or "
        "in another mode): its algorithm, stage, detector, observation and hyper-parameters are "
        "kept, the step count continues, its training history goes into the new metadata",
    )
    p.add_argument("--episode-steps", type=int, default=EPISODE_STEPS, help="steps per episode")
    p.add_argument(
        "--continue-prob",
        type=cli_args.non_negative_float,
        default=None,
        metavar="Q",
        help="probability that an ending episode carries on from where it is (delays, drift, "
        "set-points) instead of a fresh start: the states of a long run enter the training data "
        "(in-process batched environments; default 0; --resume and --init-from: the model's)",
    )
    p.add_argument(
        "--namespace",
        action="append",
        default=None,
        help="(ros) namespace of a simulator; repeat for several (one per env)",
    )
    p.add_argument(
        "--ros-timeout",
        type=cli_args.non_negative_float,
        default=0.0,
        help="(ros) seconds to wait for an answer of the simulator before failing; 0 (default): "
        "no limit, training waits through lost messages and outages and carries on",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--device", default="cpu", help="torch device")
    p.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        help="torch CPU threads (small networks train fastest on 1; 0: torch default)",
    )


_STOP_SIGNALS: list[int] = []  # Ctrl-C / SIGTERM received while training


def _stop_to_interrupt(signum, frame):
    """Ctrl-C and SIGTERM stop a training run the same way. Recorded as well as raised: a
    KeyboardInterrupt raised while rclpy converts a message in C++ reaches Python as a
    RuntimeError ("Unable to convert call argument"), which is still a requested stop."""
    _STOP_SIGNALS.append(signum)
    raise KeyboardInterrupt


def observation_options(args) -> dict[str, Any]:
    """The run's observation choices (memory, observation set, set-point window) for every env
    it builds."""
    options = {"history": args.obs_history, "observation": args.observation}
    if args.setpoint_window:  # (left out when 0: a spec as before the option)
        options["setpoint_window_cycles"] = args.setpoint_window
    return options


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
        stage=args.stage,
        mode=args.mode,
        split=args.split,
        detector=args.detector,
        max_episode_steps=args.episode_steps,
        observation_options=observation_options(args),
        **args.rig_config,
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
        "detector": args.detector,
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
        "obs_history": args.obs_history,
        "observation": args.observation,
        "rig": args.rig_config,
        "reward": args.reward,
        "hyperparams_set": args.hyperparams_set,
        "continue_prob": args.continue_prob,
        "hyperparams": params,
        "interrupted": interrupted,
        "train_final_power_mean": float(powers.mean()) if powers.size else None,
        "history": history,
    }


def _save(
    out: Path,
    args,
    params,
    model,
    venv,
    argv,
    wall_s,
    interrupted,
    previous,
    replay: bool = True,
    extra: dict | None = None,
) -> None:
    from ops_controller_ros.policy_io import save_metadata

    out.mkdir(parents=True, exist_ok=True)
    tmp = out / "model.tmp.zip"
    model.save(str(tmp))
    tmp.replace(out / "model.zip")
    if replay and hasattr(model, "replay_buffer") and model.replay_buffer is not None:
        model.save_replay_buffer(str(out / "replay_buffer.pkl"))
    from stable_baselines3.common.vec_env import VecNormalize

    if isinstance(venv, VecNormalize):
        venv.save(str(out / "vecnormalize.pkl"))
    meta = build_metadata(args, params, model, venv, argv, wall_s, interrupted, previous)
    save_metadata(out, {**meta, **(extra or {})})


def _best_model_hooks(run: TrainRun, t0_ref: list[float]):
    """(every, evaluate, save_best) of --eval-freq: deterministic test-environment episodes on
    the batched simulator, with the run's observation (memory) and normalization."""
    from stable_baselines3.common.vec_env import VecNormalize

    from .rollouts import rollout_policy

    args = run.args
    cfg = make_config(
        args.stage,
        args.mode,
        "test",
        detector=args.detector,
        episode_steps=args.episode_steps,
        **args.rig_config,
    )

    def evaluate(model) -> float:
        venv = run.venv
        norm = venv.normalize_obs if isinstance(venv, VecNormalize) else (lambda o: o)
        res = rollout_policy(
            lambda obs: model.predict(norm(obs), deterministic=True)[0],
            cfg,
            args.eval_episodes,
            args.episode_steps,
            seed=0,
            observation_options=observation_options(args),
        )
        power = float(res["power"][:, -1].mean())
        print(
            f"[train] step {model.num_timesteps}: evaluation (test, {args.eval_episodes} "
            f"episodes) final P_N/P_max {power:.4f}",
            flush=True,
        )
        return power

    def save_best(model, power: float) -> None:
        wall = time.monotonic() - t0_ref[0]
        extra = {"eval_final_power": power, "eval_episodes": args.eval_episodes}
        _save(
            run.out / "best",
            args,
            run.params,
            model,
            run.venv,
            run.command_line,
            wall,
            False,
            run.previous,
            replay=False,
            extra=extra,
        )

    return max(args.eval_freq // max(args.n_envs, 1), 1), evaluate, save_best


@dataclass
class TrainRun:
    """One training run, filled step by step by :func:`run`."""

    args: Any
    command_line: list[str]
    out: Path
    params: dict
    previous: dict | None = None
    venv: Any = None
    model: Any = None
    start_steps: int = 0
    wall_limit_reached: bool = False
    #: More SB3 callbacks for ``learn`` (e.g. the benchmark's per-episode record).
    extra_callbacks: list = field(default_factory=list)


# ---------------------------------------------------------------------------------- steps
def resolve_run(args, raw: list[str]) -> TrainRun:
    """The hyper-parameters, and for ``--resume`` what the stored run fixes (TrainError)."""
    from ops_controller_ros.policy_io import PolicyLoadError, read_metadata

    out = Path(args.out).expanduser().resolve()
    command_line = ["ros2", "run", "ops_gym_bridge", "train", *raw]
    if args.timesteps < 0:
        raise TrainError("--timesteps must be >= 0")
    if args.max_minutes is not None and not args.max_minutes > 0:
        raise TrainError("--max-minutes must be > 0")
    if args.eval_freq < 0 or args.eval_episodes < 1:
        raise TrainError("--eval-freq must be >= 0 and --eval-episodes >= 1")
    _resolve_rig(args, out, raw)
    if args.init_from:
        return _resolve_init(args, out, command_line, raw)
    if not args.resume:
        if (out / "model.zip").exists():
            raise TrainError(
                f"{out} already holds a model; use --resume to continue it or choose another --out"
            )
        _fill_set_defaults(args)
        try:
            base = hp.load(args.algo, args.hyperparams_set)
        except ValueError as exc:
            raise TrainError(str(exc)) from None
        params = _hyperparams(base, args)
        return TrainRun(args, command_line, out, params)
    try:
        previous = read_metadata(out)
    except PolicyLoadError as exc:
        raise TrainError(f"cannot resume from {out}: {exc}") from None
    given = {a.split("=")[0] for a in raw if a.startswith("--")}
    for key in RUN_KEYS:
        flag = "--" + key.replace("_", "-")
        if flag in given and getattr(args, key) != previous.get(key, getattr(args, key)):
            raise TrainError(
                f"--resume: {flag} {getattr(args, key)} differs from the model's "
                f"{previous[key]} in {out}"
            )
        default = (previous.get("config") or {}).get(key, getattr(args, key))
        setattr(args, key, previous.get(key, default))
    if "--backend" not in given and previous.get("backend"):  # may change, if asked to
        args.backend = previous["backend"]
    if args.hyperparams_set is None:  # a model from before hyper-parameter sets
        args.hyperparams_set = "paper"
    if args.obs_history is None:  # ... or before observation memory
        args.obs_history = int(previous["observation_spec"].get("history", 0))
    if args.observation is None:  # ... or before observation sets
        args.observation = str(previous["observation_spec"].get("observation", "rig"))
    if args.reward is None:  # ... or before training rewards
        args.reward = "paper"
    window = _model_setpoint_window(previous)
    if args.setpoint_window is not None and args.setpoint_window != window:
        raise TrainError(
            f"--resume: --setpoint-window {args.setpoint_window:g} differs from the model's "
            f"{window:g} in {out} (a resumed model keeps its observation)"
        )
    args.setpoint_window = window
    _fill_set_defaults(args)
    params = _hyperparams(
        previous.get("hyperparams") or hp.load(args.algo, args.hyperparams_set), args
    )
    return TrainRun(args, command_line, out, params, previous)


def _resolve_rig(args, out: Path, raw: list[str]) -> None:
    """``args.rig_config``: the rig's OpsConfig fields (--realism, --rig); a resumed run
    without them keeps its model's rig."""
    from ops_controller_ros.policy_io import PolicyLoadError, read_metadata

    try:
        args.rig_config = cli_args.resolve_rig(args.realism, args.rig)
    except ValueError as exc:
        raise TrainError(str(exc)) from None
    if args.rig_config or not args.resume or not ({"--realism", "--rig"}.isdisjoint(raw)):
        return
    try:
        config = read_metadata(out).get("config") or {}
    except PolicyLoadError:
        return  # resolve_run says what is wrong with the stored run
    args.rig_config = {k: config[k] for k in ("realism", *RIG_KEYS) if k in config}


def _resolve_init(args, out: Path, command_line: list[str], raw: list[str]) -> TrainRun:
    """``--init-from DIR``: the initial model's metadata fixes INIT_KEYS (a differing option
    is refused, naming both values) and the hyper-parameters (overrides on top)."""
    from ops_controller_ros.policy_io import PolicyLoadError, read_metadata

    if args.resume:
        raise TrainError("--init-from starts a new run; it cannot be combined with --resume")
    if (out / "model.zip").exists():
        raise TrainError(f"{out} already holds a model; choose another --out")
    source = Path(args.init_from).expanduser().resolve()
    try:
        initial = read_metadata(source)
    except PolicyLoadError as exc:
        raise TrainError(f"--init-from: {exc}") from None
    if not (source / "model.zip").exists():
        raise TrainError(f"--init-from: no model.zip in {source}")
    args.init_from = str(source)  # resolved once; build_model loads from it
    given = {a.split("=")[0] for a in raw if a.startswith("--")}
    for key in INIT_KEYS:
        flag = "--" + key.replace("_", "-")
        value = initial.get(key)
        if flag in given and getattr(args, key) != value:
            raise TrainError(
                f"--init-from: {flag} {getattr(args, key)} differs from the model's {value} in "
                f"{source} (a fine-tuned model keeps its algorithm, stage, detector and "
                "observation)"
            )
        setattr(args, key, value)
    # The task may change (mode, split, episode length, reward, environments); by default it
    # stays the model's.
    for key in ("mode", "split", "episode_steps", "n_envs", "reward", "continue_prob"):
        if "--" + key.replace("_", "-") not in given and initial.get(key) is not None:
            setattr(args, key, initial[key])
    if args.setpoint_window is None:  # a fine-tune may change it; by default the model's
        args.setpoint_window = _model_setpoint_window(initial)
    _fill_set_defaults(args)
    params = _hyperparams(
        initial.get("hyperparams") or hp.load(args.algo, args.hyperparams_set), args
    )
    if params.get("normalize_obs"):
        raise TrainError("--init-from: models trained with normalize_obs are not supported yet")
    previous = {"history": [*initial.get("history", []), {"init_from": str(source)}]}
    return TrainRun(args, command_line, out, params, previous)


def _model_setpoint_window(metadata: dict) -> float:
    """A model's set-point window (0 for models from before the option)."""
    spec = metadata.get("observation_spec") or {}
    return float(spec.get("setpoint_window_cycles", 0.0))


def _fill_set_defaults(args) -> None:
    """Options not given take the hyper-parameter set's defaults (algo, n_envs, obs_history,
    reward)."""
    try:
        defaults = hp.set_defaults(args.hyperparams_set)
    except ValueError as exc:
        raise TrainError(str(exc)) from None
    for key, value in defaults.items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    if args.observation is None:
        args.observation = "rig"
    if args.setpoint_window is None:
        args.setpoint_window = 0.0
    if args.continue_prob is None:
        args.continue_prob = 0.0
    if not args.continue_prob < 1.0:
        raise TrainError(f"--continue-prob must be in [0, 1) (got {args.continue_prob})")
    if args.continue_prob > 0 and (args.backend != "inprocess" or args.n_envs < 2):
        raise TrainError(
            "--continue-prob needs the in-process batched environments (--backend inprocess, "
            f"--n-envs >= 2; got --backend {args.backend}, --n-envs {args.n_envs})"
        )
    if args.obs_history < 0:
        raise TrainError("--obs-history must be >= 0")
    if args.n_envs < 1:
        raise TrainError(f"--n-envs must be >= 1 (got {args.n_envs})")


def _hyperparams(base: dict, args) -> dict:
    try:
        return hp.apply_overrides(base, args.hyperparams, args.algo)
    except ValueError as exc:
        raise TrainError(str(exc)) from None


def build_env(run: TrainRun) -> None:
    """The (monitored, optionally normalized) vector env of the run."""
    from stable_baselines3.common.vec_env import VecNormalize

    args = run.args
    try:
        venv = make_vec_env(
            args.backend,
            args.stage,
            args.mode,
            args.split,
            n_envs=args.n_envs,
            seed=args.seed,
            namespaces=args.namespace,
            timeout_s=args.ros_timeout or None,
            episode_steps=args.episode_steps,
            overrides={"detector": args.detector, **args.rig_config},
            observation_options=observation_options(args),
            continue_prob=args.continue_prob,
        )
    except ValueError as exc:
        raise TrainError(str(exc)) from None
    venv = wrap_training_reward(venv, args.reward)
    if run.params.get("normalize_obs", False):
        vn_path = run.out / "vecnormalize.pkl"
        if args.resume and vn_path.exists():
            venv = VecNormalize.load(str(vn_path), venv)
            venv.training = True
        else:
            venv = VecNormalize(venv, norm_obs=True, norm_reward=False, clip_obs=10.0)
    run.venv = venv


def build_model(run: TrainRun) -> None:
    """A new model from the hyper-parameters, or the stored one for ``--resume``."""
    import torch
    from ops_controller_ros.policy_io import algo_class
    from stable_baselines3.common.logger import configure

    args, out = run.args, run.out
    if args.torch_threads > 0:
        torch.set_num_threads(args.torch_threads)
    out.mkdir(parents=True, exist_ok=True)
    cls = algo_class(args.algo)
    if args.init_from:
        source = Path(args.init_from) / "model.zip"
        model = cls.load(str(source), env=run.venv, device=args.device)
        print(
            f"[train] fine-tuning {args.algo} from {source} (step {model.num_timesteps}; an "
            "empty replay buffer)",
            flush=True,
        )
    elif args.resume:
        source = out / "model.zip"
        if not source.exists():
            source = _latest_checkpoint(out)
            if source is None:
                raise TrainError(f"nothing to resume in {out}: no model.zip and no checkpoint")
        model = cls.load(str(source), env=run.venv, device=args.device)
        rb = out / "replay_buffer.pkl"
        if hasattr(model, "replay_buffer") and rb.exists():
            model.load_replay_buffer(str(rb))
        print(
            f"[train] resuming {args.algo} from {source.name} at step {model.num_timesteps}",
            flush=True,
        )
    else:
        action_dim = int(np.prod(run.venv.action_space.shape))
        try:
            kwargs = hp.sb3_kwargs(args.algo, run.params, action_dim)
            model = cls(env=run.venv, seed=args.seed, device=args.device, verbose=0, **kwargs)
        except (TypeError, ValueError) as exc:
            raise TrainError(f"invalid hyper-parameters for {args.algo}: {exc}") from None
    model.set_logger(configure(str(out / "logs"), ["csv", "tensorboard"]))
    run.model = model
    run.start_steps = int(model.num_timesteps)


def learn_and_save(run: TrainRun) -> tuple[bool, BaseException | None, float]:
    """Train; on success, Ctrl-C / SIGTERM or an error after the first step, save the model.
    Returns (interrupted, error, wall seconds)."""
    from ops_controller_ros.policy_io import save_metadata

    from .callbacks import training_callbacks

    args, out, model = run.args, run.out, run.model
    total = run.start_steps + args.timesteps
    every = max(int(run.params.get("checkpoint_freq", 10000)) // max(args.n_envs, 1), 1)
    normalize = bool(run.params.get("normalize_obs", False))
    max_s = None if not args.max_minutes else 60.0 * args.max_minutes
    t0_ref = [time.monotonic()]
    best = _best_model_hooks(run, t0_ref) if args.eval_freq > 0 else None
    callbacks = training_callbacks(total, not args.no_progress, every, out, normalize, max_s, best)
    callbacks.callbacks.extend(run.extra_callbacks)
    # Checkpoints are loadable with policy_io too: they share this metadata (steps: planned).
    meta = build_metadata(
        args, run.params, model, run.venv, run.command_line, 0.0, False, run.previous
    )
    save_metadata(out / "checkpoints", {**meta, "checkpoint": True})

    _STOP_SIGNALS.clear()
    previous_handler = signal.signal(signal.SIGTERM, _stop_to_interrupt)
    signal.signal(signal.SIGINT, _stop_to_interrupt)
    interrupted, error = False, None
    t0 = t0_ref[0] = time.monotonic()
    print(
        f"[train] training started: {args.algo} stage={args.stage} mode={args.mode} "
        f"detector={args.detector} backend={args.backend} n_envs={args.n_envs} "
        f"obs_history={args.obs_history} observation={args.observation} reward={args.reward} "
        f"hyperparams_set={args.hyperparams_set} setpoint_window={args.setpoint_window:g} "
        f"continue_prob={args.continue_prob:g} "
        + "".join(f"{k}={v} " for k, v in sorted(args.rig_config.items()))
        + f"steps {run.start_steps} -> {total}, out={out}",
        flush=True,
    )
    try:
        model.learn(
            total_timesteps=args.timesteps,
            callback=callbacks,
            # a fine-tuned model keeps its step count: past learning_starts, it acts from the
            # first step instead of filling its new buffer with random actions
            reset_num_timesteps=not (args.resume or args.init_from),
            log_interval=1,
        )
    except KeyboardInterrupt:
        interrupted = True
    except Exception as exc:  # e.g. the simulator died: keep what was learned, then report
        if _STOP_SIGNALS:  # the stop, surfacing through a C++ call (see _stop_to_interrupt)
            interrupted = True
        else:
            error = exc
    finally:
        # A second Ctrl-C must not corrupt the model being written.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        callbacks.callbacks[0].close()
    run.wall_limit_reached = any(getattr(c, "reached", False) for c in callbacks.callbacks)
    wall = time.monotonic() - t0
    try:
        # A run that failed before its first step (e.g. no simulator) has nothing worth saving.
        if error is None or model.num_timesteps > run.start_steps:
            failed = interrupted or error is not None
            _save(
                out, args, run.params, model, run.venv, run.command_line, wall, failed, run.previous
            )
    finally:
        with contextlib.suppress(Exception):  # closing must not hide the result
            run.venv.close()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, previous_handler)
    return interrupted, error, wall


def summarize(run: TrainRun, interrupted: bool, error: BaseException | None, wall: float) -> int:
    """Print how the run ended; returns the exit code."""
    model, out = run.model, run.out
    powers = final_powers(model.ep_info_buffer or [])
    summary = (
        f"{model.num_timesteps} steps ({model.num_timesteps - run.start_steps} new) in {wall:.1f} s"
    )
    if powers.size:
        summary += (
            f"; last {powers.size} episodes: return "
            f"{np.mean([ep['r'] for ep in model.ep_info_buffer]):.2f}, final P_N/P_max "
            f"{powers.mean():.3f}"
        )
    if error is not None:
        print(f"[train] error after {summary}: {type(error).__name__}: {error}", file=sys.stderr)
        if model.num_timesteps > run.start_steps:
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
    why = f" (stopped at --max-minutes {run.args.max_minutes:g})" if run.wall_limit_reached else ""
    print(f"[train] done: {summary}{why}; model saved to {out / 'model.zip'}", flush=True)
    return 0


def _fail(message: str, code: int = 2) -> int:
    print(f"[train] error: {message}", file=sys.stderr, flush=True)
    return code


def run(argv: list[str] | None = None) -> int:
    raw = list(sys.argv[1:] if argv is None else argv)
    args = cli_args.parse_args(build_parser(), raw)
    train_run = None
    try:
        train_run = resolve_run(args, raw)
        build_env(train_run)
        build_model(train_run)
    except TrainError as exc:
        if train_run is not None and train_run.venv is not None:
            train_run.venv.close()
        return _fail(str(exc))
    return summarize(train_run, *learn_and_save(train_run))


def main(argv: list[str] | None = None) -> None:
    limit_blas_threads()
    try:
        code = run(argv)
    except KeyboardInterrupt:  # before training started: nothing to save
        print("\n[train] interrupted before training started; nothing saved", file=sys.stderr)
        code = EXIT_INTERRUPTED
    sys.exit(code)


if __name__ == "__main__":
    main()
