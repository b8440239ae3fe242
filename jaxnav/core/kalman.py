"""Kalman primitives: EKF and UKF predict/update, shared by every Gaussian filter.

**Overview**

Functions over one Gaussian ``(mean [n], cov [n, n])``; batch them with
``jax.vmap`` (FastSLAM runs one per particle and landmark). Models are plain
functions — ``f(x) -> x'`` for the motion, ``h(x, aux) -> z`` for an
observation, where ``aux`` is per-observation data such as a landmark
position — and every Jacobian comes from ``jax.jacfwd`` of them, never by hand.

* EKF ([A] Alg. 1; Thrun et al. Tab. 3.3):
  predict ``x' = f(x)``, ``P' = F P Fᵀ + Q`` with ``F = ∂f/∂x``;
  update ``K = P Hᵀ S⁻¹``, ``S = H P Hᵀ + R`` and the Joseph form
  ``P' = (I − KH) P (I − KH)ᵀ + K R Kᵀ``, which stays symmetric positive
  semi-definite in float32 where ``(I − KH) P`` does not.
* UKF (Julier & Uhlmann; Wan & van der Merwe's scaled sigma points with
  ``α, β, κ``; Thrun et al. Tab. 3.4): ``2n + 1`` points
  ``x ± √((n + λ)) L`` with ``L`` the Cholesky factor of ``P``.

Angles: ``state_angle_dims`` / ``obs_angle_dims`` name the components that
live on the circle (a heading, a bearing). Their residuals are wrapped to
``[-π, π)`` and sigma-point means are taken as wrapped offsets from the
central point, so a belief straddling ±π is averaged correctly.

Several observations in one step are fused one after another
(:func:`ekf_update_sequential`, :func:`ukf_update_sequential`: a
``lax.scan`` over the fixed observation slots, invalid slots skipped), which
equals the joint update for a linear model with independent noises.

Gating: with ``gate`` set, an observation whose normalised innovation
squared ``NIS = yᵀ S⁻¹ y`` exceeds it is rejected (the Mahalanobis test of
Thrun et al. §7.5.2); :func:`chi2_gate` gives the threshold for a
probability. Rejections are reported, never silent.

Robustness: covariances are symmetrised after every operation and
:func:`ensure_pd` adds diagonal jitter where needed; a failed Cholesky
factorisation in the UKF falls back to the square root of the jittered
diagonal and is reported in the result's ``cholesky_failed`` flag, so no
NaN leaves these functions.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.fastmath import matmul, small_sum
from jaxnav.core.weights import wrap_angle

__all__ = [
    "Gaussian",
    "UpdateResult",
    "SigmaWeights",
    "symmetrize",
    "ensure_pd",
    "chi2_gate",
    "gaussian_log_pdf",
    "ekf_predict",
    "ekf_update",
    "ekf_update_sequential",
    "sigma_weights",
    "sigma_points",
    "ukf_predict",
    "ukf_update",
    "ukf_update_sequential",
    "kalman_predict",
    "kalman_update",
    "finite_or_previous",
]

DEFAULT_JITTER = 1e-9  # added to the diagonal (units²) by ensure_pd


class Gaussian(NamedTuple):
    """A Gaussian belief: ``mean [n]`` and ``cov [n, n]``."""

    mean: jax.Array
    cov: jax.Array


class UpdateResult(NamedTuple):
    """Result of one (or a sequence of) measurement updates.

    Attributes:
        mean, cov: the posterior.
        nis: normalised innovation squared ``yᵀ S⁻¹ y`` (``[K]`` for a
            sequential update; 0 where a slot was invalid).
        log_likelihood: ``log N(z; ẑ, S)`` summed over accepted observations.
        accepted: bool, the observation was valid and passed the gate.
        cholesky_failed: bool, the UKF's sigma-point factorisation failed
            and the diagonal fallback was used (always False for the EKF).
    """

    mean: jax.Array
    cov: jax.Array
    nis: jax.Array
    log_likelihood: jax.Array
    accepted: jax.Array
    cholesky_failed: jax.Array


# ---------------------------------------------------------------------------
# small helpers


def symmetrize(cov: jax.Array) -> jax.Array:
    """``(P + Pᵀ) / 2`` over the last two axes."""
    return 0.5 * (cov + jnp.swapaxes(cov, -1, -2))


def ensure_pd(cov: jax.Array, jitter: float = DEFAULT_JITTER) -> jax.Array:
    """Symmetrise and lift the diagonal to at least ``jitter`` (keeps a Cholesky factor defined)."""
    cov = symmetrize(cov)
    d = jnp.diagonal(cov, axis1=-2, axis2=-1)
    lift = jnp.maximum(jitter - d, 0.0)
    return cov + lift[..., None] * jnp.eye(cov.shape[-1], dtype=cov.dtype)


def chi2_gate(probability: float, dof: int) -> float:
    """χ² quantile with ``dof`` degrees of freedom: the NIS threshold that keeps ``probability``
    of consistent observations (host side; bisection on the exact CDF, relative accuracy 1e-12)."""
    p = float(probability)
    if not 0.0 < p < 1.0:
        raise ValueError(f"gate probability must be in (0, 1), got {probability!r}")
    if isinstance(dof, bool) or int(dof) != dof or dof < 1:
        raise ValueError(f"dof must be a positive integer, got {dof!r}")
    if dof == 2:
        return -2.0 * math.log1p(-p)
    lo, hi = 0.0, 1.0
    while _chi2_cdf(hi, dof) < p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _chi2_cdf(mid, dof) < p else (lo, mid)
    return 0.5 * (lo + hi)


def _chi2_cdf(x: float, dof: int) -> float:
    """``P(dof/2, x/2)``, the regularised lower incomplete gamma function, by its power series."""
    a, h = 0.5 * dof, 0.5 * x
    if h <= 0.0:
        return 0.0
    term = total = 1.0 / a
    n = 0
    while term > 1e-17 * total and n < 100_000:
        n += 1
        term *= h / (a + n)
        total += term
    return min(1.0, math.exp(a * math.log(h) - h - math.lgamma(a)) * total)


def _diff(a: jax.Array, b: jax.Array, angle_dims: tuple[int, ...]) -> jax.Array:
    """``a − b`` with the components in ``angle_dims`` wrapped to ``[-π, π)``."""
    d = a - b
    for i in angle_dims:
        d = d.at[..., i].set(wrap_angle(d[..., i]))
    return d


def _wrap(x: jax.Array, angle_dims: tuple[int, ...]) -> jax.Array:
    for i in angle_dims:
        x = x.at[..., i].set(wrap_angle(x[..., i]))
    return x


_UNROLL_MAX = 4  # factorise m × m matrices up to this size with unrolled scalar code


def _cholesky(cov: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Lower Cholesky factor and a failure flag; on failure the jittered diagonal's square root.

    Matrices up to 4 × 4 (innovation covariances, landmark and pose
    covariances) are factorised by unrolled scalar code instead of LAPACK's
    ``potrf``: XLA:CPU cannot fuse that custom call and, under ``vmap``, runs
    it once per batch element, which made it the largest cost of a batched
    Kalman update (benchmark W4).
    """
    m = cov.shape[-1]
    if m > _UNROLL_MAX:
        chol = jnp.linalg.cholesky(cov)
    else:
        low = [[jnp.zeros((), cov.dtype)] * m for _ in range(m)]
        for j in range(m):
            d = cov[j, j]
            for k in range(j):
                d = d - low[j][k] * low[j][k]
            low[j][j] = jnp.sqrt(d)
            for i in range(j + 1, m):
                v = cov[i, j]
                for k in range(j):
                    v = v - low[i][k] * low[j][k]
                low[i][j] = v / low[j][j]
        chol = jnp.stack([jnp.stack(row) for row in low])
    failed = ~jnp.all(jnp.isfinite(chol))
    fallback = jnp.diag(jnp.sqrt(jnp.maximum(jnp.diagonal(cov), DEFAULT_JITTER)))
    return jnp.where(failed, fallback, chol), failed


