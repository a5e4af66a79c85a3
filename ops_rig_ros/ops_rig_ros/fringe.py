"""The fits of the calibration (pure numpy; the stacker's model from ops_sim_ros.physics).

* :func:`find_slots`: the record index of every pulse slot from records in which the slots lit
  up (the maximum over them): peaks, then a regular grid fitted through them.
* :func:`fit_fringe`: a sinusoid ``a + b cos(2 pi f V + phi)`` of a signal against voltage; the
  frequency by a scan of linear least-squares fits, refined by a parabola.
* :func:`indicator_weights`: a signed sum of slot energies that shows stage j's fringe with
  its maximum at zero delay error whatever the later stages do (the slots m with m + 1 a
  multiple of 2^j, signed by the model). So stage j is calibrated from its own sweep alone.
"""

from __future__ import annotations

import numpy as np


class CalibrationError(RuntimeError):
    """The sweeps do not give a trustworthy fit (the message says why)."""


def find_slots(max_record: np.ndarray, num_slots: int, min_fraction: float = 0.15) -> np.ndarray:
    """Centres (fractional record indices) of ``num_slots`` evenly spaced pulse slots."""
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
    return a + b * np.arange(num_slots)


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
    (a, c, d), cost = _lsq(v, s, f)
    b = float(np.hypot(c, d))
    phi = float(np.arctan2(-d, c))  # c cos x + d sin x = b cos(x + phi)
    return f, float(a), b, phi, (cost / v.size) ** 0.5


def indicator_weights(stage: int, j: int, optics: dict | None = None) -> np.ndarray:
    """Weights (+1, -1 or 0 per output slot) of the signal that shows stage j's (0-based)
    fringe at its maximum at zero delay error of stage j, whatever the later stages do (the
    earlier ones at zero). The slots m with (m + 1) divisible by 2^j have a fringe in stage j's
    delay whose phase does not depend on the other stages; the model says whether each has a
    maximum (+1) or a minimum (-1) at zero error, so their signed sum adds up."""
    from ops_sim_ros.physics import PulseStacker

    optics = optics or {}
    ps = PulseStacker(
        stage=stage,
        wavelength_nm=float(optics.get("wavelength_nm", 1030.0)),
        pulse_fwhm_fs=float(optics.get("pulse_fwhm_fs", 1000.0)),
        detector=str(optics.get("detector", "polarizer")),
        dtype=np.float64,
    )
    phases = np.linspace(0.0, ps.optical_period_fs, 16, endpoint=False)
    d = np.zeros((phases.size, stage))
    d[:, j] = phases
    coef = ps.slot_energies(d).T @ np.exp(-2j * np.pi * phases / ps.optical_period_fs)
    weights = np.sign(coef.real) * (np.abs(coef) > 1e-9)
    weights[(np.arange(ps.num_slots) + 1) % 2**j != 0] = 0.0
    return weights


def optical_period_fs(optics: dict | None = None) -> float:
    from ops_sim_ros.config import SPEED_OF_LIGHT_NM_PER_FS

    return float((optics or {}).get("wavelength_nm", 1030.0)) / SPEED_OF_LIGHT_NM_PER_FS


def zero_from_fit(f: float, phi: float, psi: float, near: float) -> float:
    """The voltage nearest ``near`` where the fringe's phase is the model's ``psi`` at zero
    delay error: 2 pi f (V - V0) + psi = 2 pi f V + phi."""
    v0 = (psi - phi) / (2 * np.pi * f)
    period_v = 1.0 / f
    return float(v0 + np.round((near - v0) / period_v) * period_v)
