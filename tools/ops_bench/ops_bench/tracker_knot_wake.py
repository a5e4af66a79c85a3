"""What a knot of the drift costs the tracker, reading by reading after it.

N = 5, testing split, ``--mode`` (default extreme), each ``--realism`` in turn (default ``lab``
and ``ideal``): the tracker's episodes exactly as ``evaluate --controller tracker`` runs them
(``rollouts.controller_episodes``; the tracker is told the rig), with the simulator's slopes
read beside each step. A knot is a change of one stage's drift slope (a knot of the drift, or
the drift turned at its bound) from the episode's ``--from-step`` on; reading 0 is the first
reading the new slope acts on. For each count of readings since a knot (``--readings``):

* **P_N/P_max**: the mean reading;
* **drift error / change**: the median of |the tracker's drift of the knotted stage - its new
  slope| / |new slope - old slope| (1 at reading 0: the estimate still holds the old slope);
* **knot taken**: the share of knots after which the tracker has taken a knot hypothesis
  (``PhaseTracker.knots`` grew since the reading before the knot).

A knot counts at a reading only while its episode lasts; other knots may fall in its wake, as
they do in the mode. docs/tracker.md ("What a knot costs, reading by reading") quotes it.

Usage (after `source setup.bash`):
  ops-bench tracker-knot-wake [--mode extreme] [--realism lab ideal]
      [--seeds 8101 8102 8103 8104] [--episodes 5] [--param KEY=VALUE] [--out wake.json]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from ops_contract.config import MODES, REALISMS, make_config
from ops_contract.threads import limit_blas_threads
from ops_controller_ros.tracker import TrackerParams
from ops_experiments import cli_args
from ops_experiments.envs import EPISODE_STEPS

from ops_bench import study

STAGE = 5
READINGS = (0, 2, 3, 4, 5, 6, 8, 10, 12, 16)


class WakeRecorder:
    """``on_step`` of :func:`controller_episodes`: each step's reading, the tracker's drift and
    knot count, and the simulator's slopes (cycles per step) after the step."""

    def __init__(self, episodes: int, steps: int, period_fs: float):
        self.period_fs = period_fs
        self.power = np.empty((episodes, steps))
        self.drift = np.empty((episodes, steps, STAGE))
        self.taken = np.empty((episodes, steps), dtype=int)
        self.slope = np.empty((episodes, steps, STAGE))

    def __call__(self, e: int, t: int, ctl, env, r) -> None:
        self.power[e, t] = float(r.power[0])
        self.drift[e, t] = ctl.drift
        self.taken[e, t] = ctl.knots
        self.slope[e, t] = env.sim.noise.slope[0] / self.period_fs


def knots_of(slope: np.ndarray, from_step: int) -> list[tuple[int, int]]:
    """(first step the new slope acts on, stage) of every slope change in one episode's
    ``slope`` (steps, stages; the slope after each step) acting from ``from_step`` on."""
    changed = np.abs(np.diff(slope, axis=0)) > 1e-15  # [i]: changed during step i + 1
    return [
        (i + 2, s)  # redrawn during step i + 1: acts from step i + 2
        for i, s in zip(*np.nonzero(changed), strict=True)
        if from_step <= i + 2 < slope.shape[0]
    ]


def wake(rec: WakeRecorder, from_step: int, readings) -> dict:
    """The module docstring's three rows, one entry per count of ``readings``."""
    cells = {k: {"power": [], "error": [], "taken": []} for k in readings}
    knots = 0
    steps = rec.power.shape[1]
    for e in range(rec.power.shape[0]):
        for start, stage in knots_of(rec.slope[e], from_step):
            knots += 1
            old, new = rec.slope[e, start - 2, stage], rec.slope[e, start - 1, stage]
            before = rec.taken[e, start - 1]
            for k in readings:
                t = start + k
                if t >= steps:
                    continue
                cells[k]["power"].append(rec.power[e, t])
                cells[k]["error"].append(abs(rec.drift[e, t, stage] - new) / abs(new - old))
                cells[k]["taken"].append(rec.taken[e, t] > before)
    rows = {
        str(k): {
            "power": float(np.mean(c["power"])) if c["power"] else None,
            "drift_error_over_change": float(np.median(c["error"])) if c["error"] else None,
            "knot_taken": float(np.mean(c["taken"])) if c["taken"] else None,
            "knots": len(c["power"]),
        }
        for k, c in cells.items()
    }
    return {"knots": knots, "by_readings": rows}


