"""The shared observation builder (ops_contract.observation)."""

import numpy as np
import pytest
from ops_contract.config import make_config
from ops_contract.observation import (
    ObservationBuilder,
    ObservationSpec,
    build_frame,
    build_observation,
    pulse_energies_from_trace,
)
from ops_sim_ros.physics import PulseStacker


def test_layout_bounds_and_round_trip():
    cfg = make_config(stage=3)
    spec = ObservationSpec.from_config(cfg)
    assert spec.dim == 7 + 1 + 3
    e = np.linspace(0, 1, 7)
    sp = np.array([1.0, -2.0, 1e9])
    obs = build_observation(spec, e, 0.5, sp)
    assert obs.dtype == np.float32 and obs.shape == (11,)
    np.testing.assert_allclose(obs[:7], e, atol=1e-7)
    assert obs[7] == 0.5
    assert obs[8] == np.float32(1.0 / cfg.optical_period_fs)
    assert obs[10] == cfg.actuator_range_cycles  # clipped into the Box
    assert obs in spec.space()
    batch = build_observation(spec, np.stack([e, e]), np.array([0.1, 0.2]), np.stack([sp, sp]))
    assert batch.shape == (2, 11) and batch[1, 7] == np.float32(0.2)
    assert ObservationSpec.from_dict(spec.to_dict()) == spec


def test_optional_blocks_and_trace_sampling():
    spec = ObservationSpec(stage=2, include_setpoints=False, include_power=False)
    assert spec.dim == 3
    ps = PulseStacker(2, samples_per_slot=6)
    d = np.array([0.4, -0.9])
    tr = ps.trace(d)
    e = pulse_energies_from_trace(tr, 6)
    np.testing.assert_allclose(build_observation(spec, e, 0.0, d), ps.slot_energies(d), atol=1e-6)


# ------------------------------------------------------------------ memory (history = k)
def test_history_spec_layout_bounds_and_round_trip():
    cfg = make_config(stage=3)
    spec = ObservationSpec.from_config(cfg, history=3)
    frame = 7 + 1 + 3
    assert spec.frame_dim == frame and spec.dim == 3 * (frame + 3)
    low, high = spec.bounds()
    base_low, _ = ObservationSpec.from_config(cfg).bounds()
    np.testing.assert_array_equal(low[:frame], base_low)
    np.testing.assert_array_equal(high[frame : frame + 3], np.ones(3, np.float32))
    np.testing.assert_array_equal(low[frame : frame + 3], -np.ones(3, np.float32))
    np.testing.assert_array_equal(high[-3:], np.ones(3, np.float32))
    assert ObservationSpec.from_dict(spec.to_dict()) == spec
    # a spec saved before memory existed has no "history": it is the memoryless one
    old = {k: v for k, v in ObservationSpec.from_config(cfg).to_dict().items() if k != "history"}
    assert ObservationSpec.from_dict(old).history == 0
    assert spec.options()["history"] == 3
    assert ObservationSpec.from_config(cfg, **spec.options()) == spec
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="history"):
            ObservationSpec(stage=3, history=bad)
    with pytest.raises(ValueError, match="unknown keys"):
        ObservationSpec.from_dict({**spec.to_dict(), "memory": 2})
    with pytest.raises(ValueError, match="ObservationBuilder"):
        build_observation(spec, np.zeros(7), 0.0, np.zeros(3))


def test_builder_reset_fills_and_step_shifts():
    spec = ObservationSpec(stage=2, history=3)
    f, n = spec.frame_dim, 2
    b = ObservationBuilder(spec)
    e0, e1, e2 = np.full(3, 0.1), np.full(3, 0.2), np.full(3, 0.3)
    obs = b.reset(e0, 0.5, [0.0, 0.0])
    assert obs.shape == (spec.dim,) and obs.dtype == np.float32 and obs in spec.space()
    frame0 = build_frame(spec, e0, 0.5, [0.0, 0.0])
    for i in range(3):  # every slot: the first frame and a zero action
        np.testing.assert_array_equal(obs[i * (f + n) : i * (f + n) + f], frame0)
        np.testing.assert_array_equal(obs[i * (f + n) + f : (i + 1) * (f + n)], 0.0)
    obs1 = b.step(e1, 0.6, [1.0, -1.0], [0.25, 7.0])  # the action is clipped to [-1, 1]
    np.testing.assert_array_equal(obs1[:f], build_frame(spec, e1, 0.6, [1.0, -1.0]))
    np.testing.assert_array_equal(obs1[f : f + n], np.float32([0.25, 1.0]))
    np.testing.assert_array_equal(obs1[f + n :], obs[: 2 * (f + n)])  # the older ones shifted
    obs2 = b.step(e2, 0.7, [2.0, -2.0], [-0.5, 0.0])
    np.testing.assert_array_equal(obs2[f + n :], obs1[: 2 * (f + n)])
    obs1[:] = 9  # outputs are fresh arrays
    assert b.step(e2, 0.7, [2.0, -2.0], [0.0, 0.0])[f + n] != 9


