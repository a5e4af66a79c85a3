"""ops-bench rate-sweep and its loop (ops_experiments.timed_loop): the compute cap, the residual
phase, the figures taken chunk by chunk, and a tiny sweep that stores, resumes and reports."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ops_experiments.continuous import lock_figures
from ops_experiments.timed_loop import (
    CappedLoop,
    RunStats,
    phase_mrad,
    start_loop,
    steps_for,
    timed_config,
)
from ops_sim_ros.simulation import BatchedSimulation

from ops_bench import rate_sweep


def test_phase_of_a_known_delay_error():
    period = 3.4357
    errors = np.array([0.01, -0.01, 1.01, -2.01, 0.25]) * period
    expected = np.array([0.01, -0.01, 0.01, -0.01, 0.25]) * 2000.0 * np.pi
    assert np.allclose(phase_mrad(errors, period), expected)
    # a whole number of periods is no error at all; half a period is the largest
    assert np.allclose(phase_mrad(np.array([0.0, 3.0, -7.0]) * period, period), 0.0, atol=1e-9)
    assert abs(phase_mrad(0.4999 * period, period)) < 1000 * np.pi


def test_steps_for_a_compute():
    assert steps_for(0.0, 0.001) == 1
    assert steps_for(0.0009, 0.001) == 1
    assert steps_for(0.001, 0.001) == 1
    assert steps_for(0.00101, 0.001) == 2
    assert steps_for(0.25, 0.1) == 3


class Recorder:
    """A controller that asks for new set-points at every answer and records what it is told."""

    stage = 5

    def __init__(self):
        self.answers = 0
        self.told = []

    def command(self):
        return np.full(self.stage, float(self.answers))

    def observe(self, power, pulse_energies=None, steps=1, command_age=None):
        self.answers += 1
        self.told.append((steps, command_age))


def recorded_loop(rate_hz: float, compute_ms, wait_steps: int = 0):
    config = timed_config(rate_hz, realism="ideal", vibration="none", latency_ms=0, lag_ms=0)
    sim = BatchedSimulation(config, 1, seed=1)
    sim.reset(seed=1)
    taken = []
    step = sim.step_setpoints

    def spy(setpoints):
        taken.append(np.array(setpoints, dtype=float).ravel()[0])
        return step(setpoints)

    sim.step_setpoints = spy
    ctl = Recorder()
    return CappedLoop(sim, ctl, compute_ms=compute_ms, wait_steps=wait_steps), ctl, taken


@pytest.mark.parametrize("k", [1, 3])
def test_a_capped_controller_commands_every_k_steps(k):
    # a compute of (k - 0.5) periods: the answer to a reading is taken k steps on
    loop, ctl, taken = recorded_loop(1000.0, compute_ms=k - 0.5)
    loop.run(10 * k)
    # the n-th answer (set-points n) comes from the reading of step n k, taken at step (n + 1) k
    changes = [i + 1 for i in range(1, len(taken)) if taken[i] != taken[i - 1]]
    assert changes == list(range(2 * k, 10 * k + 1, k))
    assert [taken[c - 1] for c in changes] == list(range(1, 10))
    assert ctl.answers == 10  # one reading per command
    assert all(told == (k, 0) for told in ctl.told)  # k steps between readings; just taken
    assert loop.compute_figures()["steps_per_command_median"] == k


class Thinker(Recorder):
    """A controller whose work after the command (``think``) takes 25 ms of CPU, the first
    time revising the command it gave."""

    def __init__(self):
        super().__init__()
        self.commands = 0
        self.thought = 0

    def command(self):
        self.commands += 1
        return np.full(self.stage, float(self.commands))

    def think(self):
        import time

        t0 = time.thread_time()
        while time.thread_time() - t0 < 0.025:
            pass
        self.thought += 1
        return self.thought == 1


def test_the_work_after_the_command_delays_the_next_reading_not_the_answer():
    config = timed_config(100.0, realism="ideal", vibration="none", latency_ms=0, lag_ms=0)
    sim = BatchedSimulation(config, 1, seed=1)
    sim.reset(seed=1)
    taken, step = [], sim.step_setpoints
    sim.step_setpoints = lambda s: taken.append(float(np.ravel(s)[0])) or step(s)
    ctl = Thinker()
    loop = CappedLoop(sim, ctl, compute_ms=None)  # measured: 25 ms of think is 2.5 steps
    loop.run(100)
    # the first answer is taken at once, its revision when the think ends (step 3) ...
    assert taken[:3] == [1.0, 1.0, 2.0]
    # ... and each reading's work, 2.5 steps and a little, keeps the controller from the next:
    # it works without pause, a reading every 2.5 steps or so (with the think counted in the
    # answer it would be one every 3 steps: 33)
    assert 34 <= ctl.answers <= 40, ctl.answers
    assert {steps for steps, _ in ctl.told} <= {1, 2, 3}


def test_a_policy_waits_for_its_command_to_show():
    # a latency of 2 steps: the next reading is 2 steps after the step that took the command
    loop, ctl, _ = recorded_loop(100.0, compute_ms=0.0, wait_steps=2)
    loop.run(30)
    assert ctl.answers == 10
    assert all(steps == 3 for steps, _ in ctl.told)


def test_measured_compute_sets_the_cap():
    loop, _, _ = recorded_loop(1e5, compute_ms=None)  # 10 us a step: any answer is late
    loop.run(50)
    figures = loop.compute_figures()
    assert figures["compute_ms_median"] > 0
    assert figures["steps_per_command_mean"] >= 1
    assert figures["readings"] >= 1


def test_run_stats_in_chunks_are_the_whole_run_figures():
    rng = np.random.default_rng(5)
    power = np.clip(0.97 + 0.02 * rng.standard_normal(3000), 0, 1)
    power[:40] = np.linspace(0.1, 0.9, 40)  # no lock yet
    for start, length in ((500, 7), (997, 9), (2000, 1), (2990, 10)):  # dips, one at a chunk edge
        power[start : start + length] = 0.5
    applied = rng.normal(0.0, 0.1, (3000, 5))
    stats = RunStats(5, 3.4)
    cuts = np.sort(rng.choice(np.arange(1, 3000), 30, replace=False))
    for p, a in zip(np.split(power, cuts), np.split(applied, cuts), strict=True):
        stats.update(p, a)
    got, want = stats.figures(), lock_figures(power)
    assert got["first_lock_step"] == want["first_lock_step"] + 1
    assert got["losses"] == want["losses"] == 4
    assert got["longest_loss"] == max(want["loss_lengths"]) == 10
    assert got["locked_fraction"] == pytest.approx(want["locked_fraction"], abs=1e-6)
    assert got["worst_after_lock"] == pytest.approx(want["worst_after_lock"])
    tail = power[want["first_lock_step"] :]
    assert got["power_mean"] == pytest.approx(tail.mean(), abs=1e-6)
    assert got["power_rms_pct"] == pytest.approx(100 * tail.std() / tail.mean(), abs=1e-3)
    phases = phase_mrad(applied[want["first_lock_step"] :], 3.4)
    assert got["residual_mrad_stages"] == pytest.approx(np.sqrt((phases**2).mean(0)), abs=1e-3)


def test_a_loop_that_never_locks_has_no_residual():
    stats = RunStats(5, 3.4)
    stats.update(np.full(10, 0.5), np.zeros((10, 5)))
    figures = stats.figures()
    assert figures["first_lock_step"] is None and figures["residual_mrad"] is None


def test_the_latency_in_ms_becomes_steps_of_each_rate():
    assert timed_config(10, latency_ms=1.0).latency_steps == 0
    assert timed_config(1000, latency_ms=1.0).latency_steps == 1
    assert timed_config(1000, latency_ms=10.0).latency_steps == 10
    assert timed_config(300, lag_ms=1.0).actuator_lag_steps == pytest.approx(0.3)
    config = timed_config(100)
    assert config.time_base == "seconds" and config.step_s == pytest.approx(0.01)
    assert config.vibration == "lab" and config.realism == "lab"


def test_spgd_in_the_loop_is_told_its_rig(tmp_path):
    loop = start_loop("spgd", timed_config(1000, latency_ms=2.0), seed=3, compute_ms=0.0)
    assert loop.ctl.latency == 2
    power, applied = loop.run(20)
    assert power.shape == (20,) and applied.shape == (20, 5)


def test_a_tiny_sweep_stores_resumes_and_reports(tmp_path, capsys):
    out, fig = tmp_path / "sweep", tmp_path / "sweep.png"
    argv = ["--controllers", "spgd", "--rates", "100", "1000", "--seeds", "1", "--seconds",
            "0.05", "--compute-ms", "spgd=1.5", "--out", str(out), "--figure", str(fig),
            "--no-progress"]  # fmt: skip
    assert rate_sweep.main(argv) == 0
    cells = [json.loads(line) for line in (out / "cells.jsonl").read_text().splitlines()]
    assert sorted(c["rate_hz"] for c in cells) == [100.0, 1000.0]
    by_rate = {c["rate_hz"]: c for c in cells}
    assert by_rate[1000.0]["steps_per_command_median"] == 2  # 1.5 ms at 1 kHz
    assert by_rate[100.0]["steps_per_command_median"] == 1
    assert by_rate[1000.0]["steps"] == 50 and by_rate[100.0]["steps"] == 5
    capsys.readouterr()
    assert rate_sweep.main(argv) == 0  # everything stored: nothing runs again
    assert "0 cells to run" in capsys.readouterr().out
    assert len((out / "cells.jsonl").read_text().splitlines()) == 2
    page = (out / "index.md").read_text()
    assert "| spgd | 100 Hz |" in page and "| spgd | 1000 Hz | 2 (500 Hz)" in page
    assert fig.exists() and fig.stat().st_size > 0


def test_bad_compute_figures_are_refused(tmp_path):
    assert rate_sweep.main(["--compute-ms", "spgd", "--out", str(tmp_path)]) == 2
    assert rate_sweep.main(["--compute-ms", "spgd=-1", "--out", str(tmp_path)]) == 2


def test_the_reference_leaves_little_without_vibration_and_no_more_than_it():
    from ops_experiments.timed_loop import run_for

    quiet, shaken = (timed_config(100, vibration=v) for v in ("none", "lab"))
    figures = {}
    for name, config in (("quiet", quiet), ("shaken", shaken)):
        loop = start_loop("oracle", config, seed=4)
        stats = RunStats(5, config.optical_period_fs)
        run_for(loop, 300, stats)
        figures[name] = stats.figures()
    # the walk of one 10 ms period is ~2 mrad; the rig's hysteresis and lag add a little
    assert figures["quiet"]["residual_mrad"] < 20.0
    assert figures["quiet"]["first_lock_step"] <= 3
    # lab vibration is 121 mrad rms per line: a reference that knows it leaves no more
    assert 20.0 < figures["shaken"]["residual_mrad"] < 125.0
