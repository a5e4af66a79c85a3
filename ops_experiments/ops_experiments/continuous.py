"""Continuous operation: the figures of one long closed-loop run (``evaluate --continuous``).

A lab closes the loop once and expects the stacker to stay locked for hours; an episode of 200
steps from a random start does not show whether it does. A continuous run is one episode of
``STEPS`` control steps per seed, with the environment's noise and drift running all the time
(no reset: the drift's knots and its bound at +- ``drift_bound_cycles`` keep acting).

From the readings P_N / P_max of one run (the one after the start, then one per step):

* ``first_lock_step``: the first reading >= ``LOCK`` (0.95), in steps (None: never);
* ``locked_fraction``: the fraction of readings >= ``LOCK`` from the first lock on;
* ``losses``: the lock losses after the first lock, maximal runs of readings < ``LOSS`` (0.8),
  their number and lengths (readings);
* ``worst_after_lock`` and ``worst``: the lowest reading after the first lock and overall.

Pure numpy (no rclpy, no torch): ``ops-bench continuous-dds`` computes the same figures from the
readings of the real nodes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

LOCK = 0.95  # a reading at or above this is "locked"
LOSS = 0.8  # a reading below this, after the first lock, is part of a lock loss


def run_lengths(mask: np.ndarray) -> np.ndarray:
    """Lengths of the maximal runs of True in a 1-D boolean array, in order."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m))
    return edges[1::2] - edges[0::2]


def lock_figures(power, lock: float = LOCK, loss: float = LOSS) -> dict[str, Any]:
    """The continuous-run figures of one run's readings ``power`` (1-D)."""
    p = np.asarray(power, dtype=np.float64).ravel()
    if p.size == 0 or not np.all(np.isfinite(p)):
        raise ValueError("a continuous run needs one or more finite readings")
    locked = np.flatnonzero(p >= lock)
    out: dict[str, Any] = {
        "readings": int(p.size),
        "first_lock_step": None,
        "locked_readings": 0,
        "readings_after_lock": 0,
        "locked_fraction": 0.0,
        "losses": 0,
        "loss_lengths": [],
        "worst_after_lock": None,
        "worst": float(p.min()),
    }
    if locked.size == 0:
        return out
    tail = p[locked[0] :]
    lengths = run_lengths(tail < loss)
    out.update(
        first_lock_step=int(locked[0]),
        locked_readings=int(np.count_nonzero(tail >= lock)),
        readings_after_lock=int(tail.size),
        locked_fraction=float(np.count_nonzero(tail >= lock) / tail.size),
        losses=int(lengths.size),
        loss_lengths=[int(n) for n in lengths],
        worst_after_lock=float(tail.min()),
    )
    return out


