"""Tiny models on disk for the tests of the runner (imported by the tests beside it): real
stable-baselines3 / sb3-contrib models, built and saved, not trained (loading and running do not
care), with their metadata written through ops_contract.policy_meta."""

from __future__ import annotations

import json
from pathlib import Path

HIDDEN = 8  # the tiny recurrent policy's LSTM


def tiny_model(out: Path, algo: str = "sac", stage: int = 2, mode: str = "easy", **entries) -> Path:
    """A model directory ``out`` (model.zip, metadata.json) of ``algo`` ("sac" or
    "recurrent_ppo") for ``stage`` and ``mode``; ``entries`` override metadata entries
    (``observation``: the observation set, ``history``: its memory)."""
    from ops_contract.policy_meta import write_meta

    from ops_sim_ros import OpsEnv

    options = {k: entries.pop(k) for k in ("observation", "history") if k in entries}
    env = OpsEnv(stage=stage, mode=mode, observation_options=options)
    if algo == "recurrent_ppo":
        from sb3_contrib import RecurrentPPO

        kwargs = {"lstm_hidden_size": HIDDEN, "net_arch": [8]}
        model = RecurrentPPO(
            "MlpLstmPolicy", env, n_steps=16, batch_size=16, policy_kwargs=kwargs, seed=0
        )
        recurrent = {"kind": "lstm", "hidden": HIDDEN, "layers": 1}
    else:
        from stable_baselines3 import SAC

        model = SAC("MlpPolicy", env, policy_kwargs={"net_arch": [16, 16]}, seed=0, device="cpu")
        recurrent = None
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model.save(str(out / "model.zip"))
    metadata = {
        "algo": algo,
        "recipe": algo,
        "recurrent": recurrent,
        "training_wall_s": 0.0,
        "stage": stage,
        "mode": mode,
        "split": "train",
        "action_type": "increment",
        "max_step_fs": env.config.max_step_fs,
        "observation_spec": env.obs_spec.to_dict(),
        "observation_shape": list(env.observation_space.shape),
        "config": env.config.to_dict(),
        "normalization": None,
    }
    write_meta(out, {**metadata, **entries})
    return out


def edit_metadata(model: Path, **entries) -> Path:
    """Change ``model``'s metadata.json as a file (no validation: what a bad model holds)."""
    path = Path(model) / "metadata.json"
    data = json.loads(path.read_text())
    data.update(entries)
    path.write_text(json.dumps(data))
    return Path(model)
