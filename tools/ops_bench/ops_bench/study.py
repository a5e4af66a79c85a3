"""What the in-process studies of ``ops-bench`` (tracker-late, tracker-knot-wake, spgd-attempts)
share: a controller's ``--param KEY=VALUE`` checked before any run; ``--out``, a JSON file of
the figures that names the command which made them; and a controller's evaluation episodes
with a look inside at every step."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from ops_experiments.cli_args import parse_key_values
from ops_experiments.rollouts import controller_episodes
from ops_sim_ros.env import OpsEnv


def add_options(ap: argparse.ArgumentParser, controller: str) -> None:
    """``--param`` (the ``controller``'s parameters, repeatable) and ``--out``."""
    ap.add_argument(
        "--param", action="extend", nargs="+", default=[], metavar="KEY=VALUE",
        help=f"{controller} parameters; repeatable",
    )  # fmt: skip
    ap.add_argument("--out", type=Path, help="also write the figures to this JSON file")


def check_params(ap: argparse.ArgumentParser, args: argparse.Namespace, params_class) -> None:
    """``args.params``: ``--param`` as a dict, built into ``params_class`` once so that unknown
    names and values out of range stop the command (exit 2, naming ``--param``) before any run."""
    try:
        args.params = parse_key_values(args.param, "--param")
        params_class(**args.params)
    except (TypeError, ValueError) as exc:
        ap.error(f"--param: {exc}")


def write_figures(out: Path, tool: str, argv, payload: dict) -> None:
    """``payload`` as JSON at ``out``, headed by the command line that made it (``argv``: the
    tool's own arguments, None: this process's)."""
    given = sys.argv[1:] if argv is None else list(argv)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps({"command": f"ops-bench {tool} " + " ".join(given), **payload}, indent=1)
    out.write_text(text + "\n")
    print(f"wrote {out}")


def recorded_episodes(cfg, controller: str, params: dict, seeds, episodes: int, on_step):
    """``evaluate --controller``'s episodes of ``controller`` on ``cfg`` (simulator and nominal
    model alike, ``cfg.episode_steps`` steps): ``episodes`` for each of ``seeds``, numbered
    0, 1, ... across the seeds for ``on_step(row, step, ctl, env, result)``
    (:func:`~ops_experiments.rollouts.controller_episodes`). Returns each
    episode's final P_N/P_max, in that order."""
    steps = cfg.episode_steps
    env = OpsEnv.from_config(cfg, max_episode_steps=steps)
    finals = []
    try:
        for i, seed in enumerate(seeds):

            def hook(e, t, ctl, env, r, first=i * episodes):
                on_step(first + e, t, ctl, env, r)

            out = controller_episodes(env, controller, params, cfg, episodes, steps, seed, hook)
            finals.extend(out["power"][:, -1].tolist())
    finally:
        env.close()
    return np.array(finals)
