"""Online calibration of the tracker's model: what a rig does not tell its controller.

The tracker (:mod:`ops_controller_ros.tracker`) is built from a nominal model; a real rig is off
it. :class:`ModelCalibration` estimates, from the tracker's own fits and readings and without a
calibration phase:

* the detector's **gain and offset** (detected energy = gain x model energy + offset): a least
  squares line through (model-predicted, detected) slot energies of every tracked reading, with
  exponential forgetting over ``memory`` readings; the tracker fits its delays to the corrected
  readings ``(detected - offset) / gain``. Where an acquisition does not fit, the same line is
  fitted once to its best candidate, so a detector far off its calibration is still acquired.
* the **centre wavelength** and the **pulse width** (FWHM): Gauss-Newton on normal equations
  accumulated over the windows of tracked readings, each window's fitted error path held fixed.
  The wavelength is seen through the set-points: a move of d fs is d / period cycles of phase,
  so within a window the commanded moves (excursions, the drift's feed-forward) are stretched or
  shrunk by a wrong period. The pulse width is seen only through the envelopes' overlap, which
  changes by about (delay / width)^2 (1e-4 at a few fs of delay against 1 ps): near lock it is
  barely observable and a ridge keeps it near its nominal value unless the readings say
  otherwise. Each update moves the wavelength by at most 0.5 % and the width by at most 5 %.

Pure numpy (no rclpy).
"""

from __future__ import annotations

import numpy as np

WAVELENGTH_STEP = 1e-3  # relative finite-difference step of the wavelength
WIDTH_STEP = 0.05  # relative finite-difference step of the pulse width
MAX_WAVELENGTH_MOVE = 0.005  # per update, relative
MAX_WIDTH_MOVE = 0.05


