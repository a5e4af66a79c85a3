"""Tests of the stacker physics itself (ops_sim_ros.physics)."""

import numpy as np
import pytest
from ops_sim_ros.physics import PulseStacker, geometry_matrices, input_coding, power_to_reward

PERIOD = 1030.0 / 299.792458


@pytest.fixture(scope="module")
def ref3():
    return PulseStacker(3, dtype=np.float64, quadrature_points=12)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6, 7, 8])
def test_perfect_stacking_puts_all_energy_in_one_pulse(n):
    ps = PulseStacker(n)
    out = ps.evaluate(np.zeros((1, n)), rejected_port=True)
    assert out.power[0] == pytest.approx(1.0, abs=1e-5)
    assert out.main_pulse_energy[0] == pytest.approx(1.0, abs=1e-5)
    assert out.rejected_energy[0] == pytest.approx(0.0, abs=1e-6)
    assert np.abs(out.satellite_energies).max() < 1e-6
    assert ps.slot_energies(np.zeros(n)).argmax() == ps.main_slot == 2 ** (n - 1) - 1


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
def test_energy_is_conserved_for_arbitrary_delays(n):
    rng = np.random.default_rng(n)
    # small, medium and walk-off sized errors (up to 400 fs per stage, t0 = 567 fs)
    d = np.concatenate(
        [
            rng.uniform(-5, 5, (20, n)),
            rng.uniform(-100, 100, (20, n)),
            rng.uniform(-400, 400, (8, n)),
        ]
    )
    ps = PulseStacker(n, dtype=np.float64, quadrature_points=16)
    out = ps.evaluate(d, rejected_port=True)
    total = out.slot_energies.sum(axis=1) + out.rejected_slot_energies.sum(axis=1)
    np.testing.assert_allclose(total, 1.0, atol=1e-6)
    assert np.all(out.slot_energies >= -1e-12) and np.all(out.power <= 1.0 + 1e-9)
    assert np.all(out.rejected_energy > -1e-12)
    # The fast float32, K=6 path agrees within the actuator range (+-103 fs per stage) and its
    # implicit rejected energy (1 - H energy) equals the explicit port; beyond, K=6 loses digits.
    fast = PulseStacker(n).evaluate(d)
    np.testing.assert_allclose(fast.rejected_energy[:40], out.rejected_energy[:40], atol=2e-5)
    np.testing.assert_allclose(fast.power[:40], out.power[:40], atol=2e-5)
    np.testing.assert_allclose(fast.power, out.power, atol=3e-3)


def test_geometry_matrix_properties():
    for n in (1, 3, 6):
        c_s, c_p = geometry_matrices(n)
        # the geometry is unitary: every input pattern's amplitudes keep unit norm overall
        cols = (c_s**2).sum(axis=0) + (c_p**2).sum(axis=0)
        np.testing.assert_allclose(cols.reshape(2**n, -1).sum(), 2**n, rtol=1e-12)
        # perfect stacking: amplitude sqrt(2^N) in slot 2^N - 1, all of it in s
        assert abs(c_s[2**n - 1].sum()) == pytest.approx(2 ** (n / 2))
        assert c_p[2**n - 1].sum() == pytest.approx(0.0, abs=1e-12)
        # no per-stage gating: every pattern reaches the output from exactly one input pulse
        assert np.all(np.count_nonzero(c_s**2 + c_p**2 > 1e-24, axis=0) >= 1)


def test_input_coding_is_the_seeds_recursion():
    assert input_coding(1) == [("p", 1), ("s", -1)]
    assert input_coding(2) == [("p", 1), ("s", 1), ("p", 1), ("s", -1)]
    for n in (3, 5):
        code = input_coding(n)
        assert len(code) == 2**n
        # in every first-stage pair the earlier pulse is p and the later one s
        assert [pol for pol, _ in code] == ["p", "s"] * 2 ** (n - 1)


# The authors' code (pynlo CPS_env) at these delay errors, in optical cycles.
AUTHORS = [
    (3, {0: 0.5}, 0.0156, 0.4375),
    (5, {0: 0.5}, 0.0100, 0.1084),
    (5, {1: 0.5}, 0.0410, 0.2109),
    (5, {0: 0.25}, 0.2525, 0.2771),
    (5, {3: 0.5}, 0.1250, 0.5000),
]


