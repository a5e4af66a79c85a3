"""``evaluate --record DIR``: the evaluated controller's episodes as a rosbag2 MCAP bag.

Runs ``--episodes`` episodes of the first split and seed in-process through
:class:`ops_sim_ros.bag_recording.RecordBag` (an OpsEnv wrapper), driven as the evaluation drives
them: SPGD-PID exactly as ``rollout_spgd`` (same seeds, so the recorded episodes are the
evaluated ones), a learned policy one observation at a time. Open the bag with
``ros2 bag info/play DIR`` or in Foxglove (docs/recording.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def new_bag_path(value: str) -> Path:
    """argparse type of ``--record``: a bag directory that does not exist yet."""
    import argparse

    path = Path(value)
    if path.exists():
        raise argparse.ArgumentTypeError(f"Output folder '{path}' already exists.")
    return path


def record_episodes(args, stage: int, mode: str, path: Path) -> Path:
    from ops_sim_ros.bag_recording import RecordBag

    from ops_sim_ros import OpsEnv

    split, seed = args.splits[0], args.seeds[0]
    controller = "spgd" if args.spgd else "policy"
    env = RecordBag(
        OpsEnv(stage=stage, mode=mode, split=split, max_episode_steps=args.steps),
        path,
        custom_data={
            "source": "ops_gym_bridge evaluate",
            "controller": controller,
            "stage": str(stage),
            "mode": mode,
            "split": split,
            "seed": str(seed),
            "episodes": str(args.episodes),
        },
    )
    try:
        if args.spgd:
            from ops_controller_ros.spgd import SpgdParams, SpgdPid

            from .evaluate import _parse_kv

            params = SpgdParams(**_parse_kv(args.spgd_param))
            for e in range(args.episodes):
                _, info = env.reset(seed=seed * 1000 + e)
                ctl = SpgdPid(
                    stage, params, setpoints_fs=info["setpoints_fs"], seed=seed * 1000 + e
                )
                for _ in range(args.steps):
                    # absolute set-points, one measurement per command (as rollout_spgd)
                    r = env.step_setpoints(ctl.command())
                    ctl.observe(float(r.power[0]))
        else:
            from .evaluate import load_for_evaluation

            loaded, _ = load_for_evaluation(args.model, stage)
            for e in range(args.episodes):
                obs, _ = env.reset(seed=seed * 1000 + e)
                for _ in range(args.steps):
                    action = np.asarray(loaded.predict(obs[None, :]))[0]
                    obs, _, _, _, _ = env.step(action)
    finally:
        env.close()
    return path
