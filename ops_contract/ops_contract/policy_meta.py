"""What a trained model's ``metadata.json`` holds: the one schema, its validation, its reading and
writing. Training (``ops_experiments``) writes it through :func:`write_meta`; the runner factory
(``ops_controller_ros.runner_factory``) reads it once through :func:`read_meta`. Pure Python.

A model directory holds::

    DIR/model.zip        the stable-baselines3 (or sb3-contrib) model (algo.save)
    DIR/metadata.json    what a runner needs besides the network (below)

Metadata, ``format_version`` 2 (1: the same without ``recipe``, ``recurrent`` and
``training_wall_s``, read with the defaults said below)::

    format_version    2
    algo              the class model.zip loads with: "ppo" | "td3" | "sac" (stable-baselines3),
                      "tqc" | "crossq" | "recurrent_ppo" (sb3-contrib)
    recipe            how the model was trained: an algo's name (reinforcement learning with it),
                      "dagger" | "bc" | "distill" (a student imitating a teacher) or
                      "asymmetric" (an actor-critic whose critic saw what the actor does not),
                      each maybe with a variant after a dash ("dagger-oracle": DAgger with the
                      simulator's oracle as teacher); absent: the algo
    recurrent         null (the policy is a function of its observation), or the recurrent state
                      it carries from reading to reading: {"kind": "lstm", "hidden": H,
                      "layers": L} (sb3-contrib RecurrentPPO; layers absent: 1); absent: null
    training_wall_s   wall seconds of all the training behind the model, from scratch (its
                      teachers, the runs it was fine-tuned from and distillation included), or
                      null where not known; absent: the sum of ``history``'s wall_s where it
                      has any (the runs of the model's own lineage), else null
    stage, mode, split   the environment it was trained on
    detector          (optional) "polarizer" | "total"; absent: config's, else "polarizer"
    action_type       "increment": actions in [-1, 1]^N times max_step_fs added to the set-points
    max_step_fs       the actuator's largest set-point change per step (fs)
    observation_spec  ObservationSpec.to_dict() (ops_contract.observation: the observation set,
                      "rig" or "authors", and ``history``, the observation's memory)
    observation_shape, action_shape   (optional) shapes of the spaces (lists of ints)
    config            OpsConfig.to_dict() of the training environment
    normalization     null, or {"obs_mean": [...], "obs_var": [...], "clip_obs": float,
                      "epsilon": float} (VecNormalize observation statistics)
    critic_observation  (optional) what the critic saw in training: "rig" (what the actor sees)
                      or "privileged" (the rig's observation and the simulator's true delay
                      errors: an asymmetric actor-critic, recipe "asymmetric-..."); the saved
                      policy sees ``observation_spec`` alone either way; absent: "rig"
    hold_steps        (optional) readings per decision trained with (train --hold-steps; 0:
                      auto, the rig's latency_steps + 1); absent: 1
    switch            (optional) a switching model: ops_contract.policy_layers.SwitchParams and
                      ``acquire_model``, the acquiring policy's directory inside this one
    reacquire         (optional) the re-acquiring watchdog: policy_layers.WatchdogParams
    versions, command_line, timesteps, seed, history, ...   kept, not needed to run

A checkpoint (``DIR/checkpoints/model_<steps>_steps.zip``) shares one metadata.json with
``"checkpoint": true``; its own step count is in its name.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .observation import OBSERVATION_SETS, ObservationSpec
from .policy_layers import REACQUIRE_KEY, SWITCH_KEY, SwitchParams, WatchdogParams

FORMAT_VERSION = 2
FORMAT_VERSIONS = (1, 2)
MODEL_FILE = "model.zip"
METADATA_FILE = "metadata.json"
CHECKPOINT_NAME = re.compile(r"^model_(\d+)_steps\.zip$")
#: stable-baselines3's algorithms, then sb3-contrib's.
SB3_ALGOS = ("ppo", "td3", "sac")
CONTRIB_ALGOS = ("tqc", "crossq", "recurrent_ppo")
ALGOS = SB3_ALGOS + CONTRIB_ALGOS
#: The algorithms whose policy carries a recurrent state, and the kind each carries.
RECURRENT_ALGOS = {"recurrent_ppo": "lstm"}
RECURRENT_KINDS = tuple(sorted(set(RECURRENT_ALGOS.values())))
#: How a model may have been trained: an algo's own reinforcement learning, or these.
DISTILL_RECIPES = ("dagger", "bc", "distill")
RECIPES = ALGOS + DISTILL_RECIPES + ("asymmetric",)
#: What a critic may have seen in training (``critic_observation``); "privileged" only with a
#: recipe of the "asymmetric" family.
CRITIC_OBSERVATIONS = ("rig", "privileged")
RECIPE_VARIANT = re.compile(r"[a-z0-9_]+(-[a-z0-9_]+)*")
ACTION_TYPES = ("increment",)
DETECTORS = ("polarizer", "total")
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


@dataclass(frozen=True)
class RecurrentSpec:
    """The recurrent state a policy carries across readings (``recurrent`` of the metadata)."""

    kind: str
    hidden: int
    layers: int = 1

    @classmethod
    def from_entry(cls, entry: Any, source: str, model: str) -> RecurrentSpec:
        if not isinstance(entry, dict) or not isinstance(entry.get("kind"), str):
            raise PolicyLoadError(
                f"metadata malformed: {source}: 'recurrent' must be null or an object with "
                f"'kind' and 'hidden' (got {entry!r})"
            )
        if entry["kind"] not in RECURRENT_KINDS:
            raise PolicyLoadError(
                f"model {model} carries a recurrent state of kind {entry['kind']!r}, which "
                f"this runner does not know (known: {', '.join(RECURRENT_KINDS)}, run by "
                "sb3-contrib RecurrentPPO, algo 'recurrent_ppo')"
            )
        for key, default in (("hidden", None), ("layers", 1)):
            value = entry.get(key, default)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise PolicyLoadError(
                    f"metadata malformed: {source}: recurrent {key} must be an integer >= 1 "
                    f"(got {value!r})"
                )
        return cls(entry["kind"], int(entry["hidden"]), int(entry.get("layers", 1)))

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "hidden": self.hidden, "layers": self.layers}


def lineage_wall_s(entries: dict) -> float | None:
    """The wall seconds of the training runs in a metadata's ``history`` (None: none given)."""
    walls = [
        float(h["wall_s"])
        for h in entries.get("history") or []
        if isinstance(h, dict) and isinstance(h.get("wall_s"), int | float)
    ]
    return round(sum(walls), 2) if walls else None


