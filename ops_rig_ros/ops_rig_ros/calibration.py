"""The calibration procedure (no rclpy): sweeps each stage gently within the limits, fits the
fringe and returns a :class:`~.rig_config.Calibration` (docs/rig.md, "Calibration").

1. Slots: every channel moves through its sweep span at once on a Lissajous path (different
   frequencies per channel), so every output slot lights up in some record; the slot centres
   are the peaks of the records' maximum, the grid centred where the records' mean is
   mirror-symmetric (:func:`~.fringe.find_slots`).
2. Stage by stage (j = 1 .. N), the others held (earlier ones at their zero, later ones at mid
   range): the earlier stages peaked up again on their own indicators (they drifted since their
   sweeps), then a sweep of ``sweep_span_volts`` around mid range, up and back down
   (:func:`_sweep_stage`); stage j's indicator signal (a signed sum of slot energies,
   :func:`~.fringe.indicator_weights`) fitted by ``a + b cos(2 pi f V + phi)``: fs per volt =
   optical period x f (f the mean of the two directions'); the zero is where the indicator
   peaks (its phase is that at zero delay error whatever the later stages do), the one nearest
   mid range. A stage without a clear fringe is tried once more (:data:`SWEEP_TRIES`).
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
    fit_at_frequency,
    fit_fringe,
    indicator_weights,
    optical_period_fs,
    zero_from_fit,
)
from .rig import Rig
from .rig_config import Calibration

SWEEP_POINTS = 30  # per direction: each stage is swept up, then down
SWEEP_TRIES = 2  # sweeps of a stage whose fringe is not clear before the calibration gives up
SLOT_SEARCH_POINTS = 64
MIN_FRINGE_SNR = 3.0  # fitted amplitude over the residual rms
PEAK_POINTS = 9  # per stage and pass of the final peaking
PEAK_SPAN_CYCLES = 0.5  # the peaking sweep: this many optical cycles about the zero
PEAK_PASSES = 2  # the peaking up goes over every stage this many times


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
    records = []
    for ti in t:
        target = mid + (high - mid) * np.sin(2 * np.pi * ti * (1.0 + 0.37 * np.arange(n)))
        rig.drive.ramp_to(target)
        records.append(rig.read_record())
    records = np.array(records)
    positions = find_slots(records.max(0), 2**n - 1, mean_record=records.mean(0))
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
        read = indicator_reader(n, j, cfg.optics, positions)
        for attempt in range(1, SWEEP_TRIES + 1):
            # The earlier stages drifted since their sweeps (hard mode: up to ~0.1 cycle per
            # stage's sweep); their indicators peaked up again, so stage j's fringe stays clear.
            for i in range(j):
                held[i] = zero[i] = _peak_stage(
                    rig, held, i, period / k[i], indicator_reader(n, i, cfg.optics, positions)
                )[0]
            try:
                f, a, b, phi, rms = _sweep_stage(rig, held, j, low[j], high[j], read)
                break
            except CalibrationError as exc:
                if attempt == SWEEP_TRIES:
                    raise
                log(f"{exc}: sweeping it again")
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


def _sweep_stage(rig: Rig, held, j: int, low: float, high: float, read):
    """Stage j swept from ``low`` to ``high`` and back (the others at ``held``), the signal
    ``read(record)`` fitted by ``a + b cos(2 pi f V + phi)`` in each direction: returns f (the
    mean of the two: a steady drift adds to the fringe's frequency on the way up what it takes
    on the way down) and a, b, phi, rms of the way down (the latest). CalibrationError when a
    fringe is weaker than :data:`MIN_FRINGE_SNR` x its residual."""
    up = np.linspace(low, high, SWEEP_POINTS)
    span = high - low
    fits = []
    for volts in (up, up[::-1]):
        signal = _sweep_signal(rig, held, j, volts, read)
        f, _, b, _, rms = fit_fringe(volts, signal, 1.5 / span, SWEEP_POINTS / (2.5 * span))
        if b < MIN_FRINGE_SNR * rms:
            raise CalibrationError(
                f"stage {j + 1}: no clear fringe (amplitude {b:.3g} V against {rms:.3g} V of "
                "residual); widen sweep_span_volts or check the light"
            )
        fits.append((volts, signal, f))
    f = 0.5 * (fits[0][2] + fits[1][2])
    volts, signal, _ = fits[1]
    return (f, *fit_at_frequency(volts, signal, f))


def _sweep_signal(rig: Rig, held, j: int, volts: np.ndarray, read) -> np.ndarray:
    """``read(record)`` with stage j at each of ``volts`` in turn (the others at ``held``),
    each move at the slew limit."""
    signal = np.empty(volts.size)
    for i, v in enumerate(volts):
        target = held.copy()
        target[j] = v
        rig.drive.ramp_to(target)
        signal[i] = read(_settled_record(rig))
    return signal


def indicator_reader(n: int, j: int, optics: dict, positions) -> Callable[[np.ndarray], float]:
    """Stage j's indicator signal (:func:`~.fringe.indicator_weights`) of a record."""
    weights = indicator_weights(n, j, optics)
    used = weights != 0
    at = positions[used]
    return lambda record: float(np.interp(at, np.arange(record.size), record) @ weights[used])


def _peak_stage(rig: Rig, held, j: int, period_v: float, read) -> tuple[float, float]:
    """Stage j swept at :data:`PEAK_POINTS` points over :data:`PEAK_SPAN_CYCLES` about
    ``held[j]`` (the others at ``held``), the signal ``read(record)`` fitted by
    ``a + b cos(2 pi (V - V0) / period_V)``: the voltage of its peak nearest ``held[j]`` (or
    ``held[j]`` when the fit finds none within the sweep) and the fitted peak reading."""
    lim = rig.config.limits
    volts = held[j] + period_v * PEAK_SPAN_CYCLES * np.linspace(-1, 1, PEAK_POINTS)
    volts = np.clip(volts, lim.volts_min[j], lim.volts_max[j])
    signal = _sweep_signal(rig, held, j, volts, read)
    rig.drive.ramp_to(held)
    x = 2 * np.pi * volts / period_v
    design = np.stack([np.ones_like(x), np.cos(x), np.sin(x)], 1)
    (a, c, d), *_ = np.linalg.lstsq(design, signal, rcond=None)
    b = float(np.hypot(c, d))
    best = float(np.arctan2(d, c)) * period_v / (2 * np.pi)  # where the cosine peaks
    best += np.round((held[j] - best) / period_v) * period_v
    if not (abs(best - held[j]) < period_v * PEAK_SPAN_CYCLES and b > 0):
        best = float(held[j])
    return best, float(a + b)


def peak_up(rig: Rig, zero, k, period: float, positions, log) -> tuple[np.ndarray, float]:
    """Refine the zeros on the stacked pulse itself, quickly, so the drift during the long
    sweeps does not stay in them: each stage in turn (the others at their zeros) by
    :func:`_peak_stage` on the stacked slot's reading (period known from the fs per volt);
    twice over. Returns the zeros and the fitted peak reading (volts) of the last fit."""
    main = positions[(positions.size - 1) // 2]

    def read(record):
        return float(np.interp(main, np.arange(record.size), record))

    zero = zero.copy()
    peak = None
    for _ in range(PEAK_PASSES):
        for j in range(zero.size):
            zero[j], peak = _peak_stage(rig, zero, j, period / k[j], read)
    rig.drive.ramp_to(zero)
    return zero, float(peak)
