"""A trained policy loaded (:class:`LoadedPolicy`) and run on readings (:class:`PolicyRunner`).

What a model directory holds and what its ``metadata.json`` says is declared once, in
:mod:`ops_contract.policy_meta` (read once by :func:`~ops_contract.policy_meta.read_meta`); this
module loads the network its metadata names. The whole runner of a model (switch, watchdog,
held decisions) is composed by :mod:`ops_controller_ros.runner_factory`. Pure Python: no
``rclpy``.

A policy may carry a recurrent state (metadata ``recurrent``: sb3-contrib RecurrentPPO's LSTM):
:meth:`LoadedPolicy.step` takes and returns it with ``episode_start`` flags (True: the state
starts afresh), as stable-baselines3's ``predict`` does; :class:`PolicyRunner` carries it from
reading to reading, and :meth:`LoadedPolicy.predictor` for a batched rollout. For a policy
without one the state is None throughout.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from ops_contract.observation import ObservationSpec
from ops_contract.policy_meta import (  # noqa: F401  (the model directory's names, re-exported)
    ALGOS,
    CHECKPOINT_NAME,
    METADATA_FILE,
    MODEL_FILE,
    PolicyLoadError,
    PolicyMeta,
    check_asked,
    library_versions,
    read_meta,
    resolve_paths,
    write_meta,
)


def algo_class(algo: str):
    """The stable-baselines3 (or sb3-contrib) class for an algorithm name."""
    name = str(algo).lower()
    if name not in ALGOS:
        raise PolicyLoadError(
            f"unknown algo {algo!r} in the metadata; supported: {', '.join(ALGOS)}"
        )
    if name in ("ppo", "td3", "sac"):
        import stable_baselines3 as sb3

        return {"ppo": sb3.PPO, "td3": sb3.TD3, "sac": sb3.SAC}[name]
    try:
        import sb3_contrib
    except ImportError:
        raise PolicyLoadError(
            f"algo {name!r} needs sb3-contrib (pinned in requirements/python.txt; run make setup)"
        ) from None
    classes = {"tqc": "TQC", "crossq": "CrossQ", "recurrent_ppo": "RecurrentPPO"}
    return getattr(sb3_contrib, classes[name])


def read_metadata(path: str | os.PathLike) -> dict:
    """The validated metadata of a model directory, as a dict (:func:`read_meta`'s entries)."""
    return read_meta(path).to_dict()


def save_metadata(out_dir: str | os.PathLike, metadata: dict) -> Path:
    """:func:`~ops_contract.policy_meta.write_meta`: validate and write ``metadata.json``."""
    return write_meta(out_dir, metadata)


@dataclass
class LoadedPolicy:
    """A trained model with its metadata (:class:`~ops_contract.policy_meta.PolicyMeta`);
    ``predict`` maps one observation (or a batch) to one action."""

    model: Any
    meta: PolicyMeta
    _norm: dict | None = field(default=None, repr=False)

    @property
    def metadata(self) -> dict:
        """Every metadata entry, as a dict (a copy)."""
        return self.meta.to_dict()

    @property
    def path(self) -> Path:
        return self.meta.path if self.meta.path is not None else Path(self.meta.source)

    @property
    def algo(self) -> str:
        return self.meta.algo

    @property
    def stage(self) -> int:
        return self.meta.stage

    @property
    def mode(self) -> str:
        return self.meta.mode

    @property
    def observation_spec(self) -> dict:
        return self.meta.observation.to_dict()

    @property
    def max_step_fs(self) -> float:
        return self.meta.max_step_fs

    @property
    def action_type(self) -> str:
        return self.meta.action_type

    @property
    def recurrent(self) -> bool:
        return self.meta.recurrent is not None

    def normalize(self, obs) -> np.ndarray:
        """The observation as the network saw it in training (saved statistics applied)."""
        x = np.asarray(obs, dtype=np.float32)
        if self._norm is None:
            return x
        mean, var = self._norm["mean"], self._norm["var"]
        x = (x - mean) / np.sqrt(var + self._norm["epsilon"])
        clip = self._norm["clip"]
        return np.clip(x, -clip, clip).astype(np.float32)

    def _input(self, obs) -> np.ndarray:
        x = self.normalize(obs)
        expected = tuple(self.model.observation_space.shape)
        if x.shape != expected and x.shape[1:] != expected:
            raise ValueError(
                f"observation has shape {x.shape}, the model expects {expected} "
                f"(stage {self.stage}, spec {self.observation_spec})"
            )
        return x

    def predict(self, obs) -> np.ndarray:
        """Deterministic action in [-1, 1]^N for one observation (or a batch of them); a
        recurrent policy starts from a fresh state at every call (:meth:`step` carries it)."""
        action, _ = self.model.predict(self._input(obs), deterministic=True)
        return np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)

    def step(self, obs, state, episode_start) -> tuple[np.ndarray, Any]:
        """(action, next state) for ``obs`` and the recurrent ``state`` carried so far (None:
        fresh); ``episode_start``: (rigs,) bools, True where the state starts afresh. A policy
        without a recurrent state: :meth:`predict`'s action and None."""
        if self.meta.recurrent is None:
            return self.predict(obs), None
        starts = np.asarray(episode_start, dtype=np.float32).reshape(-1)
        action, state = self.model.predict(
            self._input(obs), state=state, episode_start=starts, deterministic=True
        )
        return np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0), state

    def predictor(self):
        """A batched ``predict(obs)`` for one rollout whose episodes start together (the first
        call starts them): :meth:`predict` itself for a policy without a recurrent state, else
        one that carries the state from call to call."""
        if self.meta.recurrent is None:
            return self.predict
        carried: dict[str, Any] = {"state": None, "start": True}

        def predict(obs) -> np.ndarray:
            rows = 1 if np.ndim(obs) == 1 else len(obs)
            starts = np.full(rows, carried["start"])
            action, carried["state"] = self.step(obs, carried["state"], starts)
            carried["start"] = False
            return action

        return predict


