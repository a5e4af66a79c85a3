"""A learned controller in two parts: one policy finds the stack, another holds it.

Measured (docs/results.md, "Continuous operation"): a policy trained on 200-step episodes finds
the stack fast but lets go in a long run; the same policy fine-tuned on episodes that carry on
(``train --continue-prob``) holds a long run but acquires slowly. A switching model runs both on
every reading and applies one action:

* the *acquiring* policy until P_N / P_max has been >= ``lock_power`` for ``lock_readings``
  readings in a row;
* then the *holding* policy, until P_N / P_max has been < ``release_power`` for
  ``release_readings`` readings in a row (a lost lock: back to the acquiring policy, whose
  recurrent state, if it has one, starts afresh: a new search).

Both policies build their observations from every reading, with the action actually applied in
their memory, so the one that takes over has the history it was trained with.

On disk a switching model is the holding policy's model directory (``model.zip``,
``metadata.json``) with the acquiring policy's whole model directory inside it (``acquire/``)
and a ``switch`` entry in the metadata (its settings: :class:`~ops_contract.policy_layers.
SwitchParams`)::

    "switch": {"acquire_model": "acquire", "lock_power": 0.95, "lock_readings": 3,
               "release_power": 0.8, "release_readings": 2, "acquire_setpoint_window": 1.0}

:class:`SwitchingRunner` is one layer of a model's runner, composed with the others by
:mod:`ops_controller_ros.runner_factory` (which the policy node and ``evaluate`` call);
:func:`write_switch_model` makes such a directory.
"""

from __future__ import annotations

import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np
from ops_contract.policy_layers import ACQUIRE_DIR, SWITCH_KEY, SwitchParams
from ops_contract.policy_meta import (
    MODEL_FILE,
    PolicyLoadError,
    PolicyMeta,
    read_meta,
    write_meta,
)

from .policy_io import PolicyRunner


class SwitchingRunner:
    """Two policies' runners on the same readings, one acting (module docstring); the interface
    of :class:`~ops_controller_ros.policy_io.PolicyRunner` (``act``, ``restart``, ``took``,
    ``reset_state``, ``spec``, ``policy``: the holding policy's).

    ``holding``: per rig, whether the holding policy acts now (bool, or (B,) for a batch);
    ``switches``: hand-overs so far, either way."""

    def __init__(
        self,
        hold: PolicyRunner,
        acquire: PolicyRunner,
        params: SwitchParams | None = None,
        num_envs: int | None = None,
    ) -> None:
        self.params = params or SwitchParams()
        self.hold, self.acquire = hold, acquire
        self.policy = hold.policy
        self.spec = hold.spec
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

    def reset_state(self, rigs=None) -> None:
        """Both policies' recurrent states start afresh at the next reading on ``rigs``."""
        self.hold.reset_state(rigs)
        self.acquire.reset_state(rigs)

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
        lost = self._holding & ~holding
        if lost.any():  # a lost lock: the acquiring policy searches anew
            self.acquire.reset_state(lost)
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


def check_pair(hold: PolicyMeta, acquire: PolicyMeta) -> None:
    """Refuse two policies that cannot drive the same rig in turn."""
    checks = (
        ("stage", hold.stage, acquire.stage),
        ("max_step_fs", hold.max_step_fs, acquire.max_step_fs),
        ("action_type", hold.action_type, acquire.action_type),
        ("detector", hold.detector, acquire.detector),
        ("observation set", hold.observation.observation, acquire.observation.observation),
    )
    for what, held, found in checks:
        if held != found:
            raise PolicyLoadError(
                f"the switching model's policies disagree on the {what}: holding "
                f"({hold.name}) {held!r}, acquiring ({acquire.name}) {found!r}"
            )


def merged_wall_s(*metas: PolicyMeta) -> float | None:
    """The training wall seconds behind several policies together: each one's
    ``training_wall_s``, counting the runs their lineages (``history``) share once (a holder
    fine-tuned from the acquirer shares its first run)."""
    runs: dict[tuple, float] = {}
    for meta in metas:
        entries = [h for h in meta.entries.get("history") or [] if isinstance(h, dict)]
        walls = [h for h in entries if isinstance(h.get("wall_s"), int | float)]
        if meta.training_wall_s is not None and not walls:
            runs[("meta", meta.name)] = meta.training_wall_s
        extra = (meta.training_wall_s or 0.0) - sum(float(h["wall_s"]) for h in walls)
        for h in walls:
            runs[(str(h.get("command_line")), str(h.get("finished")))] = float(h["wall_s"])
        if walls and extra > 0.01:  # beyond the lineage (a teacher, distillation)
            runs[("extra", meta.name)] = extra
    return round(sum(runs.values()), 2) if runs else None


def write_switch_model(
    out,
    hold_dir,
    acquire_dir,
    params: SwitchParams | None = None,
    note: str = "",
    mode: str | None = None,
) -> Path:
    """Write a switching model to ``out``: ``hold_dir``'s model and metadata (plus a
    ``switch`` entry) and ``acquire_dir``'s model directory as ``out/acquire``. Both are
    checked first; returns ``out``. ``mode``: the mode the model is for (what ``evaluate``
    runs by default; default: the holding policy's training mode, kept in ``config``). Its
    ``training_wall_s`` counts both policies' training (:func:`merged_wall_s`)."""
    params = params or SwitchParams()
    hold, acquire = read_meta(hold_dir), read_meta(acquire_dir)
    check_pair(hold, acquire)
    for meta in (hold, acquire):
        if not meta.model_file.is_file():
            raise PolicyLoadError(f"model file missing: {meta.model_file} not found")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    shutil.copy2(hold.model_file, out / MODEL_FILE)
    target = out / ACQUIRE_DIR
    target.mkdir(exist_ok=True)
    shutil.copy2(acquire.model_file, target / MODEL_FILE)
    write_meta(target, acquire)
    entries = dict(hold.entries)
    if mode is not None:
        from ops_contract.config import MODES

        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)} (got {mode!r})")
        entries["mode"] = mode
    entries[SWITCH_KEY] = {
        "acquire_model": ACQUIRE_DIR,
        **asdict(params),
        "hold_from": str(hold_dir),
        "acquire_from": str(acquire_dir),
        **({"note": note} if note else {}),
    }
    entries["training_wall_s"] = merged_wall_s(hold, acquire)
    write_meta(out, entries)
    return out
