"""``ros2 run ops_gym_bridge evaluate``: evaluate a trained model or a controller.

A model directory (from ``train --out``), or ``--controller NAME`` (``--spgd``: SPGD-PID) from
:mod:`ops_controller_ros.controllers` with ``--controller-param KEY=VALUE``. ``--env KEY=VALUE``
changes the simulated environment (e.g. ``detector_noise=0.01 pulse_fwhm_fs=1200``) without
telling the controller: it is built for the nominal configuration of stage, mode, split and
detector.

Runs ``--episodes`` episodes for each of ``--seeds`` on the training and the testing environment
(``--splits train test``; the testing environment of hard mode has the shifted noise of the paper's
section 2.2), in-process. Reports, per split, the final normalized P_N / P_max (mean +- std over
seeds of each seed's mean over its episodes), the final return (P_N at the last step, the paper's
"final return"), the episode return (sum of rewards) and the P_N-vs-step curve.

Writes ``OUT/evaluation.json`` (summary + curves), ``OUT/curve.csv`` (step, split, mean, std) and
``OUT/curve.png``. ``--mode`` evaluates on another mode than the model was trained on (the
transfer experiment of section 4.2). A model is built once
(:mod:`ops_controller_ros.runner_factory`, as the policy node builds it) and runs only on the stage,
detector and observation set it was trained for: another ``--stage``, ``--detector`` or
``--observation``, or a model the runner cannot run (an unknown recipe, observation or recurrent
state, a missing model.zip or metadata.json), exits with status 2 and a message naming what
differs.
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
from ops_contract.config import SPLITS
from ops_contract.heap import freeze_after_heavy_imports
from ops_contract.held import HOLD_STEPS_MAX
from ops_contract.import_hooks import after_import
from ops_contract.observation import OBSERVATION_SETS
from ops_contract.threads import limit_blas_threads

from . import cli_args, continuous
from .cli_args import hold_steps_type
from .envs import EPISODE_STEPS
from .recording import new_bag_path
from .subject import Subject
from .summary import episode_time


class EvaluationError(RuntimeError):
    pass


def _controller_names() -> tuple[str, ...]:
    from ops_controller_ros.controllers import CONTROLLERS

    return CONTROLLERS


def controller_name(value: str) -> str:
    """``--controller``'s value: a controller's name, or an error that names them and says where
    a learned model goes (argparse exits with status 2)."""
    names = _controller_names()
    if value in names:
        return value
    raise argparse.ArgumentTypeError(
        f"{value!r} is not a controller (one of: {', '.join(names)}); to evaluate a learned "
        "model give its directory without --controller, e.g. "
        "`ros2 run ops_gym_bridge evaluate models/n5_hard`"
    )


def build_parser():
    p = cli_args.make_parser(
        "evaluate",
        "Evaluate a trained model (DIR from train --out) or a controller that needs no training.",
    )
    p.add_argument("model", nargs="?", help="model directory (or its model.zip)")
    p.add_argument(
        "--controller",
        type=controller_name,
        metavar="{" + ",".join(_controller_names()) + "}",
        help="evaluate this controller (ops_controller_ros.controllers) instead of a model",
    )
    p.add_argument(
        "--spgd",
        dest="controller",
        action="store_const",
        const="spgd",
        help="the same as --controller spgd",
    )
    cli_args.add_env_arguments(
        p,
        defaults={
            "stage": cli_args.FROM_MODEL,
            "mode": cli_args.FROM_MODEL,
            "detector": cli_args.FROM_MODEL,
            "split": list(SPLITS),
        },
        several=("split",),
    )
    p.add_argument(
        "--episodes", type=cli_args.positive_int, default=5, help="episodes per seed and split"
    )
    p.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[0, 1, 2, 3, 4],
        help="evaluation seeds (the mean +- std is over seeds)",
    )
    p.add_argument(
        "--steps", type=cli_args.positive_int, default=EPISODE_STEPS, help="steps per episode"
    )
    p.add_argument(
        "--out",
        help="output directory (default: runs/eval/NAME_nSTAGE_MODE; NAME: the model "
        "folder's or the controller's; NAME alone if it ends in _nSTAGE_MODE already)",
    )
    p.add_argument(
        "--continuous",
        type=int,
        metavar="STEPS",
        help="instead of episodes: one run of STEPS steps per seed and split, noise and drift "
        "running all the time; reports lock fraction, lock losses, worst reading "
        "(ops_experiments.continuous)",
    )
    p.add_argument(
        "--record", metavar="DIR", type=new_bag_path, help="also record a bag of episodes"
    )
    cli_args.add_key_value_argument(
        p,
        "--controller-param",
        "--spgd-param",
        help="the controller's parameters (e.g. gain=0.1 for spgd); --spgd-param: the same",
    )
    cli_args.add_key_value_argument(
        p,
        "--env",
        help="overrides of the simulated environment (OpsConfig fields, e.g. detector_noise=0.01 "
        "pulse_fwhm_fs=1200) that the controller is not told of",
    )
    cli_args.add_rig_arguments(p, "the controller")
    _add_model_arguments(p)
    p.add_argument("--no-plot", action="store_true", help="do not write curve.png")
    p.add_argument("--torch-threads", type=int, default=1, help="torch CPU threads (0: default)")
    p.add_argument("--quiet", action="store_true", help="print only the summary table")
    return p


def _add_model_arguments(p) -> None:
    """The options only a learned model takes: its hold and its observation set."""
    p.add_argument(
        "--hold-steps",
        type=hold_steps_type,
        default=None,
        metavar="K",
        help="a model's readings per decision: it acts on one reading in K and holds its "
        "command (the same set-points) on the others, seeing only the readings it acts on, so "
        "a model trained without latency runs on a rig with L steps of it at K = L + 1; 1: "
        "every reading; auto (or 0): the told latency_steps + 1 (--realism / --rig; --env is "
        f"not told); 1 to {HOLD_STEPS_MAX} (ops_controller_ros.policy_hold; the policy node's "
        "hold_steps). Default: the model's (the hold_steps it was trained with, train "
        "--hold-steps; 1 for a model trained without)",
    )
    p.add_argument(
        "--observation",
        choices=OBSERVATION_SETS,
        help="observation set to run the model on: a model runs only on the set it was trained "
        "on: rig or authors (default: the model's, from its metadata)",
    )


def _parse(items: list[str], what: str) -> dict[str, Any]:
    try:
        return cli_args.parse_key_values(items, what)
    except ValueError as exc:
        raise EvaluationError(str(exc)) from None


def resolve_rig(args) -> dict[str, Any]:
    """The rig's figures that both the simulator and the controller know (--realism, --rig)."""
    try:
        return cli_args.resolve_rig(args.realism, args.rig)
    except ValueError as exc:
        raise EvaluationError(str(exc)) from None


