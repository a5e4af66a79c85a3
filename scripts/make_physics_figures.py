#!/usr/bin/env python3
"""Generate the figures of docs/physics.md (like the paper's Figures 2 and 6).

Usage: PYTHONPATH=ops_sim_ros python scripts/make_physics_figures.py [--out docs/figures]
"""

from __future__ import annotations

import argparse
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from ops_sim_ros.config import make_config
from ops_sim_ros.physics import PulseStacker
from ops_sim_ros.rendering import draw_trace
from ops_sim_ros.simulation import BatchedSimulation


def landscapes(out: pathlib.Path) -> None:
    ps1 = PulseStacker(1, dtype=np.float64)
    period = ps1.optical_period_fs
    d = np.linspace(-2 * period, 2 * period, 801)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    axes[0].plot(d, ps1.power(d[:, None]), label="P_1 / P_max (I² detector)")
    axes[0].plot(d, ps1.slot_energies(d[:, None])[:, 0], "--", label="stacked pulse energy")
    axes[0].set_xlabel("stage-1 delay error τ₁ (fs)")
    axes[0].set_ylabel("normalized")
    axes[0].set_title("(a) 1 stage: fringe with the optical period (3.44 fs)")
    axes[0].legend(loc="lower right", fontsize=8)
    ps2 = PulseStacker(2, dtype=np.float64)
    g = np.linspace(-period, period, 241)
    d1, d2 = np.meshgrid(g, g, indexing="ij")
    p = ps2.power(np.stack([d1.ravel(), d2.ravel()], 1)).reshape(d1.shape)
    im = axes[1].contourf(d1, d2, p, levels=40, cmap="viridis")
    fig.colorbar(im, ax=axes[1], label="P_2 / P_max")
    axes[1].set_xlabel("τ₁ error (fs)")
    axes[1].set_ylabel("τ₂ error (fs)")
    axes[1].set_title("(b) 2 stages: global maxima (1.0) and local maxima (0.125)")
    fig.tight_layout()
    fig.savefig(out / "physics_landscape.png", dpi=110)
    plt.close(fig)

    # walk-off: the fringe envelope over large delays
    d = np.linspace(-1500, 1500, 6001)
    fine = PulseStacker(1, dtype=np.float64, quadrature_points=24)
    fig, ax = plt.subplots(figsize=(8, 3.2))
    ax.plot(d, fine.power(d[:, None]), linewidth=0.3)
    ax.set_xlabel("stage-1 delay error (fs)")
    ax.set_ylabel("P_1 / P_max")
    ax.set_title("1 stage, large errors: fringes under the envelope-overlap (walk-off) limit")
    fig.tight_layout()
    fig.savefig(out / "physics_walkoff.png", dpi=110)
    plt.close(fig)


def traces(out: pathlib.Path, stage: int = 3) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4), sharey=True)
    cfg_easy = make_config(stage=stage, mode="easy")
    cfg_med = make_config(stage=stage, mode="medium")
    r_easy = BatchedSimulation(cfg_easy, 1, seed=4).reset()
    r_med = BatchedSimulation(cfg_med, 1, seed=4).reset()
    ps = PulseStacker(stage)
    spp = cfg_easy.samples_per_slot
    tr_opt = ps.trace(np.zeros(stage))
    for ax, tr, pw, title in (
        (
            axes[0],
            ps.trace_from_energies(r_easy.pulse_energies[0]),
            r_easy.power[0],
            "(a) easy: initial",
        ),
        (
            axes[1],
            ps.trace_from_energies(r_med.pulse_energies[0]),
            r_med.power[0],
            "(b) medium / hard: initial",
        ),
        (axes[2], tr_opt, 1.0, "(c) optimum"),
    ):
        draw_trace(ax, tr, spp, cfg_easy.pulse_spacing_fs, power=float(pw), title=title)
    fig.suptitle(f"{stage}-stage output traces (detected pulse energies)", fontsize=11)
    fig.tight_layout()
    fig.savefig(out / "physics_traces.png", dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="docs/figures")
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    landscapes(out)
    traces(out)
    print("wrote", *sorted(str(p) for p in out.glob("physics_*.png")))


if __name__ == "__main__":
    main()
