"""``ops-bench soak-steps``: the loop of ``ops-bench soak`` with every step logged, and where its
locks were lost: how long after one of the simulator's drift turns, whether a knot was taken,
what the tracker's drift memory let go of.

``soak`` keeps a minute's figures per point for 30 hours; this keeps every step of a shorter run
(a few MB an hour) to say why a figure is what it is. The same settings as ``soak`` (the
tracker, N = 5 hard, the ``lab`` rig, ``--rate``, ``--vibration``, the compute fixed at
``--compute-ms``), from the start: the first hours of a soak of the same seed, step for step.
Writes ``OUT`` (npz: P_N/P_max, each stage's phase error in cycles, the simulator's true drift
per step, the tracker's drift, the memory's release counts and the last knot's reading, per
step) and ``OUT`` with ``.json`` (the account it prints).

Usage (after ``source setup.bash``):
  ops-bench soak-steps --hours 9 --seed 7201 --out runs/soak_steps_7201.npz
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from ops_contract.config import VIBRATIONS
from ops_experiments.continuous import LOCK, LOSS

#: Readings after a drift turn within which a lock lost or a release counts as the turn's.
AFTER_TURN = 40


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ops-bench soak-steps", description=__doc__.split("\n\n")[0].split(": ", 1)[1]
    )
    p.add_argument("--hours", type=float, default=1.0, help="simulated hours (default 1)")
    p.add_argument("--seed", type=int, default=7201)
    p.add_argument("--rate", type=float, default=10.0, help="loop rate, Hz (default 10)")
    p.add_argument("--vibration", default="lab", choices=VIBRATIONS)
    p.add_argument("--compute-ms", type=float, default=2.0, help="compute per reading, fixed")
    p.add_argument("--realism", default="lab", choices=("lab", "ideal"), help="as soak's")
    p.add_argument("--rig", nargs="+", action="extend", default=[], metavar="KEY=VALUE",
                   help="as soak's: figures of the rig changed from the preset")  # fmt: skip
    p.add_argument("--param", nargs="+", action="extend", default=[], metavar="NAME=VALUE",
                   help="as soak's: the tracker's parameters over its defaults")  # fmt: skip
    p.add_argument("--drift-turn-s", type=float, default=0.0, metavar="S", help="as soak's")
    p.add_argument("--out", type=Path, required=True, help="the steps (.npz) and account (.json)")
    return p


def soak_settings(args) -> dict:
    """soak's settings with its defaults (the tracker, N = 5 hard, the lab rig's 1 ms) and
    these options: the same loop, step for step (ValueError as soak's, naming a bad --rig or
    --param)."""
    from .soak import build_parser as soak_parser
    from .soak import settings_of

    soak_args = soak_parser().parse_args(
        ["--rate", str(args.rate), "--seed", str(args.seed), "--vibration", args.vibration,
         "--compute-ms", str(args.compute_ms), "--realism", args.realism,
         "--drift-turn-s", str(args.drift_turn_s),
         *(["--rig", *args.rig] if args.rig else []),
         *(["--param", *args.param] if args.param else [])]
    )  # fmt: skip
    return settings_of(soak_args)


def run_logged(args, settings: dict) -> dict[str, np.ndarray]:
    """Every step of the soak's loop (of ``settings``: :func:`soak_settings`) for
    ``args.hours``."""
    from tqdm import tqdm

    from .soak import new_state

    loop = new_state(settings)["loop"]
    sim, ctl = loop.sim, loop.ctl
    period = float(sim.config.optical_period_fs)
    n, stage = round(args.hours * 3600.0 * args.rate), sim.stage
    log = {
        "power": np.empty(n, np.float32),
        "phase": np.empty((n, stage), np.float32),
        "true_drift": np.zeros((n, stage), np.float32),
        "drift": np.zeros((n, stage), np.float32),
        "releases_all": np.zeros(n, np.int32),
        "releases_stage": np.zeros(n, np.int32),
        "releases_knot": np.zeros(n, np.int32),
        "knot_reading": np.zeros(n, np.int64),
    }
    for i in tqdm(range(n), unit="step", unit_scale=True, mininterval=5.0, file=sys.stderr):
        power, applied = loop.run(1)
        cycles = applied[0] / period
        log["power"][i], log["phase"][i] = power[0], cycles - np.rint(cycles)
        if sim.noise.drift_enabled:
            log["true_drift"][i] = sim.noise.slope[0] / period
        log["drift"][i] = ctl.lock.drift
        log["knot_reading"][i] = ctl.knot.tick
        memory = ctl.lock.memory
        if memory is not None:
            log["releases_all"][i] = memory.turns
            log["releases_stage"][i] = memory.stage_turns
            log["releases_knot"][i] = memory.knots
    return log


def account(log: dict[str, np.ndarray], rate_hz: float) -> dict:
    """Where the run's locks were lost and what the memory let go of (module docstring)."""
    power = np.asarray(log["power"], dtype=np.float64)
    hits = np.flatnonzero(power >= LOCK)
    first = int(hits[0]) if hits.size else power.size
    low = np.zeros(power.size + 1, dtype=np.int8)
    low[first:-1] = power[first:] < LOSS
    starts = np.flatnonzero(np.diff(np.concatenate([[0], low])) == 1)
    turns = drift_turns(np.asarray(log["true_drift"]))
    released = np.flatnonzero(np.diff(np.concatenate([[0], log["releases_all"]])) > 0)
    knots = np.flatnonzero(np.diff(np.asarray(log["knot_reading"])) != 0) + 1
    losses = []
    for s in starts.tolist():
        before = turns[turns <= s]
        since = int(s - before[-1]) if before.size else None
        knot = bool(np.any((knots > s - AFTER_TURN) & (knots <= s + 1)))
        losses.append(
            {
                "hours": round(s / rate_hz / 3600.0, 4),
                "lowest": round(float(power[s : s + 5].min()), 4),
                "readings_after_turn": since,
                "knot_taken": knot,
            }
        )
    delays = [int(r - turns[turns <= r][-1]) for r in released if np.any(turns <= r)]
    at_turns = [d for d in delays if d <= AFTER_TURN]
    after = power[first:]
    return {
        "hours": round(power.size / rate_hz / 3600.0, 4),
        "readings_after_first_lock": int(after.size),
        "readings_locked_pct": round(100.0 * float(np.mean(after >= LOCK)), 4)
        if after.size
        else None,
        "drift_turns": int(turns.size),
        "releases_every_stage": int(released.size),
        "releases_every_stage_at_a_turn": len(at_turns),
        "release_delays_after_turn": sorted(at_turns),
        "releases_one_stage": int(log["releases_stage"][-1]) if power.size else 0,
        "releases_at_a_knot": int(log["releases_knot"][-1]) if power.size else 0,
        "locks_lost": len(losses),
        "locks_lost_within_40_after_a_turn": sum(
            1
            for x in losses
            if x["readings_after_turn"] is not None and x["readings_after_turn"] <= AFTER_TURN
        ),
        "losses": losses,
    }


def drift_turns(true_drift: np.ndarray) -> np.ndarray:
    """The steps at which any stage's true drift changed sign."""
    sign = np.sign(true_drift)
    return np.flatnonzero(np.any(sign[1:] != sign[:-1], axis=1)) + 1


def main(argv: list[str] | None = None) -> int:
    from ops_contract.threads import limit_blas_threads

    args = build_parser().parse_args(argv)
    if not (args.hours > 0 and args.rate > 0 and args.compute_ms >= 0):
        print(
            "ops-bench soak-steps: --hours and --rate must be > 0, --compute-ms >= 0",
            file=sys.stderr,
        )
        return 2
    try:
        settings = soak_settings(args)
    except ValueError as exc:
        print(f"ops-bench soak-steps: {exc}", file=sys.stderr)
        return 2
    limit_blas_threads()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    log = run_logged(args, settings)
    np.savez_compressed(args.out, **log)
    result = {
        "command": "ops-bench soak-steps " + " ".join(sys.argv[1:] if argv is None else argv),
        **account(log, args.rate),
    }
    text = json.dumps(result, indent=2)
    args.out.with_suffix(".json").write_text(text + "\n")
    print(text, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
