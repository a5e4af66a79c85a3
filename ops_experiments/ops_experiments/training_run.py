"""A training run's options resolved: what ``train`` was asked, what a stored model fixes
(``--resume``) or passes on (``--init-from``), and the hyper-parameters (:class:`TrainRun`).

Pure of stable-baselines3 and torch: :mod:`.build` builds the run's env and model,
:mod:`.learn` trains and saves it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ops_contract.config import RIG_KEYS, TIME_KEYS, make_config
from ops_contract.rig_randomization import RigRanges

from . import cli_args
from . import hyperparams as hp

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
    "hold_steps",
    "critic_observation",
)


#: What a fine-tuned run (``--init-from``) keeps of its initial model; the task (mode, split,
#: episode length, reward, environments) may change.
INIT_KEYS = ("algo", "stage", "detector", "obs_history", "observation", "hyperparams_set")


class TrainError(RuntimeError):
    """A run that cannot start; the message says why (exit code 2)."""


def observation_options(args) -> dict[str, Any]:
    """The run's observation choices (memory, observation set, set-point window) for every env
    it builds."""
    options = {"history": args.obs_history, "observation": args.observation}
    if args.setpoint_window:  # (left out when 0: a spec as before the option)
        options["setpoint_window_cycles"] = args.setpoint_window
    return options


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


def resolve_run(args, raw: list[str]) -> TrainRun:
    """The hyper-parameters, and for ``--resume`` what the stored run fixes (TrainError)."""
    run = _resolve(args, raw)
    _check_critic(run)
    return run


def _check_critic(run: TrainRun) -> None:
    """An asymmetric critic (``--critic-observation privileged``, :mod:`.asymmetric`) reads the
    batched simulator's hidden state, and its saved model is the actor alone: refuse the runs it
    cannot make."""
    args = run.args
    if args.critic_observation != "privileged":
        return
    why = None
    if args.resume or args.init_from:
        why = ("cannot --resume or --init-from: the saved model is the actor alone, without "
               "the critic that saw the privileged values")  # fmt: skip
    elif args.algo != "sac":
        why = f"is an asymmetric SAC: --algo sac (got {args.algo})"
    elif args.backend != "inprocess" or args.rig_ranges:
        why = "needs the simulator's state: --backend inprocess, one rig (no --rig-randomize)"
    elif args.observation != "rig":
        why = f"trains an actor on the rig's observation (got --observation {args.observation})"
    elif run.params.get("normalize_obs"):
        why = "does not support normalize_obs"
    if why:
        raise TrainError(f"--critic-observation privileged {why}")


def _resolve(args, raw: list[str]) -> TrainRun:
    from ops_contract.policy_meta import PolicyLoadError, read_meta

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
        previous = read_meta(out).to_dict()
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
    """``args.rig_config``: the rig's OpsConfig fields (--realism, --rig), and
    ``args.rig_ranges``: those drawn per episode (--rig-randomize); a resumed run without them
    keeps its model's."""
    try:
        args.rig_config = cli_args.resolve_rig(args.realism, args.rig)
        args.rig_ranges = cli_args.resolve_rig_randomize(getattr(args, "rig_randomize", None))
    except ValueError as exc:
        raise TrainError(str(exc)) from None
    if args.resume:
        _resume_rig(args, out, raw)
    for bound in args.rig_ranges.bounds() if args.rig_ranges else ():
        try:  # each end of every range with the rest of the rig
            make_config(**{**args.rig_config, **bound})
        except ValueError as exc:
            raise TrainError(f"--rig-randomize {args.rig_ranges.describe()}: {exc}") from None


def _resume_rig(args, out: Path, raw: list[str]) -> None:
    """A resumed run keeps its model's rig (with the physical time ``--rig`` gave it: time base,
    step, vibration) and the ranges it draws its rigs from, unless the command line gives them
    anew."""
    from ops_contract.policy_meta import PolicyLoadError, read_meta

    try:
        stored = read_meta(out).to_dict()
    except PolicyLoadError:
        return  # resolve_run says what is wrong with the stored run
    if not args.rig_config and {"--realism", "--rig"}.isdisjoint(raw):
        config = stored.get("config") or {}
        keys = ("realism", *RIG_KEYS, *TIME_KEYS)
        args.rig_config = {k: config[k] for k in keys if k in config}
    if getattr(args, "rig_randomize", None) is None and stored.get("rig_randomize"):
        try:
            args.rig_ranges = RigRanges.from_value(stored["rig_randomize"])
        except (TypeError, ValueError) as exc:
            raise TrainError(f"cannot resume from {out}: its rig_randomize: {exc}") from None


def _resolve_init(args, out: Path, command_line: list[str], raw: list[str]) -> TrainRun:
    """``--init-from DIR``: the initial model's metadata fixes INIT_KEYS (a differing option
    is refused, naming both values) and the hyper-parameters (overrides on top)."""
    from ops_contract.policy_meta import PolicyLoadError, read_meta

    if args.resume:
        raise TrainError("--init-from starts a new run; it cannot be combined with --resume")
    if (out / "model.zip").exists():
        raise TrainError(f"{out} already holds a model; choose another --out")
    source = Path(args.init_from).expanduser().resolve()
    try:
        initial = read_meta(source).to_dict()
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
    keys = ("mode", "split", "episode_steps", "n_envs", "reward", "continue_prob", "hold_steps")
    for key in keys:
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
    # the initial model's lineage, and all the training behind it (training_wall_s)
    previous = {
        "history": [*initial.get("history", []), {"init_from": str(source)}],
        "training_wall_s": initial.get("training_wall_s"),
    }
    return TrainRun(args, command_line, out, params, previous)


def _model_setpoint_window(metadata: dict) -> float:
    """A model's set-point window (0 for models from before the option)."""
    spec = metadata.get("observation_spec") or {}
    return float(spec.get("setpoint_window_cycles", 0.0))


def _fill_set_defaults(args) -> None:
    """Options not given take the hyper-parameter set's defaults (algo, n_envs, obs_history,
    reward) or their own (observation, set-point window, continue_prob, hold_steps)."""
    try:
        defaults = hp.set_defaults(args.hyperparams_set)
    except ValueError as exc:
        raise TrainError(str(exc)) from None
    for key, value in defaults.items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    if args.observation is None:
        args.observation = "rig"
    if args.critic_observation is None:
        args.critic_observation = "rig"
    if args.setpoint_window is None:
        args.setpoint_window = 0.0
    if args.continue_prob is None:
        args.continue_prob = 0.0
    if args.hold_steps is None:  # (and models from before held decisions)
        args.hold_steps = 1
    if args.hold_steps != 1 and args.backend != "inprocess":
        raise TrainError(
            f"--hold-steps holds each decision in the simulator: it needs --backend inprocess "
            f"(got --backend {args.backend})"
        )
    if not args.continue_prob < 1.0:
        raise TrainError(f"--continue-prob must be in [0, 1) (got {args.continue_prob})")
    if args.continue_prob > 0 and args.backend != "inprocess":
        raise TrainError(
            "--continue-prob carries a run on in the simulator: it needs --backend inprocess "
            f"(got --backend {args.backend})"
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
