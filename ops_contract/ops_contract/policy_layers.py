"""The settings of the layers a model's metadata can ask its runner for, declared once: the switch
between an acquiring and a holding policy (``switch``) and the re-acquiring watchdog
(``reacquire``). :mod:`ops_contract.policy_meta` validates them when it reads ``metadata.json``;
the layers themselves run in ``ops_controller_ros`` (``policy_switch``, ``reacquire``), composed by
``ops_controller_ros.runner_factory``. Pure Python.

A switching model (``switch`` entry)::

    "switch": {"acquire_model": "acquire", "lock_power": 0.95, "lock_readings": 3,
               "release_power": 0.8, "release_readings": 2, "acquire_setpoint_window": 1.0,
               "acquire_patience": 0}

A model that runs inside the watchdog (``reacquire`` entry; an empty object: the defaults)::

    "reacquire": {"good_power": 0.8, "patience": 50, "kick_steps": 5, "seed": 0}

Keys these classes do not know (a note, where the parts came from) are kept in the metadata and
ignored here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

SWITCH_KEY = "switch"
REACQUIRE_KEY = "reacquire"
#: Where a switching model keeps its acquiring policy's model directory (``acquire_model``).
ACQUIRE_DIR = "acquire"


def _check(prefix: str, obj, checks) -> None:
    """ValueError naming the first ``(name, ok, allowed)`` of ``checks`` that fails."""
    for name, ok, allowed in checks:
        value = getattr(obj, name)
        if value is None and ok:
            continue
        if isinstance(value, bool) or not ok or not math.isfinite(value):
            raise ValueError(f"{prefix} {name} must be {allowed} (got {value!r})")


def _known(cls, data, key: str) -> dict:
    if not isinstance(data, dict):
        raise ValueError(f"the '{key}' entry must be an object (got {data!r})")
    names = {f.name for f in fields(cls)}
    return {k: v for k, v in data.items() if k in names}


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
        _check(
            "switch",
            self,
            (
                ("lock_power", 0.0 < self.lock_power <= 1.0, "in (0, 1]"),
                (
                    "release_power",
                    0.0 <= self.release_power < self.lock_power,
                    "in [0, lock_power)",
                ),
                ("lock_readings", self.lock_readings >= 1, ">= 1"),
                ("release_readings", self.release_readings >= 1, ">= 1"),
                ("acquire_setpoint_window", w is None or w == 0 or w >= 0.5, "None, 0 or >= 0.5"),
                ("acquire_patience", self.acquire_patience >= 0, ">= 0"),
            ),
        )

    @classmethod
    def from_dict(cls, data: dict) -> SwitchParams:
        """From a metadata entry; unknown keys (``acquire_model``, a note) are ignored."""
        return cls(**_known(cls, data, SWITCH_KEY))


@dataclass(frozen=True)
class WatchdogParams:
    """When the watchdog kicks and how far (readings of P_N / P_max; steps of the actuator)."""

    # A reading at or above this is "the stack found": it resets the count (never kicked).
    good_power: float = 0.8
    # Readings in a row below good_power before a kick (from the start, the last good reading
    # or the end of the last kick). patience and kick_steps were chosen on tuning seeds
    # (7001-7020, models/README.md "No catastrophic episode"): longer kicks (15-40 steps)
    # made the rig-observation models worse, since they read absolute set-points.
    patience: int = 50
    # Readings during which a kick applies the largest step in its random direction.
    kick_steps: int = 5
    # Seed of the kicks' directions (drawn anew from it at every restart: reproducible runs).
    seed: int = 0

    def __post_init__(self) -> None:
        _check(
            "reacquire",
            self,
            (
                ("good_power", 0.0 < self.good_power <= 1.0, "in (0, 1]"),
                ("patience", self.patience >= 1, ">= 1"),
                ("kick_steps", self.kick_steps >= 1, ">= 1"),
                ("seed", self.seed >= 0, ">= 0"),
            ),
        )
        for name in ("patience", "kick_steps", "seed"):
            if int(getattr(self, name)) != getattr(self, name):
                raise ValueError(
                    f"reacquire {name} must be an integer (got {getattr(self, name)!r})"
                )

    @classmethod
    def from_dict(cls, data: dict) -> WatchdogParams:
        """From a metadata entry; unknown keys (a note, say) are ignored."""
        return cls(**_known(cls, data, REACQUIRE_KEY))
