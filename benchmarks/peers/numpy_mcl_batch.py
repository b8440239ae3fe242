"""W2b peer in plain NumPy: R independent W2 filters held in ``[R, N]`` arrays, stepped at once.

Each of the R runs is exactly the W2 filter of :class:`benchmarks.peers.numpy_mcl.NumpyMCL`
(Euler velocity motion with Gaussian noise, 8-landmark Gaussian range-bearing
log-likelihood, ``logsumexp`` normalisation, ESS ``1 / Σ w̄²``, systematic resampling
every step), with its own particles, observations, controls and resampling uniform.
What is batched is the bookkeeping, so that no NumPy call runs per run:

* the particles are one ``[3, R, N]`` float32 block (x, y, θ planes, each a
  contiguous ``[R, N]`` array); the motion noise is one ``standard_normal((3, R, N))``;
* the likelihood works on ``[K, R, N]`` landmark-major blocks with the same kernel
  as NumpyMCL (:func:`benchmarks.peers.numpy_mcl._loglik_into`), one broadcast
  NumPy call per operation over all runs;
* normalisation, log-normaliser and ESS are row reductions (``axis=1``);
* systematic resampling of every row is ONE ``np.searchsorted``: the float32
  cumulative sums of the rows, row ``r`` shifted by ``2r``, are concatenated into
  one sorted float64 array, and row ``r``'s points ``(u_r + i) / N`` (computed in
  float32 as NumpyMCL does) shifted by ``2r`` are searched in it; subtracting the
  row start gives the local ancestor index. Then ONE ``np.take`` gathers the three
  planes of all rows.

Why ``2r`` and float64: a float32 row sum can exceed 1 by a rounding, so with a
shift of ``r`` the end of row ``r`` could overlap the start of row ``r + 1`` and the
concatenation would not be sorted; with ``2r`` the rows are ≥ 1 apart. Adding the
integer ``2r`` to a float32 value in float64 is exact for values ≥ ``2R · 2⁻²⁹``
(4e-7 at R = 100; below, the sum is rounded to ~1e-14, monotonically), so every
row is searched with its float32 cumulative sum and float32 points: the
ancestors are those of NumpyMCL's per-row ``searchsorted`` with the same uniform
(``tests/benchmarks/test_benchmark_w2b.py``).

The buffers (likelihood scratch, cumulative sums, points, indices, the second
particle block that the gather writes into) are allocated once. As in NumpyMCL,
θ is not re-wrapped after the move and no pose estimate is computed.
"""

from __future__ import annotations

import math

import numpy as np

from benchmarks.peers.numpy_mcl import _TWO_PI, DEFAULT_DTYPE, _loglik_into

__all__ = ["NumpyMCLBatch", "DEFAULT_DTYPE"]


