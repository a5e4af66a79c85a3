"""``evaluate --record DIR``: the evaluated controller's episodes as a rosbag2 MCAP bag.

Runs ``--episodes`` episodes of the first split and seed in-process through
:class:`ops_sim_ros.bag_recording.RecordBag` (an OpsEnv wrapper), driven as the evaluation drives
them: a controller by :func:`.rollouts.controller_episodes` (the evaluation's own
loop and seeds, so the recorded episodes are the evaluated ones), a learned policy one
observation at a time. Open the bag with
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


def record_episodes(args, subject, path: Path) -> Path:
    """Record ``args.episodes`` episodes of ``subject`` (an evaluate.Subject) on the first of
    ``args.splits`` and ``args.seeds``."""
    from ops_sim_ros.bag_recording import RecordBag
    from ops_sim_ros.env import OpsEnv

    from .rollouts import controller_episodes, episode_seed

    split, seed = args.splits[0], args.seeds[0]
    env = RecordBag(
        OpsEnv.from_config(
            subject.sim_config(split, args.steps),
            observation_options=subject.observation_options(),
        ),
        path,
        custom_data={
            "source": "ops_gym_bridge evaluate",
            "controller": subject.controller or "policy",
            "stage": str(subject.stage),
            "mode": subject.mode,
            "split": split,
            "seed": str(seed),
            "episodes": str(args.episodes),
        },
    )
    try:
        if subject.controller is not None:
            nominal = subject.nominal_config(split, args.steps)
            controller_episodes(
                env,
                subject.controller,
                subject.controller_params,
                nominal,
                args.episodes,
                args.steps,
                seed,
            )
        else:
            for e in range(args.episodes):
                obs, _ = env.reset(seed=episode_seed(seed, e))
                for _ in range(args.steps):
                    action = np.asarray(subject.policy.predict(obs[None, :]))[0]
                    obs, _, _, _, _ = env.step(action)
    finally:
        env.close()
    return path
