"""``ros2 run ops_rig_ros simlab``: a simulated lab for the rig node (docs/rig.md).

Starts a simulated oscilloscope (SCPI over TCP on 127.0.0.1) and simulated MDT693B piezo
controllers (three channels each, on pseudo-terminals), backed by the project's physics, and
writes a rig YAML that points at them (``--config-out``). The instruments' fs per volt and zeros
are drawn from the seed and unknown to the rig until ``calibrate``. Runs until Ctrl-C / SIGTERM.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
from pathlib import Path

import yaml
from ops_contract.config import MODES, REALISMS

from .optics import SimOptics
from .piezo_pty import SimPiezo
from .scope_server import SimScope

VLIMIT = 75.0


class Lab:
    """The instruments of one simulated lab (in this process)."""

    def __init__(
        self,
        stage=5,
        mode="medium",
        seed=0,
        realism="ideal",
        quiet=False,
        port=0,
        record_path=None,
        scope_format="WORD",
        step_rate_hz=50.0,
        noise_volts=0.0,
    ):
        self.optics = SimOptics(
            stage=stage,
            mode=mode,
            seed=seed,
            realism=realism,
            quiet=quiet,
            step_rate_hz=step_rate_hz,
            electronic_noise_volts=noise_volts,
        )
        self.scope = SimScope(self.optics, port=port)
        self.scope_format = scope_format
        self.piezos = []
        for first in range(0, stage, 3):
            axes = min(3, stage - first)
            self.piezos.append(
                SimPiezo(self.optics, first, axes, vlimit=VLIMIT, record_path=record_path)
            )

    @property
    def received(self) -> list[tuple[int, float]]:
        return [r for p in self.piezos for r in p.received]

    def rig_yaml(self, rate_hz: float = 50.0, slew: float = 200.0) -> dict:
        stage = self.optics.stage
        return {
            "stage": stage,
            "rate_hz": rate_hz,
            "scope": {
                "driver": "scpi_scope",
                "resource": self.scope.resource,
                "channel": 1,
                "format": self.scope_format,
                "timeout_ms": 300,
            },
            "actuators": [
                {"driver": "mdt69x", "port": p.device, "channels": list(p.axes)}
                for p in self.piezos
            ],
            "limits": {
                "volts_min": 0.0,
                "volts_max": VLIMIT,
                "slew_volts_per_s": slew,
                "park_volts": 0.0,
            },
            "stale_s": 0.5,
            "sweep_span_volts": 12.0,
            # a lab rig's piezos answer a move a step late and over a few steps
            "settle_reads": 1 if self.optics.sim.actuator is None else 2,
            "trace_baseline": "record",  # the pulses are dark half-way between slots
            "optics": {"wavelength_nm": 1030.0, "pulse_fwhm_fs": 1000.0, "detector": "polarizer"},
        }

    def close(self) -> None:
        self.scope.close()
        for p in self.piezos:
            p.close()


def parse_args(argv):
    p = argparse.ArgumentParser(prog="simlab", description=__doc__.split("\n\n")[0])
    p.add_argument("--stage", type=int, default=5, help="stacking stages N (1-10)")
    p.add_argument("--mode", default="medium", choices=MODES, help="noise and drift of the optics")
    p.add_argument("--realism", default="ideal", choices=REALISMS, help="the optics' rig preset")
    p.add_argument("--seed", type=int, default=0, help="draws the hidden calibration and noise")
    p.add_argument("--config-out", required=True, type=Path, help="the rig YAML to write")
    p.add_argument(
        "--rate-hz",
        type=float,
        default=50.0,
        help="the optics' step rate and the rig's rate in the YAML (the mode's drift is per step)",
    )
    p.add_argument("--port", type=int, default=0, help="scope TCP port (0: a free one)")
    p.add_argument("--format", default="WORD", choices=("BYTE", "WORD"), help="scope data format")
    p.add_argument(
        "--noise-volts",
        type=float,
        default=0.0,
        help="the scope's electronic noise, V rms (full scale ~0.6-0.9 V; the mode's detector "
        "noise comes on top)",
    )
    p.add_argument("--quiet", action="store_true", help="no drift, jitter or detector noise")
    p.add_argument("--record", type=Path, help="append every voltage the piezos receive here")
    p.add_argument("--truth-out", type=Path, help="write the hidden calibration here (JSON)")
    args = p.parse_args(argv)
    if not 1 <= args.stage <= 10:
        p.error("--stage must be from 1 to 10")
    if not (math.isfinite(args.rate_hz) and 1.0 <= args.rate_hz <= 1000.0):
        p.error("--rate-hz must be from 1 to 1000")
    if not (math.isfinite(args.noise_volts) and 0.0 <= args.noise_volts <= 1.0):
        p.error("--noise-volts must be from 0 to 1")
    return args


def main(argv=None) -> None:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    lab = Lab(
        stage=args.stage,
        mode=args.mode,
        seed=args.seed,
        realism=args.realism,
        quiet=args.quiet,
        port=args.port,
        record_path=args.record,
        scope_format=args.format,
        step_rate_hz=args.rate_hz,
        noise_volts=args.noise_volts,
    )
    try:
        args.config_out.write_text(yaml.safe_dump(lab.rig_yaml(args.rate_hz), sort_keys=False))
        if args.truth_out:
            args.truth_out.write_text(json.dumps(lab.optics.truth.as_dict(), indent=1))
        print(
            f"simlab ready: stage={args.stage} mode={args.mode} seed={args.seed} "
            f"scope {lab.scope.resource}, piezos {' '.join(p.device for p in lab.piezos)}; "
            f"wrote {args.config_out}",
            flush=True,
        )
        while not stop.wait(5.0):
            print(
                f"simlab: {lab.optics.acquisitions} acquisitions, true P_N/P_max "
                f"{lab.optics.last_power:.4f}",
                flush=True,
            )
    finally:
        lab.close()
        print("simlab stopped", flush=True)


if __name__ == "__main__":
    main()