class NumpyMCLBatch:
    """R bootstrap MCL filters in vectorised NumPy; ``step(controls, z)`` does one W2 step of all of them.

    Args:
        particles: ``[R, N, 3]`` initial poses (m, m, rad), one set per run.
        landmarks: ``[K, 2]`` landmark positions (m), shared by the runs.
        pose_sd: ``[3]`` motion noise sd (m, m, rad).
        sensor_sd: ``[2]`` range (m) and bearing (rad) noise sd.
        seed: seed of the ``np.random.Generator`` that draws the motion noise and the
            R resampling uniforms of every step.
        dtype: float dtype of the particles and weights (float32 in the benchmark).
    """

    def __init__(self, particles, landmarks, pose_sd, sensor_sd, seed=0, dtype=DEFAULT_DTYPE):
        particles = np.asarray(particles, dtype)
        if particles.ndim != 3 or particles.shape[2] != 3:
            raise ValueError(f"particles must be [R, N, 3], got {particles.shape}")
        self.dtype = np.dtype(dtype)
        self.r, self.n = r, n = particles.shape[:2]
        self.p = np.ascontiguousarray(np.moveaxis(particles, 2, 0))  # [3, R, N]
        self._p_next = np.empty_like(self.p)  # the gather writes here, then the two swap
        self.lw = np.full((r, n), -math.log(n), dtype)
        self.rng = np.random.default_rng(seed)
        lm = np.asarray(landmarks, dtype)
        self.k = k = lm.shape[0]
        self.lmx = lm[:, 0].reshape(k, 1, 1).copy()  # broadcast against [R, N]
        self.lmy = lm[:, 1].reshape(k, 1, 1).copy()
        self.pose_sd = np.asarray(pose_sd, dtype).reshape(3, 1, 1)
        sd = [float(s) for s in np.asarray(sensor_sd)]
        self.inv_sd_r, self.inv_sd_b = 1.0 / sd[0], 1.0 / sd[1]
        self.log_norm = -math.log(sd[0]) - math.log(sd[1]) - math.log(_TWO_PI)
        self.buf_a = np.empty((k, r, n), dtype)
        self.buf_b = np.empty((k, r, n), dtype)
        self.tmp = np.empty((r, n), dtype)
        # resampling: float32 per-row grid and points, float64 shifted CDFs and points, int64 indices
        self.grid = np.arange(n, dtype=dtype)
        self.shift = (2.0 * np.arange(r, dtype=np.float64))[:, None]  # [R, 1]
        self.row_start = (n * np.arange(r, dtype=np.int64))[:, None]  # [R, 1]
        self.row_last = self.row_start + (n - 1)
        self.cdf32 = np.empty((r, n), dtype)
        self.cdf64 = np.empty((r, n), np.float64)
        self.pts32 = np.empty((r, n), dtype)
        self.pts64 = np.empty((r, n), np.float64)
        self.idx = np.empty((r, n), np.int64)

    @property
    def particles(self):
        """``[R, N, 3]`` copy of the current poses."""
        return np.moveaxis(self.p, 0, 2).copy()

    # -- the parts of a step ------------------------------------------------

    def move(self, controls):
        """Euler velocity motion of every run, ``controls [R, 3]`` (v m/s, ω rad/s, Δt s) or ``[3]``."""
        u = np.asarray(controls, np.float64)
        u = np.broadcast_to(u, (self.r, 3))
        vdt = (u[:, 0] * u[:, 2]).astype(self.dtype)[:, None]  # [R, 1]
        wdt = (u[:, 1] * u[:, 2]).astype(self.dtype)[:, None]
        x, y, th = self.p
        eps = self.rng.standard_normal((3, self.r, self.n), dtype=self.dtype)
        eps *= self.pose_sd
        c = np.cos(th, out=self.tmp)
        c *= vdt
        x += c
        s = np.sin(th, out=self.tmp)
        s *= vdt
        y += s
        th += wdt
        self.p += eps

    def weigh(self, z):
        """Add the log-likelihood of ``z [R, K, 2]`` (m, rad) to the log-weights and normalise every row.

        Returns ``(w̄ [R, N] probabilities, log-normaliser [R], ESS [R])``; the
        log-weights buffer is overwritten by ``w̄``.
        """
        z = np.asarray(z, self.dtype)
        zr = np.ascontiguousarray(z[:, :, 0].T)[:, :, None]  # [K, R, 1]
        zb = np.ascontiguousarray(z[:, :, 1].T)[:, :, None]
        x, y, th = self.p
        ll = _loglik_into(
            x,
            y,
            th,
            self.lmx,
            self.lmy,
            zr,
            zb,
            self.inv_sd_r,
            self.inv_sd_b,
            self.log_norm,
            self.buf_a,
            self.buf_b,
        )  # [R, N]
        ll += self.lw
        return normalise_rows(ll)

    def uniforms(self):
        """The R resampling uniforms of one step, in [0, 1)."""
        return self.rng.random(self.r)

    def indices(self, w, u):
        """Systematic resampling of every row of ``w [R, N]`` with uniforms ``u [R]``: local indices ``[R, N]``.

        Row ``r`` gets ``min(searchsorted(cumsum(w_r), (u_r + i) / N, 'right'), N − 1)``,
        all rows by one ``np.searchsorted`` over the row-shifted cumulative sums.
        """
        flat = self.resample_flat(w, u)
        return flat - self.row_start

    def resample_flat(self, w, u):
        """As :meth:`indices`, but indices into the flattened ``[R · N]`` particles (what the gather takes)."""
        np.cumsum(w, axis=1, out=self.cdf32)  # float32, sequential per row like NumpyMCL
        np.add(self.cdf32, self.shift, out=self.cdf64)  # exact: float32 values plus small integers
        u32 = np.asarray(u, self.dtype)[:, None]
        np.add(self.grid, u32, out=self.pts32)
        self.pts32 *= self.dtype.type(1.0 / self.n)
        np.add(self.pts32, self.shift, out=self.pts64)
        idx = np.searchsorted(self.cdf64.ravel(), self.pts64.ravel(), side="right").reshape(self.r, self.n)
        np.minimum(idx, self.row_last, out=self.idx)  # a point past its row's last sum takes the last particle
        return self.idx

    def resample(self, flat_idx):
        """Gather all three planes of every row at once; uniform log-weights."""
        np.take(self.p.reshape(3, self.r * self.n), flat_idx.ravel(), axis=1, out=self._p_next.reshape(3, -1))
        self.p, self._p_next = self._p_next, self.p
        self.lw.fill(-math.log(self.n))

    def step(self, controls, z):
        """One W2 step of all R runs: move, weigh, normalise, ESS, resample. Returns ``(log_norm [R], ess [R])``."""
        self.move(controls)
        w, log_norm, ess = self.weigh(z)
        self.resample(self.resample_flat(w, self.uniforms()))
        return log_norm, ess


def normalise_rows(lw):
    """Per-row ``logsumexp`` normalisation of ``lw [R, N]`` (overwritten by the probabilities).

    Returns ``(w̄ [R, N], log-normaliser [R], ESS [R])`` with ``ESS = 1 / Σ_i w̄_i²``.
    """
    m = lw.max(axis=1, keepdims=True)
    np.subtract(lw, m, out=lw)
    w = np.exp(lw, out=lw)
    s = w.sum(axis=1, keepdims=True)
    np.multiply(w, 1.0 / s, out=w)
    ess = 1.0 / np.einsum("ij,ij->i", w, w)
    return w, (m + np.log(s))[:, 0], ess
