"""Physical time and vibration, measured: writes docs/results/physical_time/ (results.json and
index.md; docs/physics.md, "Physical time and vibration").

(a) time_base seconds at step_s 0.1 against step: the same episodes, array by array;
(b) the walk's variance and the hard mode's drift per simulated second at step_s 0.1 .. 0.001;
(c) each vibration preset's rms per decade, sampled at 5 kHz, against the preset;
(d) P_N / P_max with the set-points held at the optimum under each preset (what a loop
    too slow to follow it keeps at best);
(e) the cost: DelayNoise.sample and batched env-steps/s with and without the vibration.

Usage: OPENBLAS_NUM_THREADS=1 ops-bench physical-time [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
from ops_contract.config import REFERENCE_STEP_S, make_config
from ops_contract.observation import build_observation
from ops_sim_ros import OpsEnv
from ops_sim_ros.noise import DelayNoise
from ops_sim_ros.simulation import BatchedSimulation
from ops_sim_ros.vibration import PRESETS, Vibration

from ops_bench import REPO
from ops_bench.physics import rate

OUT = REPO / "docs" / "results" / "physical_time"
COMMAND = "OPENBLAS_NUM_THREADS=1 ops-bench physical-time"


def _episodes(cfg, seed=11, envs=3, steps=250):
    sim = BatchedSimulation(cfg, num_envs=envs, seed=seed)
    actions = np.random.default_rng(seed + 1)
    out = [sim.reset().applied_fs]
    for _ in range(3):
        for _ in range(steps):
            r = sim.step_increments(actions.uniform(-1, 1, (envs, cfg.stage)))
            out += [r.applied_fs, r.pulse_energies, r.power[:, None]]
        sim.reset(mask=np.arange(envs) % 2 == 0)
    return np.concatenate([x.ravel() for x in out])


def identity() -> dict:
    """(a) step against seconds at 0.1 s, every mode, split and rig preset."""
    same, values = 0, 0
    cells = [
        (m, s, r)
        for m in ("easy", "medium", "hard", "extreme")
        for s in ("train", "test")
        for r in ("ideal", "lab")
    ]
    for mode, split, realism in cells:
        kw = dict(stage=5, mode=mode, split=split, realism=realism)
        a = _episodes(make_config(**kw))
        b = _episodes(make_config(**kw, time_base="seconds", step_s=REFERENCE_STEP_S))
        same += int(np.array_equal(a, b))
        values += a.size
    return {"cells": len(cells), "identical": same, "values_compared": values}


def per_second(steps_s=(0.1, 0.01, 0.001), envs=4000) -> list[dict]:
    """(b) the walk's variance (medium) and the drift (hard, walk off) after 1 s."""
    rows = []
    for step_s in steps_s:
        n = round(1.0 / step_s)
        cfg = make_config(stage=2, mode="medium", time_base="seconds", step_s=step_s)
        noise = DelayNoise.from_config(cfg, envs, np.random.default_rng(0))
        noise.new_episodes(np.ones(envs, bool))
        start = noise.offset
        for _ in range(n):
            noise.sample()
        var = float((((noise.offset - start) / cfg.optical_period_fs) ** 2).mean())
        hard = make_config(stage=2, mode="hard", time_base="seconds", step_s=step_s)
        drift = DelayNoise.from_config(
            hard.replace(jitter_sigma_cycles=0.0), 50, np.random.default_rng(1)
        )
        drift.new_episodes(np.ones(50, bool))
        start = drift.offset
        for _ in range(n):
            drift.sample()
        moved = (drift.offset - start) / hard.optical_period_fs
        rows.append(
            {
                "step_s": step_s,
                "steps": n,
                "walk_var_cycles2": var,
                "drift_cycles": moved[:3, 0].tolist(),
            }
        )
    return rows


