"""The fits of the calibration (pure numpy; the stacker's model from ops_sim_ros.physics).

* :func:`find_slots`: the record index of every pulse slot from records in which the slots lit
  up (the maximum over them): peaks, then a regular grid fitted through them, centred by the
  mirror symmetry of the records' mean.
* :func:`fit_fringe`: a sinusoid ``a + b cos(2 pi f V + phi)`` of a signal against voltage; the
  frequency by a scan of linear least-squares fits, refined by golden section
  (:func:`fit_at_frequency` at a known frequency).
* :func:`indicator_weights`: a signed sum of slot energies that shows stage j's fringe with
  its maximum at zero delay error whatever the later stages do (the slots m with m + 1 a
  multiple of 2^j, signed by the model). So stage j is calibrated from its own sweep alone.
"""

from __future__ import annotations

import numpy as np


class CalibrationError(RuntimeError):
    """The sweeps do not give a trustworthy fit (the message says why)."""


def find_slots(
    max_record: np.ndarray,
    num_slots: int,
    min_fraction: float = 0.15,
    mean_record: np.ndarray | None = None,
) -> np.ndarray:
    """Centres (fractional record indices) of ``num_slots`` evenly spaced pulse slots: the
    grid through the peaks of ``max_record``, centred where ``mean_record`` (the mean of
    records over phases that cycle) is most nearly mirror-symmetric, where given, else with
    its centre slot in the middle of the slots seen."""
    r = np.asarray(max_record, dtype=np.float64)
    base = np.median(r)
    height = r.max() - base
    if height <= 0:
        raise CalibrationError("the records are flat: no pulses seen (light, trigger, channel?)")
    above = r > base + min_fraction * height
    interior = (r[1:-1] >= r[:-2]) & (r[1:-1] > r[2:]) & above[1:-1]
    peaks = np.flatnonzero(interior) + 1
    if peaks.size < 2 and num_slots > 1:
        raise CalibrationError(f"found {peaks.size} pulse(s), need {num_slots} slots")
    # Parabolic refinement of each peak.
    y0, y1, y2 = r[peaks - 1], r[peaks], r[peaks + 1]
    den = y0 - 2 * y1 + y2
    frac = np.where(den != 0, 0.5 * (y0 - y2) / np.where(den != 0, den, 1), 0.0)
    pos = peaks + frac
    if num_slots == 1:
        return pos[[int(np.argmax(y1))]]
    gaps = np.diff(pos)
    spacing = np.min(gaps[gaps > 0.5 * np.median(gaps)])
    index = np.round((pos - pos[0]) / spacing)
    if index.max() > num_slots - 1:
        raise CalibrationError(
            f"pulses found at {index.max() + 1:.0f} slot spacings: more than {num_slots} slots"
        )
    # The outermost slots carry little light (stage 1's pairs alone): the slots seen are those
    # about the stacked pulse's, which lies in the middle of the pattern.
    index += np.round((num_slots - 1) / 2 - index.max() / 2)
    a, b = np.polyfit(index, pos, 1)[::-1]
    if mean_record is not None:
        a += b * _centre_shift(np.asarray(mean_record, dtype=np.float64), a, b, num_slots)
    return a + b * np.arange(num_slots)


