"""W3 peer in plain NumPy: one FastSLAM 1.0 step, vectorised over the particles.

The model is workload W3 (``benchmarks/README.md``), the same filter as ``jaxnav.slam.fastslam``
with ``version=1``, the velocity motion model and range-bearing landmarks:

* **motion** — the velocity model's exact circular arc (Thrun et al. eq. 5.9
  in the ``sinc`` form of :mod:`jaxnav.models.motion`: ``Δx = vΔt·sinc(ωΔt/2)·
  cos(θ + ωΔt/2)``, …) plus Gaussian pose noise ``pose_sd`` (m, m, rad), θ
  wrapped to ``[-π, π)``; the W3 noise has no control (α) part, so none is drawn;
* **landmarks** — a Python loop over the ``K`` observation slots only; in each,
  landmark ``j = ids[k]`` of every particle is updated by its EKF at once
  (Thrun et al. Tab. 13.1 lines 13–18): ``ẑ = h(x, μ)``, ``H = ∂h/∂μ``,
  ``S = H Σ Hᵀ + R``, ``K = Σ Hᵀ S⁻¹``, ``μ' = μ + K (z − ẑ)`` (bearing residual
  wrapped), Joseph form ``Σ' = (I − KH) Σ (I − KH)ᵀ + K R Kᵀ`` with the diagonal
  lifted to at least 1e-9 m² (as ``jaxnav.core.kalman.ensure_pd``); the weight
  gains ``log N(z; ẑ, S)`` (FastSLAM 1.0's importance weight). The 2 × 2
  algebra is written out on ``[M]`` component arrays (closed-form inverse and
  determinant of ``S``), one NumPy call per operation over all particles;
* **weights** — ``logsumexp`` normalisation, ESS ``1 / Σ w̄²``;
* **resampling** — systematic, every step: one uniform ``u``, points
  ``(u + m) / M`` clamped below 1, ``searchsorted`` (side ``right``) on the
  cumulative sum normalised by its last entry, indices clipped to ``M − 1``
  (the choices of ``jaxnav.core.resampling.inverse_cdf``), then every
  particle's map is copied by fancy indexing, ``means[idx]``, ``covs[idx]``.

Maps are stored as ``means [M, N, 2]`` (m) and ``covs [M, N, 2, 2]`` (m²),
jaxnav's layout. Observed landmarks are assumed to be in the map already (W3
puts every landmark in every particle before the first step), so there is no
landmark initialisation branch. The weighted-mean pose estimate jaxnav's step
also computes is not part of W3 and is not computed here.

Every part of a step is a method (:meth:`NumpyFastSLAM.move`, :meth:`update`,
:meth:`normalise`, :meth:`indices`, :meth:`resample`) so that
``tests/benchmarks/test_benchmark_w3.py`` can compare each with jaxnav given the same
particles, observations and resampling uniform.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["NumpyFastSLAM", "DEFAULT_DTYPE", "arc_motion", "wrap"]

DEFAULT_DTYPE = np.float32
_TWO_PI = 2.0 * math.pi
_JITTER = 1e-9  # m², the diagonal floor of jaxnav.core.kalman.ensure_pd


def wrap(a):
    """Angles wrapped to ``[-π, π]`` (rad): ``a − 2π·rint(a / 2π)``."""
    return a - _TWO_PI * np.rint(a * (1.0 / _TWO_PI))


def arc_motion(x, y, th, v, w, dt):
    """Noise-free velocity motion of ``[M]`` poses along the exact arc (``sinc`` form, smooth at ω = 0)."""
    a = w * dt
    h = 0.5 * a
    sinc = 1.0 - h * h / 6.0 if abs(h) < 1e-3 else math.sin(h) / h
    chord = v * dt * sinc
    mid = th + h
    return x + chord * np.cos(mid), y + chord * np.sin(mid), wrap(th + a)


class NumpyFastSLAM:
    """FastSLAM 1.0 in vectorised NumPy; ``step(control, ids, z)`` does one W3 step.

    Args:
        poses: ``[M, 3]`` particle poses (m, m, rad).
        log_weights: ``[M]`` normalised log-weights.
        means: ``[M, N, 2]`` landmark means of every particle (m).
        covs: ``[M, N, 2, 2]`` landmark covariances (m²).
        pose_sd: ``[3]`` pose noise sd added after the move (m, m, rad).
        sensor_sd: ``[2]`` range-bearing noise sd (m, rad).
        seed: seed of the ``np.random.Generator`` (pose noise, resampling uniform).
        dtype: float dtype of the whole state.

    The arrays are copied: the caller's inputs are never modified.
    """

    def __init__(self, poses, log_weights, means, covs, pose_sd, sensor_sd, seed=0, dtype=DEFAULT_DTYPE):
        self.dtype = np.dtype(dtype)
        poses = np.asarray(poses, self.dtype)
        self.m = m = poses.shape[0]
        self.x = poses[:, 0].copy()
        self.y = poses[:, 1].copy()
        self.th = poses[:, 2].copy()
        self.lw = np.array(log_weights, self.dtype)
        self.means = np.array(means, self.dtype)
        self.covs = np.array(covs, self.dtype)
        if self.means.shape[0] != m or self.means.shape[2:] != (2,) or self.covs.shape != self.means.shape + (2,):
            raise ValueError(f"maps must be [M, N, 2] and [M, N, 2, 2], got {self.means.shape}, {self.covs.shape}")
        self.rng = np.random.default_rng(seed)
        self.pose_sd = [float(s) for s in np.asarray(pose_sd)]
        sd = [float(s) for s in np.asarray(sensor_sd)]
        self.r00, self.r11 = sd[0] ** 2, sd[1] ** 2
        self.grid = np.arange(m, dtype=self.dtype)
        self.below_one = np.nextafter(self.dtype.type(1.0), self.dtype.type(0.0))

    @property
    def poses(self):
        """``[M, 3]`` current poses."""
        return np.stack([self.x, self.y, self.th], axis=-1)

    # -- the parts of a step --------------------------------------------------

    def move(self, control):
        """Velocity motion along the exact arc, then Gaussian pose noise (skipped when ``pose_sd`` is 0)."""
        v, w, dt = (float(c) for c in control)
        x, y, th = arc_motion(self.x, self.y, self.th, v, w, dt)
        if any(s != 0.0 for s in self.pose_sd):
            eps = self.rng.standard_normal((3, self.m), dtype=self.dtype)
            x += eps[0] * self.dtype.type(self.pose_sd[0])
            y += eps[1] * self.dtype.type(self.pose_sd[1])
            th = wrap(th + eps[2] * self.dtype.type(self.pose_sd[2]))
        self.x, self.y, self.th = (
            x.astype(self.dtype, copy=False),
            y.astype(self.dtype, copy=False),
            th.astype(self.dtype, copy=False),
        )

    def update(self, ids, z, mask=None):
        """EKF-update landmark ``ids[k]`` of every particle with ``z[k]``, slot after slot.

        Returns the ``[M]`` log-likelihood ``Σ_k log N(z_k; ẑ_k, S_k)`` (FastSLAM 1.0's weight).
        """
        ids = np.asarray(ids)
        z = np.asarray(z, np.float64)
        ll = np.zeros(self.m, self.dtype)
        x, y, th = self.x, self.y, self.th
        r00, r11 = self.r00, self.r11
        log_2pi = math.log(_TWO_PI)
        for k in range(ids.shape[0]):
            if mask is not None and not mask[k]:
                continue
            j = int(ids[k])
            mu = self.means[:, j]  # [M, 2] views: written back below
            cov = self.covs[:, j]
            mx, my = mu[:, 0], mu[:, 1]
            p00, p01, p11 = cov[:, 0, 0], 0.5 * (cov[:, 0, 1] + cov[:, 1, 0]), cov[:, 1, 1]
            dx = mx - x
            dy = my - y
            q = dx * dx + dy * dy
            r = np.sqrt(q)
            # residual (range, wrapped bearing)
            y0 = float(z[k, 0]) - r  # Python floats keep the arrays' dtype (NEP 50)
            y1 = wrap(float(z[k, 1]) - wrap(np.arctan2(dy, dx) - th))
            # H = ∂h/∂μ = [[dx/r, dy/r], [−dy/q, dx/q]]
            h00, h01 = dx / r, dy / r
            h10, h11 = -dy / q, dx / q
            # C = Σ Hᵀ (cross covariance), S = H C + R
            c00 = p00 * h00 + p01 * h01
            c01 = p00 * h10 + p01 * h11
            c10 = p01 * h00 + p11 * h01
            c11 = p01 * h10 + p11 * h11
            s00 = h00 * c00 + h01 * c10 + r00
            s01 = h00 * c01 + h01 * c11
            s11 = h10 * c01 + h11 * c11 + r11
            det = s00 * s11 - s01 * s01
            inv_det = 1.0 / det
            i00, i01, i11 = s11 * inv_det, -s01 * inv_det, s00 * inv_det
            maha = i00 * y0 * y0 + 2.0 * i01 * y0 * y1 + i11 * y1 * y1
            ll += -0.5 * (maha + np.log(det) + 2.0 * log_2pi)
            # gain K = C S⁻¹
            k00 = c00 * i00 + c01 * i01
            k01 = c00 * i01 + c01 * i11
            k10 = c10 * i00 + c11 * i01
            k11 = c10 * i01 + c11 * i11
            new_mx = mx + k00 * y0 + k01 * y1
            new_my = my + k10 * y0 + k11 * y1
            # Joseph form: A = I − K H, Σ' = A Σ Aᵀ + K R Kᵀ
            a00 = 1.0 - (k00 * h00 + k01 * h10)
            a01 = -(k00 * h01 + k01 * h11)
            a10 = -(k10 * h00 + k11 * h10)
            a11 = 1.0 - (k10 * h01 + k11 * h11)
            b00 = a00 * p00 + a01 * p01  # B = A Σ
            b01 = a00 * p01 + a01 * p11
            b10 = a10 * p00 + a11 * p01
            b11 = a10 * p01 + a11 * p11
            n00 = b00 * a00 + b01 * a01 + r00 * k00 * k00 + r11 * k01 * k01
            n01 = b00 * a10 + b01 * a11 + r00 * k00 * k10 + r11 * k01 * k11
            n11 = b10 * a10 + b11 * a11 + r00 * k10 * k10 + r11 * k11 * k11
            mu[:, 0] = new_mx
            mu[:, 1] = new_my
            cov[:, 0, 0] = np.maximum(n00, _JITTER)
            cov[:, 0, 1] = n01
            cov[:, 1, 0] = n01
            cov[:, 1, 1] = np.maximum(n11, _JITTER)
        return ll

    def normalise(self, ll):
        """Add ``ll`` to the log-weights and normalise: returns ``(w̄ [M], log-normaliser, ESS)``."""
        lw = self.lw + ll
        mx = lw.max()
        lw -= mx
        w = np.exp(lw)
        s = w.sum()
        w *= 1.0 / s
        log_s = math.log(float(s))
        lw -= self.dtype.type(log_s)
        self.lw = lw
        return w, float(mx) + log_s, 1.0 / float(np.dot(w, w))

    def indices(self, w, u=None):
        """Systematic resampling of probabilities ``w``; ``u`` the uniform (drawn if None)."""
        if u is None:
            u = self.rng.random()
        cdf = np.cumsum(w)
        cdf *= 1.0 / cdf[-1]
        pts = (self.grid + self.dtype.type(u)) / self.dtype.type(self.m)
        np.minimum(pts, self.below_one, out=pts)
        idx = np.searchsorted(cdf, pts, side="right")
        np.minimum(idx, self.m - 1, out=idx)
        return idx

    def resample(self, idx):
        """Copy the chosen particles, maps included (fancy indexing); weights become uniform."""
        self.x = self.x[idx]
        self.y = self.y[idx]
        self.th = self.th[idx]
        self.means = self.means[idx]
        self.covs = self.covs[idx]
        self.lw = np.full(self.m, -math.log(self.m), self.dtype)

    def step(self, control, ids, z, mask=None, u=None):
        """One W3 step: move, EKF-update the observed landmarks, weigh, normalise, ESS, resample.

        Returns ``(log-normaliser, ESS before resampling)``.
        """
        self.move(control)
        ll = self.update(ids, z, mask)
        w, log_norm, ess = self.normalise(ll)
        self.resample(self.indices(w, u))
        return log_norm, ess
