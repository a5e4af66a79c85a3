"""Figures of docs/tracker.md: an acquisition from a random start (traces and P_N against SPGD-PID)
and tracking in hard and extreme mode (the estimate against the hidden delay error).

Usage (after `source setup.bash`): OPENBLAS_NUM_THREADS=1 ops-bench figures tracker
    [--out docs/figures] [--seed 3]
"""

from __future__ import annotations

import argparse
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from ops_contract.config import make_config
from ops_controller_ros.controllers import make_controller, next_command
from ops_sim_ros.env import OpsEnv
from ops_sim_ros.rendering import draw_trace

from ops_bench.docs import save_figure


def run(mode, controller, seed, steps=200, stage=5):
    """(power (steps + 1,), traces (steps + 1, L), true errors, estimates (steps + 1, N))."""
    cfg = make_config(stage=stage, mode=mode, split="test")
    env = OpsEnv.from_config(cfg, max_episode_steps=steps)
    _, info = env.reset(seed=seed)
    ctl = make_controller(controller, cfg, {}, info["setpoints_fs"], seed=seed)
    period = cfg.optical_period_fs
    power, traces = [info["power"]], [env.trace()]
    truth = [(info["delays_fs"] - info["setpoints_fs"]) / period]
    estimate = [np.full(stage, np.nan)]
    for _ in range(steps):
        r = env.step_setpoints(next_command(ctl))
        ctl.observe(float(r.power[0]), r.pulse_energies[0])
        power.append(float(r.power[0]))
        traces.append(env.trace())
        truth.append((r.applied_fs[0] - r.setpoints_fs[0]) / period)
        est = getattr(ctl, "estimate", None)
        estimate.append(np.full(stage, np.nan) if est is None else est.copy())
    return np.array(power), np.array(traces), np.array(truth), np.array(estimate), cfg


def acquisition(out: pathlib.Path, seed: int) -> None:
    power, traces, _, _, cfg = run("medium", "tracker", seed, steps=60)
    spgd, *_ = run("medium", "spgd", seed, steps=60)
    locked = int(np.flatnonzero(power >= 0.95)[0])
    shown = (0, 3, locked - 1, locked, 30)
    fig = plt.figure(figsize=(14, 6.5))
    grid = fig.add_gridspec(2, len(shown))
    for i, t in enumerate(shown):
        ax = fig.add_subplot(grid[0, i])
        draw_trace(
            ax,
            traces[t],
            cfg.samples_per_slot,
            cfg.pulse_spacing_fs,
            power=float(power[t]),
            title=f"step {t}",
        )
    ax = fig.add_subplot(grid[1, :])
    ax.plot(power, "o-", markersize=3, label="tracker")
    ax.plot(spgd, "s-", markersize=2, alpha=0.7, label="SPGD-PID (same start)")
    ax.axhline(0.95, color="gray", linestyle=":", linewidth=0.8)
    ax.axvspan(0, locked - 1, color="tab:orange", alpha=0.1, label="acquiring: known excursions")
    ax.set_xlabel("control step")
    ax.set_ylabel("P_N / P_max")
    ax.set_ylim(0, 1.02)
    ax.legend(loc="lower right", fontsize=8)
    fig.suptitle(
        f"Tracker: acquisition from a random start (N = {cfg.stage}, medium, seed {seed})",
        fontsize=11,
    )
    save_figure(fig, out / "tracker_acquisition.png", dpi=100)


def tracking(out: pathlib.Path, seed: int) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(13, 6.5), sharex=True)
    for col, mode in enumerate(("hard", "extreme")):
        power, _, truth, est, cfg = run(mode, "tracker", seed, steps=200)
        ax = axes[0, col]
        ax.plot(power, linewidth=0.9)
        ax.set_ylim(0, 1.02)
        ax.set_ylabel("P_N / P_max")
        ax.set_title(f"{mode} mode, testing split (N = {cfg.stage}, seed {seed})", fontsize=10)
        ax = axes[1, col]
        for j in range(cfg.stage):
            line = ax.plot(truth[:, j], linewidth=0.8, label=f"stage {j + 1}")[0]
            # the estimate is known modulo one cycle: draw it on the branch of the truth
            e = est[:, j] + np.round(truth[:, j] - est[:, j])
            ax.plot(e, "--", color=line.get_color(), linewidth=0.8)
        ax.set_xlabel("control step")
        ax.set_ylabel("hidden delay error (cycles)")
        if col == 0:
            ax.legend(fontsize=7, ncol=5, loc="upper left", title="solid: true, dashed: estimate")
    save_figure(fig, out / "tracker_tracking.png", dpi=100)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    acquisition(out, args.seed)
    tracking(out, args.seed)
    print("wrote", out / "tracker_acquisition.png", out / "tracker_tracking.png")


if __name__ == "__main__":
    main()