@pytest.mark.parametrize("n, errors, polarizer, total", AUTHORS)
def test_landscape_matches_the_authors_code(n, errors, polarizer, total):
    d = np.zeros(n)
    for j, cycles in errors.items():
        d[j] = cycles * PERIOD
    for dtype in (np.float64, np.float32):
        got_pol = PulseStacker(n, dtype=dtype, detector="polarizer").power(d)
        got_tot = PulseStacker(n, dtype=dtype, detector="total").power(d)
        assert got_pol == pytest.approx(polarizer, abs=6e-4)
        assert got_tot == pytest.approx(total, abs=6e-4)
        batch = np.tile(d, (4, 1))  # the batched path gives the same
        np.testing.assert_allclose(
            PulseStacker(n, dtype=dtype, detector="total").power(batch), got_tot, atol=1e-6
        )


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_detectors_agree_at_the_optimum_and_total_never_sees_the_last_stage(n):
    pol = PulseStacker(n, dtype=np.float64, detector="polarizer")
    tot = PulseStacker(n, dtype=np.float64, detector="total")
    assert pol.power(np.zeros(n)) == pytest.approx(1.0, abs=1e-9)
    assert tot.power(np.zeros(n)) == pytest.approx(1.0, abs=1e-9)
    rng = np.random.default_rng(n)
    d = rng.uniform(-0.5, 0.5, (30, n)) * PERIOD
    moved = d.copy()
    moved[:, -1] = rng.uniform(-0.5, 0.5, 30) * PERIOD  # only the last stage changes
    # the total intensity does not depend on the last stage's phase (only its tiny walk-off)
    np.testing.assert_allclose(tot.power(moved), tot.power(d), atol=1e-5)
    # the polarizer sees it, and always at most what the total detector sees
    if n > 1:
        assert np.abs(pol.power(moved) - pol.power(d)).max() > 0.05
    assert np.all(pol.power(d) <= tot.power(d) + 1e-12)
    # both detect all the light the total detector is given (nothing rejected)
    out = tot.evaluate(d, rejected_port=True)
    np.testing.assert_allclose(out.slot_energies.sum(axis=1), 1.0, atol=1e-6)
    assert np.all(out.rejected_energy == 0.0)


def test_one_stage_with_the_total_detector_is_flat():
    tot = PulseStacker(1, dtype=np.float64, detector="total")
    d = np.linspace(-0.5, 0.5, 41)[:, None] * PERIOD
    np.testing.assert_allclose(tot.power(d), 1.0, atol=1e-5)
    # ... while the polarizer gives the cos^4 fringe of the paper's Figure 2a
    pol = PulseStacker(1, dtype=np.float64).power(d)
    np.testing.assert_allclose(pol, np.cos(np.pi * d[:, 0] / PERIOD) ** 4, atol=1e-4)


def test_a_stage_off_by_a_full_cycle_stacks_again_with_both_detectors():
    for detector in ("polarizer", "total"):
        ps = PulseStacker(5, dtype=np.float64, detector=detector)
        d = np.array([1.0, -1.0, 2.0, 0.0, 1.0]) * PERIOD
        assert ps.power(d) > 0.99  # only the few-fs envelope walk-off is lost


@pytest.mark.parametrize("n", [1, 2, 4])
def test_periodic_in_each_delay_with_the_optical_period(n):
    ps = PulseStacker(n, dtype=np.float64, quadrature_points=12)
    rng = np.random.default_rng(0)
    d = rng.uniform(-2, 2, (50, n))
    p0 = ps.power(d)
    for j in range(n):
        shifted = d.copy()
        shifted[:, j] += PERIOD
        # only the envelope walk-off (3.4 fs of a 567 fs t0) differs
        np.testing.assert_allclose(ps.power(shifted), p0, atol=2e-4)
    assert p0.max() - p0.min() > 0.2  # the landscape is not flat