def resolve_subject(args) -> Subject:
    """The controller or policy ``args`` ask for, with the environment to evaluate it on."""
    if bool(args.controller) == bool(args.model):
        raise EvaluationError("give a model directory or --controller NAME (exactly one)")
    env_overrides = _parse(args.env, "--env override")
    for key in ("stage", "mode", "split", "detector", "episode_steps"):
        if key in env_overrides:
            raise EvaluationError(f"--env {key}=...: use --{key.replace('_', '-')} instead")
    rig = resolve_rig(args)
    if args.controller:
        if args.observation is not None:
            raise EvaluationError(
                "--observation chooses a model's observation set; a controller reads the "
                "detector only"
            )
        if args.hold_steps not in (None, 1):
            raise EvaluationError(
                "--hold-steps holds a learned policy's decisions; a controller is told the "
                "latency instead (--rig latency_steps=L)"
            )
        params = _parse(args.controller_param, "--controller-param")
        subject = Subject(
            name=args.controller,
            stage=cli_args.ENV_DEFAULTS["stage"] if args.stage is None else args.stage,
            mode=args.mode or cli_args.ENV_DEFAULTS["mode"],
            detector=args.detector or cli_args.ENV_DEFAULTS["detector"],
            env_overrides=env_overrides,
            rig=rig,
            controller=args.controller,
            controller_params=params,
            meta={"controller": args.controller, "controller_params": params},
        )
        _check_controller(subject)
        return subject
    model = load_for_evaluation(args)
    trained = model.meta
    subject = Subject(
        name=trained.algo,
        stage=trained.stage,
        mode=args.mode or trained.mode,
        detector=trained.detector,
        env_overrides=env_overrides,
        rig=rig,
        model=model,
        meta={
            "controller": trained.algo,
            "model": str(model.path),
            "trained_stage": trained.stage,
            "trained_mode": trained.mode,
            "trained_detector": trained.detector,
            "trained_timesteps": trained.entries.get("timesteps"),
        },
    )
    return _with_hold(subject, args)


