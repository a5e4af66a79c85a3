"""Train a built run (:mod:`.build`) and save it: model, replay buffer, normalization, the
metadata the policy runner reads (written through ``ops_contract.policy_meta``, its schema:
``recipe`` the algo, ``recurrent`` the model's LSTM if it has one, ``training_wall_s`` the runs
behind it), checkpoints and the best model of ``--eval-freq``. Ctrl-C / SIGTERM stop training and
save a usable model.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import signal
import time
from pathlib import Path
from typing import Any

from ops_contract.config import make_config

from .envs import final_powers
from .training_run import TrainRun, observation_options

_STOP_SIGNALS: list[int] = []  # Ctrl-C / SIGTERM received while training


def _stop_to_interrupt(signum, frame):
    """Ctrl-C and SIGTERM stop a training run the same way. Recorded as well as raised: a
    KeyboardInterrupt raised while rclpy converts a message in C++ reaches Python as a
    RuntimeError ("Unable to convert call argument"), which is still a requested stop."""
    _STOP_SIGNALS.append(signum)
    raise KeyboardInterrupt


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
    from ops_contract.policy_meta import library_versions

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
        "recipe": recipe_of(args),
        "critic_observation": critic_observation(args),
        "recurrent": recurrent_of(model),
        "training_wall_s": training_wall_s(previous, history),
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
        "rig_randomize": args.rig_ranges.to_dict() if args.rig_ranges else None,
        "reward": args.reward,
        "hyperparams_set": args.hyperparams_set,
        "continue_prob": args.continue_prob,
        # readings per decision (0: auto, each rig's latency_steps + 1): evaluate and the policy
        # node hold the model so by default (ops_contract.policy_meta: PolicyMeta.hold_steps)
        "hold_steps": args.hold_steps,
        "hyperparams": params,
        "interrupted": interrupted,
        "train_final_power_mean": float(powers.mean()) if powers.size else None,
        "history": history,
    }


def critic_observation(args) -> str:
    """What the run's critic sees (``train --critic-observation``; rig for runs without one)."""
    return getattr(args, "critic_observation", None) or "rig"


def recipe_of(args) -> str:
    """The metadata's ``recipe``: the algo, or ``asymmetric-sac`` for an asymmetric critic."""
    if critic_observation(args) == "privileged":
        return f"asymmetric-{args.algo}"
    return args.algo


def saved_model(args, model):
    """What a model directory holds of a run's model: the model itself, or for an asymmetric
    critic the actor alone on the rig's observation (:func:`.asymmetric.export_actor`)."""
    if critic_observation(args) != "privileged":
        return model
    from .asymmetric import export_actor

    return export_actor(model)


def recurrent_of(model) -> dict | None:
    """The metadata's ``recurrent`` entry of an SB3 model: its LSTM (sb3-contrib
    RecurrentPPO), or None for a policy without a recurrent state."""
    shape = getattr(getattr(model, "policy", None), "lstm_hidden_state_shape", None)
    if shape is None:
        return None
    layers, _, hidden = shape
    return {"kind": "lstm", "hidden": int(hidden), "layers": int(layers)}


def training_wall_s(previous: dict | None, history: list) -> float | None:
    """The wall seconds of all the training behind a model: the runs of its lineage
    (``history``, this run's included), plus what the model it was resumed or fine-tuned from
    counted beyond its own lineage (a teacher, distillation)."""
    from ops_contract.policy_meta import lineage_wall_s

    total = lineage_wall_s({"history": history})
    before = (previous or {}).get("training_wall_s")
    if before is not None:
        beyond = float(before) - (lineage_wall_s(previous) or 0.0)
        total = (total or 0.0) + max(beyond, 0.0)
    return None if total is None else round(total, 2)


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
    from ops_contract.policy_meta import write_meta

    out.mkdir(parents=True, exist_ok=True)
    tmp = out / "model.tmp.zip"
    saved = saved_model(args, model)
    saved.save(str(tmp))
    tmp.replace(out / "model.zip")
    replay = replay and saved is model  # (an exported actor cannot be resumed)
    if replay and hasattr(model, "replay_buffer") and model.replay_buffer is not None:
        model.save_replay_buffer(str(out / "replay_buffer.pkl"))
    from stable_baselines3.common.vec_env import VecNormalize

    if isinstance(venv, VecNormalize):
        venv.save(str(out / "vecnormalize.pkl"))
    meta = build_metadata(args, params, model, venv, argv, wall_s, interrupted, previous)
    write_meta(out, {**meta, **(extra or {})})


