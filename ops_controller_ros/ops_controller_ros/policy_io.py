"""Reading and writing trained policies: ``model.zip`` (stable-baselines3) + ``metadata.json``.

The one reader/writer of model directories, shared by the training CLI (``ops_gym_bridge train``),
the evaluation CLI and the policy runner node. Pure Python: no ``rclpy``.

A model directory holds::

    DIR/model.zip        the stable-baselines3 model (algo.save)
    DIR/metadata.json    what a runner needs besides the network (schema below)

Metadata (``metadata.json``, ``format_version`` 1)::

    format_version    1
    algo              "ppo" | "td3" | "sac" (stable-baselines3) | "tqc" | "crossq" (sb3-contrib)
    stage, mode, split   the environment it was trained on
    action_type       "increment": actions in [-1, 1]^N times max_step_fs added to the set-points
    max_step_fs       the actuator's largest set-point change per step (fs)
    observation_spec  ObservationSpec.to_dict() of ops_contract.observation (``history``: the
                      number of past observations and actions in each observation; 0 or absent:
                      none, the paper's observation; ``observation``: the observation set,
                      "rig" or "authors"; absent: "rig")
    observation_shape, action_shape   shapes of the spaces (lists of ints)
    config            OpsConfig.to_dict() of the training environment
    normalization     null, or {"obs_mean": [...], "obs_var": [...], "clip_obs": float,
                      "epsilon": float} (VecNormalize observation statistics)
    versions          python, numpy, torch, stable_baselines3, gymnasium
    command_line      the argv of the training run
    timesteps         environment steps trained in total (over resumes)
    seed              the training seed
    hold_steps        (optional) readings per decision the model was trained with (train
                      --hold-steps; 0: auto, the rig's latency_steps + 1): evaluate and the
                      policy node hold it so unless told otherwise; absent: 1, every reading
    (anything else, e.g. backend, n_envs, hyperparams, created, is kept but not required)
"""

from __future__ import annotations

import json
import math
import os
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FORMAT_VERSION = 1
MODEL_FILE = "model.zip"
METADATA_FILE = "metadata.json"
# train's checkpoints (DIR/checkpoints/model_<steps>_steps.zip) share one metadata.json, written
# when the run starts; each checkpoint's own step count is in its name
CHECKPOINT_NAME = re.compile(r"^model_(\d+)_steps\.zip$")
#: stable-baselines3's algorithms, then sb3-contrib's (TQC, CrossQ).
SB3_ALGOS = ("ppo", "td3", "sac")
CONTRIB_ALGOS = ("tqc", "crossq")
ALGOS = SB3_ALGOS + CONTRIB_ALGOS
ACTION_TYPES = ("increment",)
REQUIRED_KEYS = {
    "algo": str,
    "stage": int,
    "mode": str,
    "action_type": str,
    "max_step_fs": (int, float),
    "observation_spec": dict,
}


class PolicyLoadError(RuntimeError):
    """A model directory cannot be used; the message says why and what to do."""


def algo_class(algo: str):
    """The stable-baselines3 (or sb3-contrib) class for an algorithm name."""
    name = str(algo).lower()
    if name not in ALGOS:
        raise PolicyLoadError(
            f"unknown algo {algo!r} in the metadata; supported: {', '.join(ALGOS)}"
        )
    if name in SB3_ALGOS:
        import stable_baselines3 as sb3

        return {"ppo": sb3.PPO, "td3": sb3.TD3, "sac": sb3.SAC}[name]
    try:
        import sb3_contrib
    except ImportError:
        raise PolicyLoadError(
            f"algo {name!r} needs sb3-contrib (pinned in requirements/python.txt; run make setup)"
        ) from None
    return {"tqc": sb3_contrib.TQC, "crossq": sb3_contrib.CrossQ}[name]


def library_versions() -> dict[str, str]:
    """Versions of the libraries a model depends on (recorded in the metadata)."""
    import platform

    versions = {"python": platform.python_version(), "numpy": np.__version__}
    for name, module in (
        ("torch", "torch"),
        ("stable_baselines3", "stable_baselines3"),
        ("sb3_contrib", "sb3_contrib"),
        ("gymnasium", "gymnasium"),
    ):
        try:
            versions[name] = __import__(module).__version__
        except Exception:  # a missing library is recorded, not fatal
            versions[name] = "unavailable"
    return versions


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def resolve_paths(path: str | os.PathLike) -> tuple[Path, Path]:
    """(model.zip, metadata.json) for a model directory or a model.zip path."""
    p = Path(path).expanduser()
    if p.is_dir():
        return p / MODEL_FILE, p / METADATA_FILE
    if p.suffix == ".zip" or p.name == MODEL_FILE:
        return p, p.parent / METADATA_FILE
    if not p.exists() and Path(str(p) + ".zip").exists():  # SB3 style "DIR/model"
        return Path(str(p) + ".zip"), p.parent / METADATA_FILE
    if not p.exists():
        raise PolicyLoadError(f"model not found: {p} (give the training --out directory)")
    raise PolicyLoadError(
        f"{p} is neither a model directory nor a {MODEL_FILE} (give the training --out directory)"
    )