def run(
    realism: str,
    mode: str,
    seeds,
    episodes: int,
    params: dict,
    from_step: int,
    readings,
    steps: int = EPISODE_STEPS,
) -> dict:
    """The wake on one rig over ``seeds`` x ``episodes`` episodes (the evaluation's seeds)."""
    rig = cli_args.resolve_rig(realism, None)
    cfg = make_config(STAGE, mode, "test", episode_steps=steps, **rig)
    rec = WakeRecorder(len(seeds) * episodes, steps, cfg.optical_period_fs)
    finals = study.recorded_episodes(cfg, "tracker", params, seeds, episodes, rec)
    result = {"episodes": len(finals), "mean_final": float(np.mean(finals))}
    result["worst_final"] = float(np.min(finals))
    return {**result, **wake(rec, from_step, readings)}


def table(results: dict[str, dict], readings) -> str:
    """The docs' table: a row of each figure for each rig."""
    head = "| readings since the knot | " + " | ".join(str(k) for k in readings) + " |"
    lines = [head, "|---|" + "---|" * len(readings)]
    for realism, res in results.items():
        for key, label in (
            ("power", "P_N/P_max"),
            ("drift_error_over_change", "drift error / change"),
            ("knot_taken", "knot taken"),
        ):
            cells = [res["by_readings"][str(k)][key] for k in readings]
            text = " | ".join("" if v is None else f"{v:.3f}" for v in cells)
            lines.append(f"| `{realism}`: {label} | {text} |")
    return "\n".join(lines)


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--mode", choices=MODES, default="extreme")
    ap.add_argument("--realism", choices=REALISMS, nargs="+", default=["lab", "ideal"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[8101, 8102, 8103, 8104])
    ap.add_argument("--episodes", type=cli_args.positive_int, default=5, help="per seed")
    ap.add_argument(
        "--from-step", type=cli_args.positive_int, default=40, help="knots acting from this step"
    )
    ap.add_argument(
        "--readings",
        type=int,
        nargs="+",
        default=list(READINGS),
        help="readings since a knot to report (each in 0-199)",
    )
    study.add_options(ap, "tracker")
    args = ap.parse_args(argv)
    if any(not 0 <= k < EPISODE_STEPS for k in args.readings):
        ap.error(f"--readings: each must be in 0-{EPISODE_STEPS - 1} (got {args.readings})")
    if args.from_step < 2 or args.from_step >= EPISODE_STEPS:
        ap.error(f"--from-step: must be in 2-{EPISODE_STEPS - 1} (got {args.from_step})")
    study.check_params(ap, args, TrackerParams)
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    limit_blas_threads()
    readings = sorted(set(args.readings))
    results = {}
    for realism in args.realism:
        t0 = time.monotonic()
        res = run(
            realism, args.mode, args.seeds, args.episodes, args.params, args.from_step, readings
        )
        results[realism] = res
        print(
            f"[tracker-knot-wake] {realism}, {args.mode}: {res['episodes']} episodes, final "
            f"P_N/P_max mean {res['mean_final']:.4f} (worst {res['worst_final']:.3f}); "
            f"{res['knots']} knots from step {args.from_step} ({time.monotonic() - t0:.0f} s)",
            flush=True,
        )
    print(table(results, readings))
    if args.out:
        out = {
            "settings": {
                "stage": STAGE,
                "mode": args.mode,
                "split": "test",
                "seeds": args.seeds,
                "episodes": args.episodes,
                "from_step": args.from_step,
                "tracker_params": args.params,
            },
            "results": results,
        }
        study.write_figures(args.out, "tracker-knot-wake", argv, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
