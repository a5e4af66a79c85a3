"""The shared observation builder (ops_sim_ros.observation)."""

import numpy as np
from ops_sim_ros.config import make_config
from ops_sim_ros.observation import ObservationSpec, build_observation, pulse_energies_from_trace
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
