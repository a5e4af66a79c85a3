"""`calibrate` against the simulated lab's hidden truth over several seeds, in one process (the
simulated instruments on a real TCP socket and real pseudo-terminals, as in
ops_rig_ros/test/test_rig_calibration.py): per seed, whether it succeeded, the largest fs-per-volt
error, how far the slot grid is off, and the full scale's error. Writes a JSON.

Usage (after `source setup.bash`):
  ops-bench rig-calibration --mode hard --realism lab --seeds 1-10 \\
      [--stage 5] [--out docs/results/rig/calibration_lab_hard.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from ops_rig_ros.calibration import calibrate
from ops_rig_ros.fringe import CalibrationError
from ops_rig_ros.rig import Rig
from ops_rig_ros.rig_config import load_rig_config
from ops_rig_ros.simlab.main import Lab

from ops_bench import REPO


def seeds(text: str) -> list[int]:
    low, _, high = text.partition("-")
    return list(range(int(low), int(high or low) + 1))


def one(stage: int, mode: str, realism: str, seed: int, workdir: Path) -> dict:
    lab = Lab(stage=stage, mode=mode, seed=seed, realism=realism, scope_format="WORD")
    path = workdir / f"rig_{seed}.yaml"
    path.write_text(yaml.safe_dump(lab.rig_yaml(), sort_keys=False))
    rig = Rig(load_rig_config(path))
    started, records = time.monotonic(), lab.optics.acquisitions
    try:
        rig.drive.connect()
        rig.connect_scope()
        cal = calibrate(rig, log=lambda _: None)
    except CalibrationError as exc:
        return {"seed": seed, "ok": False, "error": str(exc)}
    finally:
        rig.close()
        lab.close()
    truth = lab.optics.truth
    return {
        "seed": seed,
        "ok": True,
        "seconds": round(time.monotonic() - started, 1),
        "records": lab.optics.acquisitions - records,
        "fs_per_volt_max_error": float(np.max(np.abs(cal.fs_per_volt / truth.fs_per_volt - 1))),
        "slots_off_points": float(np.max(np.abs(cal.slot_positions - truth.slot_positions))),
        "full_scale_error": float(cal.detector_full_volts / truth.detector_full_volts - 1),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--stage", type=int, default=5)
    p.add_argument("--mode", default="hard")
    p.add_argument("--realism", default="lab")
    p.add_argument("--seeds", type=seeds, default=seeds("1-10"), help="e.g. 1-10")
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    name = f"calibration_n{args.stage}_{args.realism}_{args.mode}.json"
    out = args.out or REPO / "docs" / "results" / "rig" / name
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            r = one(args.stage, args.mode, args.realism, seed, Path(tmp))
            runs.append(r)
            if r["ok"]:
                print(
                    f"seed {seed}: ok, {r['records']} records, fs/V within "
                    f"{100 * r['fs_per_volt_max_error']:.2f} %, slots off by "
                    f"{r['slots_off_points']:.2f} points, full scale {r['full_scale_error']:+.3f}",
                    flush=True,
                )
            else:
                print(f"seed {seed}: FAILED ({r['error']})", flush=True)
    good = [r for r in runs if r["ok"]]
    summary = {
        "command": f"ops-bench rig-calibration --stage {args.stage} --mode "
        f"{args.mode} --realism {args.realism} --seeds {args.seeds[0]}-{args.seeds[-1]}",
        "succeeded": len(good),
        "runs": len(runs),
        "fs_per_volt_max_error": max((r["fs_per_volt_max_error"] for r in good), default=None),
        "slots_off_by_a_slot": sum(r["slots_off_points"] > 0.5 for r in good),
        "per_seed": runs,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=1) + "\n")
    print(f"{len(good)} of {len(runs)} succeeded; wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
