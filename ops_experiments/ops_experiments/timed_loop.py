"""A controller in physical time, in process: a loop rate, a rig's latency in ms, the controller's
own compute, and the figures a lab asks of a run (``ops-bench rate-sweep``, ``ops-bench soak``).

The simulator runs under ``time_base`` seconds (``step_s`` = 1 / rate; docs/physics.md,
"Physical time"), so a simulated second holds the same random walk, drift and vibration at any
rate. The rig's latency and the delay lines' response are given in milliseconds and become steps
of the loop (:func:`timed_config`), as the simulator node's ``latency_ms`` and
``actuator_lag_ms`` do.

**The controller's compute caps its rate** (:class:`CappedLoop`). A reading whose answer costs
the controller ``c`` (``observe`` and the next ``command``) is answered by a command that the
simulator takes on the first step whose reading comes after the answer: ``k = ceil(c / step_s)``
steps after the reading (1 when it fits in a period, the lockstep loop's convention). Until then
the set-points hold (the same command, as :mod:`ops_contract.held` holds a decision), and the
controller's next reading is the first to show its command: it issues one command every ``k``
steps and is told the steps between its readings (``observe(steps=k)``) and that the step just
taken carried its command (``command_age`` 0), as a node on a free-running simulator is. The
work a controller does once the command is out (``think()``: the tracker's deferred knot test,
or its fit under ``answer_first``) is done as a node does it: after the answer, keeping the
controller from its next reading until it ends, and a command it revised is taken when it
ends. Each part's compute is measured (thread CPU time, so other processes' load does not count;
``compute_scale`` for a machine faster or slower than this one) or fixed (``compute_ms``, for
the answer, the work after it then counting for nothing: reproducible runs and tests).

A learned policy is not told of a latency: it decides only on readings that show its last
command (``wait_steps`` = the told latency; with ``k`` = 1 the hold of ``hold_steps`` auto,
:mod:`ops_controller_ros.policy_hold`, here done by the loop). Tracker and SPGD are told the
latency (they take every reading they can).

**Figures** (:class:`RunStats`), over every simulator step (each step is a reading of the
detector, whether or not the controller takes it), from the first step at P_N/P_max >= 0.95 on:
the residual phase error of each stage, 2 pi x (its delay error to the nearest whole optical
period) / optical period, rms in mrad (:func:`phase_mrad`); P_N/P_max's mean and rms fluctuation
(standard deviation over mean, %), the fraction at or above 0.95 and the lock losses of
:mod:`ops_experiments.continuous` (runs below 0.8), counted chunk by chunk so an hours-long run
keeps no per-step arrays.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from ops_contract.config import LIMITS, make_config

from .continuous import LOCK, LOSS

#: The controllers by name, each (the controller, its parameters): ``tracker-answer-first``
#: is the tracker that answers each reading by its prediction and fits after (``answer_first``,
#: for a fast loop: docs/loop_rate.md); ``tracker-fit-every-4`` also fits one reading in four
#: (``fit_every``, for a node short of CPU).
CONTROLLERS = {
    "tracker": ("tracker", {}),
    "tracker-answer-first": ("tracker", {"answer_first": True}),
    "tracker-fit-every-4": ("tracker", {"answer_first": True, "fit_every": 4}),
    "spgd": ("spgd", {}),
}
CONTROLLER_NAMES = tuple(CONTROLLERS)
#: Not a controller a rig can run: :class:`TrueErrorReference`, the floor of the others.
REFERENCE = "oracle"


def timed_config(
    rate_hz: float,
    *,
    stage: int = 5,
    mode: str = "hard",
    split: str = "test",
    realism: str = "lab",
    vibration: str = "lab",
    latency_ms: float = 1.0,
    lag_ms: float = 1.0,
    rig: dict | None = None,
    drift_turn_s: float = 0.0,
):
    """The configuration of a loop at ``rate_hz`` in physical time: ``realism``'s rig with its
    latency (``latency_ms``, rounded to steps) and the delay lines' response time (``lag_ms``,
    in steps, not rounded) given in ms, ``vibration``, the rig's other figures changed by
    ``rig`` (OpsConfig fields: ``trace_adc_bits``, ``actuator_hysteresis``, ...) and the
    drift's turns at its bound taking ``drift_turn_s`` seconds (0: one step)."""
    step_s = 1.0 / float(rate_hz)
    latency = round(float(latency_ms) / 1000.0 / step_s)
    lag = float(lag_ms) / 1000.0 / step_s
    high = LIMITS["actuator_lag_steps"][1]
    return make_config(
        stage,
        mode,
        split,
        realism=realism,
        time_base="seconds",
        step_s=step_s,
        vibration=vibration,
        latency_steps=latency,
        actuator_lag_steps=min(lag, high),
        drift_turn_s=float(drift_turn_s),
        **(rig or {}),
    )


