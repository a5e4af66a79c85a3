"""Delay-line noise of eq. (2)/(4): e_t ~ N(mu_t, sigma), batched over environments and stages.

* jitter: independent Gaussian, standard deviation ``sigma`` (fs), every step;
* drift mu_t: piecewise linear in time. Each (env, stage) has a slope that is redrawn at random
  knots (segment lengths uniform in [knot_min, knot_max] steps; |slope| uniform in
  [slope_min, slope_max] fs/step, random sign). mu is kept within +-bound by turning the slope
  towards zero when it crosses the bound (still piecewise linear). The drift is driven by a global
  step counter that does NOT restart at episode resets; only :meth:`DelayNoise.restart` (used
  when an episode is reset with an explicit seed) starts it again from mu = 0.
"""

from __future__ import annotations

import numpy as np

_FOREVER = 1 << 62


class DelayNoise:
    """Stateful noise generator for ``num_envs`` x ``stage`` delay lines (all values in fs)."""

    def __init__(
        self,
        num_envs: int,
        stage: int,
        jitter_sigma_fs: float,
        drift_slope_min_fs: float = 0.0,
        drift_slope_max_fs: float = 0.0,
        drift_knot_min_steps: int = 100,
        drift_knot_max_steps: int = 300,
        drift_bound_fs: float = np.inf,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.num_envs = int(num_envs)
        self.stage = int(stage)
        self.sigma = float(jitter_sigma_fs)
        self.slope_min = float(drift_slope_min_fs)
        self.slope_max = float(drift_slope_max_fs)
        self.knot_min = int(drift_knot_min_steps)
        self.knot_max = int(drift_knot_max_steps)
        self.bound = float(drift_bound_fs)
        self.drift_enabled = self.slope_max > 0.0
        self.restart(rng if rng is not None else np.random.default_rng())

    @classmethod
    def from_config(cls, config, num_envs: int, rng: np.random.Generator | None = None):
        return cls(
            num_envs=num_envs,
            stage=config.stage,
            jitter_sigma_fs=config.jitter_sigma_fs,
            drift_slope_min_fs=config.cycles_to_fs(config.drift_slope_min_cycles),
            drift_slope_max_fs=config.cycles_to_fs(config.drift_slope_max_cycles),
            drift_knot_min_steps=config.drift_knot_min_steps,
            drift_knot_max_steps=config.drift_knot_max_steps,
            drift_bound_fs=config.cycles_to_fs(config.drift_bound_cycles),
            rng=rng,
        )

    def restart(self, rng: np.random.Generator) -> None:
        """Start the drift process again (mu = 0, fresh slopes) with a new random generator."""
        self.rng = rng
        self.global_step = 0
        shape = (self.num_envs, self.stage)
        self.mu = np.zeros(shape)
        self.slope = np.zeros(shape)
        self.steps_left = np.zeros(shape, dtype=np.int64)
        self._bound_safe = self._knot_in = _FOREVER
        if self.drift_enabled:
            self._redraw(np.ones(shape, dtype=bool))

    def _redraw(self, where: np.ndarray) -> None:
        count = int(where.sum())
        mag = self.rng.uniform(self.slope_min, self.slope_max, size=count)
        sign = np.where(self.rng.random(count) < 0.5, -1.0, 1.0)
        self.slope[where] = mag * sign
        self.steps_left[where] = self.rng.integers(self.knot_min, self.knot_max + 1, size=count)
        self._knot_in = int(self.steps_left.min())
        self._update_bound_safe()

    def _update_bound_safe(self) -> None:
        """Steps that can skip the |mu| > bound check: |mu| grows by at most max|slope| a step,
        so for ``_bound_safe`` steps no element can cross (one step of margin for rounding)."""
        speed = float(np.abs(self.slope).max()) if self.slope.size else 0.0
        room = self.bound - float(np.abs(self.mu).max(initial=0.0))
        if speed == 0.0 or not np.isfinite(room):
            self._bound_safe = _FOREVER
        else:
            self._bound_safe = max(int(room / speed) - 1, 0)

    def sample(self, advance: bool = True) -> np.ndarray:
        """Return e_t, shape (num_envs, stage), in fs; ``advance``: move the drift one step first.

        Episode resets measure without advancing (fresh jitter, same drift), so the drift is a
        function of the number of control steps only.
        """
        e = self.rng.standard_normal((self.num_envs, self.stage))
        e *= self.sigma
        if not advance:
            e += self.mu
            return e
        self.global_step += 1
        if self.drift_enabled:
            self.mu += self.slope
            # The bound and knot checks only run when they can fire (counters kept by _redraw
            # and _update_bound_safe); the result is the same as checking every step.
            self._bound_safe -= 1
            if self._bound_safe < 0:
                out = np.abs(self.mu) > self.bound
                if out.any():
                    self.slope[out] = -np.sign(self.mu[out]) * np.abs(self.slope[out])
                self._update_bound_safe()
            self.steps_left -= 1
            self._knot_in -= 1
            if self._knot_in <= 0:
                knot = self.steps_left <= 0
                if knot.any():
                    self._redraw(knot)
                else:
                    self._knot_in = int(self.steps_left.min())
            e += self.mu
        return e
