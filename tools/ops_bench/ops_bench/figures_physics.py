"""Generate the figures of docs/physics.md (like the paper's Figures 2 and 6).

Usage: PYTHONPATH=ops_sim_ros ops-bench figures physics [--out docs/figures]
"""

from __future__ import annotations

import argparse
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from ops_contract.config import make_config
from ops_sim_ros.physics import PulseStacker, geometry_matrices, input_coding
from ops_sim_ros.rendering import draw_trace
from ops_sim_ros.rig import Actuator
from ops_sim_ros.simulation import BatchedSimulation
from ops_sim_ros.vibration import PRESETS, Vibration

from ops_bench.docs import save_figure
from ops_bench.physical_time import periodogram


def architecture(out: pathlib.Path, stage: int = 3) -> None:
    """The polarization paths at zero delay error: the coded input and the field after each
    stage, s up (blue) and p down (red), per time slot."""
    fig, axes = plt.subplots(stage + 1, 1, figsize=(9, 1.5 * (stage + 1)), sharex=True)
    slots = np.arange(2 ** (stage + 1) - 1)
    for k, ax in enumerate(axes):
        c_s, c_p = geometry_matrices(stage, through=k)
        amp_s, amp_p = c_s.sum(axis=1), c_p.sum(axis=1)  # zero errors: patterns add up
        ax.bar(slots - 0.15, amp_s, width=0.3, color="tab:blue", label="s")
        ax.bar(slots + 0.15, -amp_p, width=0.3, color="tab:red", label="p (drawn downwards)")
        ax.axhline(0, color="k", linewidth=0.5)
        lim = 2 ** (stage / 2) + 0.3
        ax.set_ylim(-lim, lim)
        if k == 0:
            code = " ".join(("-" if sg < 0 else "+") + pol for pol, sg in input_coding(stage))
            ax.set_title(
                f"{stage}-stage stacker at zero delay error: input coding {code}", fontsize=9
            )
            ax.set_ylabel("input")
            ax.legend(loc="upper right", fontsize=7, ncol=2)
        else:
            d = 2 ** (k - 1)
            ax.set_ylabel(f"after {k}")
            ax.text(
                0.01,
                0.8,
                f"stage {k}: PBS delays p by {d} slot{'s' * (d > 1)}, 45° plate mixes s and p",
                transform=ax.transAxes,
                fontsize=8,
            )
    axes[-1].set_xlabel("time slot (units of the pulse spacing T)")
    axes[-1].set_xticks(slots)
    save_figure(fig, out / "physics_architecture.png", dpi=110)


def landscapes(out: pathlib.Path) -> None:
    ps1 = PulseStacker(1, dtype=np.float64)
    tot1 = PulseStacker(1, dtype=np.float64, detector="total")
    period = ps1.optical_period_fs
    d = np.linspace(-2 * period, 2 * period, 801)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    axes[0].plot(d, ps1.power(d[:, None]), label="P_1 / P_max, polarizer (cos⁴)")
    axes[0].plot(d, ps1.slot_energies(d[:, None])[:, 0], "--", label="stacked pulse energy")
    axes[0].plot(d, tot1.power(d[:, None]), ":", label="P_1 / P_max, total intensity (flat)")
    axes[0].set_xlabel("stage-1 delay error τ₁ (fs)")
    axes[0].set_ylabel("normalized")
    axes[0].set_ylim(-0.02, 1.08)
    axes[0].set_title("(a) 1 stage: fringe with the optical period (3.44 fs)")
    axes[0].legend(loc="lower right", fontsize=8)
    g = np.linspace(-period, period, 241)
    d1, d2 = np.meshgrid(g, g, indexing="ij")
    grid = np.stack([d1.ravel(), d2.ravel()], 1)
    for ax, detector, title in (
        (axes[1], "polarizer", "(b) 2 stages, polarizer: global (1.0) and local maxima"),
        (axes[2], "total", "(c) 2 stages, total intensity: τ₂ invisible"),
    ):
        p = PulseStacker(2, dtype=np.float64, detector=detector).power(grid).reshape(d1.shape)
        im = ax.contourf(d1, d2, p, levels=np.linspace(0, 1, 41), cmap="viridis")
        ax.set_xlabel("τ₁ error (fs)")
        ax.set_ylabel("τ₂ error (fs)")
        ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=axes[2], label="P_2 / P_max")
    save_figure(fig, out / "physics_landscape.png", dpi=110)


