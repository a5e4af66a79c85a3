"""What is evaluated and on which environment: a controller or a learned policy, run on episodes.

One :class:`Subject` serves ``evaluate`` (a model directory or ``--controller``), ``evaluate
--continuous`` and ``--record``, and every benchmark run
(:mod:`ops_experiments.table1.bench_worker`):
``Subject.run(split, episodes, steps, seed)`` returns the episodes of one evaluation seed
(:mod:`.rollouts`), which :func:`ops_experiments.summary.summarize` reduces.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from ops_contract.config import make_config

from .rollouts import rollout_controller, rollout_policy, rollout_runner


@dataclass
class Subject:
    """A controller (by name, with parameters) or a learned model (a
    :class:`~ops_controller_ros.runner_factory.ModelStack`: read and loaded once, its hold
    resolved), and the environment it runs on: stage, mode, detector, the rig both the simulator
    and the controller know, and ``env_overrides`` the controller is not told of."""

    name: str
    stage: int
    mode: str
    detector: str
    env_overrides: dict[str, Any]
    meta: dict[str, Any] = field(default_factory=dict)
    rig: dict[str, Any] = field(default_factory=dict)  # known to both sim and controller
    controller: str | None = None
    controller_params: dict[str, Any] = field(default_factory=dict)
    model: Any = None  # ModelStack
    #: The configuration a controller is built for; None: the run's own (stage, mode, split,
    #: detector, rig). The benchmark tells every controller the same nominal rig.
    nominal: Any = None
    #: A policy runs on the controllers' very episodes (one env per episode, the same initial
    #: errors and noise draws: the benchmark) instead of one batched vector env (``evaluate``).
    paired: bool = False
    #: Readings per decision of a policy (resolved: >= 1; ``evaluate --hold-steps``): k > 1 runs
    #: it through :class:`~ops_controller_ros.policy_hold.HeldRunner`, as the policy node does.
    hold_steps: int = 1

    @property
    def policy(self):
        """The model's acting policy (a ``LoadedPolicy``; None for a controller)."""
        return None if self.model is None else self.model.policy

    def with_mode(self, mode: str) -> Subject:
        """The same subject on another mode's environment (the benchmark's transfer)."""
        return dataclasses.replace(self, mode=mode)

    def nominal_config(self, split: str, steps: int):
        """The configuration the controller is built for (no --env overrides)."""
        return self.nominal if self.nominal is not None else self._config(split, steps)

    def sim_config(self, split: str, steps: int):
        """The configuration the simulator runs (with the --env overrides)."""
        return self._config(split, steps).replace(**self.env_overrides)

    def _config(self, split: str, steps: int):
        return make_config(
            self.stage, self.mode, split, detector=self.detector, episode_steps=steps, **self.rig
        )

    def observation_options(self) -> dict[str, Any] | None:
        """The policy's observation choices (memory included), as the policy runner builds
        them (``policy_io.run_observation_spec``); None for a controller."""
        if self.model is None:
            return None
        from ops_controller_ros.policy_io import run_observation_spec

        return run_observation_spec(self.model.meta).options()

    def run(self, split: str, episodes: int, steps: int, seed: int) -> dict[str, np.ndarray]:
        """``episodes`` episodes of ``steps`` steps of evaluation seed ``seed`` on ``split``."""
        sim = self.sim_config(split, steps)
        if self.controller is not None:
            nominal = self.nominal_config(split, steps)
            return rollout_controller(
                self.controller, self.controller_params, nominal, sim, episodes, steps, seed
            )
        model = dataclasses.replace(self.model, hold_steps=self.hold_steps)
        if model.layered:  # switching, watchdog or held: the runner, reading by reading
            return rollout_runner(model.build(episodes), sim, episodes, steps, seed)
        options = self.observation_options()
        return rollout_policy(
            self.model.predictor(), sim, episodes, steps, seed, options, paired=self.paired
        )

    def evaluate(
        self, splits, seeds, episodes: int, steps: int, progress=None
    ) -> dict[str, dict[str, Any]]:
        """The summary (:func:`~ops_experiments.summary.summarize`) of each split
        over ``seeds``; ``progress(split, seed, result)`` is called after each seed's run."""
        from .summary import summarize

        out = {}
        for split in splits:
            per_seed = []
            for seed in seeds:
                per_seed.append(self.run(split, episodes, steps, seed))
                if progress is not None:
                    progress(split, seed, per_seed[-1])
            out[split] = summarize(per_seed)
        return out
