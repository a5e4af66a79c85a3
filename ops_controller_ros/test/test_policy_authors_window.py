"""A model of the authors' set runs with its applied delays re-centred by whole optical periods
(``policy_io.run_observation_spec``): what the network sees does not depend on how many whole
cycles the delays (a long run's drift, or a delay the detector does not see) have moved, stays
within +- ``AUTHORS_RUN_WINDOW_CYCLES``, and is what it was trained on while the delays stay
inside that window (a 200-step episode). Measured: models/README.md, n5_sac300k_authors.

No torch: the runner's network is a stand-in; the shipped model's metadata is only read."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
from ops_contract.observation import ObservationSpec, build_frame
from ops_contract.policy_meta import PolicyMeta
from ops_controller_ros.policy_io import (
    AUTHORS_RUN_WINDOW_CYCLES,
    LoadedPolicy,
    PolicyRunner,
    observation_spec_of,
    read_metadata,
    run_observation_spec,
)

MODELS = Path(__file__).resolve().parents[2] / "models"
AUTHORS_MODEL = MODELS / "n5_sac300k_authors"


def _loaded(metadata: dict) -> LoadedPolicy:
    spec = observation_spec_of(metadata)
    model = SimpleNamespace(
        observation_space=SimpleNamespace(shape=(spec.dim,)),
        predict=lambda x, deterministic=True: (np.zeros(spec.stage, dtype=np.float32), None),
    )
    return LoadedPolicy(model=model, meta=PolicyMeta.from_dict(metadata, path="stand-in"))


def _metadata(**spec) -> dict:
    return {
        "algo": "sac",
        "stage": 5,
        "mode": "hard",
        "action_type": "increment",
        "max_step_fs": 0.07,
        "observation_spec": ObservationSpec(stage=5, **spec).to_dict(),
    }


def test_run_spec_recentres_the_authors_set_only():
    shipped = read_metadata(AUTHORS_MODEL)
    assert observation_spec_of(shipped).setpoint_window_cycles == 0.0  # as trained
    assert run_observation_spec(shipped).setpoint_window_cycles == AUTHORS_RUN_WINDOW_CYCLES
    assert PolicyRunner(_loaded(shipped)).spec.setpoint_window_cycles == AUTHORS_RUN_WINDOW_CYCLES
    # a window the model was trained with is kept; the rig set is run as trained
    own = _metadata(observation="authors", setpoint_window_cycles=1.5)
    assert run_observation_spec(own).setpoint_window_cycles == 1.5
    for rig in (_metadata(), _metadata(setpoint_window_cycles=1.0), _metadata(history=2)):
        assert run_observation_spec(rig) == observation_spec_of(rig)
    for name in ("n5_hard", "n5_hard_switch"):
        meta = read_metadata(MODELS / name)
        assert run_observation_spec(meta) == observation_spec_of(meta)


def test_authors_runner_sees_the_same_whole_cycles_away_and_within_the_window():
    shipped = read_metadata(AUTHORS_MODEL)
    trained = observation_spec_of(shipped)
    period = trained.optical_period_fs
    w = AUTHORS_RUN_WINDOW_CYCLES
    pzm = slice(1 + 31, 1 + 31 + 5)
    rng = np.random.default_rng(7)
    # whole cycles, per stage (within the +-30-cycle actuator range the frames are clipped to)
    shift = np.array([3.0, -7.0, 12.0, 20.0, -15.0]) * period
    near, far = PolicyRunner(_loaded(shipped)), PolicyRunner(_loaded(shipped))
    applied = rng.uniform(-0.4, 0.4, 5) * period
    inside = True  # while every delay stays within the window, the observation is as trained
    for _ in range(400):  # a walk that carries the delays over several cycles
        e, p, sp = rng.uniform(0, 0.2, 31), rng.uniform(), rng.uniform(-1, 1, 5) * period
        near.act(e, p, sp, applied)
        o_near = near.last_observation
        far.act(e, p, sp, applied + shift)
        np.testing.assert_allclose(o_near, far.last_observation, atol=1e-4)
        assert np.all(np.abs(far.last_observation[pzm]) <= w / 3.0 + 1e-6)
        inside = inside and bool(np.all(np.abs(applied) <= w * period))
        if inside:
            plain = build_frame(trained, e, p, sp, applied)
            np.testing.assert_allclose(o_near, plain, atol=1e-6)
        applied = applied + rng.uniform(-1, 1, 5) * 0.06 * period
    assert not inside  # the walk did leave the window (the re-centring was exercised)