def _best_model_hooks(run: TrainRun, t0_ref: list[float]):
    """(every, evaluate, save_best) of --eval-freq: deterministic test-environment episodes on
    the batched simulator, with the run's observation (memory), normalization and held
    decisions (auto: the fixed rig's latency_steps + 1, as ``evaluate`` resolves it)."""
    from ops_contract.held import resolve_hold_steps
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
    hold = resolve_hold_steps(args.hold_steps, cfg.latency_steps)

    def evaluate(model) -> float:
        venv = run.venv
        norm = venv.normalize_obs if isinstance(venv, VecNormalize) else (lambda o: o)
        if critic_observation(args) == "privileged":  # the actor, on the rig's observation
            from .asymmetric import actor_predict

            predict = actor_predict(model)
        else:
            predict = lambda obs: model.predict(norm(obs), deterministic=True)[0]  # noqa: E731
        res = rollout_policy(
            predict,
            cfg,
            args.eval_episodes,
            args.episode_steps,
            seed=0,
            observation_options=observation_options(args),
            hold_steps=hold,
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


def _carry_best(callbacks, best_dir: Path) -> None:
    """The best evaluation so far of a resumed run (DIR/best's ``eval_final_power``): a later
    evaluation replaces DIR/best only if it is better, as within one run."""
    from ops_contract.policy_meta import PolicyLoadError, read_meta

    from .callbacks import BestModelCallback

    try:
        power = read_meta(best_dir).entries.get("eval_final_power")
    except PolicyLoadError:
        return
    for callback in callbacks.callbacks:
        if isinstance(callback, BestModelCallback) and isinstance(power, int | float):
            callback.best = float(power)
            print(f"[train] best so far (DIR/best): final P_N/P_max {power:.4f}", flush=True)


def _latency_note(args) -> None:
    """Say so when the observation's memory is shorter than the commands in flight: with
    latency L a policy sees what its last L actions did only with --obs-history >= L + 1
    (docs/physics.md, "A rig drawn per episode")."""
    latency = make_config(args.stage, **args.rig_config).latency_steps
    if args.rig_ranges:
        latency = args.rig_ranges.max_latency(latency)
    if args.hold_steps == 0 or args.hold_steps > latency:
        return  # held decisions: every decision's reading shows the commands before it
    if latency > 0 and args.observation == "rig" and args.obs_history < latency + 1:
        print(
            f"[train] note: latency up to {latency} steps with --obs-history "
            f"{args.obs_history}: the policy cannot see all the commands in flight (use "
            f"--obs-history {latency + 1} or more)",
            flush=True,
        )


def _warm_buffer_until(run: TrainRun) -> int | None:
    """A fine-tune (``--init-from``) starts with an empty replay buffer. As SB3 does with
    ``learning_starts`` for a new model, it first fills the buffer for that many steps, but with
    its own policy's actions instead of random ones, and makes no update meanwhile
    (:class:`.callbacks.WarmBuffer`): its first updates then see the states it visits, not a few
    hundred samples it overfits (the first held ``lab`` fine-tune fell from 0.83 to 0.54 before
    recovering). Returns the step the updates start at (None: no warm-up)."""
    args, model = run.args, run.model
    steps = min(int(run.params.get("learning_starts", 0) or 0), args.timesteps)
    if not args.init_from or steps <= 0 or not hasattr(model, "replay_buffer"):
        return None
    print(
        f"[train] fine-tune: {steps} steps of the model's own actions into its new replay "
        "buffer before the first update (learning_starts)",
        flush=True,
    )
    return run.start_steps + steps


def _actor_frozen_until(run: TrainRun, warm_until: int | None) -> int | None:
    """The step until which the actor is kept as it is (:class:`.callbacks.ActorFreeze`): a
    fine-tune with ``critic_warmup`` fixes it once, after its warm buffer, and stores it in the
    hyper-parameters, so a resumed run keeps it. None: no warm-up (or not an actor-critic)."""
    params, model = run.params, run.model
    if not hasattr(model, "actor"):
        return None
    if run.args.init_from and int(params.get("critic_warmup", 0) or 0) > 0:
        start = warm_until or run.start_steps
        params["actor_frozen_until"] = start + int(params["critic_warmup"])
    until = params.get("actor_frozen_until")
    return int(until) if until else None


def _callbacks(run: TrainRun, t0_ref: list[float]):
    """The run's SB3 callbacks (progress, checkpoints, --eval-freq's best model, the time
    limit, a fine-tune's warm buffer and frozen actor, the caller's extra ones); the metadata
    its checkpoints share is written here."""
    from ops_contract.policy_meta import write_meta

    from .callbacks import training_callbacks

    args, out, model = run.args, run.out, run.model
    total = run.start_steps + args.timesteps
    every = max(int(run.params.get("checkpoint_freq", 10000)) // max(args.n_envs, 1), 1)
    normalize = bool(run.params.get("normalize_obs", False))
    max_s = None if not args.max_minutes else 60.0 * args.max_minutes
    best = _best_model_hooks(run, t0_ref) if args.eval_freq > 0 else None
    # A fine-tuned model is evaluated before its first step too: its starting figure, and
    # DIR/best never worse than the model it started from.
    callbacks = training_callbacks(
        total, not args.no_progress, every, out, normalize, max_s, best, bool(args.init_from)
    )
    callbacks.callbacks.extend(run.extra_callbacks)
    if critic_observation(args) == "privileged":  # checkpoints of the actor alone
        from stable_baselines3.common.callbacks import CheckpointCallback

        from .asymmetric import ExportCheckpoint

        for i, c in enumerate(callbacks.callbacks):
            if isinstance(c, CheckpointCallback):
                callbacks.callbacks[i] = ExportCheckpoint(c.save_freq, c.save_path, c.name_prefix)
    warm_until = _warm_buffer_until(run)
    if warm_until is not None:
        from .callbacks import WarmBuffer

        callbacks.callbacks.insert(1, WarmBuffer(warm_until))
    until = _actor_frozen_until(run, warm_until)
    if until is not None:
        from .callbacks import ActorFreeze

        callbacks.callbacks.insert(1, ActorFreeze(until))  # [0], the progress bar, is closed last
    if best is not None and args.resume:  # a resumed run keeps DIR/best unless it beats it
        _carry_best(callbacks, out / "best")
    # Checkpoints are loadable too: they share this metadata (policy_meta.read_meta reads each
    # one's step count from its name).
    meta = build_metadata(
        args, run.params, model, run.venv, run.command_line, 0.0, False, run.previous
    )
    write_meta(out / "checkpoints", {**meta, "checkpoint": True})
    return callbacks


def learn_and_save(run: TrainRun) -> tuple[bool, BaseException | None, float]:
    """Train; on success, Ctrl-C / SIGTERM or an error after the first step, save the model.
    Returns (interrupted, error, wall seconds)."""
    args, out, model = run.args, run.out, run.model
    total = run.start_steps + args.timesteps
    t0_ref = [time.monotonic()]
    callbacks = _callbacks(run, t0_ref)

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
        + ("critic_observation=privileged " if critic_observation(args) == "privileged" else "")
        + (f"hold_steps={args.hold_steps or 'auto'} " if args.hold_steps != 1 else "")
        + "".join(f"{k}={v} " for k, v in sorted(args.rig_config.items()))
        + (f"rig_randomize=[{args.rig_ranges.describe()}] " if args.rig_ranges else "")
        + f"steps {run.start_steps} -> {total}, out={out}",
        flush=True,
    )
    _latency_note(args)
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
        for callback in callbacks.callbacks:  # the model is saved with its own settings
            getattr(callback, "restore", lambda: None)()
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
