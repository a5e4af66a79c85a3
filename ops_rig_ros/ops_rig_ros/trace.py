"""From a scope record (volts) to the project's pulse trace and an estimate of P_N / P_max.

Pure numpy. The calibration gives the record index of each pulse slot's centre, the detector's
offset and the reading of a perfectly stacked pulse; :func:`extract_trace` samples the record
around each slot centre (``samples_per_slot`` points spread over one slot, linear
interpolation, the centre at sample ``samples_per_slot // 2`` as in the simulator's trace) and
normalizes it, so a perfectly stacked pulse reads 1 in its slot.

The reading of no light it subtracts is, by default, each record's own baseline
(:func:`record_baseline`, the record half-way between neighbouring slots): the calibration's
offset comes from a fringe fit made while the stacker drifts, and on the simulated lab it was
off by -9e-4 to +11e-4 of the full scale. At the stack every slot but one reads that error; a
positive one reads like light leaking into the empty slots, which only delay errors make, and
the tracker's fits took it for them (docs/rig.md, "The detector's offset, measured in every
record"). A detector's offset also moves with temperature long after a calibration.

:func:`estimate_power`: the simulator's P_N / P_max is the detector's second-order signal
(integral of I^2) over that of the perfect stack. For pulses that keep their shape (delay errors
of a few fs against a pulse of ~1 ps) every slot's integral of I^2 is its energy squared in
those units, so P_N / P_max = sum over slots of E_m^2 (exact to 1e-7 on the simulator's model,
ops_rig_ros/test/test_trace.py). Negative readings (noise around zero) count as zero; the
result is clipped to [0, 1].
"""

from __future__ import annotations

import numpy as np

from .rig_config import BASELINES, Calibration


class TraceError(ValueError):
    """A record that cannot give a trace (too short for the slots, non-finite)."""


def slot_spacing(positions: np.ndarray) -> float:
    """Record samples between neighbouring slot centres (1 for a single slot)."""
    return float(np.median(np.diff(positions))) if positions.size > 1 else 1.0


def sample_points(positions: np.ndarray, samples_per_slot: int) -> np.ndarray:
    """Record indices (fractional) of every trace sample, slot-major."""
    spp = int(samples_per_slot)
    step = slot_spacing(positions) / spp
    offsets = (np.arange(spp) - spp // 2) * step
    return (positions[:, None] + offsets[None, :]).ravel()


def extract_trace(
    volts: np.ndarray, cal: Calibration, samples_per_slot: int, baseline: str = "record"
) -> np.ndarray:
    """The normalized trace (S * samples_per_slot,) float64 of a record. ``baseline``:
    ``record`` subtracts the record's own baseline (:func:`record_baseline`; the calibrated
    offset where there is one slot only), ``calibrated`` the calibration's offset (a detector
    whose response has not settled half-way between slots)."""
    if baseline not in BASELINES:
        raise ValueError(f"baseline must be one of {', '.join(BASELINES)} (got {baseline!r})")
    volts = np.asarray(volts, dtype=np.float64)
    points = sample_points(cal.slot_positions, samples_per_slot)
    if volts.size < 2 or points.max() > volts.size - 1 or points.min() < 0:
        raise TraceError(
            f"record of {volts.size} points does not reach the calibrated slots "
            f"(up to index {points.max():.0f}); re-run calibrate if the scope's set-up changed"
        )
    if not np.all(np.isfinite(volts)):
        raise TraceError("non-finite values in the record")
    raw = np.interp(points, np.arange(volts.size), volts)
    offset = cal.detector_offset_volts
    if baseline == "record" and cal.slot_positions.size > 1:
        offset = record_baseline(volts, cal.slot_positions)
    return (raw - offset) / cal.detector_full_volts


def record_baseline(volts: np.ndarray, positions: np.ndarray) -> float:
    """A record's reading of no light: its mean half-way between neighbouring slots, where no
    pulse is (needs two slots at least)."""
    volts = np.asarray(volts, dtype=np.float64)
    between = 0.5 * (positions[1:] + positions[:-1])
    return float(np.mean(np.interp(between, np.arange(volts.size), volts)))


def slot_readings_volts(volts: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Each slot's reading (S,) at its centre, above the record's own baseline
    (:func:`record_baseline`). Measured in the same record, the baseline takes the offset's
    error out (against the calibrated offset, an error of 1 mV, over the 31 slots of N = 5,
    moved their sum by 31 mV)."""
    volts = np.asarray(volts, dtype=np.float64)
    centres = np.interp(positions, np.arange(volts.size), volts)
    if positions.size < 2:
        return centres
    return centres - record_baseline(volts, positions)


def slot_energies(trace: np.ndarray, samples_per_slot: int) -> np.ndarray:
    """Each slot's pulse energy: the trace at the slot centres."""
    spp = int(samples_per_slot)
    return np.asarray(trace)[spp // 2 :: spp]


def estimate_power(trace: np.ndarray, samples_per_slot: int) -> float:
    """P_N / P_max estimated from a normalized trace (see the module docstring)."""
    e = np.maximum(slot_energies(trace, samples_per_slot), 0.0)
    return float(np.clip(np.sum(e * e), 0.0, 1.0))