def walkoff(out: pathlib.Path) -> None:
    # walk-off: the fringe envelope over large delays
    d = np.linspace(-1500, 1500, 6001)
    fine = PulseStacker(1, dtype=np.float64, quadrature_points=24)
    fig, ax = plt.subplots(figsize=(8, 3.2))
    ax.plot(d, fine.power(d[:, None]), linewidth=0.3)
    ax.set_xlabel("stage-1 delay error (fs)")
    ax.set_ylabel("P_1 / P_max")
    ax.set_title("1 stage, large errors: fringes under the envelope-overlap (walk-off) limit")
    save_figure(fig, out / "physics_walkoff.png", dpi=110)


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
    save_figure(fig, out / "physics_traces.png", dpi=110)


def modes(out: pathlib.Path, stage: int = 5) -> None:
    """(a) initial delay errors per mode; (b) the hidden delay error of one stage over episodes."""
    fig, axes = plt.subplots(1, 2, figsize=(13, 4))
    bins = np.linspace(-1.0, 1.0, 81)
    for mode in ("easy", "medium", "hard"):
        sim = BatchedSimulation(make_config(stage=stage, mode=mode), num_envs=4000, seed=0)
        err = sim.reset().applied_fs / sim.optical_period_fs
        axes[0].hist(err.ravel(), bins=bins, histtype="step", density=True, label=mode)
    axes[0].set_xlabel("initial delay error per stage (optical cycles)")
    axes[0].set_ylabel("density")
    axes[0].set_title(f"(a) initial state, N = {stage} (extreme as hard)")
    axes[0].legend(fontsize=8)
    steps = 200
    for mode, split, color in (
        ("medium", "train", "tab:gray"),
        ("hard", "train", "tab:blue"),
        ("hard", "test", "tab:cyan"),
        ("extreme", "train", "tab:red"),
        ("extreme", "test", "tab:orange"),
    ):
        cfg = make_config(stage=stage, mode=mode, split=split)
        sim = BatchedSimulation(cfg, num_envs=3, seed=2)
        sim.reset()
        start = sim.last.applied_fs.copy()
        walk = [np.zeros(3)]
        for _ in range(steps):
            walk.append((sim.step_setpoints(np.zeros((3, stage))).applied_fs - start)[:, 0])
        walk = np.array(walk) / cfg.optical_period_fs
        axes[1].plot(walk, color=color, linewidth=0.8, label=[f"{mode} / {split}", None, None])
    axes[1].set_xlabel("control step (zero set-points)")
    axes[1].set_ylabel("stage-1 delay error - its initial value (cycles)")
    axes[1].set_title("(b) random walk and drift within an episode, 3 episodes each")
    axes[1].legend(fontsize=7, ncol=2)
    save_figure(fig, out / "physics_modes.png", dpi=110)


