"""The rig's ``ops/power`` against the simulated lab's true P_N / P_max at a held stack, with the
full scale followed from the summed slot readings less their dark floor and from the plain sum
(ops_rig_ros/full_scale.py). Per seed: `calibrate` against the simulated lab (its instruments on
a real TCP socket and real pseudo-terminals, as in ops-bench rig-calibration), then ``--readings``
records of the stack held near its lock (each reading the lab's delay errors are drawn anew,
normal with ``--error-fs`` rms per stage, around the calibration's zeros), read through the
scope as the rig node reads them. Prints a table and writes a JSON (docs/rig.md, "The full scale
followed while running").

Usage (after `source setup.bash`):
  ops-bench rig-full-scale --realism lab --seeds 1-5 \\
      [--mode hard] [--readings 3000] [--out docs/results/rig/full_scale_dark_floor_lab.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import yaml
from ops_rig_ros.calibration import calibrate
from ops_rig_ros.full_scale import FullScaleFollower
from ops_rig_ros.rig import Rig
from ops_rig_ros.rig_config import load_rig_config
from ops_rig_ros.simlab.main import Lab
from ops_rig_ros.trace import estimate_power, extract_trace, slot_readings_volts

from ops_bench import REPO
from ops_bench.rig_calibration import seeds

SAMPLES_PER_SLOT = 8


def one(args, seed: int, workdir: Path) -> dict:
    lab = Lab(stage=5, mode=args.mode, seed=seed, realism=args.realism, scope_format="WORD")
    path = workdir / f"rig_{seed}.yaml"
    path.write_text(yaml.safe_dump(lab.rig_yaml(), sort_keys=False))
    rig = Rig(load_rig_config(path))
    try:
        rig.drive.connect()
        rig.connect_scope()
        cal = calibrate(rig, log=lambda _: None)
        rig.drive.ramp_to(cal.zero_volts)
        optics = lab.optics
        followers = {
            "dark floor": FullScaleFollower(args.window),
            "plain sum": FullScaleFollower(args.window, subtract_dark_floor=False),
        }
        rng = np.random.default_rng(seed)
        rows = []
        for _ in range(args.readings):
            with optics.lock:  # the stack held near its lock, whatever the drift did
                sim = optics.sim
                at = sim.setpoints_fs if sim.actuator is None else sim.actuator.position
                sim.place(delay_errors_fs=rng.normal(0.0, args.error_fs, (1, 5)) - at)
            record = rig.read_record()
            trace = extract_trace(record, cal, SAMPLES_PER_SLOT, rig.config.trace_baseline)
            readings = slot_readings_volts(record, cal.slot_positions) / cal.detector_full_volts
            row = [optics.last_power]
            for follower in followers.values():
                follower.observe(readings)
                row.append(estimate_power(trace / follower.gain, SAMPLES_PER_SLOT))
            rows.append(row)
    finally:
        rig.close()
        lab.close()
    after = np.asarray(rows)[args.window :]  # once the first window is full
    truth = lab.optics.truth.detector_full_volts
    result = {
        "seed": seed,
        "calibrated_full_scale_error": float(cal.detector_full_volts / truth - 1),
        "true_power_median": float(np.median(after[:, 0])),
    }
    for k, (name, follower) in enumerate(followers.items(), start=1):
        key = name.replace(" ", "_")
        result[f"{key}_full_scale_error"] = float(
            cal.detector_full_volts * follower.gain / truth - 1
        )
        result[f"{key}_power_median"] = float(np.median(after[:, k]))
        result[f"{key}_power_error_median"] = float(np.median(after[:, k] - after[:, 0]))
    result["dark_floor"] = followers["dark floor"].floor
    return result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mode", default="hard")
    p.add_argument("--realism", default="lab", choices=("ideal", "lab"))
    p.add_argument("--seeds", type=seeds, default=seeds("1-5"), help="e.g. 1-5")
    p.add_argument("--readings", type=int, default=3000)
    p.add_argument("--window", type=int, default=250, help="the rig's full_scale_window")
    p.add_argument("--error-fs", type=float, default=0.02, help="rms delay error of the stack")
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    out = args.out or REPO / "docs/results/rig" / f"full_scale_dark_floor_{args.realism}.json"
    print(
        "| seed | calibrated full scale | followed: plain sum / less the dark floor | "
        "ops/power - truth (median): plain sum / less the dark floor | truth (median) |"
    )
    print("|---|---|---|---|---|")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            r = one(args, seed, Path(tmp))
            runs.append(r)
            print(
                f"| {seed} | {r['calibrated_full_scale_error']:+.2%} | "
                f"{r['plain_sum_full_scale_error']:+.2%} / {r['dark_floor_full_scale_error']:+.2%}"
                f" | {r['plain_sum_power_error_median']:+.4f} / "
                f"{r['dark_floor_power_error_median']:+.4f} | {r['true_power_median']:.4f} |",
                flush=True,
            )
    summary = {
        "command": f"ops-bench rig-full-scale --mode {args.mode} --realism {args.realism} "
        f"--seeds {args.seeds[0]}-{args.seeds[-1]} --readings {args.readings} --window "
        f"{args.window} --error-fs {args.error_fs:g}",
        "full scales are relative to": "simlab's pulse height (the rig's centre reading loses "
        "1-2 % of it by interpolation, and the calibration carries that)",
        "per_seed": runs,
    }
    for key in ("plain_sum", "dark_floor"):
        summary[f"{key}_power_error_median_worst"] = max(
            (r[f"{key}_power_error_median"] for r in runs), key=abs, default=None
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
