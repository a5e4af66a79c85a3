"""The tracker's behaviour on a fixed set of cases, recorded to compare two versions of its code.

Each case runs the tracker in process against an ``OpsEnv`` (as ``evaluate --controller tracker``
does, through ``controllers.next_command``) and stores every command, power, estimate and drift,
and the tracker's counters at the end, as ``CASE.npz`` in a folder. ``compare`` then tells, case
by case, whether two folders hold the same runs: exactly (``np.array_equal``), or within
``--rtol`` (``np.allclose``). A refactoring of the tracker that must not change its behaviour is
recorded before, recorded after and compared.

The cases: stages 3 and 5, every mode, both detectors, the ideal rig and the ``lab`` rig (latency,
8-bit trace, hysteresis, source noise) told to the tracker and untold, two seeds each; and some
settings the grid does not reach: commands a step late (the steps and command age a node tells),
a knot budget that every test overruns (cut short, or spread over readings), a model off in
wavelength (with and without the optics' calibration), a power that weighs nothing, the all-stage
excursion, a search spread over readings, a wrong told latency, a narrow set-point range, and
stage 7. A budget of 1e-6 ms is past before any unit ends, so those runs do not depend on the
machine's speed. BLAS runs on one thread (its sums' rounding depends on the thread count).

Usage (after `source setup.bash`):
  ops-bench tracker-reference record /tmp/tracker_ref_before [--steps 300] [--only RE]
  ops-bench tracker-reference compare /tmp/tracker_ref_before /tmp/tracker_ref_after
      [--rtol 1e-9]
"""

from __future__ import annotations

import argparse
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

COUNTERS = (
    "knots",
    "hops",
    "acquisitions",
    "false_locks",
    "latency",
    "latency_changes",
    "latency_checks",
    "knot_tests_cut",
    "knot_tests_spread",
    "range_moves",
    "calibration_resets",
    "residual",
)


@dataclass(frozen=True)
class Case:
    name: str
    stage: int
    mode: str
    detector: str = "polarizer"
    realism: str = "ideal"
    told: bool = True  # the tracker's model holds the rig (else the ideal rig's)
    seed: int = 0
    params: dict = field(default_factory=dict)
    sim: dict = field(default_factory=dict)  # the simulator's figures the tracker is not told of
    # figures the tracker is told that the simulator does not run
    told_extra: dict = field(default_factory=dict)
    p_late: float = 0.0  # share of commands a step late
    thinks: int = 1  # think() calls after each reading's command
    range_fs: tuple | None = None  # (low, high, reach) of the set-points


def cases() -> list[Case]:
    out = []
    for stage in (3, 5):
        for mode in ("easy", "medium", "hard", "extreme"):
            for detector in ("polarizer", "total"):
                for rig, told in (("ideal", True), ("lab", True), ("lab", False)):
                    for seed in (0, 1):
                        tag = rig if rig == "ideal" else f"{rig}-{'told' if told else 'untold'}"
                        name = f"n{stage}-{mode}-{detector}-{tag}-s{seed}"
                        out.append(Case(name, stage, mode, detector, rig, told, seed))
    budget = {"knot_budget_ms": 1e-6}
    out += [
        Case("late-lab-hard", 5, "hard", realism="lab", seed=2, p_late=0.15),
        Case("late-ideal-extreme", 5, "extreme", seed=3, p_late=0.15),
        Case("cut-lab-hard", 5, "hard", realism="lab", seed=4, p_late=0.15, params=budget),
        Case(
            "cut-ideal-extreme",
            5,
            "extreme",
            seed=5,
            p_late=0.15,
            params={**budget, "slice_knot_test": False},
        ),
        Case("spread-lab-extreme", 5, "extreme", realism="lab", seed=6, params=budget, thinks=4),
        Case("spread-lab-extreme-n3", 3, "extreme", realism="lab", seed=7, params=budget, thinks=2),
        Case("wavelength-off", 5, "medium", seed=8, sim={"wavelength_nm": 1040.0}),
        Case(
            "optics-calibrated",
            5,
            "medium",
            seed=9,
            sim={"wavelength_nm": 1020.0, "pulse_fwhm_fs": 1100.0},
            params={"calibrate_optics": True, "calibration_every": 10},
        ),
        Case("power-weight-0", 5, "hard", realism="lab", seed=10, params={"power_weight": 0.0}),
        Case("hold-all", 5, "hard", seed=11, params={"hold_pattern": "all"}),
        Case("search-units", 5, "hard", seed=12, params={"search_units": 3}),
        Case("wrong-latency", 5, "medium", realism="lab", seed=13, told_extra={"latency_steps": 3}),
        Case(
            "range",
            5,
            "hard",
            seed=14,
            params={"hop_every": 0},
            range_fs=(np.full(5, -12.0), np.full(5, 10.0), 6.4),
        ),
        Case("n7-hard", 7, "hard", seed=15),
        Case("n7-extreme-lab", 7, "extreme", realism="lab", seed=16),
    ]
    return out