class ModelCalibration:
    """Running estimates of wavelength, pulse width, detector gain and offset (see the module
    docstring). ``model``: the nominal OpsConfig the tracker was built from."""

    def __init__(self, model, memory: float = 500.0) -> None:
        self.nominal = model
        self.forget = 1.0 - 1.0 / float(memory)
        self.wavelength_nm = float(model.wavelength_nm)
        self.pulse_fwhm_fs = float(model.pulse_fwhm_fs)
        self.gain = 1.0
        self.offset = 0.0
        self.detector_fitted = False  # the gain and offset fitted since start or reset
        # ... by an acquisition only: to low readings, where the delay errors move the slot
        # energies as much as the gain does (see PhaseTracker._detector_settled)
        self.detector_provisional = False
        self._line = np.zeros(5)  # sums of 1, f, y, f f, f y (forgetting)
        self._normal = np.zeros((2, 2))  # J^T J of (log wavelength, log width)
        self._rhs = np.zeros(2)  # J^T r
        self._width_stacker = None  # the model at a width WIDTH_STEP wider (finite difference)
        self.updates = 0

    # ------------------------------------------------------------------ the model now
    def config(self, **changes):
        """The nominal model with the estimated optics (and ``changes``)."""
        data = dict(wavelength_nm=self.wavelength_nm, pulse_fwhm_fs=self.pulse_fwhm_fs)
        data.update(changes)
        return self.nominal.replace(**data)

    def stacker(self):
        from ops_sim_ros.physics import stacker_from_config

        return stacker_from_config(self.config())

    @property
    def period_fs(self) -> float:
        return self.config().optical_period_fs

    def estimates(self) -> dict[str, float]:
        """What is estimated now: wavelength_nm, pulse_fwhm_fs, detector_gain, detector_offset."""
        return {
            "wavelength_nm": self.wavelength_nm,
            "pulse_fwhm_fs": self.pulse_fwhm_fs,
            "detector_gain": self.gain,
            "detector_offset": self.offset,
        }

    # ------------------------------------------------------------------ detector
    def correct(self, readings: np.ndarray) -> np.ndarray:
        """Readings (K, S + 1) with the energies (not the last column, P_N/P_max) corrected."""
        y = np.array(readings, dtype=np.float64)
        y[:, :-1] = (y[:, :-1] - self.offset) / self.gain
        return y

    def detector_state(self) -> tuple:
        """What :meth:`fit_detector` changes, for :meth:`restore_detector`."""
        return self.gain, self.offset, self._line.copy()

    def restore_detector(self, state: tuple) -> None:
        self.gain, self.offset, self._line = state[0], state[1], state[2].copy()

    def reset_detector(self) -> bool:
        """Back to the nominal detector (gain 1, offset 0); True if that changed anything."""
        changed = (self.gain, self.offset) != (1.0, 0.0)
        self.gain, self.offset = 1.0, 0.0
        self.detector_fitted = self.detector_provisional = False
        self._line = np.zeros(5)
        return changed

    def fit_detector(self, predicted: np.ndarray, raw: np.ndarray, provisional=False) -> bool:
        """Fit gain and offset to one window (model-predicted and detected readings, (K, S + 1));
        False (nothing changed) where the window does not determine a plausible line.
        ``provisional``: an acquisition's fit, to be fitted again on locked readings."""
        f, y = predicted[:, :-1].ravel(), raw[:, :-1].ravel()
        line = np.array([f.size, f.sum(), y.sum(), f @ f, f @ y])
        gain, offset = _solve_line(line)
        if not 0.05 <= gain <= 20.0:
            return False
        self.gain, self.offset = gain, offset
        self.detector_fitted, self.detector_provisional = True, bool(provisional)
        self._line = line
        return True

    # ------------------------------------------------------------------ tracking
    def observe(
        self,
        stacker,
        u: np.ndarray,
        path: np.ndarray,
        raw: np.ndarray,
        period_fs,
        optics=True,
        weights=None,
    ):
        """One tracked window: set-points ``u`` (K, N) cycles, the fitted errors ``path`` (K, N),
        the detected readings ``raw`` (K, S + 1); ``stacker`` models the present estimate;
        ``optics``: accumulate the wavelength's and width's statistics too; ``weights`` (S + 1,)
        of the entries in that fit (None: alike)."""
        k = self.forget
        pts = u + path
        if not optics:
            out = stacker.evaluate(pts[-1:] * period_fs)
            self._observe_detector(out.slot_energies[0], raw[-1, :-1])
            return
        moves = u - u.mean(axis=0)
        out = stacker.evaluate(np.concatenate([pts, pts - WAVELENGTH_STEP * moves]) * period_fs)
        pred = np.concatenate([out.slot_energies, out.power[:, None]], axis=1)
        base, stretched = pred[: len(u)], pred[len(u) :]
        if self._width_stacker is None:
            from ops_sim_ros.physics import stacker_from_config

            wide = self.config(pulse_fwhm_fs=self.pulse_fwhm_fs * (1 + WIDTH_STEP))
            self._width_stacker = stacker_from_config(wide)
        out_w = self._width_stacker.evaluate(pts * period_fs)
        wide = np.concatenate([out_w.slot_energies, out_w.power[:, None]], axis=1)
        self._observe_detector(base[-1, :-1], raw[-1, :-1])
        # wavelength and width: Gauss-Newton on the window
        w = 1.0 if weights is None else weights
        r = ((self.correct(raw) - base) * w).ravel()
        jac = np.stack(
            [
                ((stretched - base) * w).ravel() / WAVELENGTH_STEP,
                ((wide - base) * w).ravel() / WIDTH_STEP,
            ]
        )
        self._normal = k * self._normal + jac @ jac.T
        self._rhs = k * self._rhs + jac @ r

    def take_fitted_line(self, gain_step: float, level_step: float) -> None:
        """A tracking fit's relative gain g and offset o of the corrected readings (the
        tracker's ``lock_gain_walk`` and ``lock_offset_walk``): those read (1 + g) times the
        prediction plus o, so the offset moves by o times the present gain, then the gain
        takes the factor 1 + g."""
        self.offset += level_step * self.gain
        self.gain *= 1.0 + gain_step

    def _observe_detector(self, f: np.ndarray, y: np.ndarray) -> None:
        """The detector's line from one reading's predicted and detected energies (each reading
        is the latest of a window once)."""
        self._line = self.forget * self._line + np.array([f.size, f.sum(), y.sum(), f @ f, f @ y])
        if self._line[0] > 4 * f.size:
            gain, offset = _solve_line(self._line)
            if 0.05 <= gain <= 20.0:
                self.gain, self.offset = gain, offset
                self.detector_fitted = True

    def update_optics(self) -> bool:
        """Move wavelength and width by the accumulated Gauss-Newton step; True if they moved."""
        a = self._normal
        if not np.all(np.isfinite(a)) or a.max() <= 0:
            return False
        ridge = 1e-2 * np.diag(a).max() + 1e-12  # an unseen direction stays where it is
        step = np.linalg.solve(a + ridge * np.eye(2), self._rhs)
        step = np.clip(
            step, [-MAX_WAVELENGTH_MOVE, -MAX_WIDTH_MOVE], [MAX_WAVELENGTH_MOVE, MAX_WIDTH_MOVE]
        )
        self.wavelength_nm *= 1.0 + float(step[0])
        self.pulse_fwhm_fs *= 1.0 + float(step[1])
        self._normal = np.zeros((2, 2))
        self._rhs = np.zeros(2)
        self._width_stacker = None
        self.updates += 1
        return True


def _solve_line(line: np.ndarray) -> tuple[float, float]:
    """(gain, offset) of the least-squares line y = gain f + offset from sums (n, f, y, ff, fy)."""
    n, sf, sy, sff, sfy = line
    det = n * sff - sf * sf
    if det <= 1e-12 * max(n * sff, 1e-300):
        return float("nan"), float("nan")
    gain = (n * sfy - sf * sy) / det
    return float(gain), float((sy - gain * sf) / n)
