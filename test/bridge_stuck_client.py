"""A Gymnasium bridge client for test_lossy_link.py's stuck-links test, run on "host B".

Steps a :class:`RosOpsEnv` without a deadline (``timeout_s=None``, re-sending every 0.5 s) against
a lockstep simulator on the other host, at most ``--rate`` steps per second, until it is stopped,
and prints ``[client] step N (reconnects K)`` every ten steps. ``--reconnect-after 0`` never
replaces the participant.

Usage: python test/bridge_stuck_client.py --stage 3 --namespace /stuck --reconnect-after 3
"""

from __future__ import annotations

import argparse
import signal
import time

import numpy as np
from ops_gym_bridge.bridge.bridge_env import RosOpsEnv


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stage", type=int, default=3)
    ap.add_argument("--mode", default="easy")
    ap.add_argument("--namespace", default="")
    ap.add_argument("--reconnect-after", type=float, default=30.0, help="0: never")
    ap.add_argument("--rate", type=float, default=50.0, help="largest step rate, 1/s")
    args = ap.parse_args()
    signal.signal(signal.SIGTERM, signal.default_int_handler)

    rng = np.random.default_rng(0)
    env = RosOpsEnv(
        stage=args.stage,
        mode=args.mode,
        namespace=args.namespace,
        timeout_s=None,
        retry_after_s=0.5,
        reconnect_after_s=args.reconnect_after or None,
    )
    try:
        env.reset()
        steps = 0
        while True:
            t0 = time.monotonic()
            env.step(rng.uniform(-1.0, 1.0, args.stage))
            steps += 1
            if steps % 10 == 0:
                print(f"[client] step {steps} (reconnects {env.client.reconnects})", flush=True)
            time.sleep(max(0.0, 1.0 / args.rate - (time.monotonic() - t0)))
    except KeyboardInterrupt:
        return 0
    finally:
        env.close()


if __name__ == "__main__":
    raise SystemExit(main())
