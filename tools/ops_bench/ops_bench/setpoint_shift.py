"""Does a learned policy read absolute set-points? Episodes started whole cycles away (issue 20).

For each k, ``--episodes`` testing episodes of the model's mode start with every set-point k
optical cycles out and the hidden delay errors of the episode's own reset, so the physics (the
landscape repeats every cycle) is the one of k = 0; only the observed set-points differ. A policy
that reads them as absolute positions ends lower as k grows; one trained with
``--setpoint-window`` sees the same observations for every k.

Usage (after `source setup.bash`):
  ops-bench setpoint-shift models/n5_hard [--cycles 0 1 -2 4] [--episodes 30]
"""

from __future__ import annotations

import argparse

import numpy as np
from ops_contract.observation import ObservationSpec
from ops_controller_ros.policy_io import load_policy
from ops_sim_ros.env import OpsEnv


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("model")
    ap.add_argument("--cycles", type=float, nargs="+", default=[0.0, 1.0, -2.0, 4.0])
    ap.add_argument("--episodes", type=int, default=30)
    ap.add_argument("--first-seed", type=int, default=5000)
    args = ap.parse_args(argv)
    policy = load_policy(args.model)
    meta = policy.metadata
    env = OpsEnv(
        stage=meta["stage"],
        mode=meta["mode"],
        split="test",
        detector=meta["detector"],
        observation_options=ObservationSpec.from_dict(policy.observation_spec).options(),
    )
    period = env.optical_period_fs
    print(f"{args.model}: {meta['mode']} mode, testing split, {args.episodes} episodes per row")
    for k in args.cycles:
        finals = []
        for e in range(args.episodes):
            seed = args.first_seed + e
            _, info = env.reset(seed=seed)
            errors = np.asarray(info["delays_fs"]) - np.asarray(info["setpoints_fs"])
            start = {"delay_errors_fs": errors, "setpoints_fs": np.full(env.stage, k * period)}
            obs, info = env.reset(seed=seed, options=start)
            for _ in range(meta.get("episode_steps", 200)):
                obs, _, _, _, info = env.step(policy.predict(obs))
            finals.append(info["power"])
        f = np.array(finals)
        print(
            f"set-points {k:+g} cycles: final P_N/P_max mean {f.mean():.3f}, worst {f.min():.3f}, "
            f"below 0.8: {(f < 0.8).sum()}/{f.size}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