def run_case(case: Case, steps: int) -> dict[str, np.ndarray]:
    """Every command, power, estimate and drift of one case's run, and its counters at the end."""
    from ops_contract.config import make_config
    from ops_controller_ros.controllers import next_command
    from ops_controller_ros.tracker import PhaseTracker, TrackerParams
    from ops_sim_ros.env import OpsEnv

    common = dict(stage=case.stage, mode=case.mode, split="test", detector=case.detector)
    sim_config = make_config(**common, realism=case.realism, **case.sim)
    nominal = make_config(**common, realism=case.realism if case.told else "ideal")
    if case.told_extra:
        nominal = nominal.replace(**case.told_extra)
    env = OpsEnv.from_config(sim_config, max_episode_steps=2 * steps + 10)
    _, info = env.reset(seed=1000 * case.seed + case.stage)
    low, high, reach = case.range_fs or (None, None, None)
    ctl = PhaseTracker(
        nominal,
        TrackerParams(**case.params),
        setpoints_fs=info["setpoints_fs"],
        seed=case.seed,
        setpoint_range_fs=None if low is None else (low, high),
        reach_fs=reach,
    )
    late = np.random.default_rng(case.seed + 77)
    n = case.stage
    out = {k: np.full((steps, n), np.nan) for k in ("command", "estimate", "drift")}
    out["power"] = np.empty(steps)
    previous = np.asarray(info["setpoints_fs"], dtype=float)
    for t in range(steps):
        command = np.asarray(next_command(ctl), dtype=float)
        for _ in range(case.thinks - 1):
            if ctl.think():
                command = np.asarray(ctl.command(), dtype=float)
        gap = 1
        if case.p_late and late.random() < case.p_late:  # the rig steps on the old set-points
            env.step_setpoints(previous)
            gap = 2
        r = env.step_setpoints(command)
        power = float(r.power[0])
        ctl.observe(power, r.pulse_energies[0], steps=gap, command_age=0 if case.p_late else None)
        out["command"][t], out["power"][t], previous = command, power, command
        if ctl.estimate is not None:
            out["estimate"][t], out["drift"][t] = ctl.estimate, ctl.drift
    env.close()
    out["counters"] = np.array([float(getattr(ctl, k)) for k in COUNTERS])
    return out


def record(folder: Path, steps: int, only: str | None) -> int:
    from threadpoolctl import threadpool_limits

    folder.mkdir(parents=True, exist_ok=True)
    chosen = [c for c in cases() if only is None or re.search(only, c.name)]
    with threadpool_limits(limits=1, user_api="blas"):
        for i, case in enumerate(chosen, 1):
            t0 = time.perf_counter()
            out = run_case(case, steps)
            np.savez(folder / f"{case.name}.npz", **out)
            locked = float(np.mean(out["power"][steps // 2 :] >= 0.95))
            print(
                f"[{i}/{len(chosen)}] {case.name}: {time.perf_counter() - t0:.1f} s, second half "
                f">= 0.95: {100 * locked:.0f} %, knots {out['counters'][0]:.0f}",
                flush=True,
            )
    return 0


def compare(before: Path, after: Path, rtol: float | None) -> int:
    """Case by case: identical, close (within ``rtol``) or different (the first step that
    differs); exit code 1 if any case differs or is missing."""
    names = sorted(p.stem for p in before.glob("*.npz"))
    counts = {"identical": 0, "close": 0, "different": 0, "missing": 0}
    for name in names:
        path = after / f"{name}.npz"
        if not path.exists():
            counts["missing"] += 1
            print(f"{name}: missing")
            continue
        a, b = np.load(before / f"{name}.npz"), np.load(path)
        same = all(np.array_equal(a[k], b[k], equal_nan=True) for k in a.files)
        close = rtol is not None and all(
            np.allclose(a[k], b[k], rtol=rtol, atol=0.0, equal_nan=True) for k in a.files
        )
        verdict = "identical" if same else "close" if close else "different"
        counts[verdict] += 1
        if verdict != "identical":
            print(f"{name}: {verdict}{'' if close else first_difference(a, b)}")
    print(f"{len(names)} cases: " + ", ".join(f"{v} {k}" for k, v in counts.items()))
    return 0 if counts["different"] == counts["missing"] == 0 else 1


def first_difference(a, b) -> str:
    """Where two runs first part: the record and its step."""
    for k in ("command", "power", "estimate", "drift"):
        x, y = a[k].reshape(len(a[k]), -1), b[k].reshape(len(b[k]), -1)
        differs = np.flatnonzero(~np.all((x == y) | (np.isnan(x) & np.isnan(y)), axis=1))
        if differs.size:
            return f" ({k} from step {differs[0]})"
    return " (counters)"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = ap.add_subparsers(dest="action", required=True)
    rec = sub.add_parser("record", help="run the cases and store them in FOLDER")
    rec.add_argument("folder", type=Path)
    rec.add_argument("--steps", type=int, default=300)
    rec.add_argument("--only", help="only the cases whose name matches this regular expression")
    cmp_ = sub.add_parser("compare", help="compare two recorded folders")
    cmp_.add_argument("before", type=Path)
    cmp_.add_argument("after", type=Path)
    cmp_.add_argument("--rtol", type=float, help="also count runs close within this as equal")
    args = ap.parse_args(argv)
    if args.action == "record":
        return record(args.folder, args.steps, args.only)
    return compare(args.before, args.after, args.rtol)


if __name__ == "__main__":
    raise SystemExit(main())
