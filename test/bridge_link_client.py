"""A Gymnasium bridge client for test_two_hosts.py, run on "host B" (its own network namespace).

Steps a :class:`RosOpsEnv` against a lockstep simulator on the other host (random actions, at most
``--rate`` steps per second) until a step raises the bridge's timeout error, which happens when the
test takes the link down. Prints how long that step took and the error, then calls ``reset()``
until the simulator answers again (each attempt bounded by the same timeout), steps
``--steps-after`` times more and exits 0. Every line it prints starts with ``[client]``.

Usage: python test/bridge_link_client.py --stage 3 --namespace /rig2 --timeout 2
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from ops_gym_bridge.bridge.bridge_env import BridgeError, RosOpsEnv, SimulatorTimeoutError


def say(text: str) -> None:
    print(f"[client] {text}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stage", type=int, default=3)
    ap.add_argument("--mode", default="easy")
    ap.add_argument("--namespace", default="")
    ap.add_argument("--timeout", type=float, default=2.0, help="the bridge's timeout_s")
    ap.add_argument("--rate", type=float, default=100.0, help="largest step rate, 1/s")
    ap.add_argument("--steps-after", type=int, default=50)
    ap.add_argument("--connect-within", type=float, default=60.0)
    ap.add_argument("--recover-within", type=float, default=60.0)
    args = ap.parse_args()

    rng = np.random.default_rng(0)
    env = RosOpsEnv(
        stage=args.stage, mode=args.mode, namespace=args.namespace, timeout_s=args.timeout
    )
    try:
        # Discovery across the link takes longer than one timeout: try until connected.
        connect_by = time.monotonic() + args.connect_within
        while True:
            try:
                env.reset()
                break
            except SimulatorTimeoutError:
                if time.monotonic() > connect_by:
                    raise
        say("connected")
        steps = 0
        while True:
            t0 = time.monotonic()
            try:
                env.step(rng.uniform(-1.0, 1.0, args.stage))
            except SimulatorTimeoutError as exc:
                say(f"timeout after {time.monotonic() - t0:.3f} s at step {steps + 1}: {exc}")
                break
            steps += 1
            if steps % 20 == 0:
                say(f"step {steps}")
            time.sleep(max(0.0, 1.0 / args.rate - (time.monotonic() - t0)))

        # The link is back when a reset is answered. Commands and reset requests that DDS kept
        # while the link was down may still be delivered to the simulator then, and their outputs
        # reach us unasked: the bridge reports those as a LockstepError; reset again.
        deadline = time.monotonic() + args.recover_within
        failed = 0
        info = {"power": float("nan")}
        done = 0
        while done < args.steps_after:
            try:
                env.reset()
                say(f"reset answered after {failed} failed attempt(s)")
                while done < args.steps_after:
                    _, _, _, _, info = env.step(rng.uniform(-1.0, 1.0, args.stage))
                    done += 1
            except BridgeError as exc:
                failed += 1
                done = 0  # count clean steps in a row
                say(f"attempt {failed} failed: {type(exc).__name__}: {exc}")
                if time.monotonic() > deadline:
                    say("gave up waiting for the simulator")
                    return 1
        say(f"done: {done} steps after recovery, P_N/P_max {info['power']:.3f}")
        return 0
    finally:
        env.close()


if __name__ == "__main__":
    raise SystemExit(main())
