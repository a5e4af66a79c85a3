"""Delay-line disturbance of eq. (2)/(4), batched over environments and stages (values in fs).

The delay a line really applies is its set-point plus an offset e_t that the controller cannot
see. As in the authors' code, e_t is a random walk:

* at an episode's start e_0 is the mode's initial delay error: normal(0, sigma_0) clipped at
  +- initial_clip_sigmas sigma_0, plus (hard, extreme) one offset per episode shared by all stages,
  uniform in +- initial_offset_sigmas sigma_0;
* every control step adds an increment N(mu_t, sigma) whose zero-mean part is clipped at
  +- jitter_clip_sigmas sigma (the vibration of the paper's fast noise; the delays wander);
* the drift mu_t (slow thermal noise) is 0 in easy and medium mode. With ``drift_knot_*_steps``
  = 0 (hard) one mu per episode is drawn at reset, |mu| uniform in [slope_min, slope_max] with a
  random sign, shared by all stages (or per stage with ``drift_per_stage``) and constant within
  the episode. With knots > 0 (extreme) each slope is redrawn every knot_min..knot_max control
  steps, on a step counter that does not restart at episode resets, so the slope process runs on
  across episodes; the accumulated drift of an episode turns back at +- ``drift_bound_fs``:
  in one step (the slope's sign flips), or with ``drift_turn_steps`` > 0 over that many steps,
  the slope going linearly from v to -v and the turn begun so that it peaks at the bound.

Only control steps advance the walk and the drift: the measurement at reset sees e_0.

Physical time (``time_base`` seconds, docs/physics.md): the figures above are per step of the
paper's 0.1 s; a step of ``step_s`` adds a walk increment of sigma x sqrt(step_s / 0.1) and a
drift of mu x step_s / 0.1, and the knots come every knot x 0.1 / step_s steps (rounded, at
least 1), so a simulated second holds the same disturbance at any rate; at step_s 0.1 the
arithmetic is that of ``step``, bit for bit. A ``vibration`` preset adds the zero-mean offsets
of :mod:`ops_sim_ros.vibration` at t = steps x ``step_s`` since the process started.
"""

from __future__ import annotations

import numpy as np
from ops_contract.config import REFERENCE_STEP_S

from .vibration import make_vibration

_FOREVER = 1 << 62


def loop_steps(reference_steps: int, time_scale: float) -> int:
    """Steps of a loop whose step lasts ``time_scale`` reference steps that make
    ``reference_steps`` of them (0 stays 0; otherwise rounded, at least 1)."""
    if reference_steps == 0 or time_scale == 1.0:
        return int(reference_steps)
    return max(1, round(reference_steps / time_scale))