def save_metadata(out_dir: str | os.PathLike, metadata: dict) -> Path:
    """Validate and write ``out_dir/metadata.json`` atomically; returns its path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    data = {"format_version": FORMAT_VERSION, **_jsonable(dict(metadata))}
    data.setdefault("versions", library_versions())
    validate_metadata(data, source="metadata to save")
    path = out / METADATA_FILE
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)
    return path


def read_metadata(path: str | os.PathLike) -> dict:
    """The validated metadata of a model directory (or of the directory of a model.zip)."""
    model_path, meta_path = resolve_paths(path)
    if not meta_path.is_file():
        raise PolicyLoadError(
            f"metadata missing: {meta_path} not found (a model directory written by "
            "'ros2 run ops_gym_bridge train --out DIR' has model.zip and metadata.json)"
        )
    try:
        data = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PolicyLoadError(
            f"metadata malformed: {meta_path} is not valid JSON ({exc})"
        ) from None
    validate_metadata(data, source=str(meta_path))
    # A checkpoint's metadata is its run's at the start: its own step count is in its name.
    match = CHECKPOINT_NAME.match(model_path.name) if data.get("checkpoint") else None
    if match:
        data["timesteps"] = int(match.group(1))
    return data


def validate_metadata(data: Any, source: str = "metadata") -> None:
    """Raise PolicyLoadError naming the first problem of a metadata dict."""
    if not isinstance(data, dict):
        raise PolicyLoadError(f"metadata malformed: {source} must hold a JSON object")
    for key, kind in REQUIRED_KEYS.items():
        if key not in data:
            raise PolicyLoadError(f"metadata malformed: {source} lacks the key {key!r}")
        value = data[key]
        if not isinstance(value, kind) or isinstance(value, bool):
            raise PolicyLoadError(
                f"metadata malformed: {source}: {key!r} has the wrong type "
                f"({type(value).__name__}: {value!r})"
            )
    if str(data["algo"]).lower() not in ALGOS:
        raise PolicyLoadError(
            f"unknown algo {data['algo']!r} in {source}; supported: {', '.join(ALGOS)}"
        )
    if data["action_type"] not in ACTION_TYPES:
        raise PolicyLoadError(
            f"metadata malformed: {source}: action_type {data['action_type']!r} is not one of "
            f"{', '.join(ACTION_TYPES)}"
        )
    if data["stage"] < 1:
        raise PolicyLoadError(f"metadata malformed: {source}: stage must be >= 1")
    if not (math.isfinite(data["max_step_fs"]) and data["max_step_fs"] > 0):
        raise PolicyLoadError(f"metadata malformed: {source}: max_step_fs must be > 0")
    version = data.get("format_version", FORMAT_VERSION)
    if version != FORMAT_VERSION:
        raise PolicyLoadError(
            f"metadata format_version {version} in {source} is not supported "
            f"(this reader knows {FORMAT_VERSION})"
        )
    if "hold_steps" in data:
        from ops_contract.held import check_hold_steps

        try:
            check_hold_steps(data["hold_steps"])
        except ValueError as exc:
            raise PolicyLoadError(f"metadata malformed: {source}: {exc}") from None
    norm = data.get("normalization")
    if norm is not None:
        if not isinstance(norm, dict) or not {"obs_mean", "obs_var"} <= set(norm):
            raise PolicyLoadError(
                f"metadata malformed: {source}: normalization needs obs_mean and obs_var"
            )
        if len(norm["obs_mean"]) != len(norm["obs_var"]):
            raise PolicyLoadError(
                f"metadata malformed: {source}: obs_mean and obs_var differ in length"
            )


@dataclass
class LoadedPolicy:
    """A trained model with its metadata; ``predict`` maps one observation to one action."""

    model: Any
    metadata: dict
    path: Path
    _norm: dict | None = field(default=None, repr=False)

    @property
    def algo(self) -> str:
        return str(self.metadata["algo"]).lower()

    @property
    def stage(self) -> int:
        return int(self.metadata["stage"])

    @property
    def mode(self) -> str:
        return str(self.metadata["mode"])

    @property
    def observation_spec(self) -> dict:
        return dict(self.metadata["observation_spec"])

    @property
    def max_step_fs(self) -> float:
        return float(self.metadata["max_step_fs"])

    @property
    def action_type(self) -> str:
        return str(self.metadata["action_type"])

    def normalize(self, obs) -> np.ndarray:
        """The observation as the network saw it in training (saved statistics applied)."""
        x = np.asarray(obs, dtype=np.float32)
        if self._norm is None:
            return x
        mean, var = self._norm["mean"], self._norm["var"]
        x = (x - mean) / np.sqrt(var + self._norm["epsilon"])
        clip = self._norm["clip"]
        return np.clip(x, -clip, clip).astype(np.float32)

    def predict(self, obs) -> np.ndarray:
        """Deterministic action in [-1, 1]^N for one observation (or a batch of them)."""
        x = self.normalize(obs)
        expected = tuple(self.model.observation_space.shape)
        if x.shape != expected and x.shape[1:] != expected:
            raise ValueError(
                f"observation has shape {x.shape}, the model expects {expected} "
                f"(stage {self.stage}, spec {self.observation_spec})"
            )
        action, _ = self.model.predict(x, deterministic=True)
        return np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)


def load_policy(path: str | os.PathLike, device: str = "cpu") -> LoadedPolicy:
    """Load ``DIR`` (or ``DIR/model.zip``) written by the training CLI.

    Raises PolicyLoadError for a missing file or directory, a corrupt zip, missing or malformed
    metadata and an unknown algorithm.
    """
    model_path, _ = resolve_paths(path)
    metadata = read_metadata(path)
    if not model_path.is_file():
        raise PolicyLoadError(
            f"model file missing: {model_path} not found (training may not have finished; "
            "a checkpoint is in DIR/checkpoints/)"
        )
    if not zipfile.is_zipfile(model_path):
        raise PolicyLoadError(f"corrupt model file: {model_path} is not a valid zip archive")
    cls = algo_class(metadata["algo"])
    try:
        model = cls.load(str(model_path), device=device)
    except Exception as exc:  # SB3 raises many kinds on a bad archive
        raise PolicyLoadError(
            f"corrupt model file: {model_path} could not be loaded as {metadata['algo']} "
            f"({type(exc).__name__}: {exc})"
        ) from None
    norm = None
    if metadata.get("normalization"):
        n = metadata["normalization"]
        norm = {
            "mean": np.asarray(n["obs_mean"], dtype=np.float64),
            "var": np.asarray(n["obs_var"], dtype=np.float64),
            "epsilon": float(n.get("epsilon", 1e-8)),
            "clip": float(n.get("clip_obs", 10.0)),
        }
    shape = tuple(model.observation_space.shape)
    if "observation_shape" in metadata and tuple(metadata["observation_shape"]) != shape:
        raise PolicyLoadError(
            f"metadata malformed: observation_shape {metadata['observation_shape']} does not "
            f"match the model's {list(shape)}"
        )
    spec = observation_spec_of(metadata, source=str(model_path.parent))
    if (spec.dim,) != shape:
        raise PolicyLoadError(
            f"metadata and model disagree: the observation_spec ({spec.describe()}) gives "
            f"observations of {spec.dim} values, the model in {model_path} takes {list(shape)}"
        )
    if norm is not None and norm["mean"].shape != shape:
        raise PolicyLoadError(
            f"metadata malformed: normalization statistics have shape {norm['mean'].shape}, "
            f"the model's observations {shape}"
        )
    return LoadedPolicy(model=model, metadata=metadata, path=model_path.parent, _norm=norm)


def observation_spec_of(metadata: dict, source: str = "metadata"):
    """The :class:`~ops_contract.observation.ObservationSpec` a model was trained with."""
    from ops_contract.observation import ObservationSpec

    try:
        return ObservationSpec.from_dict(dict(metadata["observation_spec"]))
    except (TypeError, ValueError) as exc:
        raise PolicyLoadError(
            f"metadata malformed: {source}: observation_spec is not valid ({exc})"
        ) from None


#: The window (optical cycles) of the applied delays a model of the authors' set trained without
#: one observes when it runs (:func:`run_observation_spec`).
AUTHORS_RUN_WINDOW_CYCLES = 1.0


def run_observation_spec(metadata: dict, source: str = "metadata"):
    """The spec a model *runs* with (:class:`PolicyRunner`, ``evaluate``): the one it was
    trained with, except that a model of the authors' set trained without a window
    (``setpoint_window_cycles`` 0) sees its applied delays re-centred by whole optical periods,
    within +- ``AUTHORS_RUN_WINDOW_CYCLES`` (the interference repeats with the period; the
    envelope is hundreds of periods wide). Measured (models/README.md, n5_sac300k_authors): in a
    continuous run that model walks a delay the ``total`` detector does not see (stage 5) to
    ~3.3 cycles, out of what its 200-step episodes showed it, and then holds stages 1-4
    ~0.035 cycles off the stack (P_N / P_max ~0.89)."""
    from dataclasses import replace

    spec = observation_spec_of(metadata, source)
    if spec.observation == "authors" and spec.include_setpoints and not spec.setpoint_window_cycles:
        return replace(spec, setpoint_window_cycles=AUTHORS_RUN_WINDOW_CYCLES)
    return spec


class PolicyRunner:
    """A loaded policy in a closed loop, without ROS: one reading (slot energies, P_N/P_max,
    set-points in fs) in, one normalized action in [-1, 1]^N out.

    Builds the observations with the model's own spec through the same
    :class:`~ops_contract.observation.ObservationBuilder` as the environments, so a model trained
    with memory (``history`` > 0) gets its last observations and actions: the first reading
    (and the first after :meth:`restart`) starts the history, every later one is pushed with the
    action returned for the reading before. The ``ops_policy`` node runs one.
    """

    def __init__(self, loaded: LoadedPolicy, num_envs: int | None = None) -> None:
        from ops_contract.observation import ObservationBuilder

        self.policy = loaded
        # (an authors'-set model: its applied delays re-centred by whole periods)
        self.spec = run_observation_spec(loaded.metadata, source=str(loaded.path))
        # num_envs: readings of that many rigs at once, (B, ...) arrays in and out (evaluation)
        self._builder = ObservationBuilder(self.spec, num_envs)
        self._last_action: np.ndarray | None = None
        self.last_observation: np.ndarray | None = None  # what the network saw last

    def restart(self) -> None:
        """The next reading starts a new history (e.g. after the simulator was reset)."""
        self._last_action = None

    def observe(self, pulse_energies, power, setpoints_fs, applied_fs=None) -> np.ndarray:
        """The observation of a reading, as the model saw observations in training
        (``applied_fs``: the applied delays, needed by a model of the authors' set)."""
        if self._last_action is None:
            return self._builder.reset(pulse_energies, power, setpoints_fs, applied_fs=applied_fs)
        return self._builder.step(
            pulse_energies, power, setpoints_fs, self._last_action, applied_fs=applied_fs
        )

    def act(self, pulse_energies, power, setpoints_fs, applied_fs=None) -> np.ndarray:
        """The action (float32, [-1, 1]^N; (B, N) for a batch) for a reading; it is remembered
        for the next one."""
        obs = self.observe(pulse_energies, power, setpoints_fs, applied_fs)
        self.last_observation = obs
        action = np.asarray(self.policy.predict(obs), dtype=np.float32)
        action = action.reshape(-1) if self._builder.single else action.reshape(obs.shape[0], -1)
        self._last_action = action
        return action

    def took(self, action) -> None:
        """The action actually applied after the last reading, if not the one :meth:`act`
        returned (another policy chose it: :mod:`ops_controller_ros.policy_switch`); the next
        observation's memory holds it."""
        self._last_action = np.asarray(action, dtype=np.float32)


def check_stage(loaded: LoadedPolicy, sim_stage: int) -> None:
    """Refuse a model trained for another number of stages than the simulator runs."""
    if int(sim_stage) != loaded.stage:
        raise PolicyLoadError(
            f"model was trained for stage {loaded.stage} but the simulator runs stage "
            f"{int(sim_stage)}"
        )


def observation_set_of(metadata: dict) -> str:
    """The observation set a model was trained on ("rig" for metadata from before the sets)."""
    return str(dict(metadata.get("observation_spec") or {}).get("observation", "rig"))


def check_observation(metadata: dict, observation: str, where: str = "--observation") -> None:
    """Refuse to run a model on another observation set than it was trained on."""
    trained = observation_set_of(metadata)
    if trained != observation:
        oracle = (
            " (the authors' set holds the actual delay-line lengths, a simulator-only oracle "
            "published on ops/delays_actual)"
            if "authors" in (trained, observation)
            else ""
        )
        raise PolicyLoadError(
            f"the model was trained on the {trained!r} observation set but is asked to run on "
            f"the {observation!r} one; a policy only runs on the observation it was trained on: "
            f"set {where}{'' if where.endswith('=') else ' '}{trained}{oracle}"
        )
