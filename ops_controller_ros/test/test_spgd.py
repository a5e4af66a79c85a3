"""SPGD-PID on the in-process simulation: the paper's algorithm converges where the paper says it
works and stalls where it says it does not; the default one (normalized gradient and restarts)
leaves the side peaks; and the algebra of one iteration."""

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_controller_ros.spgd import PAPER, SpgdParams, SpgdPid
from ops_sim_ros.simulation import BatchedSimulation


def run_spgd(stage, mode, seed, iterations=200, params=None):
    sim = BatchedSimulation(make_config(stage=stage, mode=mode), num_envs=1, seed=seed)
    sim.reset(seed=seed)
    ctrl = SpgdPid(stage, params, setpoints_fs=sim.setpoints_fs[0], seed=seed)
    powers = []
    for _ in range(iterations):
        for _ in range(2):
            result = sim.step_setpoints(ctrl.command()[None, :])
            ctrl.observe(result.power[0])
        powers.append(result.power[0])
    return np.array(powers), ctrl


def test_paper_spgd_easy_mode_stage5_mostly_reaches_095_within_200_iterations():
    # The seed's easy mode starts up to 0.32 cycles off per stage, so a local method sometimes
    # starts in a local optimum's basin: 17 of 20 seeds reach 0.99 (measured), 3 stall.
    finals = []
    for seed in range(10):
        powers, ctrl = run_spgd(5, "easy", seed, params=SpgdParams(**PAPER))
        assert ctrl.iterations == 200
        finals.append(powers[-20:].min())
    assert sum(f >= 0.95 for f in finals) >= 7, finals


def test_paper_spgd_medium_mode_stalls_in_local_optima():
    paper = SpgdParams(**PAPER)
    finals = [
        run_spgd(5, "medium", s, iterations=150, params=paper)[0][-10:].mean() for s in range(6)
    ]
    # SPGD is a local method: from random starts it does not find the global optimum every time.
    assert min(finals) < 0.9


def test_default_spgd_stacks_stage3_medium_from_every_start():
    # The user's first run (sim stage 3, medium mode; SPGD's defaults): the paper's SPGD stalls
    # on a side peak (~0.33) in about half the seeds; with the normalized gradient and restarts
    # 200 of 200 seeds reached 0.95 within 500 iterations (1000 readings, 10 s at 100 Hz) when
    # measured. Margin: 19 of 20 here, on seeds of their own.
    reached = []
    for seed in range(500, 520):
        powers, _ = run_spgd(3, "medium", seed, iterations=500)
        reached.append(bool((powers >= 0.95).any()) and powers[-20:].min() >= 0.9)
    assert sum(reached) >= 19, reached


def test_restart_walks_within_actuator_steps_and_ignores_its_readings():
    p = SpgdParams(restart_after=1, restart_below=1.0, restart_range_fs=3.6, restart_step_fs=0.06)
    ctrl = SpgdPid(2, p, setpoints_fs=[0.0, 0.0], seed=1)
    ctrl.observe(0.1)
    ctrl.observe(0.1)  # one iteration below restart_below: a restart starts
    assert ctrl.restarts == 1 and ctrl.restarting
    previous = np.zeros(2)
    target = ctrl.setpoints_fs.copy()
    assert np.all(np.abs(target) <= 1.8 + 1e-9)
    while ctrl.restarting:
        step = ctrl.command()
        assert np.max(np.abs(step - previous)) <= 0.06 + 1e-9
        previous = step
        ctrl.observe(0.0)  # readings on the way are not used: no iteration counted
    assert ctrl.iterations == 1
    np.testing.assert_allclose(previous, target)