def load_policy(source: str | os.PathLike | PolicyMeta, device: str = "cpu") -> LoadedPolicy:
    """Load ``DIR`` (or ``DIR/model.zip``) written by the training CLI, or the model of
    metadata already read (a :class:`~ops_contract.policy_meta.PolicyMeta`: not read again).

    Raises PolicyLoadError for a missing file or directory, a corrupt zip, missing or malformed
    metadata, an unknown algorithm and a network that does not match its metadata.
    """
    meta = source if isinstance(source, PolicyMeta) else read_meta(source)
    model_path = meta.model_file or (meta.path or Path(".")) / MODEL_FILE
    if not model_path.is_file():
        raise PolicyLoadError(
            f"model file missing: {model_path} not found (training may not have finished; "
            "a checkpoint is in DIR/checkpoints/)"
        )
    if not zipfile.is_zipfile(model_path):
        raise PolicyLoadError(f"corrupt model file: {model_path} is not a valid zip archive")
    cls = algo_class(meta.algo)
    try:
        model = cls.load(str(model_path), device=device)
    except Exception as exc:  # SB3 raises many kinds on a bad archive
        raise PolicyLoadError(
            f"corrupt model file: {model_path} could not be loaded as {meta.algo} "
            f"({type(exc).__name__}: {exc})"
        ) from None
    _check_network(meta, model, model_path)
    norm = None
    if meta.normalization:
        n = meta.normalization
        norm = {
            "mean": np.asarray(n["obs_mean"], dtype=np.float64),
            "var": np.asarray(n["obs_var"], dtype=np.float64),
            "epsilon": float(n.get("epsilon", 1e-8)),
            "clip": float(n.get("clip_obs", 10.0)),
        }
        shape = tuple(model.observation_space.shape)
        if norm["mean"].shape != shape:
            raise PolicyLoadError(
                f"metadata malformed: normalization statistics have shape "
                f"{norm['mean'].shape}, the model's observations {shape}"
            )
    return LoadedPolicy(model=model, meta=meta, _norm=norm)


def _check_network(meta: PolicyMeta, model, model_path: Path) -> None:
    """Refuse a network whose observations or recurrent state are not its metadata's."""
    shape = tuple(model.observation_space.shape)
    declared = meta.entries.get("observation_shape")
    if declared is not None and tuple(declared) != shape:
        raise PolicyLoadError(
            f"metadata malformed: observation_shape {declared} does not match the model's "
            f"{list(shape)}"
        )
    spec = meta.observation
    if (spec.dim,) != shape:
        raise PolicyLoadError(
            f"metadata and model disagree: the observation_spec ({spec.describe()}) gives "
            f"observations of {spec.dim} values, the model in {model_path} takes {list(shape)}"
        )
    lstm = getattr(getattr(model, "policy", None), "lstm_hidden_state_shape", None)
    if meta.recurrent is not None and lstm is not None:
        layers, _, hidden = lstm
        if (layers, hidden) != (meta.recurrent.layers, meta.recurrent.hidden):
            raise PolicyLoadError(
                f"metadata and model disagree: 'recurrent' says {meta.recurrent.layers} "
                f"layer(s) of {meta.recurrent.hidden}, the model in {model_path} has {layers} "
                f"of {hidden}"
            )


