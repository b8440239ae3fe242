"""W2 peers in plain NumPy: a vectorised MCL step, and its filterpy and particles variants.

The model is exactly workload W2 (``benchmarks/README.md``):

* motion (Euler): ``x += v·Δt·cos θ``, ``y += v·Δt·sin θ``, ``θ += ω·Δt``, plus
  Gaussian noise with sd ``pose_sd = (0.02 m, 0.02 m, 0.01 rad)``;
* 8 landmarks observed every step by range-bearing, Gaussian log-likelihood with
  sd ``(0.1 m, 0.05 rad)`` summed over the 8, the bearing residual wrapped to
  ``[-π, π)``;
* ``logsumexp`` normalisation, ESS ``1 / Σ w̄²``;
* systematic resampling every step (``searchsorted`` on the cumulative sum,
  one uniform).

It is written to be a fair, fast NumPy peer, not a straw man:

* particles are stored as three contiguous arrays (structure of arrays), so
  every pass is a unit-stride stream;
* the likelihood works on ``[8, N]`` landmark-major blocks (one broadcast
  NumPy call per operation, not a Python loop over landmarks), in place where
  possible (``out=``), and the bearing residual is wrapped with
  ``r − 2π·rint(r / 2π)`` (cheaper than ``np.mod``);
* the motion noise is one ``standard_normal((3, N))`` call;
* θ is not re-wrapped after the move (only ``cos θ``, ``sin θ`` and the wrapped
  bearing residual use it, so wrapping it would be wasted work);
* the resampling grid ``arange(N)`` is allocated once.

The dtype is a constructor argument; the harness uses float32
(:data:`DEFAULT_DTYPE`), jaxnav's dtype: measured on the benchmark machine it
is 2–4× faster than float64 (NumPy's SIMD ``sin``/``cos``/``arctan2`` are
wider in float32 and the ``[8, N]`` blocks stay in cache longer), so it is the
stronger peer. Where a resampler cannot take float32 weights safely
(filterpy's and particles' loops run past the end when the float32 cumulative
sum stops short of 1), the weights are handed over in float64.

A per-step weighted mean (the pose estimate jaxnav's step also computes) is
not part of W2 and is not computed here: the peers do a little less work
than jaxnav.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["NumpyMCL", "FilterpyMCL", "make_particles_fk", "DEFAULT_DTYPE"]

DEFAULT_DTYPE = np.float32
_TWO_PI = 2.0 * math.pi


def _loglik_into(x, y, th, lmx, lmy, zr, zb, inv_sd_r, inv_sd_b, log_norm, buf_a, buf_b):
    """Σ_k log N(z_k; h(x, m_k), diag σ²) for every particle, with ``[K, N]`` scratch buffers.

    ``lmx, lmy, zr, zb`` are ``[K, 1]``; ``x, y, th`` are ``[N]`` (views are fine).
    Returns a new ``[N]`` array.
    """
    dx = np.subtract(lmx, x, out=buf_a)  # [K, N]
    dy = np.subtract(lmy, y, out=buf_b)
    bearing = np.arctan2(dy, dx)  # new [K, N]
    rng = np.hypot(dx, dy, out=buf_a)  # reuses dx's buffer
    # range residual, scaled and squared
    np.subtract(zr, rng, out=rng)
    np.multiply(rng, inv_sd_r, out=rng)
    np.multiply(rng, rng, out=rng)
    # bearing residual z_b − (atan2 − θ), wrapped, scaled and squared
    np.subtract(zb, bearing, out=bearing)
    np.add(bearing, th, out=bearing)
    np.multiply(bearing, 1.0 / _TWO_PI, out=buf_b)
    np.rint(buf_b, out=buf_b)
    np.multiply(buf_b, _TWO_PI, out=buf_b)
    np.subtract(bearing, buf_b, out=bearing)
    np.multiply(bearing, inv_sd_b, out=bearing)
    np.multiply(bearing, bearing, out=bearing)
    np.add(rng, bearing, out=rng)
    ll = rng.sum(axis=0)  # [N]
    ll *= -0.5
    ll += log_norm * lmx.shape[0]
    return ll


def _normalise(lw):
    """``(normalised log-weights W̄ as probabilities, log-normaliser, ESS)``; ``lw`` is overwritten."""
    m = lw.max()
    np.subtract(lw, m, out=lw)
    w = np.exp(lw, out=lw)
    s = w.sum()
    w *= 1.0 / s
    ess = 1.0 / np.dot(w, w)
    return w, m + math.log(s), ess


class NumpyMCL:
    """Bootstrap MCL in vectorised NumPy; ``step(control, z)`` does one W2 step.

    Args:
        particles: ``[N, 3]`` initial poses.
        landmarks: ``[K, 2]``.
        pose_sd: ``[3]`` motion noise sd.
        sensor_sd: ``[2]`` range-bearing noise sd.
        seed: seed of the ``np.random.Generator`` used for motion noise and resampling.
        dtype: float dtype of the particles and weights.
    """

    def __init__(self, particles, landmarks, pose_sd, sensor_sd, seed=0, dtype=DEFAULT_DTYPE):
        particles = np.asarray(particles, dtype)
        self.dtype = np.dtype(dtype)
        self.n = n = particles.shape[0]
        self.x = np.ascontiguousarray(particles[:, 0])
        self.y = np.ascontiguousarray(particles[:, 1])
        self.th = np.ascontiguousarray(particles[:, 2])
        self.lw = np.full(n, -math.log(n), dtype)
        self.rng = np.random.default_rng(seed)
        lm = np.asarray(landmarks, dtype)
        self.k = lm.shape[0]
        self.lmx = lm[:, 0:1].copy()
        self.lmy = lm[:, 1:2].copy()
        self.pose_sd = [float(s) for s in np.asarray(pose_sd)]
        sd = [float(s) for s in np.asarray(sensor_sd)]
        self.inv_sd_r, self.inv_sd_b = 1.0 / sd[0], 1.0 / sd[1]
        self.log_norm = -math.log(sd[0]) - math.log(sd[1]) - math.log(_TWO_PI)
        self.grid = np.arange(n, dtype=dtype)
        self.buf_a = np.empty((self.k, n), dtype)
        self.buf_b = np.empty((self.k, n), dtype)
        self.tmp = np.empty(n, dtype)

    # -- the three parts of a step ------------------------------------------

    def move(self, control):
        v, w, dt = (float(c) for c in control)
        eps = self.rng.standard_normal((3, self.n), dtype=self.dtype)
        c = np.cos(self.th, out=self.tmp)
        c *= v * dt
        self.x += c
        s = np.sin(self.th, out=self.tmp)
        s *= v * dt
        self.y += s
        self.th += w * dt
        sx, sy, st = self.pose_sd
        eps[0] *= sx
        eps[1] *= sy
        eps[2] *= st
        self.x += eps[0]
        self.y += eps[1]
        self.th += eps[2]

    def weigh(self, z):
        """Log-likelihood added to the log-weights; returns ``(W̄, log_norm, ess)``."""
        z = np.asarray(z, self.dtype)
        ll = _loglik_into(
            self.x,
            self.y,
            self.th,
            self.lmx,
            self.lmy,
            z[:, 0:1],
            z[:, 1:2],
            self.inv_sd_r,
            self.inv_sd_b,
            self.log_norm,
            self.buf_a,
            self.buf_b,
        )
        ll += self.lw
        return _normalise(ll)

    def indices(self, w):
        """Systematic resampling of probabilities ``w`` (NumPy searchsorted)."""
        cdf = np.cumsum(w)
        u = self.grid + self.dtype.type(self.rng.random())
        u *= self.dtype.type(1.0 / self.n)
        idx = np.searchsorted(cdf, u, side="right")
        np.minimum(idx, self.n - 1, out=idx)
        return idx

    def resample(self, idx):
        self.x = self.x[idx]
        self.y = self.y[idx]
        self.th = self.th[idx]
        self.lw.fill(-math.log(self.n))

    def step(self, control, z):
        """One W2 step: move, weigh, normalise, ESS, resample. Returns ``(log_norm, ess)``."""
        self.move(control)
        w, log_norm, ess = self.weigh(z)
        self.resample(self.indices(w))
        return log_norm, ess


class FilterpyMCL(NumpyMCL):
    """:class:`NumpyMCL` with ``filterpy.monte_carlo.systematic_resample`` as the resampler.

    filterpy has no particle-filter class: its book builds one from NumPy
    motion and likelihood code plus these resamplers, which is what this does.
    The resampler is a pure-Python ``while`` loop over the N particles and
    draws its uniform from the global NumPy generator.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        from filterpy.monte_carlo import systematic_resample

        self._resample = systematic_resample
        self.index_errors = 0

    def indices(self, w):
        # filterpy's loop indexes past the end when the cumulative sum stops short of the
        # last point (u + N − 1)/N: hand it float64 weights renormalised in float64 (the
        # float32 normalisation is off by ~1e-7, enough to fail at N = 1e6). If it still
        # runs off the end (a uniform within round-off of 1), draw again.
        w64 = w.astype(np.float64)
        w64 /= w64.sum()
        for _ in range(3):
            try:
                return self._resample(w64)
            except IndexError:
                self.index_errors += 1
        raise RuntimeError("filterpy.systematic_resample ran past the end three times")


