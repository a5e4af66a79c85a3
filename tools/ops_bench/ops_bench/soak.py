"""``ops-bench soak``: the tracker for hours of simulated time on the ``lab`` rig, as a lab runs
it overnight: does it stay locked, and how steady is the stacked power?

In process (:mod:`ops_experiments.timed_loop`): ``time_base`` seconds at ``--rate`` (10 Hz),
``lab`` vibration, the ``lab`` rig with its latency and delay-line response in ms, N = 5 hard
(testing split), the controller's compute capping its rate as in ``ops-bench rate-sweep``
(measured per reading, or ``--compute-ms``). ``--hours`` of simulated time (30: 1.08 M steps at
10 Hz), a block of ``--block-s`` simulated seconds at a time: each block's mean and lowest
P_N/P_max and its residual phase (rms over the stages and of the worst stage) are kept for the
figure.

What a lab asks next, each kept with the run: ``--rig KEY=VALUE`` changes one of the rig's
figures (``trace_adc_bits=12``: what a finer digitizer buys over the night; the tracker is told
of it), ``--realism ideal`` starts from the ideal rig, ``--param NAME=VALUE`` sets one of the
controller's parameters, and ``--drift-turn-s S`` turns the drift at its bound over S seconds
as a lab's thermal drift turns (the simulator's default turns it in one step).

**Checkpointed**: every ``--checkpoint-every`` simulated seconds the whole state (simulator,
controller, loop, figures so far) is pickled to ``OUT/state.pkl`` (written aside, then renamed);
the same command resumes from it (a stopped run loses at most that much), and a larger
``--hours`` extends a finished run. Other settings than the stored run's are refused
(``--fresh`` starts again). At the end (and with ``--report``, from the checkpoint) it writes
``OUT/summary.json``, the figure (``--figure``) and the page (``--page``): P_N/P_max's rms
fluctuation, the share of readings >= 0.95 and the locks lost after the first lock, against the
goals (rms <= 1.5 %, >= 99.9 % of readings >= 0.95, no lock lost).

Never part of CI. Usage (after ``source setup.bash``):
  ops-bench soak --hours 0.5 --out runs/soak_short          # a short run
  nohup nice -n 15 ops-bench soak --out runs/soak --no-progress > runs/soak.log 2>&1 &
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from ops_contract.config import VIBRATIONS

from ops_bench import REPO

FIGURE = REPO / "docs" / "figures" / "soak.png"
PAGE = REPO / "docs" / "results" / "soak"
GOAL_RMS_PCT, GOAL_LOCKED, GOAL_LOSSES = 1.5, 0.999, 0
#: What a run stored before a setting existed had of it: a run resumes where its stored
#: settings, these filled in, equal the command's (the hours may grow).
SETTING_DEFAULTS = {"realism": "lab", "rig": {}, "params": {}, "drift_turn_s": 0.0}
#: Figures of the rig that --rig does not take: the latency and response are --latency-ms and
#: --lag-ms, the time base and vibration are the soak's own.
RIG_NOT_TAKEN = ("latency_steps", "actuator_lag_steps", "time_base", "step_s", "vibration")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ops-bench soak", description=__doc__.split("\n\n")[0].split(": ", 1)[1]
    )
    p.add_argument("--hours", type=float, default=30.0, help="simulated hours (default 30)")
    p.add_argument("--rate", type=float, default=10.0, help="loop rate, Hz (default 10)")
    p.add_argument("--seed", type=int, default=7201)
    p.add_argument("--controller", default="tracker", choices=("tracker", "spgd"))
    p.add_argument("--mode", default="hard", choices=("easy", "medium", "hard", "extreme"))
    p.add_argument("--vibration", default="lab", choices=VIBRATIONS)
    p.add_argument("--latency-ms", type=float, default=1.0, help="the rig's latency, ms")
    p.add_argument("--lag-ms", type=float, default=1.0, help="the delay lines' response, ms")
    p.add_argument(
        "--compute-ms",
        type=float,
        default=None,
        help="the controller's compute per reading, fixed (default: measured per reading)",
    )
    p.add_argument("--compute-scale", type=float, default=1.0, help="measured compute times this")
    p.add_argument(
        "--realism",
        default="lab",
        choices=("lab", "ideal"),
        help="the rig's preset that --rig changes (default lab; docs/physics.md, 'Rig "
        "imperfections')",
    )
    p.add_argument(
        "--rig",
        nargs="+",
        action="extend",
        default=[],
        metavar="KEY=VALUE",
        help="figures of the rig changed from the preset, which the tracker is told of too (e.g. "
        "trace_adc_bits=12: what a finer scope buys; actuator_hysteresis=0): the rig's keys of "
        "docs/physics.md but the latency and response (--latency-ms, --lag-ms)",
    )
    p.add_argument(
        "--param",
        nargs="+",
        action="extend",
        default=[],
        metavar="NAME=VALUE",
        help="the controller's parameters over its defaults (the tracker's: docs/interfaces.md), "
        "e.g. hold_dither_cycles=0.016",
    )
    p.add_argument(
        "--drift-turn-s",
        type=float,
        default=0.0,
        metavar="S",
        help="the drift's slope reverses at its bound over S seconds, as a lab's thermal drift "
        "turns (default 0: in one step, the simulator's default)",
    )
    p.add_argument("--block-s", type=float, default=60.0, help="simulated s per figure point")
    p.add_argument(
        "--checkpoint-every",
        type=float,
        default=3600.0,
        metavar="S",
        help="simulated seconds between checkpoints (default 3600)",
    )
    p.add_argument("--out", type=Path, default=REPO / "runs" / "soak", help="state and summary")
    p.add_argument("--figure", type=Path, default=FIGURE, help="default: %(default)s")
    p.add_argument(
        "--page", type=Path, default=PAGE, help="index.md and summary (default: %(default)s)"
    )
    p.add_argument("--no-docs", action="store_true", help="no figure or page (OUT only)")
    p.add_argument("--fresh", action="store_true", help="start again (drop OUT's state)")
    p.add_argument("--report", action="store_true", help="only the summary, figure and page")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def params_of(args) -> dict[str, Any]:
    """The controller's parameters of ``--param`` (ValueError naming one it does not have or a
    value it refuses: the controller is built once to check them)."""
    from ops_contract.config import make_config
    from ops_controller_ros.controllers import make_controller
    from ops_experiments.cli_args import parse_key_values

    params = dict(sorted(parse_key_values(args.param, "--param").items()))
    if params:
        make_controller(args.controller, make_config(5, args.mode), params)
    return params


def rig_of(args) -> dict[str, Any]:
    """The figures of ``--rig`` (ValueError naming a figure that is not the rig's, not taken
    here, or out of its range)."""
    from ops_experiments.cli_args import resolve_rig

    rig = resolve_rig(None, args.rig)
    taken = sorted(set(rig) & set(RIG_NOT_TAKEN))
    if taken:
        raise ValueError(
            f"--rig {', '.join(taken)}: not taken here (--latency-ms and --lag-ms give the "
            "rig's latency and response; the time base and vibration are the soak's own)"
        )
    return dict(sorted(rig.items()))


def drift_turn_of(args) -> float:
    """``--drift-turn-s`` (ValueError naming its range)."""
    from ops_contract.config import LIMITS

    low, high = LIMITS["drift_turn_s"]
    if not low <= args.drift_turn_s <= high:
        raise ValueError(f"--drift-turn-s must be from {low:g} to {high:g} s")
    return float(args.drift_turn_s)


def settings_of(args) -> dict[str, Any]:
    return {
        "controller": args.controller,
        "rate_hz": float(args.rate),
        "seed": int(args.seed),
        "mode": args.mode,
        "vibration": args.vibration,
        "latency_ms": float(args.latency_ms),
        "lag_ms": float(args.lag_ms),
        "compute_ms": args.compute_ms,
        "compute_scale": float(args.compute_scale),
        "block_s": float(args.block_s),
        "drift_turn_s": drift_turn_of(args),
        "realism": args.realism,
        "rig": rig_of(args),
        "params": params_of(args),
    }


def new_state(settings: dict[str, Any]) -> dict[str, Any]:
    """A run at its start: the loop on a fresh simulator, no figures yet."""
    from ops_experiments.timed_loop import RunStats, start_loop, timed_config

    config = timed_config(
        settings["rate_hz"],
        mode=settings["mode"],
        vibration=settings["vibration"],
        latency_ms=settings["latency_ms"],
        lag_ms=settings["lag_ms"],
        realism=settings["realism"],
        rig=settings["rig"],
        drift_turn_s=settings["drift_turn_s"],
    )
    loop = start_loop(
        settings["controller"],
        config,
        settings["seed"],
        compute_ms=settings["compute_ms"],
        compute_scale=settings["compute_scale"],
        params=settings["params"],
    )
    return {
        "settings": settings,
        "loop": loop,
        "stats": RunStats(config.stage, config.optical_period_fs),
        "blocks": {"p_mean": [], "p_min": [], "mrad": [], "mrad_worst": []},
        "wall_s": 0.0,
        "commands": [],
    }


def block_steps(settings: dict[str, Any]) -> int:
    return max(1, round(settings["block_s"] * settings["rate_hz"]))


def save_state(state: dict[str, Any], path: Path) -> None:
    """Pickle ``state`` to ``path`` (written aside, then renamed: a kill never leaves half)."""
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as f:
        pickle.dump(state, f, protocol=pickle.HIGHEST_PROTOCOL)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def load_state(path: Path) -> dict[str, Any] | None:
    if not path.exists():
        return None
    with open(path, "rb") as f:
        return pickle.load(f)


def take_block(state: dict[str, Any], power: np.ndarray, applied: np.ndarray) -> None:
    """One block's figure points."""
    from ops_experiments.timed_loop import phase_mrad

    stats = state["stats"]
    stages = np.sqrt(np.mean(phase_mrad(applied, stats.period_fs) ** 2, axis=0))
    blocks = state["blocks"]
    blocks["p_mean"].append(float(power.mean()))
    blocks["p_min"].append(float(power.min()))
    blocks["mrad"].append(float(np.sqrt(np.mean(stages**2))))
    blocks["mrad_worst"].append(float(stages.max()))


