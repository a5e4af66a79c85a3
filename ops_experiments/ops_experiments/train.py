"""``ros2 run ops_gym_bridge train``: train PPO / TD3 / SAC (or sb3-contrib's TQC / CrossQ) on
the pulse stacker.

In-process (fast, default) or through the ROS 2 bridge against running simulators in lockstep
mode (``--backend ros``). Defaults are the paper's selected hyper-parameters
(``yaml/<algo>.yaml``), with 200-step episodes; ``--hyperparams-set fast``
(``yaml/fast.yaml``) trains on many batched environments with fewer gradient steps per
environment step, and chooses the algorithm, ``--n-envs`` and ``--obs-history`` unless given.
``--obs-history K`` gives the policy memory: each observation holds the last K observations and
the actions that led to them (``ops_contract.observation``; saved in the metadata).
``--observation authors`` trains on the authors' observation set (their ``CPS_env`` default, with
the actual delay-line lengths, a simulator-only oracle) instead of the rig's (the default).
``--critic-observation privileged`` trains an asymmetric actor-critic (SAC): the critic also sees
the simulator's true delay errors, the actor and the saved model the rig's observation only
(:mod:`.asymmetric`).
``--hold-steps K`` trains with held decisions (:mod:`ops_contract.held`): each environment step is
one decision, the action applied on the first of K simulator steps and held (increment 0) on the
others, the observation built from the last reading alone (its memory holds the decisions'
readings only: what ``evaluate --hold-steps`` and the policy node's ``hold_steps`` give a
policy); ``auto``: K = each environment's latency_steps + 1, per episode with
``--rig-randomize``. The reward is the last reading's, episodes keep ``--episode-steps``
simulator steps (so about that / K decisions), and ``--timesteps`` counts decisions. Saved in
the metadata (``hold_steps``; 0 for auto), so ``evaluate`` and the policy node hold the model so
by default.

Output directory (``--out DIR``)::

    DIR/model.zip          the trained model (stable-baselines3)
    DIR/metadata.json      what the policy runner needs (ops_contract.policy_meta)
    DIR/logs/              progress.csv and TensorBoard events (a resumed run keeps the
                           earlier parts' as progress.partK.csv: experiments.progress_log)
    DIR/checkpoints/       model_<steps>_steps.zip on a schedule (+ metadata.json)
    DIR/replay_buffer.pkl  (TD3 / SAC) the replay buffer, for --resume
    DIR/vecnormalize.pkl   (normalize_obs=true) the normalization statistics, for --resume
    DIR/best/              (--eval-freq) the model that evaluated best during training
                           (model.zip + metadata.json with eval_final_power; a model directory)

Ctrl-C (or SIGTERM) stops training, saves a usable model and metadata, and exits with code 130.

This module is the command line; the run is resolved by :mod:`.training_run`, built by
:func:`.build.build_model` (as the benchmark and the training bench build theirs) and trained and
saved by :mod:`.learn`.
"""

from __future__ import annotations

import sys

import numpy as np
from ops_contract.heap import freeze_after_heavy_imports
from ops_contract.observation import OBSERVATION_SETS
from ops_contract.policy_meta import CRITIC_OBSERVATIONS
from ops_contract.threads import limit_blas_threads

from . import cli_args
from . import hyperparams as hp
from .build import build_model, make_env, make_model  # noqa: F401  (train's steps)
from .cli_args import strip_ros_args  # noqa: F401  (kept importable from here)
from .envs import BACKENDS, EPISODE_STEPS, final_powers
from .learn import learn_and_save
from .rewards import REWARDS
from .training_run import TrainError, TrainRun, resolve_run  # noqa: F401

EXIT_INTERRUPTED = 130


def build_parser():
    p = cli_args.make_parser(
        "train", "Train a learned controller (stable-baselines3) for optical pulse stacking."
    )
    _add_algorithm_arguments(p)
    cli_args.add_env_arguments(p)
    cli_args.add_rig_arguments(p, "the policy (its training environments)")
    cli_args.add_rig_randomize_argument(p)
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
        help="named defaults: paper (yaml/<algo>.yaml, the paper's tables), authors "
        "(yaml/authors.yaml, the authors' code's values) or fast (yaml/fast.yaml: "
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
        "steep near the optimum; ops_experiments.rewards). Evaluations always "
        "measure P_N/P_max (default: the set's; paper for paper)",
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
        "--critic-observation",
        choices=CRITIC_OBSERVATIONS,
        default=None,
        help="what SAC's critic sees in training: rig (the actor's observation) or privileged "
        "(the rig's observation and the simulator's true delay errors and drift: an asymmetric "
        "actor-critic, ops_experiments.asymmetric); the actor, and the model saved, see the "
        "rig's observation only; in-process, batched, one rig (default: rig)",
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
    p.add_argument(
        "--hold-steps",
        type=cli_args.hold_steps_type,
        default=None,
        metavar="K",
        help="held decisions: each environment step is one decision of K simulator steps (the "
        "action on the first, the command held on the others), the observation and its memory "
        "built from the decisions' readings alone, as evaluate --hold-steps runs a policy; "
        "auto (or 0): each environment's latency_steps + 1 (with --rig-randomize, the "
        "episode's); the reward is the last reading's and episodes keep --episode-steps "
        "simulator steps; saved in the metadata, so evaluate and the policy node hold the "
        "model so unless told otherwise (default: 1, every reading; --resume and --init-from: "
        "the model's)",
    )
    cli_args.add_key_value_argument(
        p, "--hyperparams", help="override defaults from yaml/<algo>.yaml (YAML values)"
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
        help="continue training the model in --out (step count continues; --hyperparams' "
        "learning_rate, batch_size, gamma, tau, gradient_steps apply from here on)",
    )
    p.add_argument(
        "--init-from",
        metavar="MODEL_DIR",
        help="start from a trained model's weights (fine-tuning, e.g. with longer episodes or "
        "in another mode): its algorithm, stage, detector, observation and hyper-parameters are "
        "kept, the step count continues, its training history goes into the new metadata; "
        "--hyperparams' learning_rate, batch_size, gamma, tau, gradient_steps apply; with "
        "--eval-freq it is evaluated before its first step too. Its new replay buffer first "
        "takes learning_starts steps of its own actions (no update meanwhile), and with "
        "--hyperparams critic_warmup=STEPS only the critic learns for that many steps more",
    )
    p.add_argument("--episode-steps", type=int, default=EPISODE_STEPS, help="steps per episode")
    p.add_argument(
        "--continue-prob",
        type=cli_args.non_negative_float,
        default=None,
        metavar="Q",
        help="probability that an ending episode carries on from where it is (delays, drift, "
        "set-points) instead of a fresh start: the states of a long run enter the training data "
        "(in-process environments, batched or drawing a rig per episode, which a carried-on "
        "run keeps; default 0; --resume and --init-from: the model's)",
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


def print_outcome(
    run: TrainRun, interrupted: bool, error: BaseException | None, wall: float
) -> int:
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
    try:
        train_run = build_model(raw)
    except TrainError as exc:
        return _fail(str(exc))
    return print_outcome(train_run, *learn_and_save(train_run))


def main(argv: list[str] | None = None) -> None:
    limit_blas_threads()
    freeze_after_heavy_imports()
    try:
        code = run(argv)
    except KeyboardInterrupt:  # before training started: nothing to save
        print("\n[train] interrupted before training started; nothing saved", file=sys.stderr)
        code = EXIT_INTERRUPTED
    sys.exit(code)


if __name__ == "__main__":
    main()
