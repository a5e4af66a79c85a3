"""In-process Gymnasium environment of the optical pulse stacker (the paper's Figure 5 API)."""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from ops_contract.held import check_hold_steps, hold_after, resolve_hold_steps
from ops_contract.observation import ObservationBuilder
from ops_contract.rig_randomization import RigRanges

from .env_setup import ACTION_TYPES, config_arguments, env_setup
from .simulation import BatchedSimulation, StepResult

__all__ = ["ACTION_TYPES", "OpsEnv"]


class OpsEnv(gym.Env):
    """N-stage optical pulse stacking.

    Action: Box [-1, 1]^N. ``action_type="increment"`` (default): set-point changes in units of
    the actuator's max step per control step; ``"absolute"``: set-points in units of
    ``absolute_action_range_cycles`` optical periods. Observation: see
    :mod:`ops_contract.observation` (``observation_options={"history": k}``: the last k
    observations with the actions that led to them; ``{"observation": "authors"}``: the authors'
    observation set, with the applied delays). Reward: eq. (3), -(1 - P_N/P_max)^2.
    Episodes end by truncation after ``max_episode_steps`` steps, never by termination.

    Every episode starts with the set-points at 0 and hidden delay errors drawn as the mode says
    (``reset(options={"setpoints_fs": ..., "delay_errors_fs": ...})`` chooses either instead).
    ``detector="polarizer"`` (default) or ``"total"`` and other overrides go to
    :func:`~ops_contract.config.make_config`.

    ``info``: ``power`` (P_N/P_max), ``delays_fs`` (applied delays: set-point + noise),
    ``setpoints_fs``, ``main_pulse_energy``, ``rejected_energy``, ``clipped``.

    ``rig_randomize`` (``{key: (low, high)}`` of the rig's figures, or a
    :class:`~ops_contract.rig_randomization.RigRanges`): at every reset the env draws its rig
    from its own random stream (the same seed, the same rigs), on top of its configuration
    (``realism`` and the other overrides); ``env.rig`` is the rig of the current episode, and
    ``env.config`` stays the configuration it was built with.

    ``hold_steps`` (:mod:`ops_contract.held`; default 1: none): each ``step`` is one decision of
    ``k`` simulator steps: the action on the first, ``k - 1`` held ones (increment 0) after it,
    fewer where the episode's ``max_episode_steps`` simulator steps end first; the observation,
    reward and info are the last reading's, and the observation's memory holds the decisions'
    readings alone. 0 (auto): k = the latency_steps + 1 of the episode's rig (drawn anew per
    episode with ``rig_randomize``); ``env.hold_steps`` is the current episode's k.

    ``continue_prob`` (default 0): a ``reset`` after an episode ended by truncation carries the
    same run on with this probability instead of starting afresh, as the batched env's
    (:mod:`ops_sim_ros.vec_env`): only the step count restarts; the delay errors, drift,
    set-points, the observation's memory and a drawn rig go on, and the returned observation is
    the last one. A reset with a seed or options, or one in mid-episode, always starts afresh.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(
        self,
        stage: int = 5,
        mode: str = "medium",
        split: str = "train",
        action_type: str = "increment",
        render_mode: str | None = None,
        max_episode_steps: int = 200,
        observation_options: dict[str, Any] | None = None,
        rig_randomize: Any = None,
        hold_steps: int = 1,
        continue_prob: float = 0.0,
        **overrides: Any,
    ) -> None:
        super().__init__()
        self.hold_option = check_hold_steps(hold_steps)
        if not (isinstance(continue_prob, int | float) and 0.0 <= continue_prob < 1.0):
            raise ValueError(f"continue_prob must be in [0, 1) (got {continue_prob!r})")
        self.continue_prob = float(continue_prob)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of None, human, rgb_array (got {render_mode!r})"
            )
        setup = env_setup(
            stage, mode, split, action_type, max_episode_steps, observation_options, overrides
        )
        setup.apply_to(self)
        self.observation_space = setup.observation_space
        self.action_space = setup.action_space
        self.render_mode = render_mode
        self.sim = BatchedSimulation(self.config, num_envs=1, seed=None)
        self.rig_ranges = RigRanges.from_value(rig_randomize)
        self.rig: dict[str, Any] = {}
        for bound in self.rig_ranges.bounds() if self.rig_ranges else ():
            self.config.replace(**bound)  # each end of every range, checked with the rest
        self._observations = ObservationBuilder(self.obs_spec)
        self.hold_steps = resolve_hold_steps(self.hold_option, self.config.latency_steps)
        self._abs_scale = self.config.absolute_action_range_fs
        self._last: StepResult | None = None
        self._last_obs: np.ndarray | None = None
        self._viewer = None

    @classmethod
    def from_config(cls, config, **kwargs: Any) -> OpsEnv:
        """An env running ``config`` (an OpsConfig); ``max_episode_steps`` may be given."""
        return cls(**config_arguments(config, kwargs.pop("max_episode_steps", None)), **kwargs)

    @property
    def optical_period_fs(self) -> float:
        return self.config.optical_period_fs

    def _obs_info(self, r: StepResult, action=None) -> tuple[np.ndarray, dict[str, Any]]:
        args = (r.pulse_energies[0], r.power[0], r.setpoints_fs[0])
        if action is None:  # a new episode
            obs = self._observations.reset(*args, applied_fs=r.applied_fs[0])
        else:
            obs = self._observations.step(*args, action, applied_fs=r.applied_fs[0])
        return obs, self._info(r)

    @staticmethod
    def _info(r: StepResult) -> dict[str, Any]:
        # The simulation makes fresh arrays every step, so views are safe to hand out.
        return {
            "power": float(r.power[0]),
            "delays_fs": r.applied_fs[0],
            "setpoints_fs": r.setpoints_fs[0],
            "main_pulse_energy": float(r.main_pulse_energy[0]),
            "rejected_energy": float(r.rejected_energy[0]),
            "clipped": r.clipped[0],
        }

    def _carries_on(self, seed, options) -> bool:
        """Whether this reset carries the ended run on (``continue_prob``)."""
        return (
            self.continue_prob > 0.0
            and seed is None
            and not options
            and self._last is not None
            and self._last_obs is not None
            and bool(self._last.truncated[0])
            and self.np_random.random() < self.continue_prob
        )

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if self._carries_on(seed, options):
            self.sim.continue_episodes(np.ones(1, dtype=bool))
            self._last = self.sim.last
            return self._last_obs.copy(), self._info(self._last)
        if self.rig_ranges:  # a rig of its own for this episode, drawn from the env's stream
            self.rig = self.rig_ranges.draw(self.np_random)
            self.sim.use_rig(self.config.replace(**self.rig))
        self.hold_steps = resolve_hold_steps(self.hold_option, self.sim.config.latency_steps)
        if seed is not None:
            # Same seed -> same episode: restart the simulation's random stream and its drift.
            r = self.sim.reset(seed=self.np_random)
        else:
            if self.sim.rng is not self.np_random:
                self.sim.use_rng(self.np_random)
            r = self.sim.reset()
        options = options or {}
        if "setpoints_fs" in options or "delay_errors_fs" in options:
            # A chosen start: set-points and/or the hidden delay errors of the lines (fs).
            r = self.sim.place(options.get("setpoints_fs"), options.get("delay_errors_fs"))
        self._last = r
        obs, info = self._obs_info(r)
        self._last_obs = obs
        if self.render_mode == "human":
            self.render()
        return obs, info

    def step_setpoints(self, setpoints_fs) -> StepResult:
        """One step to absolute set-points (fs, one per stage), as the simulator node takes a
        delay command; returns the simulation's step result (batched by 1)."""
        if self._last is None:
            raise RuntimeError("call reset() before step_setpoints()")
        self._last_obs = None  # no observation made: a run stepped so does not carry on
        self._last = self.sim.step_setpoints(np.asarray(setpoints_fs, dtype=np.float64)[None, :])
        return self._last

    def step(self, action):
        if self._last is None:
            raise RuntimeError("call reset() before step()")
        if self.action_type == "increment":
            r = self.sim.step_increments(action)
        else:
            a = np.asarray(action, dtype=np.float64).reshape(1, self.stage)
            r = self.sim.step_setpoints(np.clip(a, -1.0, 1.0) * self._abs_scale)
        r = hold_after(self.sim, r, self.hold_steps)
        self._last = r
        obs, info = self._obs_info(r, action)
        self._last_obs = obs
        if self.render_mode == "human":
            self.render()
        return obs, float(r.reward[0]), False, bool(r.truncated[0]), info

    # ------------------------------------------------------------------ rendering
    def trace(self) -> np.ndarray:
        """The detected output intensity trace of the last step, (S * samples_per_slot,)."""
        if self._last is None:
            raise RuntimeError("call reset() first")
        return self.sim.trace(self._last)[0]

    def render(self):
        if self.render_mode is None or self._last is None:
            return None
        from . import rendering

        title = f"{self.stage}-stage OPS, {self.config.mode}"
        power = float(self._last.power[0])
        args = (self.trace(), self.config.samples_per_slot, self.config.pulse_spacing_fs)
        if self.render_mode == "rgb_array":
            return rendering.render_rgb(*args, power=power, title=title)
        if self._viewer is None:
            self._viewer = rendering.HumanViewer()
        self._viewer.show(*args, power=power, title=title)
        return None

    def close(self) -> None:
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