def test_batched_builder_equals_single_and_resets_by_mask():
    spec = ObservationSpec(stage=2, history=2)
    rng = np.random.default_rng(0)
    batch = ObservationBuilder(spec, num_envs=3)
    singles = [ObservationBuilder(spec) for _ in range(3)]

    def readings():
        return rng.uniform(0, 1, (3, 3)), rng.uniform(0, 1, 3), rng.normal(0, 5, (3, 2))

    e, p, sp = readings()
    out = batch.reset(e, p, sp)
    ref = [s.reset(e[i], p[i], sp[i]) for i, s in enumerate(singles)]
    np.testing.assert_array_equal(out, np.stack(ref))
    for t in range(4):
        e, p, sp = readings()
        a = rng.uniform(-1.5, 1.5, (3, 2))
        out = batch.step(e, p, sp, a)
        ref = [s.step(e[i], p[i], sp[i], a[i]) for i, s in enumerate(singles)]
        np.testing.assert_array_equal(out, np.stack(ref))
        if t == 1:  # env 1 starts a new episode: only its row is refilled
            e, p, sp = readings()
            mask = np.array([False, True, False])
            out = batch.reset(e, p, sp, mask)
            ref[1] = singles[1].reset(e[1], p[1], sp[1])
            np.testing.assert_array_equal(out, np.stack(ref))
    # history 0: the builder is build_frame, no state
    plain = ObservationBuilder(ObservationSpec(stage=2), num_envs=3)
    np.testing.assert_array_equal(
        plain.step(e, p, sp, a), build_frame(ObservationSpec(stage=2), e, p, sp)
    )


# ------------------------------------------------------------------ the authors' observation set
def _known_state(observation):
    from ops_sim_ros import OpsEnv

    env = OpsEnv(stage=5, mode="easy", observation_options={"observation": observation})
    period = env.config.optical_period_fs
    setpoints = np.array([0.5, -0.25, 0.0, 0.1, 0.0]) * period
    errors = np.array([0.15, 0.0, -0.2, 0.0, 0.05]) * period
    obs, info = env.reset(seed=3, options={"setpoints_fs": setpoints, "delay_errors_fs": errors})
    return env, obs, info, setpoints, errors


def test_authors_set_holds_the_applied_delays_scaled_as_documented():
    env, obs, info, setpoints, errors = _known_state("authors")
    period = env.config.optical_period_fs
    applied = setpoints + errors
    np.testing.assert_allclose(info["delays_fs"], applied, atol=1e-9)
    assert obs.shape == (1 + 31 + 5,) and obs in env.observation_space
    # [power, 31 trace samples, 5 PZM values], the authors' order and scalings
    assert obs[0] == pytest.approx(4.58 * info["power"] - 1.29, abs=1e-5)
    energies = env.sim.last.pulse_energies[0]
    np.testing.assert_allclose(obs[1:32], 2 * 5 * energies - 1, atol=1e-5)
    np.testing.assert_allclose(obs[32:], applied / period / 3.0, atol=1e-6)
    # the rig's set of the same state holds the commanded set-points, not the applied delays
    _, rig, _, _, _ = _known_state("rig")
    np.testing.assert_allclose(rig[-5:], setpoints / period, atol=1e-6)
    # after a step the walk has moved the delay lines: the authors' set follows it
    obs2, _, _, _, info2 = env.step(np.zeros(5, dtype=np.float32))
    np.testing.assert_allclose(obs2[32:], info2["delays_fs"] / period / 3.0, atol=1e-6)
    assert not np.allclose(info2["delays_fs"], applied)


def test_authors_set_needs_the_applied_delays_and_round_trips():
    spec = ObservationSpec(stage=2, observation="authors", history=2)
    assert ObservationSpec.from_dict(spec.to_dict()) == spec
    assert spec.options()["observation"] == "authors" and "authors" in spec.describe()
    with pytest.raises(ValueError, match="applied_fs"):
        build_frame(spec, np.zeros(3), 0.5, np.zeros(2))
    with pytest.raises(ValueError, match="rig, authors"):
        ObservationSpec(stage=2, observation="oracle")
    # specs saved before observation sets are the rig's
    old = {k: v for k, v in ObservationSpec(stage=2).to_dict().items() if k != "observation"}
    assert ObservationSpec.from_dict(old).observation == "rig"