def _two_beam_power_fine_grid(delta_fs, fwhm_fs=1000.0):
    """Independent check: fields on a fine time grid, integral of I^2 at the output polarizer.

    One stage: pulse 1 (coded +p, delayed by T + delta) and pulse 2 (coded -s) meet; after the
    45-degree plate the s port carries -(a(t - delta) e^{i w0 delta} + a(t)) / sqrt(2).
    """
    t0 = fwhm_fs / (2 * np.arccosh(np.sqrt(2)))
    t = np.linspace(-40 * t0, 40 * t0, 400_001)
    w0 = 2 * np.pi / PERIOD
    a = 1 / np.cosh(t / t0)
    out = []
    for d in np.atleast_1d(delta_fs):
        e = (a + np.exp(1j * w0 * d) / np.cosh((t - d) / t0)) / np.sqrt(2)
        i = np.abs(e) ** 2
        out.append(np.trapezoid(i * i, t))
    p_max = np.trapezoid((2 * a**2) ** 2, t)
    return np.array(out) / p_max


def test_one_stage_is_two_beam_interference():
    ps = PulseStacker(1, dtype=np.float64)
    deltas = np.array([0.0, 0.3, 0.9, 1.7, 2.2, 3.0, 50.0, 51.7, 300.0, 301.7])
    expected = _two_beam_power_fine_grid(deltas)
    np.testing.assert_allclose(ps.power(deltas[:, None]), expected, atol=2e-5)
    np.testing.assert_allclose(PulseStacker(1).power(deltas[:, None]), expected, atol=2e-5)
    # far walk-off (900 fs = 1.6 t0) needs more quadrature points than the default 6
    far = np.array([900.0, 901.7, 1500.0])
    fine = PulseStacker(1, dtype=np.float64, quadrature_points=24)
    np.testing.assert_allclose(fine.power(far[:, None]), _two_beam_power_fine_grid(far), atol=2e-5)
    # Half a period off: destructive interference, nearly no light through the polarizer.
    half = ps.evaluate(np.array([[PERIOD / 2]]))
    assert half.power[0] < 1e-4 and half.rejected_energy[0] > 0.999
    # Slot energy follows the cosine fringe (1 + V cos(w0 d)) / 2 with V the envelope overlap.
    t0 = ps.t0_fs
    for d in (0.7, 120.0, 500.0):
        x = d / t0
        overlap = x / np.sinh(x)  # integral sech(u) sech(u - x) du / 2
        fringe = 0.5 * (1 + overlap * np.cos(2 * np.pi * d / PERIOD))
        assert ps.slot_energies(np.array([d]))[0] == pytest.approx(fringe, abs=1e-6)


def test_two_stages_have_local_maxima_that_are_not_global():
    ps = PulseStacker(2, dtype=np.float64, quadrature_points=8)
    g = np.linspace(-PERIOD / 2, PERIOD / 2, 120, endpoint=False)
    d1, d2 = np.meshgrid(g, g, indexing="ij")
    p = ps.power(np.stack([d1.ravel(), d2.ravel()], axis=1)).reshape(d1.shape)
    # strict local maxima on the periodic grid
    nb = [np.roll(np.roll(p, a, 0), b, 1) for a in (-1, 0, 1) for b in (-1, 0, 1) if a or b]
    is_max = np.all([p > q for q in nb], axis=0)
    values = np.sort(p[is_max])
    assert values[-1] == pytest.approx(1.0, abs=1e-3)
    local = values[values < 0.9]
    assert local.size >= 1
    assert 0.05 < local.max() < 0.6  # e.g. stage 2 in phase, stage 1 out: two satellites


def test_satellites_appear_when_and_only_when_a_stage_is_off():
    n = 4
    ps = PulseStacker(n, dtype=np.float64, quadrature_points=8)
    rng = np.random.default_rng(1)
    # all stages in phase (whole optical periods, tiny walk-off): no satellites
    d = rng.integers(-3, 4, (10, n)) * PERIOD
    out = ps.evaluate(d)
    assert out.satellite_energies.max() < 1e-3
    for j in range(n - 1):
        d = np.zeros((1, n))
        d[0, j] = 0.25 * PERIOD  # quarter period: half of that stage's light is mis-phased
        out = ps.evaluate(d)
        assert out.satellite_energies.sum() > 0.1, f"stage {j + 1} off must make satellites"
    # the last stage's error leaves through the polarizer's p port instead
    d = np.zeros((1, n))
    d[0, -1] = 0.5 * PERIOD
    out = ps.evaluate(d, rejected_port=True)
    assert out.rejected_energy[0] > 0.99


