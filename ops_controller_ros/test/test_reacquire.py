"""The re-acquiring watchdog (ops_controller_ros.reacquire): it kicks a stack lost for
``patience`` readings to a fresh point, and never touches a stack at or above ``good_power``.

Pure numpy and the simulator: no torch, no ROS (the runner wrapped is a stand-in)."""

import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_contract.policy_meta import PolicyLoadError, PolicyMeta
from ops_controller_ros.policy_io import PolicyRunner
from ops_controller_ros.reacquire import REACQUIRE_KEY, ReacquireWatchdog, WatchdogParams
from ops_controller_ros.runner_factory import load_model
from ops_sim_ros.simulation import BatchedSimulation

STAGE = 5
MODELS = Path(__file__).resolve().parents[2] / "models"


class CaptureRangePolicy:
    """A stand-in for a learned policy with a capture range: a stage whose delay error is
    within ``capture`` cycles of a stacking point is pulled to it at the largest step, one
    outside it is left where it is (a policy stuck on a flat stretch of the landscape).
    ``took`` records what was really applied."""

    def __init__(self, period_fs: float, num_envs=None, capture: float = 0.3):
        self.period, self.capture = period_fs, capture
        self.policy = SimpleNamespace(path="capture-range stand-in")
        self.spec = SimpleNamespace(stage=STAGE)
        self.single = num_envs is None
        self.applied_actions = []

    def restart(self):
        self.applied_actions.clear()

    def act(self, pulse_energies, power, setpoints_fs, applied_fs=None):
        x = np.asarray(applied_fs, dtype=np.float64) / self.period
        x = x - np.round(x)  # the error to the nearest stacking point, in cycles
        action = np.where(np.abs(x) < self.capture, np.clip(-x / 0.02, -1, 1), 0.0)
        return action.astype(np.float32)

    def took(self, action):
        self.applied_actions.append(np.asarray(action).copy())

    def reset_state(self, rigs=None):
        pass


def closed_loop(runner, errors_cycles, steps: int, seed: int = 0):
    """P_N / P_max readings (steps + 1, rigs) of ``runner`` on easy mode's testing split,
    started at the given delay errors (cycles, (rigs, N))."""
    errors = np.atleast_2d(np.asarray(errors_cycles, dtype=np.float64))
    sim = BatchedSimulation(make_config(STAGE, "easy", "test"), num_envs=len(errors), seed=seed)
    sim.reset(seed=seed)
    r = sim.place(delay_errors_fs=errors * sim.optical_period_fs)
    runner.restart()
    powers = [np.asarray(r.power, dtype=float).copy()]
    single = getattr(runner, "_single", getattr(runner, "single", False))
    for _ in range(steps):
        args = (r.pulse_energies, r.power, r.setpoints_fs, r.applied_fs)
        if single:
            args = tuple(a[0] for a in args)
        action = np.asarray(runner.act(*args)).reshape(len(errors), STAGE)
        r = sim.step_increments(action)
        powers.append(np.asarray(r.power, dtype=float).copy())
    return np.array(powers)


def period_fs():
    return BatchedSimulation(make_config(STAGE, "easy", "test"), num_envs=1).optical_period_fs


STUCK = [0.5, -0.45, 0.5, 0.48, -0.5]  # every stage out of the stand-in's capture range


def test_a_stuck_episode_ends_near_zero_without_the_watchdog():
    powers = closed_loop(CaptureRangePolicy(period_fs()), STUCK, 300)
    assert powers.max() < 0.1  # never found: the stand-in does not move


def test_the_watchdog_reacquires_the_stuck_episode():
    params = WatchdogParams(patience=10, kick_steps=5, seed=3)
    inner = CaptureRangePolicy(period_fs())
    wd = ReacquireWatchdog(inner, params)
    powers = closed_loop(wd, STUCK, 1000)
    assert wd.kicks >= 1
    assert powers[-1, 0] >= 0.95, powers[::50, 0]
    # the policy's memory holds the kicks' actions (full steps), as another part applied them
    assert inner.applied_actions and np.all(np.abs(inner.applied_actions[0]) == 1.0)


@pytest.mark.parametrize("seed", range(5))
def test_the_watchdog_reacquires_from_any_kick_seed(seed):
    wd = ReacquireWatchdog(CaptureRangePolicy(period_fs()), WatchdogParams(patience=10, seed=seed))
    assert closed_loop(wd, STUCK, 2000)[-1, 0] >= 0.95


def test_a_locked_stack_is_never_kicked():
    wd = ReacquireWatchdog(CaptureRangePolicy(period_fs()), WatchdogParams(patience=1))
    powers = closed_loop(wd, np.zeros(STAGE), 500)
    assert wd.kicks == 0 and powers.min() >= 0.95


def test_rigs_of_a_batch_are_watched_apart():
    wd = ReacquireWatchdog(
        CaptureRangePolicy(period_fs(), num_envs=2), WatchdogParams(patience=10), num_envs=2
    )
    powers = closed_loop(wd, [np.zeros(STAGE), STUCK], 1500)
    assert powers[:, 0].min() >= 0.95  # the locked rig: never kicked, never below
    assert powers[-1, 1] >= 0.95 and wd.kicks >= 1