def run(args, state: dict[str, Any], path: Path) -> dict[str, Any]:
    """Step ``state`` on to ``args.hours``, a block at a time, checkpointing as it goes."""
    from tqdm import tqdm

    settings = state["settings"]
    loop, stats = state["loop"], state["stats"]
    per_block = block_steps(settings)
    target = max(1, round(args.hours * 3600.0 * settings["rate_hz"] / per_block)) * per_block
    every = max(1, round(args.checkpoint_every * settings["rate_hz"] / per_block))
    bar = tqdm(
        total=target,
        initial=loop.step,
        unit="step",
        unit_scale=True,
        disable=args.no_progress,
        mininterval=5.0,
        file=sys.stderr,
    )
    t0, blocks = time.monotonic(), 0
    try:
        while loop.step < target:
            power, applied = loop.run(per_block)
            stats.update(power, applied)
            take_block(state, power, applied)
            blocks += 1
            bar.update(per_block)
            bar.set_postfix_str(
                f"{loop.step / settings['rate_hz'] / 3600:.2f} h, P {power.mean():.4f}"
            )
            if blocks % every == 0 or loop.step >= target:
                state["wall_s"] += time.monotonic() - t0
                t0 = time.monotonic()
                save_state(state, path)
                if args.no_progress:  # a log line per checkpoint instead of the bar
                    print(checkpoint_line(state), flush=True)
    finally:
        bar.close()
    return state