def steps_for(compute_s: float, step_s: float) -> int:
    """Steps from a reading to the step that takes its answer: ceil(compute / period), at least
    1 (a compute within a hair of a whole number of periods counts as that number)."""
    return max(1, math.ceil(float(compute_s) / float(step_s) - 1e-9))


def phase_mrad(applied_fs, period_fs: float) -> np.ndarray:
    """Each delay error's phase to the nearest whole optical period, mrad (same shape)."""
    cycles = np.asarray(applied_fs, dtype=np.float64) / float(period_fs)
    return (cycles - np.rint(cycles)) * (2000.0 * np.pi)


def label_of(name: str) -> str:
    """A controller's name in tables: one of :data:`CONTROLLERS`, ``oracle`` or a model
    folder's."""
    if name in CONTROLLER_NAMES or name == REFERENCE:
        return name
    return str(name).rstrip("/").split("/")[-1]


class TrueErrorReference:
    """A reference for every controller at a loop rate and latency, not one a rig can run: at
    each reading it knows the lines' random walk and drift exactly (the commands in flight
    counted, as :func:`ops_experiments.oracle.oracle_increments` counts them; the drift's slope
    carried over the latency) and the vibration's value then, and commands the lines to where
    cancels them when the command acts. The vibration then is predicted from its value at the
    reading by the best linear factor for that lag, its autocorrelation over (latency + 1)
    periods (from the preset's lines and floor; 0 where the lag decorrelates it, so a slow loop
    does not chase it). What it leaves is roughly what the loop's rate and latency let the
    vibration do (and the actuator's lag and hysteresis, which it ignores)."""

    def __init__(self, sim) -> None:
        self.sim = sim
        self.stage = sim.stage
        self._command = np.array(sim.setpoints_fs[0], dtype=np.float64)
        vibration = sim.noise.vibration
        self.rho = np.zeros(self.stage)
        if vibration is not None:
            lag_s = (sim.config.latency_steps + 1) * sim.config.step_s
            power = vibration.amplitude**2
            self.rho = np.cos(2.0 * np.pi * vibration.hz[0] * lag_s) @ power / power.sum()

    def command(self) -> np.ndarray:
        return self._command.copy()

    def observe(self, power, pulse_energies=None, steps: int = 1, command_age=None) -> None:
        sim, noise = self.sim, self.sim.noise
        ahead = sim.setpoints_fs[0] + noise.slow_offset[0]
        if noise.drift_enabled:
            ahead += (sim.config.latency_steps + 1) * noise.slope[0]
        if noise.vibration is not None:
            ahead += self.rho * noise.vibration.at(noise.time_s)[0]
        period = sim.config.optical_period_fs
        self._command = sim.setpoints_fs[0] - (ahead - period * np.rint(ahead / period))


def make_agent(
    name: str, config, seed: int, setpoints_fs, model=None, params: dict | None = None
) -> tuple[Any, int]:
    """The controller ``name`` (of :data:`CONTROLLERS`, told of ``config``'s rig, with
    ``params`` over its own) or, for a model directory, its policy as a loop controller
    (``model``: its loaded
    :class:`~ops_controller_ros.runner_factory.ModelStack`, read once by the caller; the loop
    holds, so its own hold is 1). Returns (controller, wait_steps): readings a policy lets pass
    after its command is taken (the told latency; 0 for a controller)."""
    if name in CONTROLLER_NAMES:
        from ops_controller_ros.controllers import make_controller

        kind, own = CONTROLLERS[name]
        told = {**own, **(params or {})}
        return make_controller(kind, config, told, setpoints_fs=setpoints_fs, seed=seed), 0
    from ops_controller_ros.policy_node import PolicyController

    stack = model.with_hold(1)
    ctl = PolicyController(stack.build(), stack.meta.max_step_fs, np.asarray(setpoints_fs))
    return ctl, int(config.latency_steps)