def _with_defaults(data: dict) -> dict:
    """``data`` with the fields of format 2 that format 1 lacks filled in."""
    out = dict(data)
    out.setdefault("recipe", str(data.get("algo", "")).lower())
    out.setdefault("recurrent", None)
    if "training_wall_s" not in out:
        out["training_wall_s"] = lineage_wall_s(out)
    return out


@dataclass(frozen=True)
class PolicyMeta:
    """A validated ``metadata.json``: every entry (``entries``, the defaults of format 2 filled
    in) and the fields a runner needs, parsed. Build with :meth:`from_dict` or :func:`read_meta`;
    ValueError-free: every problem is a :class:`PolicyLoadError` naming the file and the key."""

    entries: dict
    source: str = "metadata"  # where it was read, for messages
    path: Path | None = None  # the model directory
    model_file: Path | None = None  # its model.zip (or the checkpoint's zip)
    algo: str = field(init=False)
    recipe: str = field(init=False)
    stage: int = field(init=False)
    mode: str = field(init=False)
    detector: str = field(init=False)
    action_type: str = field(init=False)
    max_step_fs: float = field(init=False)
    observation: ObservationSpec = field(init=False)
    recurrent: RecurrentSpec | None = field(init=False)
    critic_observation: str = field(init=False)
    hold_steps: int = field(init=False)
    switch: SwitchParams | None = field(init=False)
    reacquire: WatchdogParams | None = field(init=False)
    training_wall_s: float | None = field(init=False)

    def __post_init__(self) -> None:
        data, source, model = self.entries, self.source, self.name
        _check_required(data, source)
        parsed = {
            "algo": str(data["algo"]).lower(),
            "recipe": _recipe(data, model),
            "stage": int(data["stage"]),
            "mode": str(data["mode"]),
            "detector": _detector(data, source),
            "action_type": str(data["action_type"]),
            "max_step_fs": float(data["max_step_fs"]),
            "observation": _observation(data, source, model),
            "recurrent": _recurrent(data, source, model),
            "critic_observation": _critic_observation(data, source, model),
            "hold_steps": _hold_steps(data, source),
            "switch": _layer(data, SWITCH_KEY, SwitchParams, source),
            "reacquire": _layer(data, REACQUIRE_KEY, WatchdogParams, source),
            "training_wall_s": _wall(data, source),
        }
        for name, value in parsed.items():
            object.__setattr__(self, name, value)
        _check_normalization(data.get("normalization"), source)

    @classmethod
    def from_dict(
        cls, data: Any, source: str = "metadata", path=None, model_file=None
    ) -> PolicyMeta:
        """Validate ``data`` (a metadata.json's object; format 1 gets format 2's defaults)."""
        if not isinstance(data, dict):
            raise PolicyLoadError(f"metadata malformed: {source} must hold a JSON object")
        return cls(
            _with_defaults(data),
            source,
            None if path is None else Path(path),
            None if model_file is None else Path(model_file),
        )

    def to_dict(self) -> dict[str, Any]:
        """Every entry, as metadata.json holds it (``format_version`` the one written now)."""
        return {**self.entries, "format_version": FORMAT_VERSION}

    def replace(self, **entries) -> PolicyMeta:
        """The same metadata with ``entries`` changed (validated again)."""
        return PolicyMeta.from_dict(
            {**self.entries, **entries}, self.source, self.path, self.model_file
        )

    @property
    def name(self) -> str:
        """The model directory as given (for messages), else where the metadata came from."""
        return str(self.path) if self.path is not None else self.source

    @property
    def normalization(self) -> dict | None:
        return self.entries.get("normalization") or None

    @property
    def config(self) -> dict:
        return dict(self.entries.get("config") or {})

    @property
    def acquire_dir(self) -> Path | None:
        """A switching model's acquiring policy's directory (None: not a switching model)."""
        if self.switch is None:
            return None
        return (self.path or Path(".")) / self.entries[SWITCH_KEY]["acquire_model"]