# ------------------------------------------------------------------ set-points re-centred by cycles
def test_setpoint_window_spec_checks_and_old_specs():
    cfg = make_config(stage=3)
    spec = ObservationSpec.from_config(cfg, history=2, setpoint_window_cycles=1)
    assert spec.setpoint_window_cycles == 1.0 and spec.has_state
    assert ObservationSpec.from_dict(spec.to_dict()) == spec
    assert ObservationSpec.from_config(cfg, **spec.options()) == spec
    old = {k: v for k, v in spec.to_dict().items() if k != "setpoint_window_cycles"}
    assert ObservationSpec.from_dict(old).setpoint_window_cycles == 0.0  # saved before the option
    assert "re-centred" in spec.describe()
    for bad in (-1.0, 0.2, True, float("nan"), "1"):
        with pytest.raises(ValueError, match="setpoint_window_cycles"):
            ObservationSpec(stage=3, setpoint_window_cycles=bad)
    with pytest.raises(ValueError, match="include_setpoints"):
        ObservationSpec(stage=3, include_setpoints=False, setpoint_window_cycles=1.0)
    with pytest.raises(ValueError, match="ObservationBuilder"):
        spec = ObservationSpec(stage=3, setpoint_window_cycles=1.0)
        build_observation(spec, np.zeros(7), 0, [0] * 3)


@pytest.mark.parametrize("history", [0, 3])
def test_recentred_setpoints_look_the_same_whole_cycles_away(history):
    """A run whose set-points sit whole cycles away (drift carried them) looks like one near 0."""
    cfg = make_config(stage=3)
    spec = ObservationSpec.from_config(cfg, history=history, setpoint_window_cycles=1.0)
    period = cfg.optical_period_fs
    rng = np.random.default_rng(4)
    shift = np.array([3.0, -7.0, 12.0]) * period  # whole cycles, per stage
    near, far = ObservationBuilder(spec), ObservationBuilder(spec)
    sp = rng.uniform(-0.4, 0.4, 3) * period
    e, p = rng.uniform(0, 1, 7), 0.3
    np.testing.assert_allclose(near.reset(e, p, sp), far.reset(e, p, sp + shift), atol=1e-5)
    for _ in range(60):  # a random walk of the set-points, crossing the window now and then
        a = rng.uniform(-1, 1, 3)
        sp = sp + a * 0.1 * period
        e, p = rng.uniform(0, 1, 7), rng.uniform()
        o_near, o_far = near.step(e, p, sp, a), far.step(e, p, sp + shift, a)
        np.testing.assert_allclose(o_near, o_far, atol=1e-4)
        assert o_far in spec.space()
        ref = far.setpoint_reference_cycles - near.setpoint_reference_cycles
        np.testing.assert_array_equal(ref, [3.0, -7.0, 12.0])
        cols = spec.setpoint_columns
        assert np.all(np.abs(o_far[cols]) <= 1.0 + 1e-6)  # the newest frame: within the window
    # absolute set-points (the default) do not look the same
    plain = ObservationSpec.from_config(cfg, history=history)
    a_obs = ObservationBuilder(plain).reset(e, p, sp)
    b_obs = ObservationBuilder(plain).reset(e, p, sp + shift)
    assert not np.allclose(a_obs, b_obs)


def test_recentring_is_per_env_and_reset_clears_it():
    spec = ObservationSpec(stage=2, setpoint_window_cycles=0.75)
    period = spec.optical_period_fs
    b = ObservationBuilder(spec, num_envs=2)
    e = np.zeros((2, 3))
    b.reset(e, np.zeros(2), np.zeros((2, 2)))
    obs = b.step(e, np.zeros(2), np.array([[0.8, 0.1], [0.5, -2.2]]) * period, np.zeros((2, 2)))
    np.testing.assert_array_equal(b.setpoint_reference_cycles, [[1.0, 0.0], [0.0, -2.0]])
    np.testing.assert_allclose(obs[:, spec.setpoint_columns], [[-0.2, 0.1], [0.5, -0.2]], atol=1e-5)
    b.reset(e, np.zeros(2), np.zeros((2, 2)), mask=[True, False])
    np.testing.assert_array_equal(b.setpoint_reference_cycles, [[0.0, 0.0], [0.0, -2.0]])


def test_authors_window_recentres_the_applied_delays_in_their_units():
    """The authors' set: the window (cycles) re-centres the pzm block (applied delay / 3)."""
    spec = ObservationSpec(stage=2, observation="authors", setpoint_window_cycles=1.0)
    period = spec.optical_period_fs
    b = ObservationBuilder(spec)
    cols = spec.setpoint_columns
    assert cols == slice(4, 6) and spec.setpoint_unit_cycles == 3.0
    e = np.zeros(3)
    obs = b.reset(e, 0.5, np.zeros(2), applied_fs=np.array([0.4, -0.3]) * period)
    np.testing.assert_allclose(obs[cols], [0.4 / 3, -0.3 / 3], atol=1e-6)  # inside: as built
    obs = b.step(e, 0.5, np.zeros(2), np.zeros(2), applied_fs=np.array([1.2, -5.1]) * period)
    np.testing.assert_array_equal(b.setpoint_reference_cycles, [1.0, -5.0])
    np.testing.assert_allclose(obs[cols], [0.2 / 3, -0.1 / 3], atol=1e-6)
    assert obs in spec.space()