def load_model_stack(path: str, stage: int = 5):
    """A model directory read and loaded once, for :func:`make_agent`."""
    from ops_controller_ros.runner_factory import load_model

    return load_model(path, stage=stage)


class CappedLoop:
    """One controller on one simulated rig, its rate capped by its compute (module docstring).

    ``sim``: a :class:`~ops_sim_ros.simulation.BatchedSimulation` of one env, reset. ``ctl``:
    a controller (``command``/``observe``, maybe ``think``). ``compute_ms`` None: each reading's
    measured compute (times ``compute_scale``); a number: that compute for every reading.
    Picklable (with its sim and controller) between calls of :meth:`run`."""

    def __init__(self, sim, ctl, compute_ms=None, wait_steps=0, compute_scale=1.0):
        self.sim, self.ctl = sim, ctl
        self.step_s = float(sim.config.step_s)
        self.compute_ms = None if compute_ms is None else float(compute_ms)
        self.compute_scale = float(compute_scale)
        self.wait = int(wait_steps)
        self.step = 0  # simulator steps taken
        self.setpoints = np.array(sim.setpoints_fs, dtype=np.float64)  # (1, N) in effect
        self.readings = 0  # readings the controller took
        self.compute = ComputeLog()  # each reading's measured compute and steps to its answer
        self._last_read = 0
        self._queue: list[tuple[int, np.ndarray]] = []  # (step that takes it, set-points)
        self._busy_until = 0.0  # when the controller's work of its last reading ends, in steps
        self._answer(first=True)

    def __setstate__(self, state: dict) -> None:
        """A loop stored by a version that held one pending command (a soak's checkpoint)."""
        if "_queue" not in state:
            state["_queue"] = [(state.pop("_take_at"), state.pop("_pending"))]
            state["_busy_until"] = 0.0
        self.__dict__.update(state)

    def _spent_ms(self, measured_ms: float, part: str) -> float:
        """The compute a part of a reading's work counts for: measured (times
        ``compute_scale``), or with a fixed ``compute_ms`` that for the answer and none for
        the work after it."""
        if self.compute_ms is None:
            return measured_ms * self.compute_scale
        return self.compute_ms if part == "answer" else 0.0

    def _answer(self, result=None, first: bool = False) -> None:
        """Take the reading ``result`` (None at the start: the first command, no reading) and
        schedule the answer, as a node gives it: the command when ``observe`` and ``command``
        are done, ``think()`` after it is out, and a command that think revised once that is
        done. The work starts when the controller is free (the work of the reading before may
        still run); the next reading is ``wait`` steps after the step that took the last
        command."""
        start = max(float(self.step), self._busy_until)
        t0 = time.thread_time()
        if not first:
            self.ctl.observe(
                float(result.power[0]),
                result.pulse_energies[0],
                steps=self.step - self._last_read,
                command_age=0,
            )
            self.readings += 1
        command = np.asarray(self.ctl.command(), dtype=np.float64)
        t1 = time.thread_time()
        think = getattr(self.ctl, "think", None)
        revised = think is not None and think()
        t2 = time.thread_time()
        waited_s = (start - self.step) * self.step_s  # (still at the last reading's work)
        answer_s = waited_s + self._spent_ms((t1 - t0) * 1e3, "answer") / 1e3
        done_s = answer_s + self._spent_ms((t2 - t1) * 1e3, "think") / 1e3
        k = steps_for(answer_s, self.step_s)
        self.compute.add((t2 - t0) * 1e3, k, first)
        shape = self.setpoints.shape
        self._queue = [(self.step + k, command.reshape(shape))]
        if revised:  # (sent again at once: the node's revised command)
            again = np.asarray(self.ctl.command(), dtype=np.float64).reshape(shape)
            self._queue.append((self.step + steps_for(done_s, self.step_s), again))
        self._busy_until = self.step + done_s / self.step_s
        self._last_read = self.step
        self._read_at = self._queue[-1][0] + self.wait

    def run(self, steps: int) -> tuple[np.ndarray, np.ndarray]:
        """``steps`` simulator steps: P_N/P_max (steps,) and the applied delays (steps, N) fs of
        each (the detector's reading and the delay errors, whether the controller reads it)."""
        sim = self.sim
        power = np.empty(int(steps))
        applied = np.empty((int(steps), sim.stage))
        for i in range(int(steps)):
            self.step += 1
            while self._queue and self._queue[0][0] <= self.step:
                self.setpoints = self._queue.pop(0)[1]
            result = sim.step_setpoints(self.setpoints)
            power[i] = result.power[0]
            applied[i] = result.applied_fs[0]
            if self.step == self._read_at:
                self._answer(result)
        return power, applied

    def compute_figures(self) -> dict[str, Any]:
        """The measured compute per answer (ms, unscaled) and the steps it took."""
        return {"readings": self.readings, **self.compute.figures()}