def _with_hold(subject: Subject, args) -> Subject:
    """``subject`` deciding on one reading in ``--hold-steps`` (:func:`with_hold`)."""
    return with_hold(subject, args.hold_steps, record=bool(args.record))


def with_hold(subject: Subject, asked: int | None = None, record: bool = False) -> Subject:
    """A policy ``subject`` deciding on one reading in ``asked`` (None: the model's
    ``hold_steps``, 1 where it has none; 0, auto: the told latency + 1, resolved against the rig
    it is told of); said in the results (``hold_steps``). One resolution for ``evaluate`` and
    the benchmark's evaluation (:mod:`ops_experiments.table1.bench_worker`), so a model trained
    with ``train --hold-steps`` is evaluated with its hold by both."""
    from ops_contract.policy_meta import PolicyLoadError

    model = subject.model
    asked = model.meta.hold_steps if asked is None else asked
    try:
        held = model.with_hold(asked, subject.nominal_config("train", 1).latency_steps)
    except (ValueError, PolicyLoadError) as exc:
        raise EvaluationError(str(exc)) from None
    if record and held.hold_steps != 1:
        raise EvaluationError(
            "--record records the bare policy's episodes; give --hold-steps 1 to record "
            f"(this run holds {held.hold_steps} readings per decision)"
        )
    if record and held.policy.recurrent:
        raise EvaluationError(
            "--record records a policy step by step without its recurrent state; a recurrent "
            "model cannot be recorded"
        )
    subject.model, subject.hold_steps = held, held.hold_steps
    if asked != 1:
        subject.meta["hold_steps"] = held.hold_steps
    return subject


def _check_controller(subject: Subject) -> None:
    """Build the controller and both configurations once, so bad values fail before any run."""
    from ops_controller_ros.controllers import make_controller

    try:
        subject.sim_config("train", 1)
        make_controller(
            subject.controller, subject.nominal_config("train", 1), subject.controller_params
        )
    except ValueError as exc:
        raise EvaluationError(str(exc)) from None


def load_for_evaluation(args):
    """The model ``args`` name, read and loaded once
    (:func:`ops_controller_ros.runner_factory.load_model`), or EvaluationError for one that
    cannot run on the stage, detector or observation set ``args`` ask for (a model runs on what
    it was trained for) or cannot be loaded at all."""
    from ops_contract.policy_meta import PolicyLoadError
    from ops_controller_ros.runner_factory import load_model

    try:
        return load_model(
            args.model,
            stage=args.stage,
            detector=args.detector,
            observation=args.observation,
            source="the evaluation's simulator (--stage, --detector)",
            observation_flag="--observation",
        )
    except PolicyLoadError as exc:
        raise EvaluationError(str(exc)) from None


def evaluate(args, subject: Subject | None = None) -> dict[str, Any]:
    """Evaluate what ``args`` name (or ``subject``): the results of evaluation.json."""
    if args.episodes < 1 or args.steps < 1 or not args.seeds:
        raise EvaluationError("--episodes and --steps must be >= 1 and --seeds non-empty")
    subject = subject or resolve_subject(args)
    results: dict[str, Any] = {
        **subject.meta,
        "stage": subject.stage,
        "mode": subject.mode,
        "detector": subject.detector,
        "env_overrides": subject.env_overrides,
        "rig": subject.rig,
        "episodes_per_seed": args.episodes,
        "seeds": list(args.seeds),
        "steps": args.steps,
        # the episodes in seconds beside steps: time_base, step_s, episode_s
        **episode_time(args.steps, subject.sim_config(args.splits[0], args.steps)),
        "splits": {},
    }
    t0 = time.monotonic()
    runs_total = len(args.splits) * len(args.seeds)
    if not args.quiet:
        print(
            f"[evaluate] {subject.name} stage={subject.stage} mode={subject.mode}: "
            f"{runs_total} runs of {args.episodes} episodes x {args.steps} steps "
            f"(splits {' '.join(args.splits)}, seeds {' '.join(map(str, args.seeds))})",
            flush=True,
        )
    done = 0

    def progress(split, seed, result) -> None:
        nonlocal done
        done += 1
        if not args.quiet:
            elapsed = time.monotonic() - t0
            print(
                f"[evaluate] {done}/{runs_total} split={split} seed={seed}: "
                f"final P_N/P_max {result['power'][:, -1].mean():.4f} "
                f"({_duration(elapsed)} elapsed, "
                f"~{_duration(elapsed / done * (runs_total - done))} left)",
                flush=True,
            )

    results["splits"] = subject.evaluate(
        args.splits, args.seeds, args.episodes, args.steps, progress
    )
    results["wall_s"] = round(time.monotonic() - t0, 2)
    return results