def check_asked(
    meta: PolicyMeta,
    *,
    stage: int | None = None,
    detector: str | None = None,
    observation: str | None = None,
    source: str = "the simulator",
    flag: str = "--observation",
) -> None:
    """Refuse to run ``meta``'s model where it was not trained for (None: not asked): a
    PolicyLoadError naming what differs and who asks (``source``; ``flag``: the option that
    chooses the observation set, said in the remedy)."""
    if stage is not None and int(stage) != meta.stage:
        raise PolicyLoadError(
            f"model {meta.name} was trained for stage {meta.stage}, {source} runs stage "
            f"{int(stage)}"
        )
    if detector is not None and detector != meta.detector:
        raise PolicyLoadError(
            f"model {meta.name} was trained with the {meta.detector!r} detector, {source} has "
            f"the {detector!r} one"
        )
    trained = meta.observation.observation
    if observation is not None and observation != trained:
        oracle = (
            " (the authors' set holds the actual delay-line lengths, a simulator-only oracle "
            "published on ops/delays_actual)"
            if "authors" in (trained, observation)
            else ""
        )
        raise PolicyLoadError(
            f"model {meta.name} was trained on the {trained!r} observation set but is asked to "
            f"run on the {observation!r} one; a policy only runs on the observation it was "
            f"trained on: set {flag}{'' if flag.endswith('=') else ' '}{trained}{oracle}"
        )