class ComputeLog:
    """Each answer's compute (ms, in log-spaced bins of 1 %: a run of hours keeps no list) and
    the steps from its reading to the step that took it."""

    EDGES = np.geomspace(1e-4, 1e5, 2085)  # ms; bins of 1 %

    def __init__(self) -> None:
        self.counts = np.zeros(self.EDGES.size + 1, dtype=np.int64)
        self.answers = 0
        self.late = 0  # answers taken more than one step after their reading
        self.steps = 0  # steps from reading to taking, summed
        self.k_counts: dict[int, int] = {}

    def add(self, ms: float, k: int, first: bool = False) -> None:
        """One answer (``first``: the command before any reading, not counted in the compute)."""
        if not first:
            self.counts[np.searchsorted(self.EDGES, ms)] += 1
        self.answers += 1
        self.late += k > 1
        self.steps += k
        self.k_counts[k] = self.k_counts.get(k, 0) + 1

    def percentile(self, q: float) -> float:
        """The compute at percentile ``q`` (0-100), ms, to the bins' 1 %."""
        total = int(self.counts.sum())
        if total == 0:
            return float("nan")
        i = int(np.searchsorted(np.cumsum(self.counts), q / 100.0 * total))
        i = min(max(i, 1), self.EDGES.size - 1)
        return float(np.sqrt(self.EDGES[i - 1] * self.EDGES[i]))

    def figures(self) -> dict[str, Any]:
        ks = sorted(self.k_counts)
        cum = np.cumsum([self.k_counts[k] for k in ks])
        median_k = ks[int(np.searchsorted(cum, cum[-1] / 2.0))] if ks else 1
        return {
            "compute_ms_median": round(self.percentile(50), 4),
            "compute_ms_p99": round(self.percentile(99), 4),
            "steps_per_command_median": float(median_k),
            "steps_per_command_mean": round(self.steps / max(self.answers, 1), 4),
            "commands_late": int(self.late),
        }


