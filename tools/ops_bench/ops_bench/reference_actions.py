"""Store a shipped model's reference actions: MODEL/eval/reference_actions.npz.

What a shipped model must show on any CPU (``test_shipped_models.py``) cannot be the replay of a
closed-loop episode: a neural policy on a chaotic landscape amplifies the last bits of arithmetic,
which differ between CPUs and BLAS kernels. What does hold everywhere, to ~1e-6:

* the observations the model's environment gives right after ``reset(seed)`` (no policy in the
  loop yet): stored as ``reset_obs`` with their ``reset_seed``, they pin the observation layout and
  scaling the model was trained on;
* the policy's deterministic actions for fixed observations (one forward pass, no loop): stored as
  ``obs`` / ``actions`` (observations met along short closed-loop runs of the model itself, so
  they lie where the policy works).

Usage (after `source setup.bash`): ops-bench reference-actions models/n5_hard [...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

RESET_SEED = 7
ENVS = 4
STEPS = 16


def model_rig(metadata: dict) -> dict:
    """The rig a model was trained on (``train --realism`` / ``--rig``; empty: the ideal one)."""
    return dict(metadata.get("rig") or {})


def model_realism(metadata: dict) -> str:
    """The realism preset a model was trained on (``ideal`` unless ``train --realism``)."""
    return str(model_rig(metadata).get("realism", "ideal"))


def rig_arguments(metadata: dict) -> list[str]:
    """``evaluate``'s arguments for the rig a model was trained on (none for the ideal one)."""
    argv: list[str] = []
    for key, value in model_rig(metadata).items():
        argv += ["--realism", str(value)] if key == "realism" else ["--rig", f"{key}={value}"]
    return argv


def model_env(loaded, num_envs: int):
    """The model's own environment (stage, mode, detector, rig, observation set), testing
    split."""
    from ops_contract.config import make_config
    from ops_controller_ros.policy_io import observation_spec_of
    from ops_sim_ros.vec_env import OpsVectorEnv

    config = make_config(
        loaded.stage,
        loaded.mode,
        "test",
        detector=(loaded.metadata.get("config") or {}).get("detector", "polarizer"),
        **model_rig(loaded.metadata),
    )
    options = observation_spec_of(loaded.metadata).options()
    return OpsVectorEnv.from_config(config, num_envs=num_envs, observation_options=options)


def reference(loaded) -> dict[str, np.ndarray]:
    env = model_env(loaded, ENVS)
    try:
        obs, _ = env.reset(seed=RESET_SEED)
        reset_obs = obs.copy()
        seen = [obs]
        for _ in range(STEPS - 1):
            obs, *_ = env.step(loaded.predict(obs))
            seen.append(obs)
    finally:
        env.close()
    all_obs = np.concatenate(seen).astype(np.float32)
    return {
        "reset_seed": np.array(RESET_SEED),
        "reset_obs": reset_obs.astype(np.float32),
        "obs": all_obs,
        "actions": loaded.predict(all_obs).astype(np.float32),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("models", nargs="+", type=Path, help="model folders (models/NAME)")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    from ops_controller_ros.policy_io import load_policy

    for folder in args.models:
        loaded = load_policy(folder)
        ref = reference(loaded)
        out = folder / "eval" / "reference_actions.npz"
        out.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(out, **ref)
        print(f"{out}: {ref['obs'].shape[0]} observations x {ref['obs'].shape[1]} values")
    return 0


if __name__ == "__main__":
    sys.exit(main())