def observation_spec_of(metadata: dict | PolicyMeta, source: str = "metadata"):
    """The :class:`~ops_contract.observation.ObservationSpec` a model was trained with."""
    if isinstance(metadata, PolicyMeta):
        return metadata.observation
    try:
        return ObservationSpec.from_dict(dict(metadata["observation_spec"]))
    except (TypeError, ValueError) as exc:
        raise PolicyLoadError(
            f"metadata malformed: {source}: observation_spec is not valid ({exc})"
        ) from None


#: The window (optical cycles) of the applied delays a model of the authors' set trained without
#: one observes when it runs (:func:`run_observation_spec`).
AUTHORS_RUN_WINDOW_CYCLES = 1.0


def run_observation_spec(
    metadata: dict | PolicyMeta, window: float | None = None, source: str = "metadata"
):
    """The spec a model *runs* with (:class:`PolicyRunner`, ``evaluate``): the one it was
    trained with, set-points re-centred within ``window`` cycles where one is given (a switching
    model's ``acquire_setpoint_window``), except that a model of the authors' set without a
    window (``setpoint_window_cycles`` 0) sees its applied delays re-centred by whole optical
    periods, within +- ``AUTHORS_RUN_WINDOW_CYCLES`` (the interference repeats with the period;
    the envelope is hundreds of periods wide). Measured (models/README.md, n5_sac300k_authors):
    in a continuous run that model walks a delay the ``total`` detector does not see (stage 5)
    to ~3.3 cycles, out of what its 200-step episodes showed it, and then holds stages 1-4
    ~0.035 cycles off the stack (P_N / P_max ~0.89)."""
    spec = observation_spec_of(metadata, source)
    if window is not None:
        spec = replace(spec, setpoint_window_cycles=float(window))
    if spec.observation == "authors" and spec.include_setpoints and not spec.setpoint_window_cycles:
        return replace(spec, setpoint_window_cycles=AUTHORS_RUN_WINDOW_CYCLES)
    return spec


class PolicyRunner:
    """A loaded policy in a closed loop, without ROS: one reading (slot energies, P_N/P_max,
    set-points in fs) in, one normalized action in [-1, 1]^N out.

    Builds the observations with ``spec`` (default: :func:`run_observation_spec` of the model)
    through the same :class:`~ops_contract.observation.ObservationBuilder` as the environments,
    so a model trained with memory (``history`` > 0) gets its last observations and actions: the
    first reading (and the first after :meth:`restart`) starts the history, every later one is
    pushed with the action returned for the reading before. A recurrent policy's ``state`` is
    carried from reading to reading; ``episode_start`` (per rig) says where it starts afresh at
    the next reading: everywhere after :meth:`restart`, where :meth:`reset_state` says (a lost
    lock) otherwise.
    """

    def __init__(
        self, loaded: LoadedPolicy, num_envs: int | None = None, spec: ObservationSpec | None = None
    ) -> None:
        from ops_contract.observation import ObservationBuilder

        self.policy = loaded
        self.spec = spec or run_observation_spec(loaded.meta)
        # num_envs: readings of that many rigs at once, (B, ...) arrays in and out (evaluation)
        self._builder = ObservationBuilder(self.spec, num_envs)
        self._n = 1 if num_envs is None else int(num_envs)
        self._last_action: np.ndarray | None = None
        self.last_observation: np.ndarray | None = None  # what the network saw last
        self.state: Any = None  # the recurrent state (None: none, or fresh)
        self.episode_start = np.ones(self._n, dtype=bool)

    def restart(self) -> None:
        """The next reading starts a new history and a fresh recurrent state (e.g. after the
        simulator was reset)."""
        self._last_action = None
        self.state = None
        self.episode_start[:] = True

    def reset_state(self, rigs=None) -> None:
        """The recurrent state starts afresh at the next reading on ``rigs`` ((B,) bools; None:
        all), the observation's memory kept (a lost lock: a new search)."""
        if rigs is None:
            self.episode_start[:] = True
        else:
            self.episode_start |= np.asarray(rigs, dtype=bool).reshape(self._n)

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
        action, self.state = self.policy.step(obs, self.state, self.episode_start)
        self.episode_start[:] = False
        action = np.asarray(action, dtype=np.float32)
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
    check_asked(loaded.meta, stage=sim_stage)