class Recorder:
    """A runner that returns a fixed action, to compare what the watchdog applies."""

    def __init__(self, num_envs=None):
        self.policy = SimpleNamespace(path="recorder")
        self.spec = SimpleNamespace(stage=STAGE)
        self.n = 1 if num_envs is None else num_envs
        self.single = num_envs is None

    def restart(self):
        self.state_resets = []

    def act(self, pulse_energies, power, setpoints_fs, applied_fs=None):
        a = np.full((self.n, STAGE), 0.25, dtype=np.float32)
        return a[0] if self.single else a

    def took(self, action):
        pass

    def reset_state(self, rigs=None):
        self.state_resets.append(np.asarray(rigs).copy())


def expected_kicks(powers, p: WatchdogParams) -> tuple[np.ndarray, int]:
    """The rule of the module docstring, written out again: per reading, is a kick's action
    applied; and the number of kicks begun."""
    low, left, out, begun = 0, 0, [], 0
    for power in powers:
        if left > 0:
            low = 0
        else:
            low = low + 1 if power < p.good_power else 0
            if low >= p.patience:
                left, low, begun = p.kick_steps, 0, begun + 1
        out.append(left > 0)
        left = max(left - 1, 0)
    return np.array(out), begun


@pytest.mark.parametrize("case", range(200))
def test_kicks_follow_the_rule_and_never_touch_a_good_stack(case):
    """Property: for random readings and figures, the kicks are the rule's; a stack whose last
    ``patience`` readings hold one >= good_power before a kick begins is never kicked."""
    rng = np.random.default_rng(case)
    p = WatchdogParams(
        good_power=float(rng.uniform(0.3, 0.99)),
        patience=int(rng.integers(1, 30)),
        kick_steps=int(rng.integers(1, 12)),
        seed=case,
    )
    n = int(rng.integers(1, 400))
    # readings in runs, good and bad, of random lengths
    powers, good = [], bool(rng.integers(2))
    while len(powers) < n:
        lo, hi = (p.good_power, 1.0) if good else (0.0, p.good_power - 1e-6)
        powers += list(rng.uniform(lo, hi, size=int(rng.integers(1, 3 * p.patience + 2))))
        good = not good
    powers = np.array(powers[:n])
    wd = ReacquireWatchdog(Recorder(), p)
    applied = np.array([wd.act(None, x, np.zeros(STAGE)) for x in powers])
    kicked = np.any(applied != np.float32(0.25), axis=1)
    expected, begun = expected_kicks(powers, p)
    np.testing.assert_array_equal(kicked, expected)
    assert wd.kicks == begun
    assert np.all(np.abs(applied[kicked]) == 1.0)  # a kick is the largest step
    if np.all(powers >= p.good_power):
        assert not kicked.any()
    for t in np.flatnonzero(kicked):
        start = t
        while start > 0 and kicked[start - 1]:
            start -= 1
        window = powers[max(0, start - p.patience + 1) : start + 1]
        assert np.all(window < p.good_power)  # a kick begins only after patience bad readings


def test_params_are_checked():
    for bad in (
        {"good_power": 0.0},
        {"good_power": 1.5},
        {"patience": 0},
        {"kick_steps": 0},
        {"patience": 2.5},
        {"seed": -1},
        {"patience": True},
    ):
        with pytest.raises(ValueError):
            WatchdogParams.from_dict(bad)
    assert WatchdogParams.from_dict({}) == WatchdogParams()
    assert WatchdogParams.from_dict({"patience": 7, "note": "kept"}).patience == 7


def test_a_kick_starts_the_recurrent_state_afresh_on_the_rigs_it_kicks():
    """A lost stack is a new search: the kicked rigs' recurrent state starts afresh (the
    runner's reset_state), the others' is kept; a restart draws the same kicks again."""
    inner = Recorder(num_envs=2)
    wd = ReacquireWatchdog(inner, WatchdogParams(patience=3, kick_steps=2, seed=5), num_envs=2)
    readings = [np.array([0.1, 0.9])] * 4
    first = [wd.act(None, p, np.zeros((2, STAGE))) for p in readings]
    assert [r.tolist() for r in inner.state_resets] == [[True, False]]  # at the third reading
    wd.restart()
    again = [wd.act(None, p, np.zeros((2, STAGE))) for p in readings]
    np.testing.assert_array_equal(np.array(first), np.array(again))


SHIPPED_WITH_WATCHDOG = [
    p.parent for p in sorted(MODELS.glob("*/metadata.json")) if '"reacquire"' in p.read_text()
]


@pytest.mark.parametrize(
    "folder", SHIPPED_WITH_WATCHDOG, ids=[p.name for p in SHIPPED_WITH_WATCHDOG]
)
def test_a_model_asking_for_the_watchdog_runs_in_it(folder, tmp_path):
    """The runner factory (the policy node's and evaluate's) wraps the model's runner; evaluate
    runs it reading by reading (``layered``), not the bare predict; a bad entry is refused."""
    stack = load_model(folder)
    runner = stack.build(num_envs=3)
    assert isinstance(runner, ReacquireWatchdog) and isinstance(runner.runner, PolicyRunner)
    assert stack.layered and runner.params == stack.meta.reacquire
    meta = json.loads((folder / "metadata.json").read_text())
    plain = PolicyMeta.from_dict({k: v for k, v in meta.items() if k != REACQUIRE_KEY})
    assert not load_model(stack.policy.__class__(stack.policy.model, plain)).layered
    broken = tmp_path / "broken"
    broken.mkdir()
    shutil.copy2(folder / "model.zip", broken / "model.zip")
    (broken / "metadata.json").write_text(json.dumps({**meta, REACQUIRE_KEY: {"patience": 0}}))
    with pytest.raises(PolicyLoadError, match="reacquire patience"):
        load_model(broken)
