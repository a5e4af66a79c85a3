"""SPGD-PID's climbs and restarts, attempt by attempt, at each latency.

N = 5, testing split, ``--mode`` (default hard), the rig ``--realism`` (default ``ideal``) with
each of ``--latencies`` steps in turn (``--rig latency_steps=L``; SPGD is told it): the episodes
``evaluate --controller spgd`` runs (``rollouts.controller_episodes``), with SPGD's restart
count read after each reading. An *attempt* is the episode's start or a restart, up to the next
restart or the episode's end. Per latency:

* restarts per episode, and the final P_N/P_max (mean and worst episode);
* the share of starts and of restarts that reach 0.9 (any reading >= 0.9 before the attempt
  ends; an attempt the episode's end cuts short counts as it stands);
* steps from a start / a restart to its first reading >= 0.9 (median, 90th percentile);
* steps after which a failed start / restart ends in the next restart (median; attempts the
  episode's end cuts short are left out).

docs/results/spgd/notes.md ("Where the 0.04 goes") quotes it.

Usage (after `source setup.bash`):
  ops-bench spgd-attempts [--mode hard] [--latencies 0 1] [--seeds 8101 ... 8300]
      [--episodes 5] [--param KEY=VALUE] [--out attempts.json]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from ops_contract.config import MODES, REALISMS, make_config
from ops_contract.threads import limit_blas_threads
from ops_controller_ros.spgd import SpgdParams
from ops_experiments import cli_args
from ops_experiments.envs import EPISODE_STEPS

from ops_bench import study

STAGE = 5
REACH = 0.9  # an attempt that reaches this has found the main peak's basin


class RestartRecorder:
    """``on_step`` of :func:`controller_episodes`: each step's reading and restart count."""

    def __init__(self, episodes: int, steps: int):
        self.power = np.empty((episodes, steps))
        self.restarts = np.empty((episodes, steps), dtype=int)

    def __call__(self, e: int, t: int, ctl, env, r) -> None:
        self.power[e, t] = float(r.power[0])
        self.restarts[e, t] = ctl.restarts


def attempts_of(power: np.ndarray, restarts: np.ndarray) -> list[dict]:
    """One episode's attempts: ``kind`` (start, restart), ``reached`` (steps from the attempt's
    beginning to its first reading >= REACH, or None), ``ended`` (steps to the restart that
    ended it, or None where the episode's end did)."""
    steps = len(power)
    # a restart decided on the reading of step t: the attempt begins with step t + 1
    begins = [0] + [t + 1 for t in np.flatnonzero(np.diff(restarts, prepend=0) > 0)]
    out = []
    for i, b in enumerate(begins):
        end = begins[i + 1] if i + 1 < len(begins) else steps
        high = np.flatnonzero(power[b:end] >= REACH)
        out.append(
            {
                "kind": "start" if i == 0 else "restart",
                "reached": int(high[0]) + 1 if high.size else None,
                "ended": end - b if i + 1 < len(begins) else None,
            }
        )
    return out


def summarize(rec: RestartRecorder, finals) -> dict:
    """The module docstring's figures over all episodes of ``rec``."""
    attempts = [a for p, r in zip(rec.power, rec.restarts, strict=True) for a in attempts_of(p, r)]
    res = {
        "episodes": len(finals),
        "mean_final": float(np.mean(finals)),
        "worst_final": float(np.min(finals)),
        "restarts_per_episode": float(np.mean(rec.restarts[:, -1])),
    }
    for kind in ("start", "restart"):
        mine = [a for a in attempts if a["kind"] == kind]
        steps = [a["reached"] for a in mine if a["reached"] is not None]
        failed = [a["ended"] for a in mine if a["reached"] is None and a["ended"] is not None]
        res[kind] = {
            "attempts": len(mine),
            "reach_share": len(steps) / len(mine) if mine else None,
            "steps_to_reach_median": float(np.median(steps)) if steps else None,
            "steps_to_reach_p90": float(np.percentile(steps, 90)) if steps else None,
            "failed_ends_after_median": float(np.median(failed)) if failed else None,
        }
    return res