def periodogram(x: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The one-sided, Hann-windowed periodogram of ``x`` (time along axis 0, sampled at
    ``rate_hz``): (frequencies, power per bin), the power of a band summing to its variance."""
    n = x.shape[0]
    window = np.hanning(n).reshape(n, *([1] * (x.ndim - 1)))
    power = np.abs(np.fft.rfft(x * window, axis=0)) ** 2 * 2.0 / (n**2 * np.mean(window**2))
    return np.fft.rfftfreq(n, 1.0 / rate_hz), power


def vibration_bands(name: str, rate_hz=5000.0, seconds=12.0) -> dict:
    """(c) preset ``name`` sampled on 40 lines: rms per decade and in total, measured and set."""
    preset = PRESETS[name]
    vib = Vibration(preset, 8, 5, np.random.default_rng(8))
    x = np.stack([vib.at(i / rate_hz) for i in range(int(seconds * rate_hz))]).reshape(-1, 40)
    freqs, power = periodogram(x, rate_hz)
    bands = [(1.0, 10.0), (10.0, 100.0), (100.0, 1000.0), (1.0, 1000.0)]
    rows = []
    for lo, hi in bands:
        got = np.sqrt(power[(freqs >= lo) & (freqs < hi)].sum(axis=0))
        rows.append(
            {
                "band_hz": [lo, hi],
                "measured_fs": float(np.sqrt(np.mean(got**2))),
                "preset_fs": preset.band_rms_fs(lo, hi),
            }
        )
    return {"bands": rows, "sample_rms_fs": float(x.std()), "preset_rms_fs": preset.rms_fs}


def held_optimum(name: str, stages=(1, 3, 5), envs=200, steps=300) -> list[dict]:
    """(d) P_N / P_max at the optimum set-points, no walk: preset ``name``'s cost alone."""
    rows = []
    for stage in stages:
        cfg = make_config(
            stage=stage,
            mode="easy",
            vibration=name,
            jitter_sigma_cycles=0.0,
            initial_sigma_cycles=0.0,
        )
        sim = BatchedSimulation(cfg, num_envs=envs, seed=0)
        sim.reset()
        p = np.stack([sim.step_setpoints(np.zeros((envs, stage))).power for _ in range(steps)])
        rows.append(
            {
                "stage": stage,
                "mean": float(p.mean()),
                "p01": float(np.quantile(p, 0.01)),
                "min": float(p.min()),
            }
        )
    return rows


def speed(batch=1024, repeats=3) -> list[dict]:
    """(e) DelayNoise.sample and batched step_increments + build_observation at N = 5."""
    rows = []
    for label, extra in (
        ("default", {}),
        ("seconds, step_s 0.01", {"time_base": "seconds", "step_s": 0.01}),
        ("vibration lab", {"vibration": "lab"}),
    ):
        env = OpsEnv(stage=5, mode="hard", **extra)
        row = {"config": label}
        for b in (1, batch):
            noise = DelayNoise.from_config(env.config, b, np.random.default_rng(0))
            noise.new_episodes(np.ones(b, bool))
            row[f"sample_us_b{b}"] = 1e6 / max(rate(noise.sample) for _ in range(repeats))
        sim = BatchedSimulation(env.config, num_envs=batch, seed=0)
        sim.reset()
        acts = np.random.default_rng(0).uniform(-1, 1, (batch, 5))

        def batched(sim=sim, acts=acts, spec=env.obs_spec):
            r = sim.step_increments(acts)
            build_observation(spec, r.pulse_energies, r.power, r.setpoints_fs)

        row["env_steps_per_s"] = max(rate(batched, min_time=1.0) for _ in range(repeats)) * batch
        rows.append(row)
    return rows


def vibration_section(name: str, vib: dict, held: list[dict]) -> list[str]:
    """The page's lines on one vibration preset: its bands, measured, and its cost held."""
    lines = [
        "",
        f"## Vibration `{name}`",
        "",
        "40 delay lines sampled at 5 kHz for 12 s (Hann-windowed periodogram), rms over the "
        f"lines; sample rms {vib['sample_rms_fs']:.4f} fs against the preset's "
        f"{vib['preset_rms_fs']:.4f} fs ({vib['preset_rms_fs'] * 299.792458:.1f} nm of path).",
        "",
        "| band (Hz) | measured rms (fs) | preset (fs) |",
        "|---|---|---|",
    ]
    for row in vib["bands"]:
        lo, hi = row["band_hz"]
        lines.append(f"| {lo:g}-{hi:g} | {row['measured_fs']:.4f} | {row['preset_fs']:.4f} |")
    lines += [
        "",
        f"Set-points held at the optimum, no walk, the `{name}` vibration alone (200 envs x 300 "
        "steps at the paper's 0.1 s): what a loop too slow to follow the vibration keeps at best.",
        "",
        "| N | mean P_N/P_max | 1 % quantile | worst step |",
        "|---|---|---|---|",
    ]
    for row in held:
        lines.append(
            f"| {row['stage']} | {row['mean']:.4f} | {row['p01']:.4f} | {row['min']:.4f} |"
        )
    return lines


def page(res: dict) -> str:
    """docs/results/physical_time/index.md from the measurements."""
    ident = res["identity"]
    lines = [
        "<!-- Written by `"
        + COMMAND
        + "` with results.json beside it; re-run it, do not edit. -->",
        "",
        "# Physical time and vibration",
        "",
        f"Measured {res['date']} on {res['machine']} (1-minute load average {res['load']:.1f} at "
        f"the end: other jobs shared the machine, the speeds are lower bounds) by `{COMMAND}`. "
        "What the keys mean: docs/physics.md, 'Physical time and vibration'.",
        "",
        "## The paper's step, in seconds",
        "",
        f"`time_base=seconds step_s=0.1` against `time_base=step`: {ident['identical']} of "
        f"{ident['cells']} cells identical bit for bit (every mode x split x rig preset, N = 5, "
        f"3 envs x 3 episodes x 250 steps of random increments, {ident['values_compared']:,} "
        "values each way).",
        "",
        "## One simulated second at any rate",
        "",
        "Medium mode, 4000 envs x 2 lines: the walk's mean square after 1 s (the paper's: 10 "
        "steps of 0.001 cycles clipped at 3 sigma, 9.95e-6 cycles^2). Hard mode without the walk: "
        "the drift of three episodes after 1 s (the same episodes at every rate).",
        "",
        "| step_s | steps in 1 s | walk mean square (cycles^2) | hard drift after 1 s (cycles) |",
        "|---|---|---|---|",
    ]
    for row in res["per_second"]:
        drift = ", ".join(f"{d:+.5f}" for d in row["drift_cycles"])
        lines.append(
            f"| {row['step_s']:g} | {row['steps']} | {row['walk_var_cycles2']:.3e} | {drift} |"
        )
    for name, vib in res["vibration"].items():
        lines += vibration_section(name, vib, res["held_optimum"][name])
    lines += [
        "",
        "## Cost",
        "",
        "N = 5, hard mode; `DelayNoise.sample` for 1 and 1024 envs, and the batched work of "
        "`ops-bench physics` (`step_increments` + `build_observation`, 1024 envs), best of 3.",
        "",
        "| configuration | sample, 1 env (us) | sample, 1024 envs (us) | batched env-steps/s |",
        "|---|---|---|---|",
    ]
    for row in res["speed"]:
        lines.append(
            f"| {row['config']} | {row['sample_us_b1']:.1f} | {row['sample_us_b1024']:.0f} | "
            f"{row['env_steps_per_s']:,.0f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    from ops_bench.physics import cpu_name

    res = {"identity": identity(), "per_second": per_second()}
    res["vibration"] = {name: vibration_bands(name) for name in PRESETS}
    res["held_optimum"] = {name: held_optimum(name) for name in PRESETS}
    res["speed"] = speed()
    res["date"] = time.strftime("%Y-%m-%d")
    res["machine"] = f"{cpu_name()}, {os.cpu_count()} cores"
    res["load"] = os.getloadavg()[0]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(res, indent=2) + "\n")
    (args.out / "index.md").write_text(page(res))
    print(page(res))


if __name__ == "__main__":
    main()
