"""The calibration procedure (no rclpy): sweeps each stage gently within the limits, fits the
fringe and returns a :class:`~.rig_config.Calibration` (docs/rig.md, "Calibration").

1. Slots: every channel moves through its sweep span at once on a Lissajous path (different
   frequencies per channel), so every output slot lights up in some record; the slot centres
   are the peaks of the records' maximum (:func:`~.fringe.find_slots`).
2. Stage by stage (j = 1 .. N), the others held (earlier ones at their zero, later ones at mid
   range): a sweep of ``sweep_span_volts`` around mid range; stage j's indicator signal (a
   signed sum of slot energies, :func:`~.fringe.indicator_weights`) fitted by
   ``a + b cos(2 pi f V + phi)``: fs per volt = optical period x f; the zero is where the
   indicator peaks (its phase is that at zero delay error whatever the later stages do), the
   one nearest mid range.
3. Detector offset: the last stage's indicator is the stacked pulse's slot alone, which goes
   to no light at its minimum: offset = a - b.
4. Peaking up: the sweeps take seconds, in which a drifting stacker moves; so each stage is
   swept once more over half a cycle about its zero, quickly (:func:`peak_up`, twice over),
   the zeros moved to the stacked pulse's peak, and the full scale taken as that peak's
   reading above the offset (the stack at its best reads 1).

The delay is assumed to grow with the voltage (positive fs per volt): a fringe cannot tell.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .fringe import (
    CalibrationError,
    find_slots,
    fit_fringe,
    indicator_weights,
    optical_period_fs,
    zero_from_fit,
)
from .rig import Rig
from .rig_config import Calibration

SWEEP_POINTS = 60
SLOT_SEARCH_POINTS = 64
MIN_FRINGE_SNR = 3.0
PEAK_POINTS = 9  # per stage and pass of the final peaking
PEAK_SPAN_CYCLES = 0.5  # the peaking sweep: this many optical cycles about the zero
PEAK_PASSES = 2  # fitted amplitude over the residual rms


def _settled_record(rig: Rig) -> np.ndarray:
    """The record after a move: ``settle_reads`` records taken, the last one kept (a rig whose
    piezos answer a move late, or over several readings, needs a few)."""
    record = None
    for _ in range(rig.config.settle_reads):
        record = rig.read_record()
    return record


def sweep_window(rig: Rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(low, mid, high) voltages of each channel's sweep: ``sweep_span_volts`` about mid range,
    within the limits."""
    lim = rig.config.limits
    mid = 0.5 * (lim.volts_min + lim.volts_max)
    half = np.minimum(0.5 * rig.config.sweep_span_volts, 0.5 * (lim.volts_max - lim.volts_min))
    return mid - half, mid, mid + half


def calibrate(rig: Rig, log: Callable[[str], None] = print) -> Calibration:
    """Run the calibration on a connected rig; CalibrationError when a fit is not trustworthy."""
    cfg = rig.config
    n = cfg.stage
    low, mid, high = sweep_window(rig)
    period = optical_period_fs(cfg.optics)
    rig.drive.ramp_to(mid)

    # 1. Where the slots are.
    t = np.arange(SLOT_SEARCH_POINTS) / SLOT_SEARCH_POINTS
    peak = None
    for ti in t:
        target = mid + (high - mid) * np.sin(2 * np.pi * ti * (1.0 + 0.37 * np.arange(n)))
        rig.drive.ramp_to(target)
        record = rig.read_record()
        peak = record if peak is None else np.maximum(peak, record)
    positions = find_slots(peak, 2**n - 1)
    log(
        f"found {positions.size} pulse slots, {np.median(np.diff(positions)) if n > 1 else 0:.2f} "
        f"record points apart, the first at {positions[0]:.1f}"
    )

    # 2. Stage by stage.
    held = mid.copy()
    k = np.zeros(n)
    zero = np.zeros(n)
    offset = full = None
    for j in range(n):
        volts = np.linspace(low[j], high[j], SWEEP_POINTS)
        signal = np.empty(SWEEP_POINTS)
        weights = indicator_weights(n, j, cfg.optics)
        used = weights != 0
        for i, v in enumerate(volts):
            target = held.copy()
            target[j] = v
            rig.drive.ramp_to(target)
            record = _settled_record(rig)
            at = np.interp(positions[used], np.arange(record.size), record)
            signal[i] = at @ weights[used]
        span = volts[-1] - volts[0]
        f, a, b, phi, rms = fit_fringe(volts, signal, 1.5 / span, SWEEP_POINTS / (2.5 * span))
        if b < MIN_FRINGE_SNR * rms:
            raise CalibrationError(
                f"stage {j + 1}: no clear fringe (amplitude {b:.3g} V against {rms:.3g} V of "
                "residual); widen sweep_span_volts or check the light"
            )
        k[j] = period * f
        zero[j] = zero_from_fit(f, phi, 0.0, mid[j])
        period_v = 1.0 / f
        while zero[j] > cfg.limits.volts_max[j]:
            zero[j] -= period_v
        while zero[j] < cfg.limits.volts_min[j]:
            zero[j] += period_v
        held[j] = zero[j]
        rig.drive.ramp_to(held)
        log(
            f"stage {j + 1}: {k[j]:.4f} fs/V, zero at {zero[j]:.3f} V "
            f"(fringe {b:.3g} V, residual {rms:.2g} V)"
        )
        if j == n - 1:
            offset = a - b
    zero, peak_volts = peak_up(rig, zero, k, period, positions, log)
    full = peak_volts - offset
    log(f"peaked up: zeros {np.round(zero, 3).tolist()} V, full stack reads {full:.4f} V")
    return Calibration(k, zero, positions, float(offset), float(full))


def peak_up(rig: Rig, zero, k, period: float, positions, log) -> tuple[np.ndarray, float]:
    """Refine the zeros on the stacked pulse itself, quickly, so the drift during the long
    sweeps does not stay in them: each stage in turn (the others at their zeros) at
    :data:`PEAK_POINTS` points over :data:`PEAK_SPAN_CYCLES` about its zero, the stacked slot's
    reading fitted by ``a + b cos(2 pi (V - V0) / period_V)`` (period known from the fs per
    volt); twice over. Returns the zeros and the fitted peak reading (volts) of the last fit."""
    lim = rig.config.limits
    main = positions[(positions.size - 1) // 2]
    zero = zero.copy()
    peak = None
    for _ in range(PEAK_PASSES):
        for j in range(zero.size):
            period_v = period / k[j]
            volts = zero[j] + period_v * PEAK_SPAN_CYCLES * np.linspace(-1, 1, PEAK_POINTS)
            volts = np.clip(volts, lim.volts_min[j], lim.volts_max[j])
            signal = np.empty(volts.size)
            for i, v in enumerate(volts):
                target = zero.copy()
                target[j] = v
                rig.drive.ramp_to(target)
                record = _settled_record(rig)
                signal[i] = np.interp(main, np.arange(record.size), record)
            x = 2 * np.pi * volts / period_v
            design = np.stack([np.ones_like(x), np.cos(x), np.sin(x)], 1)
            (a, c, d), *_ = np.linalg.lstsq(design, signal, rcond=None)
            b = float(np.hypot(c, d))
            best = float(np.arctan2(d, c)) * period_v / (2 * np.pi)  # where the cosine peaks
            best += np.round((zero[j] - best) / period_v) * period_v
            if abs(best - zero[j]) < period_v * PEAK_SPAN_CYCLES and b > 0:
                zero[j] = best
            peak = a + b
        rig.drive.ramp_to(zero)
    return zero, float(peak)