def run(latency: int, mode: str, realism: str, seeds, episodes: int, params: dict) -> dict:
    """SPGD's attempts on the rig with ``latency`` over ``seeds`` x ``episodes`` episodes."""
    rig = cli_args.resolve_rig(realism, [f"latency_steps={latency}"])
    cfg = make_config(STAGE, mode, "test", episode_steps=EPISODE_STEPS, **rig)
    rec = RestartRecorder(len(seeds) * episodes, EPISODE_STEPS)
    finals = study.recorded_episodes(cfg, "spgd", params, seeds, episodes, rec)
    return summarize(rec, finals)


def _f(value, spec: str, scale: float = 1.0) -> str:
    return "-" if value is None else format(value * scale, spec)


def table(results: dict[int, dict]) -> str:
    """The docs' table, a column per latency."""
    lats = list(results)
    lines = ["| | " + " | ".join(f"L = {L}" for L in lats) + " |", "|---|" + "---|" * len(lats)]

    def row(label, cell):
        lines.append(f"| {label} | " + " | ".join(cell(results[L]) for L in lats) + " |")

    row(
        "final P_N/P_max (mean / worst)",
        lambda r: f"{r['mean_final']:.3f} / {r['worst_final']:.3f}",
    )
    row("restarts per episode", lambda r: f"{r['restarts_per_episode']:.2f}")
    for kind in ("start", "restart"):
        row(
            f"a {kind} reaches {REACH}",
            lambda r, k=kind: _f(r[k]["reach_share"], ".1f", 100) + " %",
        )
    for kind in ("start", "restart"):
        row(
            f"steps from a {kind} to {REACH} (median / 90th percentile)",
            lambda r, k=kind: (
                _f(r[k]["steps_to_reach_median"], ".0f")
                + " / "
                + _f(r[k]["steps_to_reach_p90"], ".0f")
            ),
        )
    for kind in ("start", "restart"):
        row(
            f"a failed {kind} ends in a restart after (median)",
            lambda r, k=kind: _f(r[k]["failed_ends_after_median"], ".0f") + " steps",
        )
    return "\n".join(lines)


def latency_type(text: str) -> int:
    """An argparse ``type``: a latency in steps, >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0 (got {text!r})") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0 (got {value})")
    return value


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--mode", choices=MODES, default="hard")
    ap.add_argument("--realism", choices=REALISMS, default="ideal")
    ap.add_argument("--latencies", type=latency_type, nargs="+", default=[0, 1])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(8101, 8301)))
    ap.add_argument("--episodes", type=cli_args.positive_int, default=5, help="per seed")
    study.add_options(ap, "SPGD-PID")
    args = ap.parse_args(argv)
    study.check_params(ap, args, SpgdParams)
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    limit_blas_threads()
    results = {}
    for latency in dict.fromkeys(args.latencies):
        t0 = time.monotonic()
        res = run(latency, args.mode, args.realism, args.seeds, args.episodes, args.params)
        results[latency] = res
        print(
            f"[spgd-attempts] {args.mode}, {args.realism}, latency {latency}: {res['episodes']} "
            f"episodes, final P_N/P_max mean {res['mean_final']:.4f}, "
            f"{res['restarts_per_episode']:.2f} restarts an episode "
            f"({time.monotonic() - t0:.0f} s)",
            flush=True,
        )
    print(table(results))
    if args.out:
        out = {
            "settings": {
                "stage": STAGE,
                "mode": args.mode,
                "split": "test",
                "realism": args.realism,
                "seeds": args.seeds,
                "episodes": args.episodes,
                "spgd_params": args.params,
            },
            "results": {str(k): v for k, v in results.items()},
        }
        study.write_figures(args.out, "spgd-attempts", argv, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
