"""Switching models (ops_controller_ros.policy_switch): one shipped policy acquires, another
holds; both observe every reading, the one acting is chosen by the readings."""

from pathlib import Path

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_contract.policy_meta import PolicyLoadError, read_meta
from ops_controller_ros.policy_switch import SwitchingRunner, SwitchParams, write_switch_model
from ops_controller_ros.runner_factory import build_runner
from ops_sim_ros.simulation import BatchedSimulation

MODELS = Path(__file__).resolve().parents[2] / "models"
PARAMS = SwitchParams(lock_power=0.95, lock_readings=3, release_power=0.8, release_readings=2)


@pytest.fixture(scope="module")
def switch_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("switch") / "n5_hard_switch"
    return write_switch_model(out, MODELS / "n5_hard_long", MODELS / "n5_hard", PARAMS)


def closed_loop(runner, seed, steps, num_envs=None, kick_at=None):
    """Readings, the acting part and the applied actions (arrays (steps, rigs[, N])) of ``steps``
    steps on hard mode's
    testing environment; ``kick_at``: a step at which every delay error is moved half a cycle
    (a lost lock)."""
    sim = BatchedSimulation(make_config(5, "hard", "test"), num_envs=num_envs or 1, seed=seed)
    r = sim.reset(seed=seed)
    runner.restart()
    powers, holding, actions, acts = [], [], [], []
    for t in range(steps):
        if t == kick_at:
            errors = r.applied_fs - r.setpoints_fs
            r = sim.place(delay_errors_fs=errors + 0.5 * sim.optical_period_fs)
        args = (r.pulse_energies, r.power, r.setpoints_fs, r.applied_fs)
        if num_envs is None:
            args = tuple(a[0] for a in args)
        action = runner.act(*args)
        powers.append(np.asarray(r.power, dtype=float).copy())
        holding.append(np.atleast_1d(runner.holding).copy())
        acts.append(np.atleast_1d(runner.holder_acts).copy())
        actions.append(np.asarray(action).reshape(-1, sim.stage))
        r = sim.step_increments(actions[-1])
    return {
        "power": np.array(powers),
        "holding": np.array(holding),
        "holder_acted": np.array(acts),
        "action": np.array(actions),
    }


def expected_holding(powers, p: SwitchParams, acting=False):
    """The rule of the module docstring, written out again: per reading, is the lock held (or,
    ``acting``: does the holding policy act, its turns of an acquire_patience search too)."""
    holding, high, low, searched, out = False, 0, 0, 0, []
    for power in powers:
        high = high + 1 if power >= p.lock_power else 0
        low = low + 1 if power < p.release_power else 0
        holding = low < p.release_readings if holding else high >= p.lock_readings
        searched = 0 if holding else searched + 1
        turn = p.acquire_patience and not holding and (searched - 1) // p.acquire_patience % 2
        out.append(holding or (acting and bool(turn)))
    return np.array(out)


def test_the_holder_takes_over_after_the_lock_and_hands_back_on_a_loss(switch_dir):
    runner = build_runner(switch_dir, num_envs=4)
    assert isinstance(runner, SwitchingRunner) and runner.params == PARAMS
    run = closed_loop(runner, seed=4100, steps=190, num_envs=4, kick_at=150)
    powers, holding = run["power"], run["holding"]
    for e in range(4):  # each rig switches on its own readings, by the rule
        np.testing.assert_array_equal(holding[:, e], expected_holding(powers[:, e], PARAMS))
    held = holding[149]
    assert held.any(), "the acquiring policy found the stack on none of 4 rigs in 150 steps"
    assert (powers[150:152, held] < 0.8).all()  # the kick cost the lock
    assert not holding[152:, held].all(axis=0).any(), "a lost lock goes back to the acquirer"
    assert runner.switches >= 2 * held.sum()


def test_the_applied_action_is_the_acting_policys_and_both_remember_it(switch_dir):
    runner = build_runner(switch_dir)
    run = closed_loop(runner, seed=4101, steps=60)
    actions = run["action"]
    assert actions.shape == (60, 1, 5)
    # the last reading's observation through the acting policy gives the applied action
    last = actions[-1][0]
    acting = runner.hold if run["holder_acted"][-1, 0] else runner.acquire
    np.testing.assert_allclose(acting.policy.predict(acting.last_observation), last, atol=1e-6)
    # the newest memory slot of each policy's next observation holds the applied action
    for part in (runner.hold, runner.acquire):
        frame = part.spec.frame_dim
        newest = part.observe(**_reading(runner)).reshape(
            part.spec.history, frame + part.spec.stage
        )[0, frame:]
        np.testing.assert_allclose(newest, np.clip(last, -1, 1), atol=1e-6)


def _reading(runner):
    """A reading of zeros for stage 5 (only the memory slot of the observation is looked at)."""
    slots = runner.spec.num_slots
    return dict(pulse_energies=np.zeros(slots), power=0.0, setpoints_fs=np.zeros(runner.spec.stage))


def test_a_search_that_finds_nothing_is_taken_over_by_the_holder_in_turn(tmp_path):
    """acquire_patience = 10: a search that has not found the stack hands the action to the
    holding policy for readings 11-20 of the search, back for 21-30, and so on."""
    params = SwitchParams(lock_power=0.999, acquire_patience=10)  # a lock never reached
    model = write_switch_model(tmp_path / "p", MODELS / "n5_hard_long", MODELS / "n5_hard", params)
    runner = build_runner(model, num_envs=2)
    run = closed_loop(runner, seed=4103, steps=45, num_envs=2)
    powers, holding, acted = run["power"], run["holding"], run["holder_acted"]
    for e in range(2):
        np.testing.assert_array_equal(acted[:, e], expected_holding(powers[:, e], params, True))
    if not holding.any():  # as planned: turns of 10 readings each, from the 11th on
        assert acted[:10].sum() == 0 and acted[10:20].all() and not acted[20:30].any()


def test_a_switching_model_counts_both_policies_training(switch_dir):
    """Its training_wall_s: the holder's lineage (n5_hard_long: fine-tuned from n5_hard) and
    the acquirer's (n5_hard), the run they share counted once."""
    hold, acquire = read_meta(MODELS / "n5_hard_long"), read_meta(MODELS / "n5_hard")
    meta = read_meta(switch_dir)
    shared = acquire.training_wall_s
    assert shared and hold.training_wall_s > shared  # the holder's lineage holds n5_hard's run
    assert meta.training_wall_s == pytest.approx(hold.training_wall_s)
    assert meta.recipe == hold.recipe == "sac"


def test_bad_switching_models_are_refused_with_a_reason(tmp_path, switch_dir):
    with pytest.raises(PolicyLoadError, match="disagree on the stage"):
        write_switch_model(tmp_path / "mixed", MODELS / "n5_hard_long", MODELS / "n3_easy")
    broken = tmp_path / "broken"
    write_switch_model(broken, MODELS / "n5_hard_long", MODELS / "n5_hard")
    (broken / "acquire" / "model.zip").unlink()
    with pytest.raises(PolicyLoadError, match=r"acquiring policy .* is missing"):
        build_runner(broken)


@pytest.mark.parametrize(
    "field, value",
    [("lock_power", 1.5), ("release_power", 0.96), ("lock_readings", 0), ("acquire_patience", -1)],
)
def test_switch_parameters_out_of_range_name_the_parameter(field, value):
    with pytest.raises(ValueError, match=f"switch {field} must be"):
        SwitchParams(**{field: value})
