"""A learned controller in two parts: one policy finds the stack, another holds it.

Measured (docs/results.md, "Continuous operation"): a policy trained on 200-step episodes finds
the stack fast but lets go in a long run; the same policy fine-tuned on episodes that carry on
(``train --continue-prob``) holds a long run but acquires slowly. A switching model runs both on
every reading and applies one action:

* the *acquiring* policy until P_N / P_max has been >= ``lock_power`` for ``lock_readings``
  readings in a row;
* then the *holding* policy, until P_N / P_max has been < ``release_power`` for
  ``release_readings`` readings in a row (a lost lock: back to the acquiring policy).

Both policies build their observations from every reading, with the action actually applied in
their memory, so the one that takes over has the history it was trained with.

On disk a switching model is the holding policy's model directory (``model.zip``,
``metadata.json``) with the acquiring policy's whole model directory inside it (``acquire/``)
and a ``switch`` entry in the metadata::

    "switch": {"acquire_model": "acquire", "lock_power": 0.95, "lock_readings": 3,
               "release_power": 0.8, "release_readings": 2, "acquire_setpoint_window": 1.0}

:func:`make_runner` gives the runner a model directory asks for (a plain
:class:`~ops_controller_ros.policy_io.PolicyRunner` without ``switch``); the policy node and
``evaluate`` use it. :func:`write_switch_model` makes such a directory.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from .policy_hold import HeldRunner, check_hold_steps
from .policy_io import (
    METADATA_FILE,
    MODEL_FILE,
    LoadedPolicy,
    PolicyLoadError,
    PolicyRunner,
    load_policy,
    observation_set_of,
    read_metadata,
    save_metadata,
)
from .reacquire import REACQUIRE_KEY, ReacquireWatchdog, watchdog_params_of

SWITCH_KEY = "switch"
ACQUIRE_DIR = "acquire"


@dataclass(frozen=True)
class SwitchParams:
    """When the holding policy takes over and when it hands back (P_N / P_max readings)."""

    lock_power: float = 0.95
    lock_readings: int = 3
    release_power: float = 0.8
    release_readings: int = 2
    # The acquiring policy's set-points observed against a whole-cycle reference (cycles; the
    # ObservationSpec's setpoint_window_cycles), whatever it was trained with; None: as
    # trained. A policy trained on 200-step episodes read absolute set-points near 0; after
    # hours of drift they are cycles away, and it no longer finds the stack (docs/results.md,
    # "Long runs learned"); re-centred, they look like its training episodes again.
    acquire_setpoint_window: float | None = None
    # 0: off. n > 0: a search that has not found the stack in n readings is handed to the
    # holding policy for the next n, then back, in turn: the two policies' failed acquisitions
    # are different episodes (measured on hard mode, docs/results.md), so an ensemble of the two
    # searches rescues the tail of either.
    acquire_patience: int = 0

    def __post_init__(self) -> None:
        w = self.acquire_setpoint_window
        checks = (
            ("lock_power", 0.0 < self.lock_power <= 1.0, "in (0, 1]"),
            ("release_power", 0.0 <= self.release_power < self.lock_power, "in [0, lock_power)"),
            ("lock_readings", self.lock_readings >= 1, ">= 1"),
            ("release_readings", self.release_readings >= 1, ">= 1"),
            ("acquire_setpoint_window", w is None or w == 0 or w >= 0.5, "None, 0 or >= 0.5"),
            ("acquire_patience", self.acquire_patience >= 0, ">= 0"),
        )
        for name, ok, allowed in checks:
            value = getattr(self, name)
            if value is None and ok:
                continue
            if isinstance(value, bool) or not ok or not math.isfinite(value):
                raise ValueError(f"switch {name} must be {allowed} (got {value!r})")

    @classmethod
    def from_dict(cls, data: dict) -> SwitchParams:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})


class SwitchingRunner:
    """Two policies on the same readings, one acting (module docstring); the interface of
    :class:`~ops_controller_ros.policy_io.PolicyRunner` (``act``, ``restart``, ``spec``).

    ``holding``: per rig, whether the holding policy acts now (bool, or (B,) for a batch);
    ``switches``: hand-overs so far, either way."""

    def __init__(
        self,
        hold: LoadedPolicy,
        acquire: LoadedPolicy,
        params: SwitchParams | None = None,
        num_envs: int | None = None,
    ) -> None:
        self.params = params or SwitchParams()
        self.policy = hold
        self.hold = PolicyRunner(hold, num_envs)
        self.acquire = PolicyRunner(acquire, num_envs)
        self.spec = self.hold.spec
        self._single = num_envs is None
        self._n = 1 if num_envs is None else int(num_envs)
        self.switches = 0
        self.restart()

    def restart(self) -> None:
        """The next reading starts new histories, with the acquiring policy acting."""
        self.hold.restart()
        self.acquire.restart()
        self._holding = np.zeros(self._n, dtype=bool)
        self._high = np.zeros(self._n, dtype=int)
        self._low = np.zeros(self._n, dtype=int)
        self._searched = np.zeros(self._n, dtype=int)  # readings since the search began
        self._hold_acts = np.zeros(self._n, dtype=bool)

    @property
    def holding(self):
        """Whether the lock is held (the holding policy acts since the readings say locked)."""
        return bool(self._holding[0]) if self._single else self._holding.copy()

    @property
    def holder_acts(self):
        """Whether the holding policy's action was applied last (holding, or its turn of an
        ``acquire_patience`` search)."""
        return bool(self._hold_acts[0]) if self._single else self._hold_acts.copy()

    def act(self, pulse_energies, power, setpoints_fs, applied_fs=None) -> np.ndarray:
        p = self.params
        power_now = np.asarray(power, dtype=np.float64).reshape(self._n)
        self._high = np.where(power_now >= p.lock_power, self._high + 1, 0)
        self._low = np.where(power_now < p.release_power, self._low + 1, 0)
        holding = np.where(
            self._holding, self._low < p.release_readings, self._high >= p.lock_readings
        )
        self.switches += int(np.count_nonzero(holding != self._holding))
        self._holding = holding
        self._searched = np.where(holding, 0, self._searched + 1)
        hold_acts = holding.copy()
        if p.acquire_patience:
            hold_acts |= ((self._searched - 1) // p.acquire_patience) % 2 == 1
        self._hold_acts = hold_acts
        held = self.hold.act(pulse_energies, power, setpoints_fs, applied_fs)
        found = self.acquire.act(pulse_energies, power, setpoints_fs, applied_fs)
        rows = hold_acts[0] if self._single else hold_acts[:, None]
        action = np.where(rows, held, found).astype(np.float32)
        self.hold.took(action)
        self.acquire.took(action)
        return action

    def took(self, action) -> None:
        """The action actually applied, if not the one :meth:`act` returned (a re-acquiring
        watchdog's kick, :mod:`ops_controller_ros.reacquire`): both policies' memories hold it."""
        self.hold.took(action)
        self.acquire.took(action)


def _acquire_path(loaded: LoadedPolicy) -> Path:
    entry = loaded.metadata[SWITCH_KEY]
    if not isinstance(entry, dict) or not isinstance(entry.get("acquire_model"), str):
        raise PolicyLoadError(
            f"metadata malformed: {loaded.path / METADATA_FILE}: '{SWITCH_KEY}' needs "
            "'acquire_model', the acquiring policy's directory inside the model directory"
        )
    return loaded.path / entry["acquire_model"]


def check_pair(hold: LoadedPolicy, acquire: LoadedPolicy) -> None:
    """Refuse two policies that cannot drive the same rig in turn."""
    checks = (
        ("stage", hold.stage, acquire.stage),
        ("max_step_fs", hold.max_step_fs, acquire.max_step_fs),
        ("action_type", hold.action_type, acquire.action_type),
        (
            "detector",
            (hold.metadata.get("config") or {}).get("detector", "polarizer"),
            (acquire.metadata.get("config") or {}).get("detector", "polarizer"),
        ),
        (
            "observation set",
            observation_set_of(hold.metadata),
            observation_set_of(acquire.metadata),
        ),
    )
    for what, held, found in checks:
        if held != found:
            raise PolicyLoadError(
                f"the switching model's policies disagree on the {what}: holding "
                f"({hold.path}) {held!r}, acquiring ({acquire.path}) {found!r}"
            )


def make_runner(loaded: LoadedPolicy, num_envs: int | None = None, hold_steps: int = 1):
    """The runner of a loaded model directory: a :class:`SwitchingRunner` when its metadata has
    a ``switch`` entry (the acquiring policy loaded from inside it), else a PolicyRunner; either
    wrapped in a :class:`~ops_controller_ros.reacquire.ReacquireWatchdog` when the metadata has
    a ``reacquire`` entry. ``hold_steps`` > 1 (resolved: not 0, auto): all of it inside a
    :class:`~ops_controller_ros.policy_hold.HeldRunner`, deciding on one reading in that many."""
    runner = _make_policy_runner(loaded, num_envs)
    try:
        watchdog = watchdog_params_of(loaded.metadata)
    except (TypeError, ValueError) as exc:
        raise PolicyLoadError(f"metadata malformed: {loaded.path / METADATA_FILE}: {exc}") from None
    if watchdog is not None:
        runner = ReacquireWatchdog(runner, watchdog, num_envs)
    if check_hold_steps(hold_steps) == 1:
        return runner
    return HeldRunner(runner, hold_steps, num_envs)


def _make_policy_runner(loaded: LoadedPolicy, num_envs: int | None):
    if SWITCH_KEY not in loaded.metadata:
        return PolicyRunner(loaded, num_envs)
    path = _acquire_path(loaded)
    if not (path / MODEL_FILE).is_file():
        raise PolicyLoadError(
            f"switching model {loaded.path}: the acquiring policy {path / MODEL_FILE} is missing; "
            "copy the acquiring model's folder there, or write the switching model again with "
            f"`ops-bench switch-model --hold HOLD_DIR --acquire ACQUIRE_DIR --out {loaded.path}`"
        )
    acquire = load_policy(path)
    check_pair(loaded, acquire)
    try:
        params = SwitchParams.from_dict(loaded.metadata[SWITCH_KEY])
    except (TypeError, ValueError) as exc:
        raise PolicyLoadError(f"metadata malformed: {loaded.path / METADATA_FILE}: {exc}") from None
    if params.acquire_setpoint_window is not None:
        spec = dict(acquire.metadata["observation_spec"])
        spec["setpoint_window_cycles"] = float(params.acquire_setpoint_window)
        acquire = replace(acquire, metadata={**acquire.metadata, "observation_spec": spec})
    return SwitchingRunner(loaded, acquire, params, num_envs)


def needs_runner(loaded: LoadedPolicy) -> bool:
    """Whether the model runs more than its policy's bare ``predict``: a switching model, or a
    re-acquiring watchdog (``reacquire`` entry). ``evaluate`` then runs :func:`make_runner`'s
    runner on every reading (``rollouts.rollout_runner``), as the policy node does."""
    return SWITCH_KEY in loaded.metadata or REACQUIRE_KEY in loaded.metadata


def write_switch_model(
    out,
    hold_dir,
    acquire_dir,
    params: SwitchParams | None = None,
    note: str = "",
    mode: str | None = None,
) -> Path:
    """Write a switching model to ``out``: ``hold_dir``'s model and metadata (plus a
    ``switch`` entry) and ``acquire_dir``'s model directory as ``out/acquire``. Both are loaded
    and checked first; returns ``out``. ``mode``: the mode the model is for (what ``evaluate``
    runs by default; default: the holding policy's training mode, kept in ``config``)."""
    params = params or SwitchParams()
    hold, acquire = load_policy(hold_dir), load_policy(acquire_dir)
    check_pair(hold, acquire)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    shutil.copy2(hold.path / MODEL_FILE, out / MODEL_FILE)
    target = out / ACQUIRE_DIR
    target.mkdir(exist_ok=True)
    shutil.copy2(acquire.path / MODEL_FILE, target / MODEL_FILE)
    save_metadata(target, read_metadata(acquire.path))
    metadata = read_metadata(hold.path)
    if mode is not None:
        from ops_contract.config import MODES

        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)} (got {mode!r})")
        metadata["mode"] = mode
    metadata[SWITCH_KEY] = {
        "acquire_model": ACQUIRE_DIR,
        **asdict(params),
        "hold_from": str(hold_dir),
        "acquire_from": str(acquire_dir),
        **({"note": note} if note else {}),
    }
    save_metadata(out, metadata)
    return out