def _solve_lower(chol: jax.Array, rhs: jax.Array) -> jax.Array:
    """``L⁻¹ rhs`` for ``rhs [m]`` or ``[m, k]`` (forward substitution, unrolled for small m)."""
    m = chol.shape[-1]
    if m > _UNROLL_MAX:
        return jax.scipy.linalg.solve_triangular(chol, rhs, lower=True)
    rows: list[jax.Array] = []
    for i in range(m):
        v = rhs[i]
        for k in range(i):
            v = v - chol[i, k] * rows[k]
        rows.append(v / chol[i, i])
    return jnp.stack(rows)


def _solve_upper_t(chol: jax.Array, rhs: jax.Array) -> jax.Array:
    """``L⁻ᵀ rhs`` (back substitution, unrolled for small m)."""
    m = chol.shape[-1]
    if m > _UNROLL_MAX:
        return jax.scipy.linalg.solve_triangular(chol.T, rhs, lower=False)
    rows: list[jax.Array | None] = [None] * m
    for i in reversed(range(m)):
        v = rhs[i]
        for k in range(i + 1, m):
            v = v - chol[k, i] * rows[k]
        rows[i] = v / chol[i, i]
    return jnp.stack(rows)


def gaussian_log_pdf(residual: jax.Array, cov: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(log N(residual; 0, cov), residualᵀ cov⁻¹ residual)`` via a Cholesky solve."""
    chol, _ = _cholesky(cov)
    white = _solve_lower(chol, residual)
    maha = small_sum(white * white)
    log_det = 2.0 * small_sum(jnp.log(jnp.diagonal(chol)))
    return -0.5 * (maha + log_det + residual.shape[-1] * math.log(2.0 * math.pi)), maha


def _gain(cross: jax.Array, innovation_cov: jax.Array) -> jax.Array:
    """Kalman gain ``K = C S⁻¹`` for a cross covariance ``C [n, m]`` (a solve, not an inverse)."""
    chol, _ = _cholesky(innovation_cov)
    return _solve_upper_t(chol, _solve_lower(chol, cross.T)).T


def _joseph(cov: jax.Array, gain: jax.Array, jac: jax.Array, noise_cov: jax.Array) -> jax.Array:
    """Joseph form ``(I − KH) P (I − KH)ᵀ + K R Kᵀ``, reassociated.

    Evaluated as ``M = P − K (H P)``, ``M − (M Hᵀ) Kᵀ + K R Kᵀ`` — the same
    expression for any gain — so that no ``n × n`` by ``n × n`` product is
    formed: under ``vmap`` XLA:CPU hands each tiny batched matrix product to
    its thread pool at about a microsecond per batch element (W4).
    """
    m_ = cov - matmul(gain, matmul(jac, cov))
    return ensure_pd(m_ - matmul(matmul(m_, jac.T), gain.T) + matmul(matmul(gain, noise_cov), gain.T))


def _result(prior: Gaussian, posterior: Gaussian, valid, gate, nis, log_lik, cholesky_failed) -> UpdateResult:
    """Keep the posterior only for a valid observation that passes the gate; report why."""
    accepted = jnp.asarray(valid) & (True if gate is None else nis <= gate)
    zero = jnp.zeros((), prior.cov.dtype)
    return UpdateResult(
        jnp.where(accepted, posterior.mean, prior.mean),
        jnp.where(accepted, posterior.cov, prior.cov),
        jnp.where(valid, nis, zero),
        jnp.where(accepted, log_lik, zero),
        accepted,
        cholesky_failed,
    )


# ---------------------------------------------------------------------------
# EKF


def ekf_predict(
    mean: jax.Array,
    cov: jax.Array,
    f: Callable[[jax.Array], jax.Array],
    process_cov: jax.Array,
) -> Gaussian:
    """EKF prediction ([A] Alg. 1 lines 2–3): ``x' = f(x)``, ``P' = F P Fᵀ + Q``, ``F = jacfwd(f)``."""
    x_new = f(mean)
    jac = jax.jacfwd(f)(mean)
    return Gaussian(x_new, ensure_pd(matmul(matmul(jac, cov), jac.T) + process_cov))


def ekf_update(
    mean: jax.Array,
    cov: jax.Array,
    z: jax.Array,
    h: Callable[..., jax.Array],
    noise_cov: jax.Array,
    aux: Any = None,
    *,
    valid: jax.Array | bool = True,
    gate: float | jax.Array | None = None,
    state_angle_dims: tuple[int, ...] = (),
    obs_angle_dims: tuple[int, ...] = (),
) -> UpdateResult:
    """EKF measurement update ([A] Alg. 1 lines 4–8) in Joseph form.

    Args:
        mean, cov: prior ``[n]``, ``[n, n]``.
        z: measurement ``[m]``; never read when ``valid`` is False (NaN is harmless).
        h: observation mean ``h(x)`` or ``h(x, aux)`` when ``aux`` is given.
        noise_cov: ``R [m, m]``.
        aux: per-observation data passed to ``h`` (e.g. a landmark position).
        valid: whether the observation exists.
        gate: NIS threshold; observations above it are rejected (None: no gate).
        state_angle_dims, obs_angle_dims: circular components (static).
    """
    hx = (lambda x: h(x, aux)) if aux is not None else h
    z_hat = hx(mean)
    jac = jax.jacfwd(hx)(mean)
    z_safe = jnp.where(valid, z, z_hat)
    y = _diff(z_safe, z_hat, obs_angle_dims)
    s = symmetrize(matmul(matmul(jac, cov), jac.T) + noise_cov)
    log_lik, nis = gaussian_log_pdf(y, s)
    gain = _gain(matmul(cov, jac.T), s)
    new = Gaussian(_wrap(mean + matmul(gain, y), state_angle_dims), _joseph(cov, gain, jac, noise_cov))
    return _result(Gaussian(mean, cov), new, valid, gate, nis, log_lik, jnp.zeros((), bool))


def _sequential(update: Callable[..., UpdateResult]):
    def run(mean, cov, zs, h, noise_cov, aux=None, *, valid, gate=None, state_angle_dims=(), obs_angle_dims=(), **kw):
        def body(carry, slot):
            z, ok, a = slot
            r = update(
                carry.mean,
                carry.cov,
                z,
                h,
                noise_cov,
                a,
                valid=ok,
                gate=gate,
                state_angle_dims=state_angle_dims,
                obs_angle_dims=obs_angle_dims,
                **kw,
            )
            return Gaussian(r.mean, r.cov), (r.nis, r.log_likelihood, r.accepted, r.cholesky_failed)

        post, (nis, ll, acc, failed) = jax.lax.scan(body, Gaussian(mean, cov), (zs, valid, aux))
        return UpdateResult(post.mean, post.cov, nis, jnp.sum(ll), acc, jnp.any(failed))

    return run


def ekf_update_sequential(
    mean: jax.Array,
    cov: jax.Array,
    zs: jax.Array,
    h: Callable[..., jax.Array],
    noise_cov: jax.Array,
    aux: Any = None,
    *,
    valid: jax.Array,
    gate: float | jax.Array | None = None,
    state_angle_dims: tuple[int, ...] = (),
    obs_angle_dims: tuple[int, ...] = (),
) -> UpdateResult:
    """:func:`ekf_update` for ``K`` observation slots in turn (``zs [K, m]``, ``valid [K]``, ``aux`` leading ``K``).

    Returns per-slot ``nis`` and ``accepted`` (``[K]``) and the summed log-likelihood.
    """
    return _sequential(ekf_update)(
        mean,
        cov,
        zs,
        h,
        noise_cov,
        aux,
        valid=valid,
        gate=gate,
        state_angle_dims=state_angle_dims,
        obs_angle_dims=obs_angle_dims,
    )


# ---------------------------------------------------------------------------
# UKF


class SigmaWeights(NamedTuple):
    """Scaled unscented transform weights for the mean (``wm``) and covariance (``wc``), and ``√(n + λ)``."""

    wm: jax.Array
    wc: jax.Array
    scale: float


def sigma_weights(
    n: int, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0, dtype: Any = jnp.float32
) -> SigmaWeights:
    """Weights of the ``2n + 1`` scaled sigma points (van der Merwe 2004, eq. 3.5–3.6).

    ``λ = α²(n + κ) − n``; ``w_m⁰ = λ/(n + λ)``, ``w_c⁰ = w_m⁰ + 1 − α² + β``,
    ``w⁽ⁱ⁾ = 1 / (2(n + λ))``. α = 1, β = 2, κ = 0 (the default) keeps every
    point at ``√n`` standard deviations with a zero central mean weight,
    which is robust for the strongly nonlinear bearing models here.
    """
    lam = alpha**2 * (n + kappa) - n
    if n + lam <= 0:
        raise ValueError(f"UKF parameters give n + λ = {n + lam} ≤ 0; increase alpha or kappa")
    wi = 1.0 / (2.0 * (n + lam))
    wm = np.full(2 * n + 1, wi)
    wc = np.full(2 * n + 1, wi)
    wm[0] = lam / (n + lam)
    wc[0] = wm[0] + 1.0 - alpha**2 + beta
    return SigmaWeights(jnp.asarray(wm, dtype), jnp.asarray(wc, dtype), math.sqrt(n + lam))


def sigma_points(
    mean: jax.Array, cov: jax.Array, weights: SigmaWeights, state_angle_dims: tuple[int, ...] = ()
) -> tuple[jax.Array, jax.Array]:
    """``[2n + 1, n]`` sigma points ``x, x ± √(n + λ) Lᵢ`` and the Cholesky failure flag."""
    chol, failed = _cholesky(ensure_pd(cov))
    offsets = weights.scale * chol.T  # rows are the columns of L
    pts = jnp.concatenate([mean[None], mean + offsets, mean - offsets], axis=0)
    return _wrap(pts, state_angle_dims), failed


def _unscented_moments(
    points: jax.Array, weights: SigmaWeights, angle_dims: tuple[int, ...]
) -> tuple[jax.Array, jax.Array]:
    """Weighted mean (angles as wrapped offsets from the central point) and deviations."""
    ref = points[0]
    offsets = _diff(points, ref, angle_dims)
    mean = _wrap(ref + weights.wm @ offsets, angle_dims)
    return mean, _diff(points, mean, angle_dims)


def ukf_predict(
    mean: jax.Array,
    cov: jax.Array,
    f: Callable[[jax.Array], jax.Array],
    process_cov: jax.Array,
    weights: SigmaWeights,
    state_angle_dims: tuple[int, ...] = (),
) -> tuple[Gaussian, jax.Array]:
    """Unscented prediction (Thrun et al. Tab. 3.4 lines 2–5); returns ``(prior, cholesky_failed)``."""
    pts, failed = sigma_points(mean, cov, weights, state_angle_dims)
    moved = jax.vmap(f)(pts)
    m, dev = _unscented_moments(moved, weights, state_angle_dims)
    p = (dev * weights.wc[:, None]).T @ dev + process_cov
    return Gaussian(m, ensure_pd(p)), failed


def ukf_update(
    mean: jax.Array,
    cov: jax.Array,
    z: jax.Array,
    h: Callable[..., jax.Array],
    noise_cov: jax.Array,
    aux: Any = None,
    *,
    valid: jax.Array | bool = True,
    gate: float | jax.Array | None = None,
    state_angle_dims: tuple[int, ...] = (),
    obs_angle_dims: tuple[int, ...] = (),
    weights: SigmaWeights,
) -> UpdateResult:
    """Unscented measurement update (Thrun et al. Tab. 3.4 lines 6–13); arguments as :func:`ekf_update`."""
    hx = (lambda x: h(x, aux)) if aux is not None else h
    pts, failed = sigma_points(mean, cov, weights, state_angle_dims)
    zs = jax.vmap(hx)(pts)
    z_hat, dz = _unscented_moments(zs, weights, obs_angle_dims)
    dx = _diff(pts, mean, state_angle_dims)
    s = symmetrize((dz * weights.wc[:, None]).T @ dz + noise_cov)
    cross = (dx * weights.wc[:, None]).T @ dz
    z_safe = jnp.where(valid, z, z_hat)
    y = _diff(z_safe, z_hat, obs_angle_dims)
    log_lik, nis = gaussian_log_pdf(y, s)
    gain = _gain(cross, s)
    new = Gaussian(_wrap(mean + gain @ y, state_angle_dims), ensure_pd(cov - gain @ s @ gain.T))
    return _result(Gaussian(mean, cov), new, valid, gate, nis, log_lik, failed & jnp.asarray(valid))


def ukf_update_sequential(
    mean: jax.Array,
    cov: jax.Array,
    zs: jax.Array,
    h: Callable[..., jax.Array],
    noise_cov: jax.Array,
    aux: Any = None,
    *,
    valid: jax.Array,
    gate: float | jax.Array | None = None,
    state_angle_dims: tuple[int, ...] = (),
    obs_angle_dims: tuple[int, ...] = (),
    weights: SigmaWeights,
) -> UpdateResult:
    """:func:`ukf_update` over ``K`` observation slots in turn (see :func:`ekf_update_sequential`)."""
    return _sequential(ukf_update)(
        mean,
        cov,
        zs,
        h,
        noise_cov,
        aux,
        valid=valid,
        gate=gate,
        state_angle_dims=state_angle_dims,
        obs_angle_dims=obs_angle_dims,
        weights=weights,
    )


# ---------------------------------------------------------------------------
# linear Kalman filter (the reference the EKF and UKF must reproduce)


# float32, n, m ≤ 4: the linear filter runs as scalar code. Every matrix entry is a separate
# array (a ``[B]`` vector under ``vmap``) and every product is written out as multiply-adds
# over those entries, so that XLA fuses the step into a few dozen elementwise loops over the
# batch, vectorised along it, with no ``dot``, LAPACK call or ``[B, n, n]`` broadcast inside
# the step. float64 and larger sizes use the matrix form (:func:`ekf_update` with
# ``h(x) = C x``). Both are the reassociated Joseph form: in float32, on the W4 model with
# P0 × 10⁴ and R × 10⁻⁴, the standard update ``P − K C P`` lost the covariance (zero
# eigenvalues) where the Joseph form stayed positive definite and near a float64 reference
# (``tests/core/test_kalman.py``). The choice between the forms follows benchmark W4 (n = 4,
# m = 2, T = 1000, ``jit(vmap(scan))``, B = 1, 100 and 1000 sequences). In float32 the scalar
# form is faster than the matrix form and than dynamax's ``lgssm_filter``, by a margin that grows
# with the batch. In float64 it is no faster for a batch and slower for one sequence, where the
# step costs its count of kernel launches (about 44 against 27). The matrix form with the
# standard update ``P − K C P`` is the fastest for one sequence and about as fast as this one
# for a batch, but is not used for the reason above. Above n = 4 the unrolled code would grow
# as n³.
_KF_UNROLL_MAX = 4
_SCALAR_FORM_FLOAT64 = False  # float64 takes the matrix form (see above); tests set it to check both


def _unrolled(n: int, m: int, *arrays: jax.Array) -> bool:
    """Whether the linear filter's scalar form applies: float32 (not float64), ``n, m ≤ 4``,
    one unbatched Gaussian."""
    small = n <= _KF_UNROLL_MAX and m <= _KF_UNROLL_MAX and all(jnp.ndim(x) <= 2 for x in arrays)
    return small and (_SCALAR_FORM_FLOAT64 or jnp.result_type(*arrays) != jnp.float64)


def _entries(x: jax.Array) -> list[list[jax.Array]]:
    """The entries of a matrix as nested lists of scalars.

    Read from the flattened matrix: a matrix built by :func:`_stack` is a reshape of one
    concatenation of its entries, which XLA then folds away (two nested stacks it does
    not: the predicted covariance would be written out and read back).
    """
    rows, cols = x.shape
    flat = x.reshape(rows * cols)
    return [[flat[i * cols + j] for j in range(cols)] for i in range(rows)]


def _sym_entries(x: jax.Array) -> list[list[jax.Array]]:
    """The entries of ``(X + Xᵀ) / 2``, each computed once."""
    e = _entries(x)
    n = len(e)
    out: list[list[Any]] = [[None] * n for _ in range(n)]
    for i in range(n):
        out[i][i] = e[i][i]
        for j in range(i + 1, n):
            out[i][j] = out[j][i] = 0.5 * (e[i][j] + e[j][i])
    return out


def _dot(xs: list, ys: list) -> jax.Array:
    """``Σ_k xs[k] ys[k]`` as a chain of multiply-adds."""
    out = xs[0] * ys[0]
    for x, y in zip(xs[1:], ys[1:]):
        out = out + x * y
    return out


def _stack(rows: list[list[jax.Array]]) -> jax.Array:
    """The matrix of nested lists of scalars: one concatenation, reshaped (see :func:`_entries`)."""
    return jnp.stack([e for row in rows for e in row]).reshape(len(rows), len(rows[0]))


def _scalar_cholesky(s: list[list[jax.Array]]) -> tuple[list[list[jax.Array]], list[jax.Array]]:
    """Lower Cholesky factor of ``s`` (entries) and the reciprocals of its diagonal.

    As :func:`_cholesky`: when a factor entry is not finite, the square root of the
    jittered diagonal is used instead.
    """
    m = len(s)
    low: list[list[Any]] = [[jnp.zeros_like(s[0][0])] * m for _ in range(m)]
    for j in range(m):
        d = s[j][j]
        for k in range(j):
            d = d - low[j][k] * low[j][k]
        low[j][j] = jnp.sqrt(d)
        for i in range(j + 1, m):
            v = s[i][j]
            for k in range(j):
                v = v - low[i][k] * low[j][k]
            low[i][j] = v / low[j][j]
    failed = ~jnp.isfinite(low[0][0])
    for i in range(m):
        for j in range(1 if i == 0 else 0, i + 1):
            failed = failed | ~jnp.isfinite(low[i][j])
    for i in range(m):
        for j in range(i):
            low[i][j] = jnp.where(failed, jnp.zeros_like(low[i][j]), low[i][j])
        low[i][i] = jnp.where(failed, jnp.sqrt(jnp.maximum(s[i][i], DEFAULT_JITTER)), low[i][i])
    return low, [1.0 / low[i][i] for i in range(m)]


def _forward(low: list[list[jax.Array]], inv: list[jax.Array], rhs: list) -> list[jax.Array]:
    """``L⁻¹ rhs`` for a vector of entries."""
    out: list[jax.Array] = []
    for i in range(len(rhs)):
        v = rhs[i]
        for k in range(i):
            v = v - low[i][k] * out[k]
        out.append(v * inv[i])
    return out


def _backward(low: list[list[jax.Array]], inv: list[jax.Array], rhs: list) -> list[jax.Array]:
    """``L⁻ᵀ rhs`` for a vector of entries."""
    m = len(rhs)
    out: list[Any] = [None] * m
    for i in reversed(range(m)):
        v = rhs[i]
        for k in range(i + 1, m):
            v = v - low[k][i] * out[k]
        out[i] = v * inv[i]
    return out


def kalman_predict(mean: jax.Array, cov: jax.Array, transition: jax.Array, process_cov: jax.Array) -> Gaussian:
    """Linear prediction ``x' = A x``, ``P' = A P Aᵀ + Q``, symmetrised (``P`` and ``Q`` are read
    as ``(P + Pᵀ)/2``, ``(Q + Qᵀ)/2``)."""
    mean, cov, transition, process_cov = (jnp.asarray(x) for x in (mean, cov, transition, process_cov))
    n = mean.shape[-1]
    if not (_unrolled(n, 1, mean, cov, transition, process_cov) and mean.ndim == 1 and transition.shape == (n, n)):
        return Gaussian(transition @ mean, symmetrize(transition @ cov @ transition.T + process_cov))
    a, p, q = _entries(transition), _sym_entries(cov), _sym_entries(process_cov)
    x = [mean[i] for i in range(n)]
    ap = [[_dot(a[i], [p[k][j] for k in range(n)]) for j in range(n)] for i in range(n)]
    out: list[list[Any]] = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i, n):
            out[i][j] = out[j][i] = _dot(ap[i], a[j]) + q[i][j]
    return Gaussian(jnp.stack([_dot(a[i], x) for i in range(n)]), _stack(out))


def kalman_update(
    mean: jax.Array,
    cov: jax.Array,
    z: jax.Array,
    observation: jax.Array,
    noise_cov: jax.Array,
    valid: jax.Array | bool = True,
) -> UpdateResult:
    """Linear update ``z = C x + v``, ``v ~ N(0, R)``, in Joseph form: the result of
    :func:`ekf_update` with ``h(x) = C x`` (to rounding), computed in scalar form in
    float32 for ``n, m ≤ 4`` (see the note above ``_KF_UNROLL_MAX``).

    ``S = C P Cᵀ + R``, ``K = P Cᵀ S⁻¹`` (Cholesky solves), ``x' = x + K (z − C x)``,
    ``P' = M − (M Cᵀ) Kᵀ + K R Kᵀ`` with ``M = P − K (C P)`` (the Joseph form
    ``(I − KC) P (I − KC)ᵀ + K R Kᵀ`` reassociated), symmetric by construction and
    its diagonal lifted to at least ``DEFAULT_JITTER`` as by :func:`ensure_pd`. The
    scalar form reads ``P`` and ``R`` as ``(P + Pᵀ)/2``, ``(R + Rᵀ)/2``.
    """
    mean, cov, z, observation, noise_cov = (jnp.asarray(x) for x in (mean, cov, z, observation, noise_cov))
    n, m = mean.shape[-1], z.shape[-1]
    if not (
        _unrolled(n, m, mean, cov, z, observation, noise_cov)
        and mean.ndim == 1
        and z.ndim == 1
        and observation.shape == (m, n)
    ):
        return ekf_update(mean, cov, z, lambda x: observation @ x, noise_cov, valid=valid)
    c, p, r = _entries(observation), _sym_entries(cov), _sym_entries(noise_cov)
    x = [mean[i] for i in range(n)]
    z_hat = [_dot(c[k], x) for k in range(m)]
    y = [jnp.where(valid, z[k], z_hat[k]) - z_hat[k] for k in range(m)]
    pct = [[_dot(p[i], c[k]) for k in range(m)] for i in range(n)]  # (P Cᵀ)[i][k] = (C P)[k][i]
    s: list[list[Any]] = [[None] * m for _ in range(m)]
    for k in range(m):
        for l in range(k, m):
            s[k][l] = s[l][k] = _dot(c[k], [pct[i][l] for i in range(n)]) + r[k][l]
    low, inv = _scalar_cholesky(s)
    white = _forward(low, inv, y)
    nis = _dot(white, white)
    log_det = 2.0 * jnp.log(low[0][0])
    for k in range(1, m):
        log_det = log_det + 2.0 * jnp.log(low[k][k])
    log_lik = -0.5 * (nis + log_det + m * math.log(2.0 * math.pi))
    gain = [_backward(low, inv, _forward(low, inv, pct[i])) for i in range(n)]  # K[i][k]
    new_mean = jnp.stack([x[i] + _dot(gain[i], y) for i in range(n)])
    # Joseph form, reassociated as in _joseph: M = P − K (C P), P' = M − (M Cᵀ) Kᵀ + (K R) Kᵀ
    mx = [[p[i][j] - _dot(gain[i], pct[j]) for j in range(n)] for i in range(n)]
    mct = [[_dot(mx[i], c[k]) for k in range(m)] for i in range(n)]
    kr = [[_dot(gain[i], [r[l][k] for l in range(m)]) for k in range(m)] for i in range(n)]
    out: list[list[Any]] = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i, n):
            v = mx[i][j] - _dot(mct[i], gain[j]) + _dot(kr[i], gain[j])
            if i == j:
                v = v + jnp.maximum(DEFAULT_JITTER - v, 0.0)
            out[i][j] = out[j][i] = v
    posterior = Gaussian(new_mean, _stack(out))
    return _result(Gaussian(mean, cov), posterior, valid, None, nis, log_lik, jnp.zeros((), bool))


def finite_or_previous(new: Any, previous: Any) -> tuple[Any, jax.Array]:
    """The guard every Gaussian filter's step ends with: ``(new, False)`` when every floating-point
    leaf of the pytree ``new`` is finite, else ``(previous, True)`` — a step whose update is not
    finite (an overflow under a caller's ``jit``, where the host checks cannot see the values) is
    not applied, and is flagged. On finite input the select keeps every value."""
    leaves = [x for x in jax.tree_util.tree_leaves(new) if jnp.issubdtype(x.dtype, jnp.floating)]
    ok = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))
    return jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, previous), ~ok
