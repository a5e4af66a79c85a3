"""The observation vector: built by ONE function that the env, the ROS bridge and the policy
runner all call, described by an :class:`ObservationSpec` that is saved beside trained models.

Default layout for N stages (S = 2^N - 1 output slots), float32:

    [0 : S)        detected pulse energies of the output slots (time slots 1, 3, ..,
                   2^(N+1) - 3), normalized by the input energy, clipped to [0, 1];
                   the stacked pulse is index 2^(N-1) - 1 (the centre)
    [S]            P_N / P_max, the normalized second-order detector signal, clipped to [0, 1]
    [S+1 : S+1+N)  delay set-points in optical periods (set-point_fs / optical_period_fs), not
                   wrapped, clipped to +- actuator range (so the policy knows where the actuator
                   limits are)

Each block can be switched off in the spec. That is the *rig* observation set
(``ObservationSpec(observation="rig")``, the default): everything in it is measured on a real
stacker (the detector, and the set-points the controller itself commanded).

The *authors'* set (``observation="authors"``) is what the authors' ``CPS_env`` observes by default
(``obs_signal = ['power', 'pulse', 'pzm']``, normalized to their box), at our time sampling::

    [0]            power:  AUTHORS_POWER_SCALE * P_N/P_max + AUTHORS_POWER_OFFSET (4.58 P - 1.29,
                   their box for N = 5 mapped to [-1, 1])
    [1 : 1+S)      pulse:  2N * slot energy - 1 (their trace samples, box [0, I_max / N])
    [1+S : 1+S+N)  pzm:    APPLIED delay (set-point + hidden delay-line error) in optical periods
                   / 3 (their PZM lengths: a double pass, box +-1.5 wavelengths of mirror travel)

The last block is an oracle: the actual delays, noise and drift included, which a rig whose
disturbances sit in the optical path cannot measure. The simulator has them
(``StepResult.applied_fs``); every builder below takes them as ``applied_fs``. Left out of the
authors' observation: their Gaussian observation noise (sigma 1e-4 on these scaled values), the
rounding of their power to 0.01 of their units and the constant per-environment offset of their
PZM box (it is centred on the first episode's lengths; ours on the optimum).

Set-points re-centred by whole cycles (``ObservationSpec(setpoint_window_cycles=w)``, w > 0): each
stage's set-point is observed relative to a reference, a whole number of optical periods that
follows it: when a set-point leaves +- w of its reference, the reference moves to the whole cycle
nearest to it (every frame of the history is shown against the current reference). In the
authors' set the same window re-centres the applied delays of its pzm block (w in optical cycles,
the reference subtracted in their units: whole cycles / 3).
The interference is periodic in each delay by one optical period (the pulse envelope, a thousand
times wider, hardly changes over the drift's range), so a policy sees the numbers it was trained
on wherever drift has carried the delays over hours; absolute set-points (w = 0, the default)
leave a policy trained on 200-step episodes, where they stay within about a cycle of 0, once the
drift has moved them a few cycles (measured: docs/results/continuous). The reference is state:
build these observations with :class:`ObservationBuilder`.

That is one *frame*; with ``history = 0`` (the
default, the paper's observation) the observation is the current frame.

Memory (``ObservationSpec(history=k)``, k >= 1): the observation is the last k frames, each
followed by the action that led to it (the normalized increment in [-1, 1]^N, zeros before the
first step of an episode), newest first::

    [frame_t, a_t, frame_{t-1}, a_{t-1}, ..., frame_{t-k+1}, a_{t-k+1}]     k * (F + N) values

where a_t is the action whose step produced frame_t. After a reset every slot holds the first frame
and a zero action. :class:`ObservationBuilder` keeps that state for one env or a batch; the
in-process env, the vector envs, the ROS bridge and the policy runner all build their observations
with it, and the spec (``history`` included) is saved in a trained model's metadata.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import cached_property
from typing import Any

import numpy as np

from .arrays import clip as _clip
from .config import OpsConfig

#: The observation sets: ``rig`` (what a real stacker measures) and ``authors`` (the authors'
#: ``CPS_env`` default, with the actual delay-line lengths).
OBSERVATION_SETS = ("rig", "authors")
#: The authors' scalings (their ``NormalizedAct`` box at N = 5; see the module docstring).
AUTHORS_POWER_SCALE = 4.58
AUTHORS_POWER_OFFSET = -1.29
AUTHORS_PZM_CYCLES = 3.0  # applied delay in optical periods per unit of their pzm value


@dataclass(frozen=True)
class ObservationSpec:
    stage: int
    optical_period_fs: float = 1030.0 / 299.792458
    setpoint_limit_cycles: float = 30.0  # set-points are clipped to +- this (actuator range)
    include_energies: bool = True
    include_power: bool = True
    include_setpoints: bool = True
    history: int = 0  # 0: the current frame only; k >= 1: the last k frames and their actions
    observation: str = "rig"  # the observation set: one of OBSERVATION_SETS
    # 0: set-points as they are; w > 0: relative to a whole-cycle reference that follows them
    setpoint_window_cycles: float = 0.0

    def __post_init__(self) -> None:
        if self.observation not in OBSERVATION_SETS:
            raise ValueError(
                f"observation must be one of {', '.join(OBSERVATION_SETS)} "
                f"(got {self.observation!r})"
            )
        if isinstance(self.history, bool) or not isinstance(self.history, int | np.integer):
            raise ValueError(f"history must be an integer >= 0 (got {self.history!r})")
        if self.history < 0:
            raise ValueError(f"history must be >= 0 (got {self.history})")
        object.__setattr__(self, "history", int(self.history))
        w = self.setpoint_window_cycles
        if isinstance(w, bool) or not isinstance(w, int | float) or not (0.0 <= w < 1e6):
            raise ValueError(f"setpoint_window_cycles must be a number >= 0 (got {w!r})")
        object.__setattr__(self, "setpoint_window_cycles", float(w))
        if w > 0 and not self.include_setpoints:
            raise ValueError(
                "setpoint_window_cycles > 0 re-centres the set-points (the authors' set: the "
                "applied delays): it needs include_setpoints=True"
            )
        if 0 < w < 0.5:
            raise ValueError(
                f"setpoint_window_cycles must be 0 (off) or >= 0.5 (got {w}): a smaller window "
                "would move the reference back and forth at every step"
            )

    @classmethod
    def from_config(cls, config: OpsConfig, **options: Any) -> ObservationSpec:
        return cls(
            stage=config.stage,
            optical_period_fs=config.optical_period_fs,
            setpoint_limit_cycles=config.actuator_range_cycles,
            **options,
        )

    @property
    def num_slots(self) -> int:
        return 2**self.stage - 1

    @property
    def frame_dim(self) -> int:
        """Values of one frame (the whole observation when history is 0)."""
        return (
            self.num_slots * self.include_energies
            + 1 * self.include_power
            + self.stage * self.include_setpoints
        )

    @property
    def dim(self) -> int:
        if self.history == 0:
            return self.frame_dim
        return self.history * (self.frame_dim + self.stage)

    def options(self) -> dict[str, Any]:
        """The choices of the observation (blocks, history): the ``observation_options`` of an
        env that builds this observation for its own configuration."""
        return {
            "include_energies": self.include_energies,
            "include_power": self.include_power,
            "include_setpoints": self.include_setpoints,
            "history": self.history,
            "observation": self.observation,
            "setpoint_window_cycles": self.setpoint_window_cycles,
        }

    @property
    def has_state(self) -> bool:
        """True when an observation depends on the past (memory or re-centred set-points)."""
        return bool(self.history) or self.setpoint_window_cycles > 0

    @property
    def setpoint_columns(self) -> slice:
        """Where one frame holds the set-points (the authors' set: the applied delays)."""
        start = self.num_slots * self.include_energies + 1 * self.include_power
        return slice(start, start + self.stage * self.include_setpoints)

    @property
    def setpoint_unit_cycles(self) -> float:
        """Optical cycles per unit of the set-point columns (rig: 1; authors: 3)."""
        return AUTHORS_PZM_CYCLES if self.observation == "authors" else 1.0

    @property
    def needs_applied_delays(self) -> bool:
        """True for the authors' set: its frames hold the applied delays (a simulator oracle)."""
        return self.observation == "authors"

    def describe(self) -> str:
        """A short human description, e.g. for error messages."""
        memory = f"history={self.history}" if self.history else "no memory"
        window = self.setpoint_window_cycles
        recentred = f"; set-points re-centred (window {window:g} cycles)" if window else ""
        return (
            f"stage {self.stage}, {self.dim} values ({memory}; {self.observation} observation"
            f"{recentred})"
        )

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of the observation, float32 arrays of length ``dim``."""
        return self._bounds[0].copy(), self._bounds[1].copy()

    @cached_property
    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        low, high = self._frame_bounds
        if self.history == 0:
            return low, high
        ones = np.ones(self.stage, dtype=np.float32)
        return (
            np.tile(np.concatenate([low, -ones]), self.history),
            np.tile(np.concatenate([high, ones]), self.history),
        )

    @cached_property
    def _frame_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        low, high = [], []
        limit = self.setpoint_limit_cycles
        if self.observation == "authors":
            n2 = 2.0 * self.stage
            if self.include_power:
                low.append([AUTHORS_POWER_OFFSET])
                high.append([AUTHORS_POWER_SCALE + AUTHORS_POWER_OFFSET])
            if self.include_energies:
                low.append(np.full(self.num_slots, -1.0))
                high.append(np.full(self.num_slots, n2 - 1.0))
            if self.include_setpoints:
                low.append(np.full(self.stage, -limit / AUTHORS_PZM_CYCLES))
                high.append(np.full(self.stage, limit / AUTHORS_PZM_CYCLES))
        else:
            if self.include_energies:
                low.append(np.zeros(self.num_slots))
                high.append(np.ones(self.num_slots))
            if self.include_power:
                low.append(np.zeros(1))
                high.append(np.ones(1))
            if self.include_setpoints:
                low.append(np.full(self.stage, -limit))
                high.append(np.full(self.stage, limit))
        return (
            np.concatenate(low).astype(np.float32),
            np.concatenate(high).astype(np.float32),
        )

    def space(self):
        """The gymnasium Box of this observation."""
        from gymnasium import spaces

        low, high = self.bounds()
        return spaces.Box(low=low, high=high, dtype=np.float32)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ObservationSpec:
        """The spec of a metadata dict (specs saved before ``history`` existed have none, and
        before observation sets none of ``observation``: the rig's)."""
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(
                f"observation_spec has unknown keys {unknown} (written by a newer version?)"
            )
        return cls(**data)


def build_observation(
    spec: ObservationSpec, pulse_energies, power, setpoints_fs, applied_fs=None
) -> np.ndarray:
    """The memoryless observation(s) (history 0): the current frame of :func:`build_frame`.

    With ``spec.history > 0`` the observation depends on the past: use
    :class:`ObservationBuilder`, which keeps it.
    """
    if spec.has_state:
        raise ValueError(
            f"the observation spec has history={spec.history}, setpoint_window_cycles="
            f"{spec.setpoint_window_cycles}: build observations with ObservationBuilder (it keeps "
            "the last frames and actions, and the set-points' reference)"
        )
    return build_frame(spec, pulse_energies, power, setpoints_fs, applied_fs)


def build_frame(
    spec: ObservationSpec, pulse_energies, power, setpoints_fs, applied_fs=None
) -> np.ndarray:
    """Frame(s) for a batch (B, frame_dim) or a single env (frame_dim,), float32, inside the
    bounds of one frame.

    ``pulse_energies`` (B, S) or (S,), ``power`` (B,) or scalar, ``setpoints_fs`` (B, N) or (N,);
    ``applied_fs`` (same shape: set-point + hidden delay error) is needed by the authors' set
    only (the rig's ignores it).
    """
    e = np.asarray(pulse_energies, dtype=np.float64)
    single = e.ndim == 1
    slots = 2**spec.stage - 1
    e2 = e.reshape(-1, slots)
    batch = e2.shape[0]
    low, high = spec._frame_bounds
    obs = np.empty((batch, low.shape[0]), dtype=np.float32)
    if spec.observation == "authors":
        _authors_frame(spec, obs, e2, power, applied_fs)
    else:
        col = 0
        # Each block is written straight into the float32 array (float64 values rounded once).
        if spec.include_energies:
            obs[:, :slots] = e2
            col = slots
        if spec.include_power:
            obs[:, col] = np.asarray(power, dtype=np.float64).reshape(batch)
            col += 1
        if spec.include_setpoints:
            sp = np.asarray(setpoints_fs, dtype=np.float64).reshape(batch, spec.stage)
            np.multiply(sp, 1.0 / spec.optical_period_fs, out=obs[:, col:])
    _clip(obs, low, high, out=obs)
    return obs[0] if single else obs


def _authors_frame(spec: ObservationSpec, obs, energies, power, applied_fs) -> None:
    """The authors' blocks (power, pulse, pzm; their order and scalings) into ``obs``."""
    batch, slots = energies.shape
    col = 0
    if spec.include_power:
        p = np.asarray(power, dtype=np.float64).reshape(batch)
        obs[:, 0] = AUTHORS_POWER_SCALE * p + AUTHORS_POWER_OFFSET
        col = 1
    if spec.include_energies:
        obs[:, col : col + slots] = 2.0 * spec.stage * energies - 1.0
        col += slots
    if spec.include_setpoints:
        if applied_fs is None:
            raise ValueError(
                "the authors' observation holds the applied delays (set-point + hidden delay "
                "error): pass applied_fs (a simulator-only quantity, /ops/delays_actual over ROS 2)"
            )
        d = np.asarray(applied_fs, dtype=np.float64).reshape(batch, spec.stage)
        scale = 1.0 / (spec.optical_period_fs * AUTHORS_PZM_CYCLES)
        np.multiply(d, scale, out=obs[:, col:])


class ObservationBuilder:
    """The observations of one env (``num_envs=None``: 1-D arrays in and out) or of a batch of
    ``num_envs``, as ``spec`` says: the frame of :func:`build_frame` and, with
    ``spec.history = k > 0``, the last k frames with the actions that led to them.

    ``reset(...)`` starts episodes (all, or the rows where ``mask`` is True: every history slot
    gets the first frame and a zero action); ``step(..., actions)`` pushes the new frame with the
    action (in [-1, 1]^N, clipped; float32) of the step that produced it. Both return the
    observations of every env (float32, a fresh array). With history 0 both are
    :func:`build_frame` and no state is kept. ``applied_fs``: the applied delays, for the
    authors' set.
    """

    def __init__(self, spec: ObservationSpec, num_envs: int | None = None) -> None:
        self.spec = spec
        self.single = num_envs is None
        self.num_envs = 1 if num_envs is None else int(num_envs)
        self._frame = spec.frame_dim
        # Frames are kept as built (absolute set-points); the set-points' whole-cycle reference
        # (re-centred observations) is subtracted from every frame on output.
        self._window = spec.setpoint_window_cycles
        self._ref = np.zeros((self.num_envs, spec.stage), dtype=np.float32)
        self._sp_cols = spec.setpoint_columns
        self._sp_unit = np.float32(spec.setpoint_unit_cycles)
        width = self._frame + (spec.stage if spec.history else 0)
        self._buf = np.zeros((self.num_envs, max(spec.history, 1), width), dtype=np.float32)
        self._started = np.zeros(self.num_envs, dtype=bool)

    @property
    def has_memory(self) -> bool:
        return self.spec.history > 0

    @property
    def setpoint_reference_cycles(self) -> np.ndarray:
        """The whole-cycle reference of each env's set-points (zeros without re-centring)."""
        ref = self._ref.copy()
        return ref[0] if self.single else ref

    def reset(self, pulse_energies, power, setpoints_fs, mask=None, applied_fs=None) -> np.ndarray:
        frame = build_frame(self.spec, pulse_energies, power, setpoints_fs, applied_fs)
        if not self.spec.has_state:
            return frame
        rows = slice(None) if mask is None else np.asarray(mask, dtype=bool).reshape(-1)
        f = frame.reshape(self.num_envs, self._frame)
        self._buf[rows, :, : self._frame] = f[rows, None, :]
        self._buf[rows, :, self._frame :] = 0.0
        self._ref[rows] = 0.0
        self._started[rows] = True
        return self._output()

    def step(self, pulse_energies, power, setpoints_fs, actions, applied_fs=None) -> np.ndarray:
        frame = build_frame(self.spec, pulse_energies, power, setpoints_fs, applied_fs)
        if not self.spec.has_state:
            return frame
        if not self._started.all():
            raise RuntimeError("ObservationBuilder.step() before reset() of every env")
        buf = self._buf
        if self.spec.history > 1:
            buf[:, 1:] = buf[:, :-1].copy()
        buf[:, 0, : self._frame] = frame.reshape(self.num_envs, self._frame)
        if self.spec.history:
            a = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, self.spec.stage)
            _clip(a, -1.0, 1.0, out=buf[:, 0, self._frame :])
        return self._output()

    def _output(self) -> np.ndarray:
        out = self._buf.copy()  # (history 0: one slot of one frame, no action)
        if self._window > 0:  # the reference in cycles; the columns in their own units
            newest = self._buf[:, 0, self._sp_cols] * self._sp_unit
            away = np.abs(newest - self._ref) > self._window
            if away.any():
                self._ref[away] = np.round(newest[away])
            out[:, :, self._sp_cols] -= self._ref[:, None, :] / self._sp_unit
        obs = out.reshape(self.num_envs, -1)
        return obs[0] if self.single else obs


def pulse_energies_from_trace(trace, samples_per_slot: int) -> np.ndarray:
    """Sample a detected trace (..., S * samples_per_slot) at the slot centres -> (..., S)."""
    tr = np.asarray(trace, dtype=np.float32)
    spp = int(samples_per_slot)
    if tr.shape[-1] % spp:
        raise ValueError(f"trace length {tr.shape[-1]} is not a multiple of samples_per_slot {spp}")
    return tr[..., spp // 2 :: spp].copy()