def hysteresis(out: pathlib.Path) -> None:
    """The delay line's position against its set-point over sweeps of the whole travel and of a
    fifth of it, for the actuator_hysteresis of docs/physics.md."""
    fig, ax = plt.subplots(figsize=(5.2, 4.4))
    for fraction, colour in ((0.05, "tab:blue"), (0.12, "tab:red")):
        cfg = make_config(stage=1, actuator_hysteresis=fraction)
        half = cfg.actuator_range_fs
        for amplitude, style in ((1.0, "-"), (0.2, "--")):
            act = Actuator(cfg, num_envs=1)
            x = amplitude * half * np.concatenate([np.linspace(0, 1, 50), np.linspace(1, -1, 100)])
            x = np.concatenate([x, -x[50:], x[50:]])  # out, then two full cycles
            y = np.array([act.move(np.array([[v]]))[0, 0] for v in x])
            label = f"{fraction:.0%} of the travel" + (", a fifth of it swept" * (amplitude < 1))
            ax.plot(x[150:] / half, y[150:] / half, style, color=colour, lw=1.2, label=label)
    ax.plot([-1, 1], [-1, 1], ":", color="grey", lw=0.8, label="no hysteresis")
    ax.set_xlabel("set-point / half travel")
    ax.set_ylabel("delay-line position / half travel")
    ax.set_title("actuator_hysteresis: open-loop piezo loops")
    ax.legend(fontsize=7, loc="upper left")
    save_figure(fig, out / "physics_hysteresis.png", dpi=110)


def vibration(out: pathlib.Path, rate: float = 5000.0, seconds: float = 40.0) -> None:
    """The vibration presets, one delay line each: (a) the rms they hold below each frequency,
    measured on 40 s sampled at 5 kHz (periodogram) against the presets' band figures; (b) half
    a second of ``lab`` and what loops at 10 Hz (the paper's 0.1 s step) and 100 Hz read of it."""
    t = np.arange(int(rate * seconds)) / rate
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    f = np.geomspace(0.5, 2000.0, 400)
    vibs = {name: Vibration(p, 1, 1, np.random.default_rng(3)) for name, p in PRESETS.items()}
    series = {name: np.array([vib.at(ti)[0, 0] for ti in t]) for name, vib in vibs.items()}
    for (name, preset), colour in zip(PRESETS.items(), ("tab:blue", "tab:orange"), strict=False):
        freqs, power = periodogram(series[name], rate)
        label = f"{name}: {preset.rms_fs:.3f} fs = {preset.rms_fs * 299.792458:.0f} nm"
        axes[0].semilogx(
            freqs[1:],
            np.sqrt(np.cumsum(power[1:])),
            lw=1.2,
            color=colour,
            label=f"{label}, one delay line",
        )
        expected = [preset.band_rms_fs(0.1, fi) for fi in f]
        axes[0].semilogx(f, expected, "--", color=colour, lw=0.9, label=f"{name}: the preset")
    for f0, _ in PRESETS["lab"].lines:
        axes[0].axvline(f0, color="tab:red", alpha=0.2, lw=3)
    axes[0].set_xlim(0.5, 2000)
    axes[0].set_ylim(0, None)
    axes[0].set_xlabel("frequency f (Hz)  (red: the acoustic and building lines)")
    axes[0].set_ylabel("rms below f (fs)")
    axes[0].set_title("(a) each preset's rms below f, per delay line", fontsize=9)
    axes[0].legend(fontsize=7, loc="upper left")
    span = t < 0.5
    axes[1].plot(
        t[span], series["lab"][span], lw=0.7, color="grey", label="lab, one delay line (5 kHz)"
    )
    for step_s, style in ((0.1, "o"), (0.01, ".")):
        k = np.arange(0, 0.5, step_s)
        read = [vibs["lab"].at(tk)[0, 0] for tk in k]
        axes[1].plot(k, read, style, label=f"read every {step_s:g} s")
    axes[1].set_xlabel("time (s)")
    axes[1].set_ylabel("delay offset (fs)")
    axes[1].set_title("(b) the same vibration at any loop rate: t = steps x step_s", fontsize=9)
    axes[1].legend(fontsize=7)
    save_figure(fig, out / "physics_vibration.png", dpi=110)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="docs/figures")
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    architecture(out)
    landscapes(out)
    walkoff(out)
    traces(out)
    modes(out)
    hysteresis(out)
    vibration(out)
    print("wrote", *sorted(str(p) for p in out.glob("physics_*.png")))


if __name__ == "__main__":
    main()