def test_satellite_positions_identify_the_stage():
    n = 3
    ps = PulseStacker(n, dtype=np.float64)
    patterns = []
    for j in range(n - 1):
        d = np.zeros(n)
        d[j] = 0.5 * PERIOD
        e = ps.slot_energies(d)
        patterns.append(tuple(np.flatnonzero(e > 1e-3)))
    assert len(set(patterns)) == n - 1  # different stages light different slots


def test_batched_equals_unbatched_and_float32_matches_float64():
    n = 5
    rng = np.random.default_rng(3)
    d = rng.uniform(-20, 20, (64, n))
    fast = PulseStacker(n)
    ref = PulseStacker(n, dtype=np.float64)
    batch = fast.evaluate(d)
    rows = [fast.evaluate(row) for row in d]
    np.testing.assert_allclose([r.power for r in rows], batch.power, atol=1e-5)
    np.testing.assert_allclose(
        np.stack([r.slot_energies for r in rows]), batch.slot_energies, atol=1e-5
    )
    np.testing.assert_allclose(batch.power, ref.evaluate(d).power, atol=1e-5)
    # a batch of one and of two (small path vs batched path) agree with the reference
    np.testing.assert_allclose(fast.power(d[:1]), ref.power(d[:1]), atol=1e-9)


def test_trace_layout_and_pulse_energies_round_trip():
    from ops_contract.observation import pulse_energies_from_trace

    ps = PulseStacker(3, samples_per_slot=8)
    d = np.array([[0.3, 1.1, -0.4], [0.0, 0.0, 0.0]])
    tr = ps.trace(d)
    assert tr.shape == (2, 7 * 8) and tr.dtype == np.float32
    assert tr.min() >= 0.0 and tr.max() <= 1.0 + 1e-6
    assert tr[1].max() == pytest.approx(1.0, abs=1e-5)
    assert tr[1].argmax() == ps.main_slot * 8 + 4
    np.testing.assert_allclose(pulse_energies_from_trace(tr, 8), ps.slot_energies(d), atol=1e-6)
    assert ps.trace(d[0]).shape == (56,)


def test_reward_is_eq3_with_pmin_zero():
    assert power_to_reward(1.0) == 0.0
    assert power_to_reward(0.0) == -1.0
    assert power_to_reward(0.5) == pytest.approx(-0.25)


def test_bad_shapes_are_rejected():
    ps = PulseStacker(3)
    with pytest.raises(ValueError, match="shape"):
        ps.power(np.zeros((2, 4)))


@pytest.mark.parametrize("detector", ["polarizer", "total"])
@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6, 7, 8])
def test_fast_float32_path_equals_float64_reference(n, detector):
    """The float32 batched path (phase reduced per stage, cosh, padded GEMM, reused buffers)
    gives the float64 reference's numbers to float32 rounding, for every batch size."""
    rng = np.random.default_rng(10 + n)
    fast = PulseStacker(n, detector=detector)
    ref = PulseStacker(n, dtype=np.float64, detector=detector)
    for batch, scale in ((2, 1.0), (5, 20.0), (64, 103.0), (33, 3000.0)):
        d = rng.uniform(-scale, scale, (batch, n))
        d[0] = 0.0
        for rejected_port in (False, True):
            want = ref.evaluate(d, rejected_port=rejected_port)
            got = fast.evaluate(d, rejected_port=rejected_port)
            assert got.slot_energies.dtype == np.float64 and got.power.dtype == np.float64
            np.testing.assert_allclose(got.power, want.power, atol=5e-6)  # I^2 sums
            np.testing.assert_allclose(got.slot_energies, want.slot_energies, atol=2e-6)
            np.testing.assert_allclose(got.main_pulse_energy, want.main_pulse_energy, atol=2e-6)
            np.testing.assert_allclose(got.rejected_energy, want.rejected_energy, atol=2e-6)
            if rejected_port:
                np.testing.assert_allclose(
                    got.rejected_slot_energies, want.rejected_slot_energies, atol=2e-6
                )
    # buffers are reused between calls: earlier results must not change
    d1, d2 = rng.uniform(-2, 2, (2, 16, n))
    first = fast.evaluate(d1)
    kept = (first.power.copy(), first.slot_energies.copy())
    fast.evaluate(d2)
    np.testing.assert_array_equal(first.power, kept[0])
    np.testing.assert_array_equal(first.slot_energies, kept[1])