@dataclass
class RunStats:
    """The figures of a run, taken chunk by chunk (module docstring)."""

    stage: int
    period_fs: float
    steps: int = 0
    first_lock_step: int | None = None  # 1-based step of the first reading >= LOCK
    count: int = 0  # readings from the first lock on
    sum_power: float = 0.0
    sum_power2: float = 0.0
    locked: int = 0
    worst_after_lock: float = math.inf
    worst: float = math.inf
    losses: int = 0
    longest_loss: int = 0
    loss_run: int = 0  # length of the loss under way at the chunk's end (0: none)
    sum_phase2: np.ndarray | None = None  # per stage, mrad^2

    def __post_init__(self) -> None:
        if self.sum_phase2 is None:
            self.sum_phase2 = np.zeros(self.stage)

    def update(self, power, applied_fs) -> None:
        """Take the next chunk's readings (steps,) and applied delays (steps, N) fs."""
        p = np.asarray(power, dtype=np.float64).ravel()
        if p.size == 0:
            return
        self.worst = min(self.worst, float(p.min()))
        start = 0
        if self.first_lock_step is None:
            hits = np.flatnonzero(p >= LOCK)
            if hits.size == 0:
                self.steps += p.size
                return
            start = int(hits[0])
            self.first_lock_step = self.steps + start + 1
        self.steps += p.size
        tail = p[start:]
        self.count += tail.size
        self.sum_power += float(tail.sum())
        self.sum_power2 += float(np.dot(tail, tail))
        self.locked += int(np.count_nonzero(tail >= LOCK))
        self.worst_after_lock = min(self.worst_after_lock, float(tail.min()))
        self.sum_phase2 += (phase_mrad(np.asarray(applied_fs)[start:], self.period_fs) ** 2).sum(0)
        self._count_losses(tail < LOSS)

    def _count_losses(self, low: np.ndarray) -> None:
        """Runs of readings below LOSS; a run under way at a chunk's end goes on in the next."""
        m = np.concatenate([[False], low, [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(m))
        starts, ends = edges[0::2], edges[1::2]
        lengths = (ends - starts).tolist()
        if self.loss_run and lengths and starts[0] == 0:
            lengths[0] += self.loss_run  # the run under way goes on: counted already
            self.losses -= 1
        else:
            self.longest_loss = max(self.longest_loss, self.loss_run)
        self.losses += len(lengths)
        self.loss_run = lengths.pop() if lengths and ends[-1] == low.size else 0
        self.longest_loss = max([self.longest_loss, *lengths])

    def figures(self) -> dict[str, Any]:
        """The run's figures (module docstring); None where there is no reading after a lock."""
        out: dict[str, Any] = {
            "steps": self.steps,
            "first_lock_step": self.first_lock_step,
            "readings_after_lock": self.count,
            "worst": None if self.steps == 0 else round(self.worst, 6),
        }
        if self.count == 0:
            keys = ("power_mean", "power_rms_pct", "locked_fraction", "worst_after_lock")
            return {
                **out,
                **dict.fromkeys(keys),
                "losses": 0,
                "longest_loss": 0,
                "residual_mrad": None,
                "residual_mrad_stages": None,
            }
        mean = self.sum_power / self.count
        var = max(self.sum_power2 / self.count - mean * mean, 0.0)
        stages = np.sqrt(self.sum_phase2 / self.count)
        return {
            **out,
            "power_mean": round(mean, 6),
            "power_rms_pct": round(100.0 * math.sqrt(var) / mean, 4),
            "locked_fraction": round(self.locked / self.count, 6),
            "worst_after_lock": round(self.worst_after_lock, 6),
            "losses": self.losses,
            "longest_loss": max(self.longest_loss, self.loss_run),
            "residual_mrad": round(float(np.sqrt(np.mean(stages**2))), 3),
            "residual_mrad_stages": [round(float(s), 3) for s in stages],
        }


def start_loop(
    name: str, config, seed: int, model=None, compute_ms=None, compute_scale=1.0, params=None
):
    """A :class:`CappedLoop` of ``name`` (:func:`make_agent`, with ``params``) on a fresh
    simulator of ``config`` reset with ``seed`` (the controller's seed too)."""
    from ops_sim_ros.simulation import BatchedSimulation

    sim = BatchedSimulation(config, 1, seed=seed)
    result = sim.reset(seed=seed)
    if name == REFERENCE:
        return CappedLoop(sim, TrueErrorReference(sim), 0.0)
    ctl, wait = make_agent(name, config, seed, result.setpoints_fs[0], model, params)
    return CappedLoop(sim, ctl, compute_ms, wait, compute_scale)


def run_for(loop: CappedLoop, steps: int, stats: RunStats, chunk: int = 10_000, on_chunk=None):
    """``steps`` steps of ``loop`` in chunks, each taken by ``stats``; ``on_chunk(n, power,
    applied)`` after each."""
    done = 0
    while done < steps:
        n = min(int(chunk), steps - done)
        power, applied = loop.run(n)
        stats.update(power, applied)
        done += n
        if on_chunk is not None:
            on_chunk(n, power, applied)
