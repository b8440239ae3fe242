"""U1 peer in plain NumPy: one static UHF-RFID tag localization update ([A] Alg. 6), vectorised.

The update is exactly :func:`jaxnav.localization.rfid_tag.step` with
``weighting="combined"``, ``dims=3``, ``refresh=True`` (the jaxnav defaults),
written as a plain vectorised NumPy program over the ``M`` particles
``X = (x, y, z, θ_off)``. For the ``J`` reads of a step (reader pose
``r_j = (x, y, z, ψ)``, RSSI ``y_j`` in W, phase ``φ_j`` in rad, wavelength
``λ_j`` in m):

* **distance, antenna, path loss** ([A] §4.1.2, §4.3.1; ``jaxnav.models.uhf_rfid``):
  ``d = X_xyz − r_xyz``, ``D = |d|``; off-boresight angle
  ``γ = atan2(√(d_z² + (d_x sin ψ − d_y cos ψ)²), d_x cos ψ + d_y sin ψ)``;
  ``G_R = G_0`` (``γ ≤ φ_s``), ``G_SLL`` (``γ ≤ 2φ_s``), else ``G_BLL``;
  two-ray ``L = (λ / (4π D'))²`` if ``D' < D_c = 4π z_r z / λ`` else
  ``(z_r z / D'²)²`` with ``D' = max(D, 1 µm)``;
  ``a = P_T η_T (G_R G_T)² L²``;
* **RSSI weight** ([A] §4.3.1, App. C): ``u = √(y/a)``,
  ``log W_RSSI = −log 2 − k log θ − log Γ(k) − log y + k log u − u/θ``
  (``−∞`` where ``a = 0``: a particle on the ground);
* **phase weight** ([A] §4.3.2): predicted ``φ̂ = −4πD/λ + θ_off``,
  ``Δ/σ = λ/(4π) · wrap(φ − φ̂) / σ``,
  ``log W_PHASE = −½(Δ/σ)² − log σ − ½ log 2π``;
* ``ℓ = Σ_j (log W_RSSI + log W_PHASE)`` over the step's valid reads
  ([A] Alg. 6 lines 11–14); ``ℓ̄ = normalise(log w + ℓ)`` with the
  maximum shift and ``logsumexp`` of :func:`jaxnav.core.weights.normalize`
  (NaN / ``+∞`` → ``−∞``; all ``−∞`` → uniform and flagged degenerate);
* estimate ``Σ p_i X_i`` with ``θ_off`` averaged on the circle
  (``atan2(Σ p sin, Σ p cos)``), ESS ``1 / Σ p²`` ([A] Alg. 6 lines 17–19);
* when ``ESS < ess_threshold · M`` (and the step had a read): the Gaussian
  refresh of [A] §4.3.3 as jaxnav does it (``rfid_tag._resample``): the
  Gaussian fitted to the *weighted* set (mean = the estimate, plug-in
  weighted covariance with wrapped offset residuals, ``+1e-9 I``, Cholesky,
  ``μ + L ε``, offset wrapped to ``[−π, π)``; no ancestors drawn), the
  positions clipped into the search box; log-weights reset to ``−log M``.

Written to be a fair, fast NumPy peer, not a straw man:

* particles are one ``[4, M]`` array (structure of arrays: every pass is a
  unit-stride stream; the estimate and the covariance are BLAS
  matrix-vector / matrix-matrix products);
* the likelihood works on ``[J, M]`` blocks, one NumPy call per operation
  for all reads at once, in preallocated scratch buffers (``out=``);
* everything that depends on the read only (``log y``, ``√y``, ``4π/λ``,
  ``λ/(4πσ)``, ``log Γ(k)``, the gain constants ``P_T η_T (G G_T)²``, …) is
  computed once per read on ``[J, 1]`` columns, not per particle;
* masked read slots are dropped on the host before the ``[J, M]`` work
  (NumPy has no fixed-shape constraint; jaxnav evaluates every slot and
  masks), and a step without a valid read skips the likelihood;
* the phase residual is wrapped with ``r − 2π·rint(r / 2π)`` (cheaper than
  ``np.mod``; the sign at ±π does not matter, it is squared);
* the box clip is applied only to refreshed particles (jaxnav clips every
  step; without a resampling the particles are already inside the box,
  because :func:`~jaxnav.localization.rfid_tag.init` draws them there, so
  the clip is an identity it can skip).

The arithmetic is float32 (jaxnav's dtype); the per-read constants are
computed in float64 and rounded once. ``tests/benchmarks/test_bench_uhf.py`` checks
that :func:`log_likelihoods` equals ``rfid_tag.log_likelihoods`` on the same
particles and reads (float64: to 1e-9; float32: to ``5e-3 + 2e-5·|ℓ|``), and
that a full step equals the jitted body of ``rfid_tag.step`` given the same
refresh draws.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["UHFModel", "model_from_params", "NumpyRFIDTag", "StepInfo", "log_likelihoods", "DEFAULT_DTYPE"]

DEFAULT_DTYPE = np.float32
_TWO_PI = 2.0 * math.pi
_TINY_DISTANCE = 1e-6  # m, jaxnav.models.uhf_rfid._TINY_DISTANCE
_JITTER = 1e-9  # diagonal jitter of jaxnav.core.resampling.gaussian_refresh


class UHFModel(NamedTuple):
    """The read model's constants as Python floats (SI units; see the module docstring).

    ``tx_power`` (W), ``tag_efficiency``, ``tag_gain`` (linear), ``g0, g_sll, g_bll``
    (linear reader gains), ``phi_s`` (rad), ``k, theta`` (Gamma shape and scale),
    ``phase_sigma`` (m), ``box_lo, box_hi`` (``[3]`` m).
    """

    tx_power: float
    tag_efficiency: float
    tag_gain: float
    g0: float
    g_sll: float
    g_bll: float
    phi_s: float
    k: float
    theta: float
    phase_sigma: float
    box_lo: tuple
    box_hi: tuple


def model_from_params(params) -> UHFModel:
    """:class:`UHFModel` from a :class:`jaxnav.localization.rfid_tag.RFIDTagParams` (any array type)."""
    f = lambda x: float(np.asarray(x))  # noqa: E731
    ch, ant = params.channel, params.channel.antenna
    return UHFModel(
        f(ch.tx_power),
        f(ch.tag_efficiency),
        f(ch.tag_gain),
        f(ant.g0),
        f(ant.g_sll),
        f(ant.g_bll),
        f(ant.phi_s),
        f(params.gamma.k),
        f(params.gamma.theta),
        f(params.phase_sigma),
        tuple(float(v) for v in np.asarray(params.box_lo)),
        tuple(float(v) for v in np.asarray(params.box_hi)),
    )


class _ReadConstants:
    """Per-read ``[J, 1]`` columns (in the filter's dtype), computed in float64 once per step from the valid reads."""

    def __init__(self, model: UHFModel, reader, rssi, phase, wavelength, dtype):
        reader = np.asarray(reader, np.float64)
        y = np.asarray(rssi, np.float64)
        lam = np.asarray(wavelength, np.float64)
        phi = np.asarray(phase, np.float64)
        col = lambda v: np.ascontiguousarray(np.asarray(v, np.float64).reshape(-1, 1), dtype)  # noqa: E731
        m = model
        self.rx, self.ry, self.rz = col(reader[:, 0]), col(reader[:, 1]), col(reader[:, 2])
        psi = reader[:, 3]
        self.cos, self.sin = col(np.cos(psi)), col(np.sin(psi))
        # D_c = 4π z_r z / λ = bc · z,  near L = (λ/4π)² / D'²,  far L = (z_r z)² / D'⁴
        self.bc = col(4.0 * math.pi * reader[:, 2] / lam)
        self.near = col((lam / (4.0 * math.pi)) ** 2)
        # log W_RSSI = −log 2 − k log θ − log Γ(k) − log y + k log u − u/θ,  log u = ½ log y − ½ log a
        self.c_rssi = col(-math.log(2.0) - m.k * math.log(m.theta) - math.lgamma(m.k) - np.log(y))
        self.half_log_y = col(0.5 * np.log(y))
        # φ − φ̂ = φ + (4π/λ) D − θ_off
        self.phi = col(phi)
        self.four_pi_over_lam = col(4.0 * math.pi / lam)
        self.delta_scale = col(lam / (4.0 * math.pi) / m.phase_sigma)  # Δ/σ per radian of residual
        self.c_phase = dtype(-math.log(m.phase_sigma) - 0.5 * math.log(_TWO_PI))
        pe = m.tx_power * m.tag_efficiency * m.tag_gain**2
        self.gains = np.asarray([pe * m.g0**2, pe * m.g_sll**2, pe * m.g_bll**2], dtype)  # P_T η_T (G G_T)²
        self.phi_s, self.two_phi_s = dtype(m.phi_s), dtype(2.0 * m.phi_s)
        self.j = reader.shape[0]


class _Scratch:
    """Preallocated ``[J, M]`` buffers, reused every step (reallocated when ``J`` or ``M`` changes)."""

    def __init__(self):
        self.shape = None

    def get(self, j: int, n: int, dtype):
        if self.shape != (j, n, dtype):
            self.f = [np.empty((j, n), dtype) for _ in range(6)]
            self.cls = np.empty((j, n), np.uint8)
            self.flag = np.empty((j, n), bool)
            self.shape = (j, n, dtype)
        return self.f, self.cls, self.flag


def _loglik(model: UHFModel, c: _ReadConstants, x, y, z, off, scratch: _Scratch, dtype) -> np.ndarray:
    """``[M]`` ``Σ_j log W_RSSI + log W_PHASE`` for particles given as ``[M]`` rows ``x, y, z, off``.

    Every line is one NumPy call on ``[J, M]`` (``out=`` into the scratch buffers).
    """
    n = x.shape[0]
    (b0, b1, b2, b3, b4, b5), cls, flag = scratch.get(c.j, n, dtype)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        dx = np.subtract(x, c.rx, out=b0)
        dy = np.subtract(y, c.ry, out=b1)
        dz = np.subtract(z, c.rz, out=b2)
        # D = |d|
        dist = np.multiply(dx, dx, out=b3)
        np.multiply(dy, dy, out=b4)
        np.add(dist, b4, out=dist)
        np.multiply(dz, dz, out=b4)
        np.add(dist, b4, out=dist)
        np.sqrt(dist, out=dist)  # b3 = D (kept to the phase term)
        # off-boresight angle γ = atan2(|d × b|, d·b), b = (cos ψ, sin ψ, 0)
        dot = np.multiply(dx, c.cos, out=b4)
        np.multiply(dy, c.sin, out=b5)
        np.add(dot, b5, out=dot)  # b4 = d·b
        lat = np.multiply(dx, c.sin, out=b5)
        np.multiply(dy, c.cos, out=b0)
        np.subtract(lat, b0, out=lat)  # b5 = d_x sin ψ − d_y cos ψ
        np.multiply(lat, lat, out=lat)
        np.multiply(dz, dz, out=b0)
        np.add(lat, b0, out=lat)
        np.sqrt(lat, out=lat)  # b5 = |d × b|
        gamma = np.arctan2(lat, dot, out=b0)  # b0 = γ
        # gain class 0 (γ ≤ φ_s), 1 (γ ≤ 2φ_s), 2 → coefficient P_T η_T (G_R G_T)²
        np.greater(gamma, c.phi_s, out=cls.view(bool))
        np.greater(gamma, c.two_phi_s, out=flag)
        np.add(cls, flag, out=cls)
        coef = np.take(c.gains, cls, out=b1, mode="clip")  # b1 = P_T η_T (G_R G_T)²
        # two-ray L with D' = max(D, 1 µm); near when D' < D_c = (4π z_r / λ) · z
        dcl = np.maximum(dist, dtype(_TINY_DISTANCE), out=b2)
        dc = np.multiply(z, c.bc, out=b4)
        np.less(dcl, dc, out=flag)
        inv2 = np.multiply(dcl, dcl, out=b2)
        np.divide(dtype(1.0), inv2, out=inv2)  # b2 = 1 / D'²
        near = np.multiply(inv2, c.near, out=b4)  # b4 = (λ / 4π D')²
        loss = np.multiply(z, c.rz, out=b5)
        np.multiply(loss, inv2, out=loss)
        np.multiply(loss, loss, out=loss)  # b5 = (z_r z / D'²)²
        np.copyto(loss, near, where=flag)  # b5 = L
        np.multiply(loss, loss, out=loss)
        a = np.multiply(coef, loss, out=b1)  # b1 = a
        # log W_RSSI = c_rssi + k log u − u/θ,  log u = ½ log y − ½ log a
        log_u = np.log(a, out=b1)
        np.multiply(log_u, dtype(-0.5), out=log_u)
        np.add(log_u, c.half_log_y, out=log_u)
        u = np.exp(log_u, out=b2)
        np.multiply(u, dtype(-1.0 / model.theta), out=u)
        np.multiply(log_u, dtype(model.k), out=log_u)
        np.add(log_u, u, out=log_u)
        total = np.add(log_u, c.c_rssi, out=log_u)  # b1 = log W_RSSI
        # log W_PHASE + ½ log 2π + log σ = −½ (λ/(4πσ) · wrap(φ + (4π/λ) D − θ_off))²
        res = np.multiply(dist, c.four_pi_over_lam, out=b3)
        np.add(res, c.phi, out=res)
        np.subtract(res, off, out=res)
        turns = np.multiply(res, dtype(1.0 / _TWO_PI), out=b4)
        np.rint(turns, out=turns)
        np.multiply(turns, dtype(_TWO_PI), out=turns)
        np.subtract(res, turns, out=res)
        np.multiply(res, c.delta_scale, out=res)
        np.multiply(res, res, out=res)
        np.multiply(res, dtype(-0.5), out=res)
        np.add(total, res, out=total)
        ll = total.sum(axis=0)
    ll += dtype(c.j * c.c_phase)
    # a = 0 (a particle on the ground z = 0: the far-field L is 0) gives ∞ − ∞ = NaN here;
    # jaxnav gives −inf (zero weight) there.
    bad = np.isnan(ll)
    if bad.any():
        ll[bad] = -np.inf
    return ll


def _as_step_reads(reads):
    """``(reader [J, 4], rssi [J], phase [J], wavelength [J], mask [J])`` as NumPy arrays."""
    reader, rssi, phase, lam, mask = (np.asarray(r) for r in reads)
    return reader, rssi, phase, lam, mask.astype(bool)


def log_likelihoods(model: UHFModel, particles, reads, dtype=DEFAULT_DTYPE) -> np.ndarray:
    """``[M]`` ``Σ_j log W_RSSI + log W_PHASE`` over the valid reads of one step.

    Args:
        model: :class:`UHFModel` (:func:`model_from_params`).
        particles: ``[M, 4]`` ``(x, y, z, θ_off)`` (m, m, m, rad).
        reads: ``(reader [J, 4], rssi [J], phase [J], wavelength [J], mask [J])``
            (a :class:`jaxnav.models.uhf_rfid.UHFReads` of one step works).
    """
    p = np.ascontiguousarray(np.asarray(particles, dtype).T)
    reader, rssi, phase, lam, mask = _as_step_reads(reads)
    if not mask.any():
        return np.zeros(p.shape[1], dtype)
    c = _ReadConstants(model, reader[mask], rssi[mask], phase[mask], lam[mask], np.dtype(dtype).type)
    return _loglik(model, c, p[0], p[1], p[2], p[3], _Scratch(), np.dtype(dtype).type)


def _wrap(a):
    """``(a + π) mod 2π − π`` ∈ ``[−π, π)`` (jaxnav's ``wrap_angle``)."""
    return np.remainder(a + np.pi, _TWO_PI).astype(a.dtype, copy=False) - a.dtype.type(np.pi)


class StepInfo(NamedTuple):
    """What :meth:`NumpyRFIDTag.step` returns (jaxnav's ``RFIDTagInfo`` fields)."""

    estimate: np.ndarray
    ess: float
    resampled: bool
    log_likelihood: float
    degenerate: bool
    num_reads: int


class NumpyRFIDTag:
    """[A] Alg. 6 in vectorised NumPy; :meth:`step` is one ``rfid_tag.step`` (combined weighting).

    Args:
        particles: ``[M, 4]`` initial particles ``(x, y, z, θ_off)``.
        model: :class:`UHFModel` (:func:`model_from_params`).
        log_weights: ``[M]`` normalised log-weights (default uniform).
        ess_threshold: resample when ESS < ``ess_threshold · M`` (jaxnav's default 0.1).
        seed: seed of the ``np.random.Generator`` (the refresh normals).
        dtype: float dtype (float32, jaxnav's).
    """

    def __init__(
        self,
        particles,
        model: UHFModel,
        log_weights=None,
        ess_threshold: float = 0.1,
        seed: int = 0,
        dtype=DEFAULT_DTYPE,
    ):
        self.dtype = np.dtype(dtype)
        self.f = self.dtype.type
        self.p = np.ascontiguousarray(np.asarray(particles, dtype).T)  # [4, M]
        self.n = n = self.p.shape[1]
        self.lw = np.full(n, -math.log(n), dtype) if log_weights is None else np.array(log_weights, dtype)
        self.model = model
        self.ess_threshold = float(ess_threshold)
        self.rng = np.random.default_rng(seed)
        self.lo = np.asarray(model.box_lo, dtype)[:, None]
        self.hi = np.asarray(model.box_hi, dtype)[:, None]
        self.scratch = _Scratch()
        self.resamplings = 0

    def reset(self, particles, log_weights=None, seed: int = 0) -> None:
        """Start again from ``particles [M, 4]`` (same ``M``), keeping the scratch buffers."""
        self.p = np.ascontiguousarray(np.asarray(particles, self.dtype).T)
        if self.p.shape[1] != self.n:
            raise ValueError(f"reset needs {self.n} particles, got {self.p.shape[1]}")
        self.lw = (
            np.full(self.n, -math.log(self.n), self.dtype) if log_weights is None else np.array(log_weights, self.dtype)
        )
        self.rng = np.random.default_rng(seed)
        self.resamplings = 0

    @property
    def particles(self) -> np.ndarray:
        """``[M, 4]`` view of the particles."""
        return self.p.T

    def log_likelihoods(self, reads) -> np.ndarray:
        reader, rssi, phase, lam, mask = _as_step_reads(reads)
        c = _ReadConstants(self.model, reader[mask], rssi[mask], phase[mask], lam[mask], self.f)
        p = self.p
        return _loglik(self.model, c, p[0], p[1], p[2], p[3], self.scratch, self.f)

    def _normalise(self, lw):
        """``(normalised log-weights, probabilities, log-normaliser, degenerate)``; ``lw`` is overwritten.

        :func:`jaxnav.core.weights.normalize`: shift by the maximum, ``logsumexp``; all ``−inf`` → uniform.
        """
        top = lw.max()
        if not np.isfinite(top):  # every particle has zero likelihood (NaN was mapped to −inf)
            lw.fill(-math.log(self.n))
            return lw, np.full(self.n, 1.0 / self.n, self.dtype), -math.inf, True
        np.subtract(lw, top, out=lw)
        probs = np.exp(lw)
        s = probs.sum(dtype=self.dtype)
        lse = math.log(float(s))
        np.subtract(lw, self.f(lse), out=lw)
        probs *= self.f(1.0 / float(s))
        return lw, probs, lse + float(top), False

    def _estimate(self, probs):
        """Weighted mean ``(x, y, z)`` and circular mean ``θ_off`` ([A] Alg. 6 line 19)."""
        est = self.p @ probs  # [4] (BLAS)
        off = self.p[3]
        est[3] = math.atan2(float(np.sin(off) @ probs), float(np.cos(off) @ probs))
        return est

    def _refresh(self, probs, mean, normals):
        """[A] §4.3.3: a new set ``[4, M]`` from the Gaussian of the weighted set (``mean`` its estimate)."""
        n = self.n
        resid = self.p - mean[:, None]
        resid[3] = _wrap(resid[3])
        cov = (resid * probs) @ resid.T  # BLAS
        cov = 0.5 * (cov + cov.T) + self.f(_JITTER) * np.eye(4, dtype=self.dtype)
        try:
            chol = np.linalg.cholesky(cov)
            if not np.all(np.isfinite(chol)):
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:  # jaxnav falls back to the diagonal standard deviations
            chol = np.diag(np.sqrt(np.clip(np.diag(cov), 0.0, None)))
        eps = self.rng.standard_normal((4, n), dtype=self.dtype) if normals is None else np.asarray(normals, self.dtype)
        new = chol.astype(self.dtype) @ eps
        new += mean[:, None]
        new[3] = _wrap(new[3])
        np.clip(new[:3], self.lo, self.hi, out=new[:3])
        return new

    def step(self, reads, normals=None) -> StepInfo:
        """One update on the step's ``J`` read slots ``(reader, rssi, phase, wavelength, mask)``.

        ``normals`` (``[4, M]`` refresh draws) are drawn from the generator unless
        given (the tests pass jaxnav's draws).
        """
        reader, rssi, phase, lam, mask = _as_step_reads(reads)
        any_read = bool(mask.any())
        if any_read:
            c = _ReadConstants(self.model, reader[mask], rssi[mask], phase[mask], lam[mask], self.f)
            p = self.p
            lw = _loglik(self.model, c, p[0], p[1], p[2], p[3], self.scratch, self.f)
            lw += self.lw
        else:
            lw = self.lw.copy()
        lw, probs, log_norm, degenerate = self._normalise(lw)
        est = self._estimate(probs)
        ess = 1.0 / float(np.dot(probs, probs))
        threshold = self.ess_threshold if any_read else 0.0
        resampled = ess < threshold * self.n
        if resampled:
            self.p = self._refresh(probs, est.astype(self.dtype), normals)
            lw.fill(-math.log(self.n))
            self.resamplings += 1
        self.lw = lw
        return StepInfo(est, ess, resampled, log_norm if any_read else 0.0, degenerate, int(mask.sum()))

    def run(self, reads_t) -> int:
        """:meth:`step` over ``T`` steps; ``reads_t`` is ``(reader [T, J, 4], rssi [T, J], …, mask [T, J])``.

        Returns the number of resamplings.
        """
        reader, rssi, phase, lam, mask = _as_step_reads(reads_t)
        before = self.resamplings
        for t in range(mask.shape[0]):
            self.step((reader[t], rssi[t], phase[t], lam[t], mask[t]))
        return self.resamplings - before
