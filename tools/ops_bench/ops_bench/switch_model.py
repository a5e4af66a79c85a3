"""Make a switching model: one learned policy finds the stack, another holds it.

Writes DEST with the holding policy's model.zip and metadata.json (plus a ``switch`` entry) and
the acquiring policy's model directory as DEST/acquire (ops_controller_ros.policy_switch). The
folder is what `ros2 run ops_controller_ros policy --ros-args -p model:=DEST` and `evaluate`
accept, like any model folder.

Usage (after `source setup.bash`):
  ops-bench switch-model --hold runs/ft/n5_medium_hold --acquire models/n5_medium \\
      --out models/n5_medium_long [--lock-power 0.95 --lock-readings 3 --release-power 0.8 \\
      --release-readings 2 --acquire-setpoint-window 1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ops_controller_ros.policy_io import PolicyLoadError
from ops_controller_ros.policy_switch import SwitchParams, write_switch_model


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--hold", type=Path, required=True, help="model directory of the holder")
    ap.add_argument("--acquire", type=Path, required=True, help="model directory of the finder")
    ap.add_argument("--out", type=Path, required=True, help="the switching model to write")
    defaults = SwitchParams()
    ap.add_argument("--lock-power", type=float, default=defaults.lock_power)
    ap.add_argument("--lock-readings", type=int, default=defaults.lock_readings)
    ap.add_argument("--release-power", type=float, default=defaults.release_power)
    ap.add_argument("--release-readings", type=int, default=defaults.release_readings)
    ap.add_argument(
        "--acquire-setpoint-window",
        type=float,
        default=defaults.acquire_setpoint_window,
        help="the acquiring policy's set-points observed against a whole-cycle reference "
        "(cycles, >= 0.5; default: as it was trained)",
    )
    ap.add_argument(
        "--acquire-patience",
        type=int,
        default=defaults.acquire_patience,
        help="readings of search before the holding policy searches in turn (0: never)",
    )
    ap.add_argument(
        "--mode", default=None, help="the mode the model is for (default: the holder's)"
    )
    ap.add_argument("--note", default="", help="a line kept in the metadata")
    args = ap.parse_args(argv)
    try:
        params = SwitchParams(
            args.lock_power,
            args.lock_readings,
            args.release_power,
            args.release_readings,
            args.acquire_setpoint_window,
            args.acquire_patience,
        )
        out = write_switch_model(args.out, args.hold, args.acquire, params, args.note, args.mode)
    except (ValueError, PolicyLoadError) as exc:
        print(f"make_switch_model: {exc}", file=sys.stderr)
        return 2
    print(f"[make_switch_model] wrote {out} ({params})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
