"""The one way a training run's env and model are built: ``train``, the benchmark's training runs
(:mod:`ops_experiments.table1.bench_worker`) and the training bench (``ops_bench training``) all
call :func:`build_model` with ``train``'s own options, so each measures what a user's ``ros2 run
ops_gym_bridge train`` does.

    run = build_model(["--algo", "sac", "--stage", "5", "--mode", "medium", "--timesteps", "0"],
                      out="runs/x")
    run.model, run.venv, run.params   # the SB3 model, its vector env, the hyper-parameters

Steps (what :func:`build_model` does): :func:`~.training_run.resolve_run` (options, ``--resume``,
``--init-from``, hyper-parameters), :func:`make_env` (the monitored vector env with the training
reward, normalized if asked), :func:`make_model` (a new model, the stored one for ``--resume``, or
the initial one of ``--init-from``). Train it with :func:`.learn.learn_and_save`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from . import cli_args
from . import hyperparams as hp
from .envs import make_vec_env
from .progress_log import keep_earlier_parts
from .rewards import wrap_training_reward
from .training_run import TrainError, TrainRun, observation_options, resolve_run


def build_model(options: Sequence[str], out: str | Path | None = None) -> TrainRun:
    """The env and model of a training run, built as ``ros2 run ops_gym_bridge train OPTIONS
    --out OUT`` builds them. ``options``: train's command-line options (strings, as typed);
    ``out``: the run's directory (or ``--out`` among the options). Returns the
    :class:`~.training_run.TrainRun` (``model``, ``venv``, ``params``, ``args``: every option
    resolved, ``out``); raises :class:`~.training_run.TrainError` for a run that cannot start
    (its env closed), SystemExit(2) for options train's parser refuses."""
    from .train import build_parser

    raw = [*options, *(["--out", str(out)] if out is not None else [])]
    run = resolve_run(cli_args.parse_args(build_parser(), raw), raw)
    try:
        make_env(run)
        make_model(run)
    except TrainError:
        if run.venv is not None:
            run.venv.close()
        raise
    return run


#: Hyper-parameters a fine-tuned model (``--init-from``) takes from the run when it is loaded.
_TUNABLE_ON_LOAD = ("learning_rate", "batch_size", "gamma", "tau", "gradient_steps")


def _latest_checkpoint(out: Path) -> Path | None:
    ckpts = sorted(
        (out / "checkpoints").glob("model_*_steps.zip"),
        key=lambda p: int(p.stem.split("_")[1]) if p.stem.split("_")[1].isdigit() else -1,
    )
    return ckpts[-1] if ckpts else None


def make_env(run: TrainRun) -> None:
    """The (monitored, optionally normalized) vector env of the run."""
    from stable_baselines3.common.vec_env import VecNormalize

    args = run.args
    if args.critic_observation == "privileged":
        from .asymmetric import make_privileged_vec_env

        run.venv = wrap_training_reward(make_privileged_vec_env(args), args.reward)
        return
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
            rig_randomize=args.rig_ranges or None,
            hold_steps=args.hold_steps,
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


def make_model(run: TrainRun) -> None:
    """A new model from the hyper-parameters, or the stored one for ``--resume``."""
    import torch
    from ops_controller_ros.policy_io import algo_class
    from stable_baselines3.common.logger import configure

    args, out = run.args, run.out
    if args.torch_threads > 0:
        torch.set_num_threads(args.torch_threads)
    out.mkdir(parents=True, exist_ok=True)
    cls = algo_class(args.algo)
    # A loaded model (--init-from, --resume) takes the run's values of what an update reads
    # (the stored model's, or --hyperparams'): SB3's load would otherwise keep the stored ones
    # (learning_rate=0.0003 was ignored).
    tuned = {k: run.params[k] for k in _TUNABLE_ON_LOAD if k in run.params}
    if args.init_from:
        source = Path(args.init_from) / "model.zip"
        model = cls.load(str(source), env=run.venv, device=args.device, **tuned)
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
        model = cls.load(str(source), env=run.venv, device=args.device, **tuned)
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
            if args.critic_observation == "privileged":
                from .asymmetric import asymmetric_policy

                kwargs.update(asymmetric_policy(run.venv, kwargs.get("policy_kwargs")))
            model = cls(env=run.venv, seed=args.seed, device=args.device, verbose=0, **kwargs)
        except (TypeError, ValueError) as exc:
            raise TrainError(f"invalid hyper-parameters for {args.algo}: {exc}") from None
    if args.resume:  # SB3's CSV logger starts its file afresh: keep the earlier parts
        keep_earlier_parts(out / "logs")
    model.set_logger(configure(str(out / "logs"), ["csv", "tensorboard"]))
    run.model = model
    run.start_steps = int(model.num_timesteps)
