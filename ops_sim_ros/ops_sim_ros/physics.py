"""Batched physics of the seed's N-stage optical pulse stacker (polarization-coded input).

Model (see ``docs/physics.md`` for the derivation and a figure of the paths):

* Input: 2^N identical sech^2 pulses in time slots 0 .. 2^N - 1 (slot spacing T). A modulator in
  front of the stacker gives each pulse a linear polarization (s or p) and a sign (+-1). The code
  is recursive: start from the single label -s and expand it N times, every label into an ordered
  pair (earlier pulse first): p -> (p, s), -p -> (-p, -s), s -> (-p, s), -s -> (p, -s).
* Stage j = 1..N, d = 2^(j-1) (no per-stage gating; the whole beam goes through every stage):
  1. a polarizing beam splitter sends p through the delay line: p moves by d slots plus the delay
     error delta_j (envelope shift and carrier phase exp(i w0 delta_j)); s goes straight, so in
     every coded pair the earlier pulse (p) lands on the later one (s);
  2. the beams recombine and a wave plate at 45 deg mixes them:
     p' = (p + s) / sqrt(2), s' = (s - p) / sqrt(2).
* The perfectly stacked pulse leaves in s in time slot 2^N - 1. The detector integrates I^2 of
  either the s port behind an output polarizer (``detector="polarizer"``, the default and the
  physical choice: one stage gives the cos^4 fringe of the paper's Figure 2a) or the total
  intensity of both polarizations (``detector="total"``, as the authors' code: the last stage's
  phase is then invisible, so N stages pose an (N - 1)-stage phase problem and N = 1 is flat).

Every path through the stacker is labelled by its delay pattern b (bit j-1 set: went through
stage j's delay line), so the field of port q (s or p) in output slot m is exactly

    E_qm(t) = sum_b C_q[m, b] * exp(i w0 s_b) * a(t - s_b),     s_b = sum_j bit_j(b) delta_j,

with C_s, C_p constant real matrices of the geometry, built once by propagating the coded unit
amplitudes. Slot energies and the second-order detector signal (integral of I^2) are integrals
over t, done with a K-point Gauss-Legendre rule in x = tanh(t / t0), which is exact for an
unshifted sech^2 and sech^4 and converges geometrically for shifted ones. For a batch all of this
is ONE real matrix product.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ops_contract.config import DETECTORS, SPEED_OF_LIGHT_NM_PER_FS

from .source import burst_amplitudes

SECH_FWHM_FACTOR = 2.0 * np.arccosh(np.sqrt(2.0))  # FWHM of sech^2(t/t0) = 1.7627 t0


def input_coding(stage: int) -> list[tuple[str, int]]:
    """Polarization and sign of each of the 2^N input pulses, earliest first: [("p", 1), ...].

    The modulator's code of the seed: start from -s and expand each label N times into an
    ordered pair, p -> (p, s), -p -> (-p, -s), s -> (-p, s), -s -> (p, -s).
    """
    labels = [("s", -1)]
    for _ in range(int(stage)):
        expanded = []
        for pol, sign in labels:
            if pol == "p":
                expanded += [("p", sign), ("s", sign)]
            else:
                expanded += [("p", -sign), ("s", sign)]
        labels = expanded
    return labels


def geometry_matrices(
    stage: int, through: int | None = None, amplitudes=None
) -> tuple[np.ndarray, np.ndarray]:
    """Propagate the coded input amplitudes through the stacker geometry.

    Returns ``(C_s, C_p)``, each (2^(N+1) - 1 time slots, 2^N delay patterns): the amplitude with
    which light of delay pattern b arrives in time slot m of the s port (the one the output
    polarizer passes) and of the p port, before the envelope and carrier factors. ``through``:
    stop after that many stages (0: the coded input), for figures of the paths. ``amplitudes``
    (2^N,): the input pulses' field amplitudes, earliest first (default: all 1). Light of
    pattern b in time slot m comes from input slot m - b alone, so an amplitude scales entries.
    """
    n = int(stage)
    last = n if through is None else int(through)
    num_in = 2**n
    num_slots = 2 ** (n + 1) - 1
    amp = np.zeros((2, num_slots, num_in))  # (polarization s/p, time slot, pattern)
    scale = np.ones(num_in) if amplitudes is None else np.asarray(amplitudes, dtype=np.float64)
    if scale.shape != (num_in,):
        raise ValueError(f"amplitudes must have shape ({num_in},), got {scale.shape}")
    for k, (pol, sign) in enumerate(input_coding(n)):
        amp[0 if pol == "s" else 1, k, 0] = sign * scale[k]
    inv_sqrt2 = 1.0 / np.sqrt(2.0)
    for j in range(1, last + 1):
        d = 2 ** (j - 1)
        s = amp[0]
        p = np.zeros_like(s)  # PBS: p takes the delay line (d slots, pattern bit j-1)
        assert not np.any(amp[1, num_slots - d :]), "energy would leave the slot window"
        p[d:, d:] = amp[1, : num_slots - d, : num_in - d]
        # A pattern bit j-1 is never set before stage j, so the shift above is exact; check it.
        assert not np.any(amp[1][:, d:][:, ((np.arange(d, num_in) >> (j - 1)) & 1) == 1])
        amp = np.stack(((s - p) * inv_sqrt2, (p + s) * inv_sqrt2))  # wave plate at 45 deg
    return amp[0].copy(), amp[1].copy()


@dataclass
class StackerOutput:
    """Everything one physics evaluation gives, for a batch of B delay-error vectors.

    Energies are normalized by the input energy (2^N pulses), so detected plus rejected energy
    sums to 1. "Detected" follows the stacker's detector: the s port behind the output polarizer
    (``polarizer``) or both polarizations (``total``, which rejects nothing).
    """

    power: np.ndarray  # (B,) P_N / P_max: second-order detector signal, normalized
    slot_energies: np.ndarray  # (B, S) detected energy in each output slot
    main_pulse_energy: np.ndarray  # (B,) detected energy in the stacked-pulse slot (2^N - 1)
    rejected_energy: np.ndarray  # (B,) energy the detector does not see (the polarizer's p port)
    rejected_slot_energies: np.ndarray | None = None  # (B, S) when computed explicitly

    @property
    def satellite_energies(self) -> np.ndarray:
        """(B, S) detected energies with the main slot set to zero."""
        sat = self.slot_energies.copy()
        sat[:, (sat.shape[1] - 1) // 2] = 0.0
        return sat


class PulseStacker:
    """Noise-free, batched N-stage pulse stacker.

    Parameters
    ----------
    stage:
        Number of stages N (2^N pulses are stacked).
    wavelength_nm, pulse_fwhm_fs:
        Carrier wavelength and sech^2 intensity FWHM of the input pulses.
    quadrature_points:
        Time samples per slot for the energy and I^2 integrals (Gauss-Legendre in tanh(t/t0)).
    samples_per_slot:
        Samples of the detected intensity trace per slot (see :meth:`trace`).
    detector:
        ``"polarizer"`` (default): the s port behind an output polarizer; ``"total"``: the
        intensity of both polarizations (the authors' code).
    dtype:
        ``np.float32`` (fast, default) or ``np.float64`` (reference) for the big matrix product.
    amplitudes:
        Field amplitudes (2^N,) of the input pulses, earliest first (mean energy 1; see
        :func:`ops_sim_ros.source.burst_amplitudes`); None: equal pulses. Unequal pulses cannot
        stack perfectly: the power is then normalized by the highest one they reach (at zero
        delay errors), and ``reachable_fraction`` holds that maximum over an even burst's.

    All delay arguments are delay *errors* in fs relative to the nominal 2^(j-1) T, shaped
    (batch, N) or (N,).
    """

    def __init__(
        self,
        stage: int = 5,
        wavelength_nm: float = 1030.0,
        pulse_fwhm_fs: float = 1000.0,
        quadrature_points: int = 6,
        samples_per_slot: int = 8,
        detector: str = "polarizer",
        dtype: type = np.float32,
        amplitudes=None,
    ) -> None:
        self.stage = int(stage)
        if self.stage < 1:
            raise ValueError(f"stage must be >= 1 (got {stage})")
        if detector not in DETECTORS:
            raise ValueError(f"detector must be one of {', '.join(DETECTORS)} (got {detector!r})")
        self.detector = detector
        self._total = detector == "total"
        self.wavelength_nm = float(wavelength_nm)
        self.pulse_fwhm_fs = float(pulse_fwhm_fs)
        self.quadrature_points = int(quadrature_points)
        self.samples_per_slot = int(samples_per_slot)
        self.dtype = np.dtype(dtype)
        n = self.stage
        self.num_patterns = 2**n
        self.num_slots = 2**n - 1  # output slots that can hold light (odd time slots)
        self.main_slot = 2 ** (n - 1) - 1  # index of the stacked pulse (time slot 2^N - 1)
        self.optical_period_fs = self.wavelength_nm / SPEED_OF_LIGHT_NM_PER_FS
        self.omega0 = 2.0 * np.pi / self.optical_period_fs  # rad / fs
        self.t0_fs = self.pulse_fwhm_fs / SECH_FWHM_FACTOR

        c_s, c_p = geometry_matrices(n, amplitudes=amplitudes)
        # Light only ever reaches odd time slots (every input pulse of an even slot is p-coded and
        # delayed by stage 1; each later stage moves by an even number of slots), so the output
        # window is the 2^N - 1 odd slots 1, 3, ..., 2^(N+1) - 3; even rows are zero.
        assert not np.any(c_s[0::2]) and not np.any(c_p[0::2])
        self.c_s, self.c_p = c_s[1::2], c_p[1::2]
        c_s, c_p = self.c_s, self.c_p
        self.slot_times_T = np.arange(1, 2 ** (n + 1) - 2, 2)  # slot centres in units of T
        self._ct_s = np.ascontiguousarray(c_s.T, dtype=self.dtype)  # (P, S)
        self._ct_sp = np.ascontiguousarray(np.concatenate([c_s, c_p]).T, dtype=self.dtype)
        patterns = np.arange(self.num_patterns)
        self.bits = ((patterns[:, None] >> np.arange(n)[None, :]) & 1).astype(np.float64)
        self._bits_t = np.ascontiguousarray(self.bits.T)  # (N, P)

        x, w = np.polynomial.legendre.leggauss(self.quadrature_points)
        self.quad_t_fs = self.t0_fs * np.arctanh(x)  # nodes in time, relative to slot centre
        self.quad_w_fs = self.t0_fs * w / (1.0 - x * x)  # weights incl. Jacobian dt/dx
        self._nodes_u = (self.quad_t_fs / self.t0_fs).astype(self.dtype)  # nodes in units of t0
        self._w = (w / (1.0 - x * x)).astype(self.dtype)  # weights in units of t0
        self._exp_nodes = np.exp(self._nodes_u.astype(np.float64)).astype(self.dtype)
        self._exp_neg_nodes = np.exp(-self._nodes_u.astype(np.float64)).astype(self.dtype)
        self.pulse_energy = 2.0 * self.t0_fs  # integral of sech^2(t/t0) dt, one input pulse
        self.input_energy = self.num_patterns * self.pulse_energy
        # P_max: integral of I^2 of the perfectly stacked pulse, 2^(2N) * integral of sech^4.
        self.p_max = float(self.num_patterns**2 * (4.0 / 3.0) * self.t0_fs)
        self._energy_scale = self.t0_fs / self.input_energy
        self._power_scale = self.t0_fs / self.p_max
        self._prepare_fast_paths(c_s, c_p, x, w)
        # Input slot of each (pattern, output column) entry: where a pulse's own factor applies.
        cols = np.arange(2 * self.num_slots) % self.num_slots
        self._input_slot = np.clip(
            (2 * cols[None, :] + 1) - patterns[:, None], 0, self.num_patterns - 1
        )
        self.reachable_fraction = 1.0
        if amplitudes is not None:
            # The reachable maximum: every path in phase, at zero delay errors.
            self.reachable_fraction = float(self._single(np.zeros((1, n)))[1][0])
            self._power_scale /= self.reachable_fraction
            self.p_max *= self.reachable_fraction
        spp = self.samples_per_slot
        width = max(spp / 8.0, 0.5)
        self.trace_bump = np.exp(-0.5 * ((np.arange(spp) - spp // 2) / width) ** 2).astype(
            np.float32
        )

    def _prepare_fast_paths(self, c_s, c_p, x, w) -> None:
        """Precomputed arrays of the batched float32 and the single-env float64 paths."""
        # Fast float32 batched path (see _fast_intensity): output columns padded to a multiple of
        # 8 (31 -> 32 makes the GEMM ~1.5x faster), the per-stage phase reduced to a fraction of a
        # cycle in float64 before anything is rounded to float32, 2 pi folded into the pattern bits.
        sp = -(-self.num_slots // 8) * 8
        self._slots_padded = sp
        self._ctp_s = np.zeros((self.num_patterns, sp), dtype=np.float32)
        self._ctp_s[:, : self.num_slots] = c_s.T
        self._ctp_sp = np.zeros((self.num_patterns, 2 * sp), dtype=np.float32)
        self._ctp_sp[:, : self.num_slots] = c_s.T
        self._ctp_sp[:, sp : sp + self.num_slots] = c_p.T
        self._phase_bits32 = (2.0 * np.pi * self._bits_t).astype(np.float32)  # (N, P)
        self._neg_c32 = (-(self._bits_t - 0.5) / self.t0_fs).astype(np.float32)  # (N, P)
        self._nodes32 = np.arctanh(x).astype(np.float32)[:, None, None]  # (K, 1, 1)
        self._w32 = (w / (1.0 - x * x)).astype(np.float32)
        self._buffers: dict[tuple[int, bool], tuple[np.ndarray, ...]] = {}
        # Small batches (a single env) take a float64 complex path with fewer numpy calls; with
        # the total detector it needs both ports (columns S..2S-1: the p port).
        single_ct = np.concatenate([c_s, c_p]).T if self._total else c_s.T
        self._ct_single_complex = single_ct.astype(np.complex128)
        self._bits_t_complex = self._bits_t * (1j * self.omega0)
        # envelope argument u_k - (s_p - m)/t0 = nodes_k + d @ A  (A: (N, K*P))
        k, npat = self.quadrature_points, self.num_patterns
        self._arg_a = np.tile(-(self._bits_t - 0.5) / self.t0_fs, (1, k))
        self._arg_nodes = np.repeat(np.arctanh(x), npat)
        self._sqrt_w = np.sqrt(w / (1.0 - x * x))[:, None]
        self._sqrt_w_energy = self._sqrt_w.T * self._energy_scale  # (1, K)

    # ------------------------------------------------------------------ core evaluation
    def evaluate(self, delay_errors_fs, rejected_port: bool = False) -> StackerOutput:
        """Evaluate a batch of delay-error vectors; see :class:`StackerOutput`.

        With ``rejected_port=True`` the polarizer's p port is computed explicitly (one wider
        matrix product); otherwise ``rejected_energy`` is 1 - (detected energy), which the tests
        show equals it. The ``total`` detector rejects nothing (zeros).
        """
        d = np.asarray(delay_errors_fs, dtype=np.float64)
        single = d.ndim == 1
        if single:
            d = d[None, :]
        if d.ndim != 2 or d.shape[1] != self.stage:
            raise ValueError(
                f"delay errors must have shape (batch, {self.stage}) or ({self.stage},), "
                f"got {np.shape(delay_errors_fs)}"
            )
        batch = d.shape[0]
        s = self.num_slots
        k = self.quadrature_points
        rejected_slots = None
        if batch == 1 and not rejected_port:
            energies, power = self._single(d)
        elif self.dtype == np.float32:
            energies, power, rejected_slots = self._fast_intensity(d, rejected_port)
        else:
            both = rejected_port or self._total
            inten = self._intensity_at_nodes(d, self._ct_sp if both else self._ct_s)
            inten_det = inten[:, :, :s]  # (K, B, S) detected |E|^2 at the nodes
            if rejected_port and not self._total:
                rej = np.ascontiguousarray(inten[:, :, s:]).reshape(k, -1)
                rejected_slots = (self._w @ rej).reshape(batch, s).astype(np.float64)
                rejected_slots *= self._energy_scale
            if self._total:
                inten_det = inten_det + inten[:, :, s:]
            energies = (self._w @ inten_det.reshape(k, -1)).reshape(batch, -1)
            energies = energies.astype(np.float64) * self._energy_scale
            np.square(inten_det, out=inten_det)
            p_n = (self._w @ inten_det.reshape(k, -1)).reshape(batch, -1)
            power = p_n.sum(axis=1, dtype=np.float64) * self._power_scale
        if rejected_port and rejected_slots is None:
            rejected_slots = np.zeros((batch, s))  # the total detector rejects nothing
        if self._total:
            rejected = np.zeros(batch)
        elif rejected_port:
            rejected = rejected_slots.sum(axis=1)
        else:
            rejected = 1.0 - energies.sum(axis=1)
        out = StackerOutput(
            power=power,
            slot_energies=energies,
            main_pulse_energy=energies[:, self.main_slot].copy(),
            rejected_energy=rejected,
            rejected_slot_energies=rejected_slots,
        )
        if single:
            out = StackerOutput(
                power=out.power[0],
                slot_energies=out.slot_energies[0],
                main_pulse_energy=out.main_pulse_energy[0],
                rejected_energy=out.rejected_energy[0],
                rejected_slot_energies=None if rejected_slots is None else rejected_slots[0],
            )
        return out

    def _single(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Same integrals as the batched path for one row, float64 complex, few numpy calls."""
        # np.dot, not @: less overhead for these tiny products (this path is call-bound).
        env = np.dot(d, self._arg_a)  # (1, K*P) envelope arguments u_k - c_p
        np.add(env, self._arg_nodes, out=env)
        np.cosh(env, out=env)
        u = np.exp(np.dot(d, self._bits_t_complex))  # (1, P) carrier factors exp(i w0 s_p)
        e = np.divide(u, env.reshape(self.quadrature_points, self.num_patterns))
        iw = np.abs(e.dot(self._ct_single_complex))  # (K, S) or (K, 2S) |E| at the nodes
        np.multiply(iw, iw, out=iw)  # |E|^2
        if self._total:
            s = self.num_slots
            iw = np.add(iw[:, :s], iw[:, s:])  # both polarizations
        iw *= self._sqrt_w  # sqrt(w_k) |E|^2
        energies = np.dot(self._sqrt_w_energy, iw)  # (1, S)
        power = np.array([np.vdot(iw, iw) * self._power_scale])
        return energies, power

    def energies_and_power(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Detected slot energies (B, S) and power (B,) for a (B, N) float64 array of delay
        errors in fs that the caller has checked (shape, finiteness).

        What :meth:`evaluate` computes, without its checks and output record: the simulation's
        per-step path, where a few microseconds a call matter.
        """
        if d.shape[0] == 1:
            return self._single(d)
        if self.dtype == np.float32:
            return self._fast_intensity(d, False)[:2]
        out = self.evaluate(d)
        return out.slot_energies, out.power

    def _fast_intensity(
        self, d: np.ndarray, rejected_port: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The float32 batched path: (energies (B, S), power (B,), p-port energies or None).

        Same integrals as :meth:`_intensity_at_nodes` (the float64 reference), arranged for
        fewer, cheaper passes over the (K, B, P) arrays:

        * carrier phase of pattern p: 2 pi * sum_j bit_j(p) frac_j with frac_j = d_j / period
          reduced to [-1/2, 1/2] cycle in float64, so float32 sin/cos see |phase| <= N pi;
        * envelope: sech(u_k - c_p) = 1 / cosh(u_k - c_p), c_p = sum_j (bit_j(p) - 1/2) d_j / t0
          (the nodes centred on the middle of the pattern spread, as in the reference);
        * G = {cos, sin} / cosh into preallocated buffers, then ONE real GEMM with C^T padded to
          a multiple of 8 columns (zero columns), |E|^2 and the weighted sums over the nodes.
        """
        batch = d.shape[0]
        k, npat, s = self.quadrature_points, self.num_patterns, self.num_slots
        both = rejected_port or self._total
        ct = self._ctp_sp if both else self._ctp_s
        cols = ct.shape[1]
        key = (batch, both)
        buf = self._buffers.get(key)
        if buf is None:
            if len(self._buffers) > 8:
                self._buffers.clear()
            buf = (
                np.empty((2, batch, npat), dtype=np.float32),  # cos, sin of the carrier phase
                np.empty((k, batch, npat), dtype=np.float32),  # cosh of the envelope argument
                np.empty((2, k, batch, npat), dtype=np.float32),  # G
                np.empty((2, k, batch, cols), dtype=np.float32),  # E (re, im) at the nodes
            )
            self._buffers[key] = buf
        trig, ch, g, e = buf
        frac = d * (1.0 / self.optical_period_fs)
        frac -= np.rint(frac)
        phase = frac.astype(np.float32) @ self._phase_bits32  # (B, P)
        np.cos(phase, out=trig[0])
        np.sin(phase, out=trig[1])
        neg_c = d.astype(np.float32) @ self._neg_c32  # (B, P)
        np.add(self._nodes32, neg_c, out=ch)
        np.cosh(ch, out=ch)
        np.divide(trig[0], ch, out=g[0])
        np.divide(trig[1], ch, out=g[1])
        np.matmul(g.reshape(2 * k * batch, npat), ct, out=e.reshape(2 * k * batch, cols))
        np.square(e, out=e)
        inten = np.add(e[0], e[1], out=e[0]).reshape(k, batch * cols)  # |E|^2 at the nodes
        rejected = None
        if both:
            sp = cols // 2
            inten3 = inten.reshape(k, batch, cols)
            if self._total:
                inten = np.add(inten3[:, :, :sp], inten3[:, :, sp:]).reshape(k, batch * sp)
            else:
                wsum = (self._w32 @ inten).reshape(batch, cols)
                rejected = np.multiply(wsum[:, sp : sp + s], self._energy_scale, dtype=np.float64)
                inten = np.ascontiguousarray(inten3[:, :, :sp]).reshape(k, batch * sp)
            cols = sp
        wsum = (self._w32 @ inten).reshape(batch, cols)
        energies = np.multiply(wsum[:, :s], self._energy_scale, dtype=np.float64)
        np.square(inten, out=inten)
        p_n = (self._w32 @ inten).reshape(batch, -1)
        power = p_n.sum(axis=1, dtype=np.float64)
        power *= self._power_scale
        return energies, power, rejected

    def energies_and_power_of_pulses(
        self, d: np.ndarray, factors: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`energies_and_power`, with input pulse k's field of env b multiplied by
        ``factors[b, k]`` (B, 2^N): pulses that differ from step to step (the source's noise).
        The power keeps this stacker's normalization (of the pulses without the factors)."""
        batch = d.shape[0]
        both = self._total
        ct = self._ct_sp if both else self._ct_s
        cols = ct.shape[1]
        per_env = ct.astype(np.float64)[None] * factors[:, self._input_slot[:, :cols]]
        g = self._pattern_factors(d).astype(np.float64)  # (2, K, B, P)
        e = np.einsum("ckbp,bps->ckbs", g, per_env)
        inten = e[0] ** 2 + e[1] ** 2  # (K, B, cols)
        if both:
            inten = inten[:, :, : self.num_slots] + inten[:, :, self.num_slots :]
        k = self.quadrature_points
        w = self._w.astype(np.float64)
        energies = (w @ inten.reshape(k, -1)).reshape(batch, -1) * self._energy_scale
        p_n = (w @ np.square(inten).reshape(k, -1)).reshape(batch, -1)
        return energies, p_n.sum(axis=1) * self._power_scale

    def _intensity_at_nodes(self, d: np.ndarray, ct: np.ndarray) -> np.ndarray:
        """|E|^2 at the K quadrature nodes of every output slot: (K, B, S) (S doubled for s|p).

        The float64 reference path (``dtype=np.float64``); float32 stackers use
        :meth:`_fast_intensity`, which the tests check against this one.

        G[c, k, b, p] = {cos, sin}(w0 s_p) * sech(u_k - (s_p - m) / t0) for c = re, im, then
        E = G @ C^T as one (2 K B, P) x (P, S) real matrix product.
        """
        g = self._pattern_factors(d)
        k, batch, npat = g.shape[1:]
        e = g.reshape(2 * k * batch, npat) @ ct  # ONE real GEMM for the whole batch
        e = e.reshape(2, k, batch, ct.shape[1])
        np.square(e, out=e)
        return np.add(e[0], e[1], out=e[0])

    def _pattern_factors(self, d: np.ndarray) -> np.ndarray:
        """G (2, K, B, P): {2 cos, 2 sin}(w0 s_p) / (e^{u_k - c_p} + e^{c_p - u_k}), the carrier
        and envelope of every delay pattern at every quadrature node (re, im)."""
        batch = d.shape[0]
        k = self.quadrature_points
        npat = self.num_patterns
        if batch >= 16:
            # Build per-pattern factors by doubling over stages: factor(b) = prod_j f_j^bit_j.
            # Cheaper than trig/exp on (B, P) and exact up to rounding.
            z = np.exp(1j * self.omega0 * d)  # (B, N) carrier factor of each stage
            ez = np.exp(d * (1.0 / self.t0_fs))  # (B, N) envelope-shift factor
            u = np.empty((batch, npat), dtype=np.complex128)
            ep = np.empty((batch, npat), dtype=np.float64)
            u[:, 0] = 1.0
            ep[:, 0] = 1.0
            for j in range(self.stage):
                h = 1 << j
                np.multiply(u[:, :h], z[:, j : j + 1], out=u[:, h : 2 * h])
                np.multiply(ep[:, :h], ez[:, j : j + 1], out=ep[:, h : 2 * h])
            ep *= np.exp(-0.5 * d.sum(axis=1, keepdims=True) * (1.0 / self.t0_fs))
            cos2 = (2.0 * u.real).astype(self.dtype)
            sin2 = (2.0 * u.imag).astype(self.dtype)
        else:
            shifts = d @ self._bits_t  # (B, P) total delay of each pattern, fs
            phase = shifts * self.omega0
            ep = np.exp((shifts - 0.5 * d.sum(axis=1, keepdims=True)) * (1.0 / self.t0_fs))
            cos2 = (2.0 * np.cos(phase)).astype(self.dtype)
            sin2 = (2.0 * np.sin(phase)).astype(self.dtype)
        ep32 = ep.astype(self.dtype)
        em32 = (1.0 / ep).astype(self.dtype)
        # sech(u_k - c) = 2 / (e^{u_k} e^{-c} + e^{-u_k} e^{c})
        den = np.multiply(self._exp_nodes[:, None, None], em32[None])  # (K, B, P)
        den += self._exp_neg_nodes[:, None, None] * ep32[None]
        g = np.empty((2, k, batch, npat), dtype=self.dtype)
        np.divide(cos2[None], den, out=g[0])
        np.divide(sin2[None], den, out=g[1])
        return g

    # ------------------------------------------------------------------ public helpers
    def power(self, delay_errors_fs) -> np.ndarray:
        """P_N / P_max, shape (batch,) (a scalar array for an (N,) input)."""
        return self.evaluate(delay_errors_fs).power

    def reward(self, delay_errors_fs) -> np.ndarray:
        """Eq. (3) with P_min = 0: -(1 - P_N/P_max)^2."""
        return power_to_reward(self.power(delay_errors_fs))

    def slot_energies(self, delay_errors_fs) -> np.ndarray:
        """Detected energy per output slot, normalized by the input energy."""
        return self.evaluate(delay_errors_fs).slot_energies

    def trace(self, delay_errors_fs) -> np.ndarray:
        """Detected output intensity traces, (batch, S * samples_per_slot) float32 in [0, 1]."""
        return self.trace_from_energies(self.evaluate(delay_errors_fs).slot_energies)

    def trace_from_energies(self, slot_energies) -> np.ndarray:
        """Draw each slot's energy as a detector-limited bump of ``samples_per_slot`` samples.

        The bump peaks at sample ``samples_per_slot // 2`` of its slot with the slot energy
        (normalized by the perfectly stacked pulse's energy), so sampling the slot centres gives
        the pulse energies back (:func:`ops_contract.observation.pulse_energies_from_trace`).
        """
        e = np.asarray(slot_energies, dtype=np.float32)
        tr = e[..., :, None] * self.trace_bump
        return tr.reshape(*e.shape[:-1], e.shape[-1] * self.samples_per_slot)

    def trace_time_axis_ns(self, pulse_spacing_fs: float = 12.5e6) -> np.ndarray:
        """Time of every trace sample in ns (output slot i is time slot 2i + 1)."""
        return trace_time_axis_ns(self.num_slots, self.samples_per_slot, pulse_spacing_fs)


def trace_time_axis_ns(num_slots: int, samples_per_slot: int, pulse_spacing_fs: float):
    """Time (ns) of every trace sample: output slot i is time slot 2i + 1, spaced 2T."""
    spp = int(samples_per_slot)
    idx = np.arange(int(num_slots) * spp)
    slot = 2 * (idx // spp) + 1
    return (slot + 2.0 * (idx % spp - spp // 2) / spp) * pulse_spacing_fs * 1e-6


def power_to_reward(power, p_min: float = 0.0) -> np.ndarray:
    """Eq. (3) of the paper with normalized P: -(P - 1)^2 / (P_min - 1)^2 (the one reward
    formula: the simulation, the envs and the nodes all use it). Shape of ``power``."""
    scale = 1.0 / (p_min - 1.0) ** 2
    if type(power) is np.ndarray and power.shape == (1,):
        x = 1.0 - float(power[0])  # one env: Python floats (fewer numpy calls per step)
        return np.array([-(x * x) * scale])
    p = np.asarray(power)
    if p.dtype.kind != "f":
        p = p.astype(np.float64)
    if p.ndim == 0:
        return np.float64(-((1.0 - float(p)) ** 2) * scale)
    reward = np.subtract(p, 1.0)
    np.multiply(reward, np.subtract(1.0, p), out=reward)  # -(1 - P)^2
    if scale != 1.0:
        reward *= scale
    return reward


def stacker_from_config(config, dtype: type = np.float32) -> PulseStacker:
    """The :class:`PulseStacker` an :class:`~ops_contract.config.OpsConfig` describes."""
    return PulseStacker(
        stage=config.stage,
        wavelength_nm=config.wavelength_nm,
        pulse_fwhm_fs=config.pulse_fwhm_fs,
        quadrature_points=config.quadrature_points,
        samples_per_slot=config.samples_per_slot,
        detector=config.detector,
        dtype=dtype,
        amplitudes=burst_amplitudes(config.stage, config.burst_envelope),
    )