class DelayNoise:
    """Stateful disturbance of ``num_envs`` x ``stage`` delay lines (all values in fs)."""

    # Smooth turns at the bound (class defaults: a process pickled before they existed has none)
    turn_steps = 0
    _turning = False

    def __init__(
        self,
        num_envs: int,
        stage: int,
        jitter_sigma_fs: float,
        jitter_clip_sigmas: float = 3.0,
        drift_slope_min_fs: float = 0.0,
        drift_slope_max_fs: float = 0.0,
        drift_per_stage: bool = False,
        drift_knot_min_steps: int = 0,
        drift_knot_max_steps: int = 0,
        drift_bound_fs: float = np.inf,
        drift_turn_steps: int = 0,
        initial_sigma_fs: float = 0.0,
        initial_clip_sigmas: float = 2.0,
        initial_offset_sigmas: float = 0.0,
        rng: np.random.Generator | None = None,
        step_s: float = 0.1,
        vibration: str = "none",
    ) -> None:
        self.num_envs = int(num_envs)
        self.stage = int(stage)
        self.sigma = float(jitter_sigma_fs)
        self.clip = float(jitter_clip_sigmas) * self.sigma
        self.slope_min = float(drift_slope_min_fs)
        self.slope_max = float(drift_slope_max_fs)
        self.per_stage = bool(drift_per_stage)
        self.knot_min = int(drift_knot_min_steps)
        self.knot_max = int(drift_knot_max_steps)
        self.bound = float(drift_bound_fs)
        self.turn_steps = int(drift_turn_steps)
        self.initial_sigma = float(initial_sigma_fs)
        self.initial_clip = float(initial_clip_sigmas) * self.initial_sigma
        self.initial_offset = float(initial_offset_sigmas) * self.initial_sigma
        self.drift_enabled = self.slope_max > 0.0
        self.knots = self.drift_enabled and self.knot_max > 0
        self.step_s = float(step_s)
        self.vibration_name = str(vibration)
        self.restart(rng if rng is not None else np.random.default_rng())

    @classmethod
    def from_config(cls, config, num_envs: int, rng: np.random.Generator | None = None):
        """The disturbance ``config`` describes, in steps of its ``step_s`` under ``time_base``
        seconds (``config.time_scale`` 1, the figures as they are, under ``step``)."""
        scale = config.time_scale
        walk_scale = float(np.sqrt(scale))
        return cls(
            num_envs=num_envs,
            stage=config.stage,
            jitter_sigma_fs=config.jitter_sigma_fs * walk_scale,
            jitter_clip_sigmas=config.jitter_clip_sigmas,
            drift_slope_min_fs=config.cycles_to_fs(config.drift_slope_min_cycles) * scale,
            drift_slope_max_fs=config.cycles_to_fs(config.drift_slope_max_cycles) * scale,
            drift_per_stage=config.drift_per_stage,
            drift_knot_min_steps=loop_steps(config.drift_knot_min_steps, scale),
            drift_knot_max_steps=loop_steps(config.drift_knot_max_steps, scale),
            drift_bound_fs=config.cycles_to_fs(config.drift_bound_cycles),
            drift_turn_steps=round(config.drift_turn_s / (REFERENCE_STEP_S * scale)),
            initial_sigma_fs=config.initial_sigma_fs,
            initial_clip_sigmas=config.initial_clip_sigmas,
            initial_offset_sigmas=config.initial_offset_sigmas,
            rng=rng,
            step_s=config.step_s,
            vibration=config.vibration,
        )

    # ------------------------------------------------------------------ episodes
    def restart(self, rng: np.random.Generator) -> None:
        """Start the process again with a new generator: zero offsets and drift, fresh knot slopes.

        Episodes are then begun with :meth:`new_episodes`."""
        self.rng = rng
        self.global_step = 0
        shape = (self.num_envs, self.stage)
        self.walk = np.zeros(shape)  # initial error + random walk of each line
        self.mu = np.zeros(shape)  # drift accumulated in this episode
        self.slope = np.zeros(shape)  # drift per control step
        self.steps_left = np.full(shape, _FOREVER, dtype=np.int64)
        self.turn_left = np.zeros(shape, dtype=np.int64)  # steps left of a smooth turn
        self.turn_rate = np.zeros(shape)  # its change of slope per step
        self.turn_to = np.zeros(shape)  # the slope it ends on
        self._turning = False
        self._bound_safe = self._knot_in = _FOREVER
        if self.knots:
            self._redraw_knots(np.ones(shape, dtype=bool))
        # the vibration's clock: t = time0 + (global_step - step0) * step_s
        self._time0, self._step0 = 0.0, 0
        self.vibration = make_vibration(self.vibration_name, self.num_envs, self.stage, rng)

    def continue_from(self, other: DelayNoise) -> None:
        """Carry on where ``other`` (the same lines under other figures) is: its walk and
        accumulated drift become this walk (the drift process starts afresh), its clock runs
        on at this ``step_s``, and its vibration goes on where the preset is the same."""
        self.walk = other.walk + other.mu
        self._time0, self._step0 = other.time_s, self.global_step
        if other.vibration_name == self.vibration_name:
            self.vibration = other.vibration

    def place(self, errors: np.ndarray) -> None:
        """Make e_t equal ``errors`` (num_envs, stage) fs now: the walk takes the difference."""
        if self.vibration is None:
            self.walk = errors - self.mu
        else:
            self.walk = errors - (self.mu + self.vibration.at(self.time_s))

    @property
    def time_s(self) -> float:
        """Physical time since the process started (steps x ``step_s``), s."""
        return self._time0 + (self.global_step - self._step0) * self.step_s

    def new_episodes(self, mask) -> None:
        """Draw the initial delay errors (and, for per-episode drift, mu) where ``mask`` is True."""
        mask = np.asarray(mask, dtype=bool)
        count = int(mask.sum())
        if count == 0:
            return
        e0 = self.rng.standard_normal((count, self.stage))
        e0 *= self.initial_sigma
        np.clip(e0, -self.initial_clip, self.initial_clip, out=e0)
        if self.initial_offset > 0.0:
            e0 += self.rng.uniform(-self.initial_offset, self.initial_offset, size=(count, 1))
        self.walk[mask] = e0
        self.mu[mask] = 0.0
        if self._turning:
            self.turn_left[mask] = 0
        if self.drift_enabled and not self.knots:
            self.slope[mask] = self._draw_slopes(count)
        self._update_bound_safe()

    def _draw_slopes(self, count: int) -> np.ndarray:
        """(count, stage) slopes: |slope| uniform in [min, max], random sign, maybe shared."""
        cols = self.stage if self.per_stage else 1
        mag = self.rng.uniform(self.slope_min, self.slope_max, size=(count, cols))
        sign = np.where(self.rng.random((count, cols)) < 0.5, -1.0, 1.0)
        return np.broadcast_to(mag * sign, (count, self.stage))

    def _redraw_knots(self, where: np.ndarray) -> None:
        if not self.per_stage:  # a knot of one stage is a knot of its whole env
            where = np.repeat(where.any(axis=1, keepdims=True), self.stage, axis=1)
        rows = where.any(axis=1)
        slopes = self._draw_slopes(int(rows.sum()))
        self.slope[rows] = np.where(where[rows], slopes, self.slope[rows])
        if self._turning:  # a knot ends a turn under way
            self.turn_left[where] = 0
        lengths = self.rng.integers(self.knot_min, self.knot_max + 1, size=where.shape)
        if not self.per_stage:
            lengths[:] = lengths[:, :1]
        self.steps_left[where] = lengths[where]
        self._knot_in = int(self.steps_left.min())
        self._update_bound_safe()

    def _update_bound_safe(self) -> None:
        """Steps that can skip the |mu| > bound check: |mu| grows by at most max|slope| a step,
        so for ``_bound_safe`` steps no element can cross (one step of margin for rounding)."""
        speed = float(np.abs(self.slope).max()) if self.slope.size else 0.0
        room = self.bound - float(np.abs(self.mu).max(initial=0.0)) - speed * self._turn_lead
        if self._turning:
            self._bound_safe = 0
        elif speed == 0.0 or not np.isfinite(room):
            self._bound_safe = _FOREVER
        else:
            self._bound_safe = max(int(room / speed) - 1, 0)

    # ------------------------------------------------------------------ stepping
    @property
    def offset(self) -> np.ndarray:
        """e_t, (num_envs, stage) fs: what each line adds to its set-point now (a fresh array)."""
        return self.sample(advance=False)

    @property
    def slow_offset(self) -> np.ndarray:
        """The walk and the drift without the vibration (a fresh array), fs."""
        return self.walk + self.mu

    def sample(self, advance: bool = True) -> np.ndarray:
        """Return e_t (a fresh (num_envs, stage) array, fs); ``advance``: take one step first."""
        if advance:
            self.global_step += 1
            inc = self.rng.standard_normal((self.num_envs, self.stage))
            inc *= self.sigma
            np.clip(inc, -self.clip, self.clip, out=inc)
            self.walk += inc
            if self.drift_enabled:
                self._advance_drift()
        out = self.walk + self.mu if self.drift_enabled or not advance else self.walk.copy()
        if self.vibration is not None:
            out += self.vibration.at(self.time_s)
        return out

    def _advance_drift(self) -> None:
        """One step of the drift: mu moves by its slope, turns at the bound, knots redraw."""
        self.mu += self.slope
        if self._turning:
            self._turn_on()
        # The bound and knot checks only run when they can fire (counters kept by
        # _redraw_knots and _update_bound_safe); the result is the same as checking every step.
        self._bound_safe -= 1
        if self._bound_safe < 0:
            if self.turn_steps:
                self._begin_turns()
            else:
                out = np.abs(self.mu) > self.bound
                if out.any():
                    self.slope[out] = -np.sign(self.mu[out]) * np.abs(self.slope[out])
            self._update_bound_safe()
        if self.knots:
            self.steps_left -= 1
            self._knot_in -= 1
            if self._knot_in <= 0:
                knot = self.steps_left <= 0
                if knot.any():
                    self._redraw_knots(knot)
                else:
                    self._knot_in = int(self.steps_left.min())

    @property
    def _turn_lead(self) -> float:
        """Slopes of travel from a smooth turn's start to its peak: one step at v, then the
        slope's first half-turn (T/4 - 1/2); 0 for the one-step turn."""
        return self.turn_steps / 4 + 0.5 if self.turn_steps else 0.0

    def _begin_turns(self) -> None:
        """Begin a smooth turn where the drift heads out and would pass the bound by its peak
        (the slope then goes from v to -v in ``turn_steps`` equal steps and the accumulated
        drift peaks within one step's drift beyond the bound)."""
        speed = np.abs(self.slope)
        begin = (self.slope * self.mu > 0.0) & (self.turn_left == 0)
        begin &= np.abs(self.mu) + speed * self._turn_lead > self.bound
        if begin.any():
            self.turn_to[begin] = -self.slope[begin]
            self.turn_rate[begin] = -2.0 * self.slope[begin] / self.turn_steps
            self.turn_left[begin] = self.turn_steps
            self._turning = True

    def _turn_on(self) -> None:
        """One step of the turns under way (a turn's last step lands on its end slope)."""
        on = self.turn_left > 0
        self.slope[on] += self.turn_rate[on]
        self.turn_left[on] -= 1
        done = on & (self.turn_left == 0)
        self.slope[done] = self.turn_to[done]
        self._turning = bool(self.turn_left.any())
