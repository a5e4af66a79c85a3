"""The runner factory (ops_controller_ros.runner_factory): a model directory read once, checked
against what the run asks, its layers composed; a recurrent state carried across readings and
started afresh on a new episode or a lost lock. Real files: the shipped models in models/ and
tiny models (tiny_models.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from ops_contract.policy_meta import PolicyLoadError
from ops_controller_ros.policy_hold import HeldRunner
from ops_controller_ros.policy_io import PolicyRunner
from ops_controller_ros.policy_switch import SwitchingRunner, write_switch_model
from ops_controller_ros.reacquire import ReacquireWatchdog
from ops_controller_ros.runner_factory import build_runner, load_model
from tiny_models import edit_metadata, tiny_model

pytest.importorskip("sb3_contrib")

MODELS = Path(__file__).resolve().parents[2] / "models"
SHIPPED = sorted(p.parent for p in MODELS.glob("*/metadata.json"))


def _format(folder: Path) -> int:
    return json.loads((folder / "metadata.json").read_text()).get("format_version", 1)


#: The shipped models written before format 2 (no recipe, recurrent, training_wall_s) and after.
LEGACY = [p for p in SHIPPED if _format(p) == 1]
CURRENT = [p for p in SHIPPED if _format(p) >= 2]


def _layers(runner) -> list[str]:
    names = []
    while runner is not None:
        names.append(type(runner).__name__)
        runner = runner.__dict__.get("runner")
    return names


@pytest.mark.parametrize("folder", LEGACY, ids=[p.name for p in LEGACY])
def test_shipped_models_load_with_the_defaults_of_the_new_fields(folder):
    """A model written before recipe, recurrent and training_wall_s: the algo, none, and the
    wall seconds of the runs of its history."""
    raw = json.loads((folder / "metadata.json").read_text())
    stack = load_model(folder)
    meta = stack.meta
    assert meta.recipe == raw["algo"] and meta.recurrent is None
    walls = [h["wall_s"] for h in raw["history"] if isinstance(h.get("wall_s"), int | float)]
    assert meta.training_wall_s == pytest.approx(sum(walls)) and meta.training_wall_s > 0
    expected = ["PolicyRunner"]
    if "switch" in raw:
        expected = ["SwitchingRunner"]
    if "reacquire" in raw:
        expected = ["ReacquireWatchdog", *expected]
    assert _layers(stack.build()) == expected
    assert stack.layered == (expected != ["PolicyRunner"])


def test_the_hold_is_the_models_unless_asked_and_auto_counts_the_told_latency():
    lab = MODELS / "n5_hard_lab"  # hold_steps 0 (auto) in its metadata
    assert load_model(lab).hold_steps == 1  # an ideal rig: every reading
    held = build_runner(lab, num_envs=2, latency_steps=1)
    assert isinstance(held, HeldRunner) and held.hold_steps == 2
    assert isinstance(held.runner, SwitchingRunner)
    assert load_model(lab, hold_steps=1, latency_steps=1).hold_steps == 1
    assert load_model(MODELS / "n3_easy", hold_steps=3).hold_steps == 3
    with pytest.raises(PolicyLoadError, match="hold_steps must be 0"):
        load_model(MODELS / "n3_easy", hold_steps=-3)


def test_each_metadata_file_is_read_once(monkeypatch):
    """Loading a switching model reads its metadata.json and its acquiring policy's once each;
    building runners from it reads nothing again."""
    reads: list[str] = []
    read_text = Path.read_text

    def counting(self, *args, **kwargs):
        if self.name == "metadata.json":
            reads.append(str(self))
        return read_text(self, *args, **kwargs)

    monkeypatch.setattr(Path, "read_text", counting)
    stack = load_model(MODELS / "n5_hard_switch", hold_steps=2)
    for n in (None, 3, 5):
        runner = stack.build(n)
        assert _layers(runner) == ["HeldRunner", "SwitchingRunner"]
    folder = MODELS / "n5_hard_switch"
    assert sorted(reads) == [
        str(folder / "acquire" / "metadata.json"),
        str(folder / "metadata.json"),
    ]


@pytest.mark.parametrize(
    "asked, message",
    [
        ({"stage": 5}, r"model .*n3_easy was trained for stage 3, the simulator runs stage 5"),
        (
            {"detector": "total"},
            r"model .*n3_easy was trained with the 'polarizer' detector, the simulator has the "
            r"'total' one",
        ),
        ({"observation": "authors"}, r"trained on the 'rig' observation set .* 'authors' one"),
    ],
)
def test_a_model_asked_to_run_where_it_was_not_trained_is_refused(asked, message):
    with pytest.raises(PolicyLoadError, match=message):
        load_model(MODELS / "n3_easy", **asked)
    load_model(MODELS / "n3_easy", stage=3, detector="polarizer", observation="rig")


@pytest.mark.parametrize(
    "entries, message",
    [
        ({"recipe": "evolution"}, r"recipe 'evolution', which this runner does not know"),
        ({"recipe": "dagger-"}, r"recipe 'dagger-'"),
        ({"recurrent": {"kind": "gru", "hidden": 64}}, r"recurrent state of kind 'gru'"),
        ({"recurrent": {"kind": "lstm", "hidden": 8}}, r"algo 'sac' carries no recurrent state"),
        ({"training_wall_s": -1}, r"training_wall_s must be null or seconds >= 0"),
        ({"format_version": 3}, r"format_version 3 .* is not supported"),
    ],
)
def test_metadata_the_runner_does_not_know_is_refused_naming_it(tmp_path, entries, message):
    model = edit_metadata(tiny_model(tmp_path / "m"), **entries)
    with pytest.raises(PolicyLoadError, match=message):
        load_model(model)


def test_an_unknown_observation_set_is_refused(tmp_path):
    model = tiny_model(tmp_path / "m")
    spec = json.loads((model / "metadata.json").read_text())["observation_spec"]
    edit_metadata(model, observation_spec={**spec, "observation": "camera"})
    with pytest.raises(PolicyLoadError, match=r"observation set 'camera', which this runner"):
        load_model(model)


def test_a_recipe_variant_and_the_distilled_recipes_load(tmp_path):
    for recipe in ("dagger-oracle", "asymmetric", "bc"):
        model = edit_metadata(tiny_model(tmp_path / recipe), recipe=recipe)
        stack = load_model(model)
        assert stack.meta.recipe == recipe and f"recipe {recipe}" in stack.describe()[0]


def test_missing_files_say_what_is_missing(tmp_path):
    model = tiny_model(tmp_path / "m")
    (model / "model.zip").unlink()
    with pytest.raises(PolicyLoadError, match=r"model file missing: .*m/model.zip not found"):
        load_model(model)
    (model / "metadata.json").unlink()
    with pytest.raises(PolicyLoadError, match=r"metadata missing: .*m/metadata.json not found"):
        load_model(model)
    with pytest.raises(PolicyLoadError, match=r"model not found: .*nowhere"):
        load_model(tmp_path / "nowhere")


@pytest.fixture(scope="module")
def recurrent(tmp_path_factory):
    return tiny_model(tmp_path_factory.mktemp("rppo") / "rppo", "recurrent_ppo")


def test_a_recurrent_model_whose_metadata_disagrees_with_its_network_is_refused(
    recurrent, tmp_path
):
    bad = tmp_path / "bad"
    shutil.copytree(recurrent, bad)
    edit_metadata(bad, recurrent={"kind": "lstm", "hidden": 64})
    with pytest.raises(PolicyLoadError, match=r"'recurrent' says 1 layer\(s\) of 64, .* 1 of 8"):
        load_model(bad)
    edit_metadata(bad, recurrent=None)
    with pytest.raises(PolicyLoadError, match=r"'recurrent_ppo' carries a recurrent state"):
        load_model(bad)


READING = (np.full(3, 0.2), 0.3, np.array([0.5, -0.5]))  # stage 2: energies, power, set-points


def test_the_runner_carries_the_recurrent_state_and_restarts_it(recurrent):
    stack = load_model(recurrent)
    assert stack.meta.recurrent.hidden == 8 and "recurrent lstm state of 8" in stack.describe()[0]
    runner = stack.build()
    assert isinstance(runner, PolicyRunner) and runner.state is None
    first = [runner.act(*READING) for _ in range(4)]
    assert runner.state is not None and not runner.episode_start.any()
    assert not np.array_equal(first[0], first[1])  # the same reading, another state
    runner.restart()  # a new episode: the state starts afresh
    assert runner.state is None and runner.episode_start.all()
    again = [runner.act(*READING) for _ in range(4)]
    np.testing.assert_array_equal(np.array(first), np.array(again))
    runner.reset_state()  # a lost lock: the state afresh, the observation's memory kept
    np.testing.assert_array_equal(runner.act(*READING), first[0])


def test_a_batch_resets_the_state_of_the_rigs_asked_only(recurrent):
    stack = load_model(recurrent)
    runner, alone = stack.build(2), stack.build(2)
    batch = tuple(np.stack([x, x]) for x in map(np.atleast_1d, READING))
    for _ in range(3):
        runner.act(*batch)
        alone.act(*batch)
    runner.reset_state(np.array([True, False]))
    reset, kept = runner.act(*batch), alone.act(*batch)
    fresh = stack.build(2).act(*batch)
    np.testing.assert_array_equal(reset[0], fresh[0])
    np.testing.assert_array_equal(reset[1], kept[1])
    assert not np.array_equal(reset[0], kept[0])


def test_a_lost_lock_starts_the_acquiring_policys_state_afresh(recurrent, tmp_path):
    model = write_switch_model(tmp_path / "switch", recurrent, recurrent)
    runner = build_runner(model)
    assert isinstance(runner, SwitchingRunner) and runner.acquire.policy.recurrent
    resets = []
    original = runner.acquire.reset_state
    runner.acquire.reset_state = lambda rigs=None: (resets.append(rigs.copy()), original(rigs))
    energies, _, setpoints = READING
    holding = []
    for power in (0.99, 0.99, 0.99, 0.99, 0.1, 0.1, 0.1):
        runner.act(energies, power, setpoints)
        holding.append(runner.holding)
    assert holding == [False, False, True, True, True, False, False]
    assert [r.tolist() for r in resets] == [[True]]  # once, on the reading that lost the lock


def test_a_rollouts_predictor_carries_the_state_from_call_to_call(recurrent):
    from ops_sim_ros import OpsEnv

    policy = load_model(recurrent).policy
    obs, _ = OpsEnv(stage=2, mode="easy").reset(seed=3)
    batch = np.stack([obs, obs])
    predict = policy.predictor()
    first, second = predict(batch), predict(batch)
    np.testing.assert_array_equal(first, policy.predict(batch))  # a fresh state
    assert not np.array_equal(first, second)
    np.testing.assert_array_equal(policy.predictor()(batch), first)  # a new rollout: fresh
    plain = load_model(MODELS / "n3_easy").policy
    assert plain.predictor() == plain.predict  # no state: the bare predict


def test_the_layers_are_plain_and_compose_in_the_factory(recurrent):
    """The watchdog and the hold wrap the recurrent runner and pass a reset on."""
    stack = load_model(recurrent)
    from dataclasses import replace

    from ops_contract.policy_layers import WatchdogParams

    meta = stack.meta.replace(reacquire={"patience": 2, "kick_steps": 1})
    runner = replace(stack, meta=meta, hold_steps=2).build()
    assert _layers(runner) == ["HeldRunner", "ReacquireWatchdog", "PolicyRunner"]
    assert runner.runner.params == WatchdogParams(patience=2, kick_steps=1)
    inner = runner.runner.runner
    energies, _, setpoints = READING
    for _ in range(6):  # decisions on readings 0, 2, 4; the second low decision kicks
        runner.act(energies, 0.1, setpoints)
    assert isinstance(runner.runner, ReacquireWatchdog) and runner.runner.kicks >= 1
    assert runner.decisions == 3 and inner.state is not None