def _centre_shift(mean_record: np.ndarray, a: float, b: float, num_slots: int) -> int:
    """Whole slots by which the grid ``a + b k`` must move so that the mean record's slot
    heights are most nearly mirror-symmetric about its centre slot: slot m and slot
    2^N - 2 - m are each other's mirror image in the stacker, and so are their energies averaged
    over phases that cycle. (The slots seen in the records' maximum are not always centred on
    the stacked pulse's: a drifting stacker lit them unevenly, one slot off in 6 runs of 14 at
    N = 5, hard, lab.)"""
    x = np.arange(mean_record.size)
    base = np.median(mean_record)
    best, shift = -np.inf, 0
    for s in range(-(num_slots // 2), num_slots // 2 + 1):
        at = a + b * (np.arange(num_slots) + s)
        inside = (at >= 0) & (at <= mean_record.size - 1)
        heights = np.where(inside, np.interp(at, x, mean_record) - base, 0.0)
        # Square roots (field amplitudes): the dim outer slots, which mark the pattern's ends,
        # weigh in (mean heights: one centre off in 14 runs at N = 5, hard, lab; roots: none)
        heights = np.sqrt(np.clip(heights, 0.0, None))
        score = float(heights @ heights[::-1]) / (float(heights @ heights) + 1e-12)
        if score > best + 1e-9:
            best, shift = score, s
    return shift


def _lsq(v, s, f):
    design = np.stack([np.ones_like(v), np.cos(2 * np.pi * f * v), np.sin(2 * np.pi * f * v)], 1)
    coef, *_ = np.linalg.lstsq(design, s, rcond=None)
    resid = s - design @ coef
    return coef, float(resid @ resid)


def fit_fringe(volts, signal, f_min: float, f_max: float, grid: int = 400):
    """Fit ``signal ~ a + b cos(2 pi f V + phi)``; returns (f cycles/V, a, b >= 0, phi, rms)."""
    v = np.asarray(volts, dtype=np.float64)
    s = np.asarray(signal, dtype=np.float64)
    freqs = np.linspace(f_min, f_max, grid)
    costs = np.array([_lsq(v, s, f)[1] for f in freqs])
    i = int(np.clip(np.argmin(costs), 1, grid - 2))
    lo, hi = freqs[i - 1], freqs[i + 1]
    for _ in range(40):  # golden-section refinement in the bracket
        m1, m2 = lo + 0.382 * (hi - lo), lo + 0.618 * (hi - lo)
        if _lsq(v, s, m1)[1] < _lsq(v, s, m2)[1]:
            hi = m2
        else:
            lo = m1
    f = 0.5 * (lo + hi)
    return (f, *fit_at_frequency(v, s, f))


def fit_at_frequency(volts, signal, f: float):
    """Fit ``signal ~ a + b cos(2 pi f V + phi)`` at a known ``f``; returns (a, b >= 0, phi,
    rms)."""
    v = np.asarray(volts, dtype=np.float64)
    (a, c, d), cost = _lsq(v, np.asarray(signal, dtype=np.float64), f)
    phi = float(np.arctan2(-d, c))  # c cos x + d sin x = b cos(x + phi)
    return float(a), float(np.hypot(c, d)), phi, (cost / v.size) ** 0.5


def indicator_weights(stage: int, j: int, optics: dict | None = None) -> np.ndarray:
    """Weights (+1, -1 or 0 per output slot) of the signal that shows stage j's (0-based)
    fringe at its maximum at zero delay error of stage j, whatever the later stages do (the
    earlier ones at zero). The slots m with (m + 1) divisible by 2^j have a fringe in stage j's
    delay whose phase does not depend on the other stages; the model says whether each has a
    maximum (+1) or a minimum (-1) at zero error, so their signed sum adds up."""
    ps = _stacker(stage, optics)
    phases = np.linspace(0.0, ps.optical_period_fs, 16, endpoint=False)
    d = np.zeros((phases.size, stage))
    d[:, j] = phases
    coef = ps.slot_energies(d).T @ np.exp(-2j * np.pi * phases / ps.optical_period_fs)
    weights = np.sign(coef.real) * (np.abs(coef) > 1e-9)
    weights[(np.arange(ps.num_slots) + 1) % 2**j != 0] = 0.0
    return weights


def _stacker(stage: int, optics: dict | None):
    from ops_sim_ros.physics import PulseStacker

    optics = optics or {}
    return PulseStacker(
        stage=stage,
        wavelength_nm=float(optics.get("wavelength_nm", 1030.0)),
        pulse_fwhm_fs=float(optics.get("pulse_fwhm_fs", 1000.0)),
        detector=str(optics.get("detector", "polarizer")),
        dtype=np.float64,
    )


def optical_period_fs(optics: dict | None = None) -> float:
    from ops_contract.config import SPEED_OF_LIGHT_NM_PER_FS

    return float((optics or {}).get("wavelength_nm", 1030.0)) / SPEED_OF_LIGHT_NM_PER_FS


def zero_from_fit(f: float, phi: float, psi: float, near: float) -> float:
    """The voltage nearest ``near`` where the fringe's phase is the model's ``psi`` at zero
    delay error: 2 pi f (V - V0) + psi = 2 pi f V + phi."""
    v0 = (psi - phi) / (2 * np.pi * f)
    period_v = 1.0 / f
    return float(v0 + np.round((near - v0) / period_v) * period_v)