def test_two_sided_perturbation_and_update_direction():
    paper = SpgdParams(gain=0.1, perturbation_fs=0.05, **PAPER)
    ctrl = SpgdPid(2, paper, setpoints_fs=[1.0, -1.0], seed=3)
    plus = ctrl.command()
    ctrl.observe(0.8)
    minus = ctrl.command()
    np.testing.assert_allclose(plus + minus, 2 * np.array([1.0, -1.0]))
    np.testing.assert_allclose(np.abs(plus - minus), 0.1)
    ctrl.observe(0.6)
    # J+ > J-: u moves along the + perturbation by gain * dJ / (2a) per stage.
    expected = np.array([1.0, -1.0]) + 0.1 * (0.2 / 0.1) * np.sign(plus - minus)
    np.testing.assert_allclose(ctrl.setpoints_fs, expected)
    assert ctrl.iterations == 1


def test_update_is_clipped_and_momentum_accumulates():
    p = SpgdParams(gain=100.0, perturbation_fs=0.05, max_update_fs=0.2, momentum=0.5, **PAPER)
    ctrl = SpgdPid(1, p, setpoints_fs=[0.0], seed=0)
    ctrl.observe(1.0)
    ctrl.observe(0.0)
    assert abs(ctrl.setpoints_fs[0]) == pytest.approx(0.2)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"gain": 0.0}, "gain"),
        ({"perturbation_fs": -1.0}, "perturbation_fs"),
        ({"momentum": 1.0}, "momentum"),
        ({"kp": float("nan")}, "kp"),
        ({"recovery": "sometimes"}, "recovery"),
        ({"restart_after": 0}, "restart_after"),
        ({"restart_range_fs": float("inf")}, "restart_range_fs"),
    ],
)
def test_invalid_parameters_name_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SpgdParams(**kwargs)


def _latency_finals(latency: int, told: bool, seeds=range(8), steps: int = 400) -> np.ndarray:
    """Final P_N/P_max of default SPGD at N = 3, medium, on a rig whose commands act
    ``latency`` steps late; SPGD knows it if ``told``."""
    rig = make_config(stage=3, mode="medium", latency_steps=latency)
    finals = []
    for seed in seeds:
        sim = BatchedSimulation(rig, num_envs=1, seed=seed)
        sim.reset(seed=seed)
        ctrl = SpgdPid(3, setpoints_fs=sim.setpoints_fs[0], seed=seed, latency=latency * told)
        for _ in range(steps):
            command = ctrl.command()
            assert np.array_equal(ctrl.command(), command)  # asked again: the same command
            result = sim.step_setpoints(command[None, :])
            ctrl.observe(result.power[0])
        finals.append(result.power[0])
    return np.array(finals)


@pytest.mark.parametrize("latency", [1, 2, 3])
def test_told_the_latency_spgd_stacks_as_without_it(latency):
    """With a step of latency an untold SPGD falls from 0.42 to 0.03 (N = 5, medium). Told it, it
    files each reading under the perturbation that made it, both halves of a pair around the
    same set-points."""
    ideal = _latency_finals(0, told=True)
    told = _latency_finals(latency, told=True)
    blind = _latency_finals(latency, told=False)
    assert np.median(told) > 0.95 and np.median(ideal) > 0.95, (told, ideal)
    assert told.mean() > blind.mean() + 0.3, (told, blind)
    with pytest.raises(ValueError, match="latency must be >= 0"):
        SpgdPid(3, latency=-1)


def test_restarts_under_latency_keep_no_pairs_of_old_epochs():
    """A restart drops the perturbations still in flight; their bookkeeping must go with them,
    or a node that restarts for hours grows without bound."""
    p = SpgdParams(restart_after=1, restart_below=1.0, restart_step_fs=10.0)
    ctrl = SpgdPid(3, p, setpoints_fs=np.zeros(3), seed=2, latency=3)
    for _ in range(2000):
        ctrl.command()
        ctrl.observe(0.1)  # flat and low: a restart after every iteration
    assert ctrl.restarts > 50
    assert len(ctrl._pairs) <= ctrl.latency // 2 + 2, len(ctrl._pairs)