def _duration(seconds: float) -> str:
    """``42 s`` or ``3 min 05 s``: a duration for progress lines."""
    seconds = round(seconds)
    return f"{seconds} s" if seconds < 60 else f"{seconds // 60} min {seconds % 60:02d} s"


def default_out(args, subject: Subject) -> Path:
    """Where results go without ``--out``: ``runs/eval/NAME_nSTAGE_MODE`` under the current
    directory, or ``runs/eval/NAME`` where NAME already ends in ``nSTAGE_MODE`` as the shipped
    models' folders do (``runs/`` is git-ignored at the repository root; a shipped model's tracked
    ``eval/`` folder is never overwritten by accident)."""
    if args.model:
        from ops_contract.policy_meta import resolve_paths

        name = resolve_paths(args.model)[0].parent.name
    else:
        name = subject.name
    cell = f"n{subject.stage}_{subject.mode}"
    if name == cell or name.endswith(f"_{cell}"):  # a model named for its cell: not twice
        return Path("runs") / "eval" / name
    return Path("runs") / "eval" / f"{name}_{cell}"


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


def _seconds(results: dict[str, Any]) -> str:
    """`` = 20 s`` after the steps (at step_s each; the paper's 0.1 s under time_base step)."""
    return f" = {results['episode_s']:g} s" if "episode_s" in results else ""


def format_table(results: dict[str, Any]) -> str:
    lines = [
        f"{results['controller']} on stage {results['stage']}, {results['mode']} mode "
        f"({len(results['seeds'])} seeds x {results['episodes_per_seed']} episodes, "
        f"{results['steps']} steps{_seconds(results)})",
        f"{'split':<6} {'final P_N/P_max':>20} {'worst episode':>14} {'episode return':>20} "
        f"{'initial P_N':>12}",
    ]
    for split, s in results["splits"].items():
        lines.append(
            f"{split:<6} {s['final_power_mean']:>11.4f} ± {s['final_power_std']:<6.4f} "
            f"{s['final_power_min_episode']:>14.4f} "
            f"{s['episode_return_mean']:>11.2f} ± {s['episode_return_std']:<6.2f} "
            f"{s['initial_power_mean']:>12.4f}"
        )
    return "\n".join(lines)


def run(argv: list[str] | None = None) -> int:
    args = cli_args.parse_args(build_parser(), argv)
    if args.torch_threads > 0:
        # As torch loads (a learned model's evaluation): a controller's evaluation never needs
        # it, and importing torch only to set its threads cost ~2 s of CPU.
        threads = args.torch_threads
        after_import("torch", lambda torch: torch.set_num_threads(threads))
    try:
        subject = resolve_subject(args)
        if args.continuous is not None:
            results = continuous.evaluate(args, subject)
        else:
            results = evaluate(args, subject)
    except (EvaluationError, ValueError) as exc:
        print(f"[evaluate] error: {exc}", file=sys.stderr, flush=True)
        return 2
    out = Path(args.out) if args.out else default_out(args, subject)
    if args.continuous is not None:
        written = continuous.write_outputs(results, out, plot=not args.no_plot)
        print(continuous.format_table(results))
        print(f"[evaluate] wrote {', '.join(str(p) for p in written)}", flush=True)
        return 0
    written = write_outputs(results, out, plot=not args.no_plot)
    if args.record:
        from .recording import record_episodes

        written.append(record_episodes(args, subject, Path(args.record)))
    print(format_table(results))
    print(f"[evaluate] wrote {', '.join(str(p) for p in written)}", flush=True)
    return 0


def main(argv: list[str] | None = None) -> None:
    limit_blas_threads()
    freeze_after_heavy_imports()
    try:
        code = run(argv)
    except KeyboardInterrupt:
        print("\n[evaluate] interrupted", file=sys.stderr)
        code = 130
    sys.exit(code)


if __name__ == "__main__":
    main()