def checkpoint_line(state: dict[str, Any]) -> str:
    settings, loop = state["settings"], state["loop"]
    fig = state["stats"].figures()
    hours = loop.step / settings["rate_hz"] / 3600.0
    rms, locked = fig["power_rms_pct"], fig["locked_fraction"]
    return (
        f"[soak] checkpoint at {hours:.3f} h ({loop.step:,} steps, {state['wall_s'] / 3600:.2f} h "
        f"of wall time): P_N/P_max rms {'-' if rms is None else f'{rms:.2f} %'}, readings >= "
        f"0.95 {'-' if locked is None else f'{100 * locked:.3f} %'}, locks lost {fig['losses']}"
    )


def summary(state: dict[str, Any]) -> dict[str, Any]:
    """The run's figures against the goals."""
    settings, loop = state["settings"], state["loop"]
    fig = state["stats"].figures()
    hours = loop.step / settings["rate_hz"] / 3600.0
    rms, locked, losses = fig["power_rms_pct"], fig["locked_fraction"], fig["losses"]
    return {
        **settings,
        "hours": round(hours, 4),
        **fig,
        **loop.compute_figures(),
        "goals": {
            "power_rms_pct <= 1.5": rms is not None and rms <= GOAL_RMS_PCT,
            "readings >= 0.95: >= 99.9 %": locked is not None and locked >= GOAL_LOCKED,
            "no lock lost": fig["first_lock_step"] is not None and losses == GOAL_LOSSES,
        },
        "wall_s": round(state["wall_s"], 1),
        "commands": state["commands"],
    }


def main(argv: list[str] | None = None) -> int:
    from ops_contract.threads import limit_blas_threads

    from .soak_report import write_docs

    args = build_parser().parse_args(argv)
    if args.hours <= 0 or args.rate <= 0 or args.block_s <= 0 or args.checkpoint_every <= 0:
        print(
            "ops-bench soak: --hours, --rate, --block-s, --checkpoint-every must be > 0",
            file=sys.stderr,
        )
        return 2
    limit_blas_threads()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "state.pkl"
    state = None if args.fresh else load_state(path)
    try:
        settings = settings_of(args)
    except ValueError as exc:
        print(f"ops-bench soak: {exc}", file=sys.stderr)
        return 2
    if state is not None:
        state["settings"] = {**SETTING_DEFAULTS, **state["settings"]}
    if state is not None and state["settings"] != settings and not args.report:
        print(
            f"ops-bench soak: {path} holds a run with other settings ({state['settings']}); "
            "give the same options to resume it, or --fresh to start again",
            file=sys.stderr,
        )
        return 2
    if state is None:
        if args.report:
            print(f"ops-bench soak: no run stored in {path}", file=sys.stderr)
            return 2
        state = new_state(settings)
    if not args.report:
        state["commands"].append(shlex.join(sys.argv[1:] if argv is None else argv))
        loop = state["loop"]
        print(
            f"[soak] {settings['controller']} at {settings['rate_hz']:g} Hz to {args.hours:g} h"
            + (f", resumed at {loop.step / settings['rate_hz'] / 3600:.3f} h" if loop.step else ""),
            flush=True,
        )
        state = run(args, state, path)
    result = summary(state)
    (args.out / "summary.json").write_text(json.dumps(result, indent=2) + "\n")
    print(
        json.dumps(
            {
                k: result[k]
                for k in (
                    "hours",
                    "power_mean",
                    "power_rms_pct",
                    "locked_fraction",
                    "losses",
                    "residual_mrad",
                    "goals",
                )
            }
        ),
        flush=True,
    )
    if not args.no_docs:
        write_docs(state, result, args.figure, args.page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