def overall(per_seed: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures of several runs together (pooled readings; worst and longest over runs)."""
    after = sum(r["readings_after_lock"] for r in per_seed)
    good = sum(r["locked_readings"] for r in per_seed)
    lengths = [n for r in per_seed for n in r["loss_lengths"]]
    firsts = [r["first_lock_step"] for r in per_seed if r["first_lock_step"] is not None]
    worst_after = [r["worst_after_lock"] for r in per_seed if r["worst_after_lock"] is not None]
    return {
        "runs": len(per_seed),
        "runs_never_locked": len(per_seed) - len(firsts),
        "locked_fraction": float(good / after) if after else 0.0,
        "locked_fraction_worst_run": float(min(r["locked_fraction"] for r in per_seed)),
        "losses": len(lengths),
        "runs_with_losses": sum(1 for r in per_seed if r["losses"]),
        "longest_loss": max(lengths, default=0),
        "readings_in_losses": int(sum(lengths)),
        "worst_after_lock": min(worst_after) if worst_after else None,
        "worst": float(min(r["worst"] for r in per_seed)),
        "first_lock_step_median": float(np.median(firsts)) if firsts else None,
        "first_lock_step_max": max(firsts) if firsts else None,
    }


def _fmt(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def format_run(name: str, figures: dict[str, Any]) -> str:
    """One line of figures (a seed's run, or ``overall`` of several)."""
    lengths = figures.get("loss_lengths")
    longest = max(lengths, default=0) if lengths is not None else figures["longest_loss"]
    first = figures.get("first_lock_step", figures.get("first_lock_step_median"))
    return (
        f"{name:<10} {100 * figures['locked_fraction']:>8.2f} % {figures['losses']:>7d} "
        f"{longest:>8d} {_fmt(figures['worst_after_lock'], '.4f'):>11} "
        f"{figures['worst']:>7.4f} {_fmt(first, '.0f'):>11}"
    )


def format_table(results: dict[str, Any]) -> str:
    """The printed summary of ``evaluate --continuous``."""
    lines = [
        f"{results['controller']} on stage {results['stage']}, {results['mode']} mode, continuous "
        f"({len(results['seeds'])} runs of {results['continuous_steps']} steps; locked: "
        f">= {LOCK}, loss: < {LOSS} after the first lock)"
    ]
    header = (
        f"{'run':<10} {'locked':>10} {'losses':>7} {'longest':>8} {'worst lock':>11} "
        f"{'worst':>7} {'first lock':>11}"
    )
    for split, s in results["splits"].items():
        lines += [f"split {split}", header]
        for seed, fig in zip(results["seeds"], s["per_seed"], strict=True):
            lines.append(format_run(f"seed {seed}", fig))
        lines.append(format_run("overall", s["overall"]))
    return "\n".join(lines)


# ---------------------------------------------------------------------------------- evaluate
def evaluate(args, subject) -> dict[str, Any]:
    """``evaluate --continuous STEPS``: one run of STEPS steps per seed and split of
    ``subject`` (an :class:`ops_experiments.subject.Subject`), its figures per run and
    overall."""
    import time

    steps = args.continuous
    if steps < 1 or not args.seeds:
        raise ValueError("--continuous STEPS must be >= 1 and --seeds non-empty")
    if args.record:
        raise ValueError("--record records episodes; it cannot be combined with --continuous")
    results: dict[str, Any] = {
        **subject.meta,
        "stage": subject.stage,
        "mode": subject.mode,
        "detector": subject.detector,
        "env_overrides": subject.env_overrides,
        "seeds": list(args.seeds),
        "continuous_steps": steps,
        "lock_threshold": LOCK,
        "loss_threshold": LOSS,
        "splits": {},
    }
    t0 = time.monotonic()
    for split in args.splits:
        runs, traces = [], []
        for seed in args.seeds:
            power = subject.run(split, 1, steps, seed)["power"][0]
            runs.append(lock_figures(power))
            traces.append(_downsample(power))
            if not args.quiet:
                print(
                    f"[evaluate] {subject.name} stage={subject.stage} mode={subject.mode} "
                    f"split={split} seed={seed}: "
                    + format_run("continuous", runs[-1]).split(None, 1)[1],
                    flush=True,
                )
        results["splits"][split] = {
            "overall": overall(runs),
            "per_seed": runs,
            "trace_min_per_block": traces,
        }
    results["trace_block_steps"] = BLOCK
    results["wall_s"] = round(time.monotonic() - t0, 2)
    return results


BLOCK = 100  # readings per point of the stored trace (its minimum)


def _downsample(power: np.ndarray) -> list[float]:
    """The lowest reading of each block of BLOCK readings (a dip is never averaged away)."""
    n = -(-power.size // BLOCK) * BLOCK
    padded = np.concatenate([power, np.full(n - power.size, np.inf)])
    return [round(float(v), 5) for v in padded.reshape(-1, BLOCK).min(axis=1)]


def write_outputs(results: dict[str, Any], out, plot: bool = True) -> list:
    """``OUT/evaluation.json`` and (``plot``) ``OUT/continuous.png``: each run's lowest reading
    per block of steps."""
    import json
    from pathlib import Path

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "evaluation.json").write_text(json.dumps(results, indent=2) + "\n")
    written = [out / "evaluation.json"]
    if plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        splits = results["splits"]
        fig, axes = plt.subplots(len(splits), 1, figsize=(7, 2.6 * len(splits)), dpi=110)
        for ax, (split, s) in zip(np.atleast_1d(axes), splits.items(), strict=True):
            for seed, trace in zip(results["seeds"], s["trace_min_per_block"], strict=True):
                steps = np.arange(len(trace)) * results["trace_block_steps"]
                ax.plot(steps, trace, lw=0.8, label=f"seed {seed}")
            ax.axhline(LOCK, color="k", lw=0.5, ls="--")
            ax.axhline(LOSS, color="r", lw=0.5, ls=":")
            ax.set_ylim(0, 1.02)
            ax.set_ylabel(f"min P_N/P_max per {results['trace_block_steps']}")
            ax.set_title(
                f"{results['controller']}, stage {results['stage']}, {results['mode']}, "
                f"{split}: {100 * s['overall']['locked_fraction']:.2f} % locked",
                fontsize=9,
            )
            if len(results["seeds"]) <= 10:
                ax.legend(fontsize=6, loc="lower right", ncol=5)
        np.atleast_1d(axes)[-1].set_xlabel("step")
        fig.tight_layout()
        fig.savefig(out / "continuous.png")
        plt.close(fig)
        written.append(out / "continuous.png")
    return written