def _check_required(data: dict, source: str) -> None:
    for key, kind in REQUIRED_KEYS.items():
        if key not in data:
            raise PolicyLoadError(f"metadata malformed: {source} lacks the key {key!r}")
        value = data[key]
        if not isinstance(value, kind) or isinstance(value, bool):
            raise PolicyLoadError(
                f"metadata malformed: {source}: {key!r} has the wrong type "
                f"({type(value).__name__}: {value!r})"
            )
    version = data.get("format_version", FORMAT_VERSION)
    if version not in FORMAT_VERSIONS:
        raise PolicyLoadError(
            f"metadata format_version {version} in {source} is not supported "
            f"(this reader knows {', '.join(map(str, FORMAT_VERSIONS))})"
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


def recipe_known(recipe: Any) -> bool:
    """Whether ``recipe`` is one of :data:`RECIPES` or a variant of one (``dagger-oracle``: the
    family ``dagger``, what taught it after the dash)."""
    if not isinstance(recipe, str):
        return False
    family, _, variant = recipe.partition("-")
    return family in RECIPES and (not _ or bool(RECIPE_VARIANT.fullmatch(variant)))


def _recipe(data: dict, model: str) -> str:
    recipe = data["recipe"]
    if not recipe_known(recipe):
        raise PolicyLoadError(
            f"model {model} was trained with the recipe {recipe!r}, which this runner does not "
            f"know (known: {', '.join(RECIPES)}, or one of them with a variant after a dash, "
            "e.g. dagger-oracle)"
        )
    return recipe


def _detector(data: dict, source: str) -> str:
    detector = data.get("detector") or (data.get("config") or {}).get("detector") or "polarizer"
    if detector not in DETECTORS:
        raise PolicyLoadError(
            f"metadata malformed: {source}: detector {detector!r} is not one of "
            f"{', '.join(DETECTORS)}"
        )
    return str(detector)


def _observation(data: dict, source: str, model: str) -> ObservationSpec:
    entry = dict(data["observation_spec"])
    known = entry.get("observation", "rig")
    if known not in OBSERVATION_SETS:
        raise PolicyLoadError(
            f"model {model} was trained on the observation set {known!r}, which this runner "
            f"does not know (known: {', '.join(OBSERVATION_SETS)})"
        )
    try:
        spec = ObservationSpec.from_dict(entry)
    except (TypeError, ValueError) as exc:
        raise PolicyLoadError(
            f"metadata malformed: {source}: observation_spec is not valid ({exc})"
        ) from None
    if spec.stage != int(data["stage"]):
        raise PolicyLoadError(
            f"metadata malformed: {source}: observation_spec is for stage {spec.stage}, the "
            f"model for stage {data['stage']}"
        )
    return spec


def _recurrent(data: dict, source: str, model: str) -> RecurrentSpec | None:
    entry, algo = data["recurrent"], str(data["algo"]).lower()
    spec = None if entry is None else RecurrentSpec.from_entry(entry, source, model)
    carries = RECURRENT_ALGOS.get(algo)
    if spec is None and carries:
        raise PolicyLoadError(
            f"metadata malformed: {source}: algo {algo!r} carries a recurrent state, but "
            f'\'recurrent\' is null (give {{"kind": "{carries}", "hidden": ...}})'
        )
    if spec is not None and spec.kind != carries:
        raise PolicyLoadError(
            f"model {model}: 'recurrent' says {spec.kind!r}, but algo {algo!r} carries "
            + (f"a {carries!r} state" if carries else "no recurrent state")
        )
    return spec


def _critic_observation(data: dict, source: str, model: str) -> str:
    seen = data.get("critic_observation", "rig")
    if seen not in CRITIC_OBSERVATIONS:
        raise PolicyLoadError(
            f"model {model} was trained with a critic that saw {seen!r}, which this runner does "
            f"not know (known: {', '.join(CRITIC_OBSERVATIONS)})"
        )
    if seen == "privileged" and str(data["recipe"]).partition("-")[0] != "asymmetric":
        raise PolicyLoadError(
            f"metadata malformed: {source}: critic_observation 'privileged' needs a recipe of "
            f"the 'asymmetric' family (got {data['recipe']!r})"
        )
    return str(seen)


def _hold_steps(data: dict, source: str) -> int:
    from .held import HOLD_STEPS_DEFAULT, check_hold_steps

    try:
        return check_hold_steps(data.get("hold_steps", HOLD_STEPS_DEFAULT))
    except ValueError as exc:
        raise PolicyLoadError(f"metadata malformed: {source}: {exc}") from None


def _layer(data: dict, key: str, cls, source: str):
    if key not in data:
        return None
    entry = data[key]
    if key == SWITCH_KEY and (
        not isinstance(entry, dict) or not isinstance(entry.get("acquire_model"), str)
    ):
        raise PolicyLoadError(
            f"metadata malformed: {source}: '{SWITCH_KEY}' needs 'acquire_model', the acquiring "
            "policy's directory inside the model directory"
        )
    try:
        return cls.from_dict(entry)
    except (TypeError, ValueError) as exc:
        raise PolicyLoadError(f"metadata malformed: {source}: {exc}") from None


def _wall(data: dict, source: str) -> float | None:
    wall = data["training_wall_s"]
    if wall is None:
        return None
    if isinstance(wall, bool) or not isinstance(wall, int | float) or not 0 <= wall < math.inf:
        raise PolicyLoadError(
            f"metadata malformed: {source}: training_wall_s must be null or seconds >= 0 "
            f"(got {wall!r})"
        )
    return float(wall)


def _check_normalization(norm: Any, source: str) -> None:
    if norm is None:
        return
    if not isinstance(norm, dict) or not {"obs_mean", "obs_var"} <= set(norm):
        raise PolicyLoadError(
            f"metadata malformed: {source}: normalization needs obs_mean and obs_var"
        )
    if len(norm["obs_mean"]) != len(norm["obs_var"]):
        raise PolicyLoadError(
            f"metadata malformed: {source}: obs_mean and obs_var differ in length"
        )


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


def read_meta(path: str | os.PathLike) -> PolicyMeta:
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
    match = CHECKPOINT_NAME.match(model_path.name)
    if isinstance(data, dict) and data.get("checkpoint") and match:
        data["timesteps"] = int(match.group(1))  # the checkpoint's own step count
    return PolicyMeta.from_dict(data, str(meta_path), model_path.parent, model_path)


def write_meta(out_dir: str | os.PathLike, metadata: PolicyMeta | dict) -> Path:
    """Validate and write ``out_dir/metadata.json`` atomically (format 2; ``versions`` filled
    in where absent); returns its path."""
    data = metadata.to_dict() if isinstance(metadata, PolicyMeta) else _jsonable(dict(metadata))
    data = {**data, "format_version": FORMAT_VERSION}
    data.setdefault("versions", library_versions())
    meta = PolicyMeta.from_dict(data, "metadata to save")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / METADATA_FILE
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(_jsonable(meta.to_dict()), indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)
    return path


def library_versions() -> dict[str, str]:
    """Versions of the libraries a model depends on (recorded in the metadata)."""
    import platform

    import numpy as np

    versions = {"python": platform.python_version(), "numpy": np.__version__}
    for name in ("torch", "stable_baselines3", "sb3_contrib", "gymnasium"):
        try:
            versions[name] = __import__(name).__version__
        except Exception:  # a missing library is recorded, not fatal
            versions[name] = "unavailable"
    return versions


def _jsonable(value: Any) -> Any:
    import numpy as np

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