def make_particles_fk(particles_module, x0, controls, zs, landmarks, pose_sd, sensor_sd, seed=0, dtype=DEFAULT_DTYPE):
    """A ``particles.FeynmanKac`` bootstrap model of W2 (same NumPy kernels).

    The time index of ``particles`` maps onto W2's steps as follows: ``M0``
    moves the initial particles with control 0 and ``logG(0, ·)`` scores
    observation 0; for ``t ≥ 1``, ``SMC.__next__`` resamples (``ESSrmin = 1``:
    every step), ``M(t, ·)`` moves with control ``t`` and ``logG(t, ·)`` scores
    observation ``t``. So ``next(alg)`` for ``t ≥ 1`` is one full W2 step
    (resample, move, weigh, normalise, ESS); the resampling sits at the start
    of the step rather than the end, the same work per step.

    Particles are ``[N, 3]`` arrays (``particles`` indexes them with the
    ancestor array).
    """
    fk_base = particles_module.FeynmanKac
    x0 = np.asarray(x0, dtype)
    controls = np.asarray(controls, np.float64)
    zs = np.asarray(zs, dtype)
    lm = np.asarray(landmarks, dtype)
    n = x0.shape[0]
    k = lm.shape[0]
    psd = [float(s) for s in np.asarray(pose_sd)]
    sd = [float(s) for s in np.asarray(sensor_sd)]
    inv_sd_r, inv_sd_b = 1.0 / sd[0], 1.0 / sd[1]
    log_norm = -math.log(sd[0]) - math.log(sd[1]) - math.log(_TWO_PI)
    lmx, lmy = lm[:, 0:1].copy(), lm[:, 1:2].copy()

    class W2FeynmanKac(fk_base):
        def __init__(self):
            super().__init__(T=controls.shape[0])
            self.rng = np.random.default_rng(seed)
            self.buf_a = np.empty((k, n), dtype)
            self.buf_b = np.empty((k, n), dtype)

        def _move(self, xp, t):
            v, w, dt = (float(c) for c in controls[t])  # Python floats keep float32 math
            eps = self.rng.standard_normal((xp.shape[0], 3), dtype=dtype)
            eps *= np.asarray(psd, dtype)
            th = xp[:, 2]
            out = np.empty_like(xp)
            np.multiply(np.cos(th), v * dt, out=out[:, 0])
            np.multiply(np.sin(th), v * dt, out=out[:, 1])
            out[:, 2] = w * dt
            out += xp
            out += eps
            return out

        def M0(self, N):
            return self._move(x0, 0)

        def M(self, t, xp):
            return self._move(xp, t)

        def logG(self, t, xp, x):
            z = zs[t]
            ll = _loglik_into(
                x[:, 0],
                x[:, 1],
                x[:, 2],
                lmx,
                lmy,
                z[:, 0:1],
                z[:, 1:2],
                inv_sd_r,
                inv_sd_b,
                log_norm,
                self.buf_a,
                self.buf_b,
            )
            # float64 weights: particles' numba inverse_cdf has no bounds check and
            # a float32 running sum can stop short of the last uniform.
            return ll.astype(np.float64)

    return W2FeynmanKac()
