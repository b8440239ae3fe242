"""Grid (histogram) localization with a known landmark map, [A] Alg. 2 / Thrun et al. Tab. 8.1.

**Overview**

The belief is a histogram over a fixed grid of ``nx × ny × nθ`` pose cells
(Thrun et al. §8.2): the rectangle ``bounds = (x_min, x_max, y_min, y_max)``
cut into ``nx × ny`` equal cells and the heading circle ``[-π, π)`` into
``nθ`` equal bins. Cell ``(i, j, k)`` stands for its centre
``(x_min + (i + ½)Δx, y_min + (j + ½)Δy, −π + (k + ½)Δθ)``. The state is the
normalised *log*-belief ``log p_t(x_k)``, shape ``[nx, ny, nθ]``
(``logsumexp == 0``). Each step ([A] Alg. 2):

1. **prediction** (line 2), ``p̂_t(x_k) = Σ_kk p_{t−1}(x_kk) f_motion(x_kk, x_k, u_t)``,
   computed as a *convolution*, never as a dense ``K × K`` transition matrix
   (see below);
2. **correction** (line 3), ``p_t(x_k) = η p̂_t(x_k) f_landmark(m, x_k, z_t)``,
   with ``log f_landmark`` the range-bearing log-likelihood of
   :func:`jaxnav.models.landmarks.log_likelihood` at the cell centres
   (computed factorised: range and absolute bearing per ``(x, y)``, then the
   heading offsets, ``nθ`` times cheaper; same values), and η applied by
   ``logsumexp`` (:func:`jaxnav.core.weights.normalize`);
3. **estimate**: the belief's mean over the cell centres (heading on the
   circle), the MAP cell, the entropy and ``log η⁻¹ = log p(z_t | z_{1:t−1})``.

**Prediction as a convolution**

Every jaxnav motion model is translation-invariant in ``(x, y)``: the move
from a pose depends on its heading and the control, not on where it is. For
heading bin ``k`` the model's mean move ``d_k`` and its linearised covariance
``Σ_k = get_motion_model(name).process_cov(pose_k, u, params)`` (Thrun et al.
Tab. 7.1 line 5) are evaluated once, at the bin's centre heading; the
prediction is then

* **in (x, y)**, per heading slice: a shift by ``d_k`` plus Gaussian noise
  ``N(0, Σ_k[:2, :2])``. The shift is split into an integer number of cells
  (applied as an exact zero-filled shift) and a fractional rest, which the
  kernel carries: the kernel is the *cloud-in-cell* transport of a cell's
  mass, ``K(m) = E[tri(D/Δ − m)]`` with ``D ~ N(d, σ²)`` and ``tri`` the unit
  tent, i.e. a point at the cell centre moved by the noisy displacement and
  shared linearly between the two cells it falls between. In 1-D this has a
  closed form (a second difference of ``E[(D − a)₊]``), is non-negative,
  sums to one, has mean exactly ``d`` for any fractional shift, and tends
  to linear interpolation as ``σ → 0`` (so a move of a tenth of a cell is
  not lost to rounding, the classic histogram-filter failure). A correlated
  2-D covariance is handled row-conditionally: along the axis of larger
  variance the 1-D kernel above; along the other axis, per row, the 1-D
  kernel of the conditional Gaussian, its mean regressed on the row offset
  with slope ``β = Σ_xy / V`` (``V`` the variance of the first kernel). This
  reproduces the mean and the full 2 × 2 covariance of ``N(d, Σ)`` (plus the
  cell-assignment spread of the tent) — exact for diagonal ``Σ``, moment
  matched otherwise. The kernel lives on a ``(2R + 1)²`` stencil around the
  integer shift (``R = config.kernel_radius``); the noise mass beyond it is
  dropped, the kernel renormalised, and the dropped fraction reported in
  ``info.kernel_truncation`` (raise ``kernel_radius`` if it is not ≈ 0). The
  integer shift is a ``dynamic_slice`` of the zero-padded slice and the
  stencil a sum of ``(2R + 1)²`` shifted copies (faster on CPU than a grouped
  ``lax.conv``). Cost ``O(nx·ny·nθ·((2R + 1)² + nθ))`` per step.
* **in θ**: a circular convolution along the heading axis with the 1-D
  cloud-in-cell kernel of ``N(δθ_k, Σ_k[2, 2])``, folded onto the circle. (The
  kernel may depend on the source bin; for every jaxnav model it does not, and
  the operator is then a circulant, i.e. a plain circular convolution.)

Approximations, stated once: the move of every pose in a heading bin is that
of the bin's centre heading; the cross-covariance between the position and
the heading noise (``Σ_k[:2, 2]``) is dropped, the marginals are kept; the
Gaussian is the linearisation of the model's noise (what ``process_cov``
returns). Sharing a fractional move between two cells keeps the mean move
exact but spreads the belief by ``f(1 − f)Δ²`` per step and axis even without
noise (``f`` the fractional part of the move in cells): the numerical diffusion
every histogram filter pays for resolving sub-cell motion (rounding instead
would lose the motion altogether).

Boundary: the grid is not periodic in ``x, y``. Mass moved beyond the
rectangle *leaves the grid* and is lost (no wrap-around, no piling up at the
edge); the lost fraction of each step is ``info.mass_lost`` and the belief is
renormalised over the grid, i.e. conditioned on the robot being inside it.
If *all* mass leaves, the belief resets to uniform (``mass_lost == 1``).

Numerics: the convolution runs in probability space after a per-step
max-shift (``p = exp(log b − max log b)``, so the largest cell is 1 and
nothing of consequence underflows), and the result goes back to logs; cells
whose predicted probability underflows (below ~1e−38 of the maximum in
float32) become ``−inf``, exactly representable in the log-belief.

Correction: a masked slot, or a slot whose id is not in the map, is ignored
(counted in ``info.num_ignored``, via :func:`jaxnav.models.landmarks.lookup`).
With ``association="unknown"`` the landmarks are *identical*: an observation
may come from any map landmark, equally likely a priori, and
``f_landmark = Π_slots (1/M) Σ_j N(z; h(x, m_j), Q)`` (ids are not read).
This is the case a histogram represents and a Gaussian cannot: a map symmetric
under a rotation gives a multimodal posterior. (Cost ``O(K·M)`` pair
evaluations per cell, one slot at a time.) If the corrected belief is
degenerate (every cell has likelihood zero, e.g. an unmasked NaN measurement)
the step keeps the *predicted* belief and sets ``info.degenerate``; it never
produces NaN.

Interface (that of the other jaxnav filters, minus the key: nothing here is random)::

    state = grid.init(config, params, initial_pose, initial_sd)   # or no pose: uniform
    state, info = grid.step(state, config, params, control, observation)
    final_state, trace = grid.run(config, params, controls, observations, state)

Units: metres and radians throughout; ``info.entropy`` in nats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erfc, logsumexp

from jaxnav.core import filter as filter_api
from jaxnav.core import memory, weights
from jaxnav.core.validation import (
    check_choice,
    check_finite,
    check_nonnegative,
    check_positive_int,
    check_shape,
    float_array,
    is_concrete,
)
from jaxnav.models import landmarks as lm
from jaxnav.models.motion import check_motion_model, get_motion_model, validate_controls

__all__ = [
    "GridConfig",
    "GridParams",
    "GridState",
    "GridInfo",
    "MotionKernels",
    "ASSOCIATIONS",
    "cell_centres",
    "init",
    "motion_kernels",
    "predict",
    "kernel",
    "step",
    "run",
    "cic_1d",
    "cell_log_likelihood",
]

ASSOCIATIONS = ("known", "unknown")
_ANGLE_DIMS = (2,)
_TINY_VAR = 1e-20  # cells²; keeps the kernel's σ > 0 (and its gradient finite) for a noise-free move


@dataclass(frozen=True)
class GridConfig:
    """Static configuration (hashable; a static argument of ``jit``). It fixes the grid's shape.

    Attributes:
        bounds: ``(x_min, x_max, y_min, y_max)`` of the gridded rectangle (m).
        nx, ny: number of cells along x and y (cell size ``Δx = (x_max − x_min)/nx``).
        ntheta: number of heading bins over ``[-π, π)`` (``Δθ = 2π/nθ``).
        motion_model: name in :data:`jaxnav.models.motion.MODELS`.
        kernel_radius: R, half-width in cells of the (x, y) noise stencil around
            the integer part of the move; it must hold the fractional shift and
            tent (1.5 cells) plus ~4 σ of the per-step position noise.
        association: ``"known"`` (observation ids index the map, [A] Alg. 2) or
            ``"unknown"`` (identical landmarks; a mixture over the map).
    """

    bounds: tuple[float, float, float, float] = (0.0, 10.0, 0.0, 10.0)
    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("nx", "ny", "ntheta")
    nx: int = 40
    ny: int = 40
    ntheta: int = 36
    motion_model: str = "velocity"
    kernel_radius: int = 3
    association: str = "known"

    def __post_init__(self) -> None:
        try:
            b = tuple(float(v) for v in self.bounds)
        except (TypeError, ValueError):
            raise ValueError(f"bounds must be four numbers (x_min, x_max, y_min, y_max), got {self.bounds!r}") from None
        if len(b) != 4 or not all(math.isfinite(v) for v in b) or not (b[0] < b[1] and b[2] < b[3]):
            raise ValueError(
                f"bounds must be four finite numbers with x_min < x_max and y_min < y_max, got {self.bounds!r}"
            )
        object.__setattr__(self, "bounds", b)
        check_positive_int("nx", self.nx)
        check_positive_int("ny", self.ny)
        check_positive_int("ntheta", self.ntheta)
        check_positive_int("kernel_radius", self.kernel_radius)
        _check_grid_size(self.nx, self.ny, self.ntheta)
        check_motion_model("motion_model", self.motion_model)
        check_choice("association", self.association, ASSOCIATIONS)

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(nx, ny, nθ)``."""
        return (self.nx, self.ny, self.ntheta)

    @property
    def cell_size(self) -> tuple[float, float, float]:
        """``(Δx [m], Δy [m], Δθ [rad])``."""
        x0, x1, y0, y1 = self.bounds
        return ((x1 - x0) / self.nx, (y1 - y0) / self.ny, 2.0 * math.pi / self.ntheta)


BYTES_PER_CELL = 16
"""Memory a cell needs during a step (float32), for the belief and the prediction's working copies."""


def _check_grid_size(nx: int, ny: int, ntheta: int) -> None:
    """Refuse, before anything is allocated, a grid that cannot be indexed (more than 2³¹ − 1
    cells) or whose step needs more memory than the device can hold
    (:func:`jaxnav.core.memory.check_fits`, which :func:`jaxnav.core.memory.allow_large_allocations`
    turns off)."""
    cells = nx * ny * ntheta
    if cells > np.iinfo(np.int32).max:
        raise ValueError(
            f"a {nx} × {ny} × {ntheta} grid has {cells:.3g} cells, more than the 2³¹ − 1 a grid can index: "
            "use fewer or larger cells"
        )
    memory.check_fits(
        cells * BYTES_PER_CELL,
        what=f"a step on a {nx} × {ny} × {ntheta} grid ({cells:.3g} cells)",
        fields=f"nx ({nx}), ny ({ny}) or ntheta ({ntheta}): use fewer or larger cells",
    )


GridParams = lm.LandmarkMapParams
"""The grid filter's differentiable parameters, :class:`jaxnav.models.landmarks.LandmarkMapParams`
(motion noise, range-bearing noise, landmarks ``[M, 2]`` in m), shared with MCL, EKF and UKF."""


class GridState(NamedTuple):
    """Filter state carried between steps.

    Attributes:
        log_belief: ``[nx, ny, nθ]`` normalised log-probabilities of the cells.
    """

    log_belief: jax.Array


class GridInfo(NamedTuple):
    """Per-step diagnostics (stacked over time by :func:`run`).

    Attributes:
        estimate: ``[3]`` mean of the corrected belief over the cell centres
            (m, m, rad; heading averaged on the circle).
        map_estimate: ``[3]`` centre of the most probable cell.
        entropy: entropy of the cell distribution, ``−Σ p log p`` (nats; at most
            ``log(nx·ny·nθ)``).
        log_likelihood: ``log p(z_t | z_{1:t−1})`` on the grid, the log of the
            normaliser η⁻¹ (−inf if degenerate; 0 with no valid observation).
        degenerate: bool, every cell had zero likelihood (the predicted belief was kept), or the
            prediction was not finite, an overflowing control inside a caller's ``jit`` (the
            previous belief was kept, with ``mass_lost`` and ``kernel_truncation`` 0).
        num_ignored: int32, observation slots dropped because their id is not in the map.
        mass_lost: fraction of the belief that the prediction moved off the grid.
        kernel_truncation: largest fraction of an (x, y) motion kernel that fell
            outside the ``(2R + 1)²`` stencil (renormalised away).
        invalid_inputs: bool, the step's control or parameters were outside the models' domain (a
            negative Δt or noise level, a value that is not finite or exceeds
            :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
            caller's ``jit``: the state was carried over unchanged.
    """

    estimate: jax.Array
    map_estimate: jax.Array
    entropy: jax.Array
    log_likelihood: jax.Array
    degenerate: jax.Array
    num_ignored: jax.Array
    mass_lost: jax.Array
    kernel_truncation: jax.Array
    invalid_inputs: jax.Array = False


class MotionKernels(NamedTuple):
    """The prediction operator of one control (see the module docstring).

    A cell ``(i, j, k)`` sends the fraction ``xy[k, R + a, R + b] · heading[k, l]``
    of its mass to cell ``(i + shift[k, 0] + a, j + shift[k, 1] + b, l)``, for
    ``a, b ∈ [−R, R]``; destinations off the grid are lost.

    Attributes:
        shift: ``[nθ, 2]`` int32 integer part of the move of heading bin ``k`` (cells).
        xy: ``[nθ, 2R + 1, 2R + 1]`` (x, y) kernels (each sums to 1).
        heading: ``[nθ, nθ]`` heading transition ``source → destination`` (rows sum to 1).
        truncation: ``[nθ]`` kernel mass that fell outside the stencil before renormalisation.
    """

    shift: jax.Array
    xy: jax.Array
    heading: jax.Array
    truncation: jax.Array


# ---------------------------------------------------------------------------
# grid geometry


def _axes(config: GridConfig, dtype: Any) -> tuple[jax.Array, jax.Array, jax.Array]:
    x0, _, y0, _ = config.bounds
    dx, dy, dth = config.cell_size
    xs = x0 + (jnp.arange(config.nx, dtype=dtype) + 0.5) * dx
    ys = y0 + (jnp.arange(config.ny, dtype=dtype) + 0.5) * dy
    ths = -jnp.pi + (jnp.arange(config.ntheta, dtype=dtype) + 0.5) * dth
    return xs, ys, ths


def cell_centres(config: GridConfig, dtype: Any = jnp.float32) -> jax.Array:
    """Poses of the cell centres, ``[nx, ny, nθ, 3]`` (m, m, rad)."""
    xs, ys, ths = _axes(config, dtype)
    gx, gy, gt = jnp.meshgrid(xs, ys, ths, indexing="ij")
    return jnp.stack([gx, gy, gt], axis=-1)


# ---------------------------------------------------------------------------
# cloud-in-cell kernels


def _unit_loss(z: jax.Array) -> jax.Array:
    """``ψ(z) = φ(z) − z·Q(z) = E[(N(0,1) − z)₊]`` for ``z ≥ 0`` (the standard normal loss function)."""
    phi = jnp.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
    q = 0.5 * erfc(z / math.sqrt(2.0))
    return jnp.maximum(phi - z * q, 0.0)


def cic_1d(offsets: jax.Array, mean: jax.Array, var: jax.Array) -> jax.Array:
    """``E[tri(D − m)]`` for ``D ~ N(mean, var)`` at integer ``offsets`` m (all in cell units).

    The cloud-in-cell mass that a unit mass at offset 0, moved by ``D``, puts at
    offset ``m``. With ``G(a) = E[(D − a)₊] = (μ − a)₊ + σ ψ(|μ − a|/σ)`` and
    ``tri(t) = (t + 1)₊ − 2t₊ + (t − 1)₊``, ``K(m) = G(m − 1) − 2G(m) + G(m + 1)``;
    the ramp part's second difference is the tent ``tri(m − μ)``, computed
    directly so that nothing large cancels. Broadcasts over its arguments.
    """
    sd = jnp.sqrt(var + _TINY_VAR)
    t = offsets - mean
    tent = jnp.maximum(1.0 - jnp.abs(t), 0.0)
    # one ψ evaluation (one erfc in the graph) for the three points
    psi = _unit_loss(jnp.abs(jnp.stack([t - 1.0, t, t + 1.0])) / sd)
    return jnp.maximum(tent + sd * (psi[0] - 2.0 * psi[1] + psi[2]), 0.0)


def _row_conditional(offsets, r_out, v_out, r_in, v_in, cov):
    """2-D kernel ``[out, in]``: 1-D CIC along ``out``, conditional 1-D CIC along ``in`` per row.

    ``β = cov / V_out`` with ``V_out`` the variance of the ``out`` kernel, and
    the conditional variance ``v_in − β·cov``: the kernel's covariance is then
    ``[[V_out, cov], [cov, v_in + spread_in]]``, the Gaussian's plus the tent spread.
    """
    k_out = cic_1d(offsets, r_out, v_out)
    mass = jnp.sum(k_out)
    v_spread = jnp.sum(k_out * (offsets - r_out) ** 2) / jnp.maximum(mass, 1e-30)
    beta = cov / jnp.maximum(v_spread, _TINY_VAR)
    v_cond = jnp.maximum(v_in - beta * cov, 0.0)
    mu_rows = r_in + beta * (offsets - r_out)
    k_in = cic_1d(offsets[None, :], mu_rows[:, None], v_cond)
    return k_out[:, None] * k_in


def _xy_kernel(config: GridConfig, d: jax.Array, cov: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Integer shift ``[2]``, normalised kernel ``[2R+1, 2R+1]`` and truncated mass of one heading bin."""
    dx, dy, _ = config.cell_size
    r = config.kernel_radius
    scale = jnp.asarray([dx, dy], d.dtype)
    dc = d / scale
    shift = jnp.round(dc)
    res = dc - shift
    # Beyond nx + R (ny + R) cells every destination is off the grid; clip before the int cast.
    limit = jnp.asarray([config.nx, config.ny], d.dtype) + r + 1
    shift = jnp.clip(shift, -limit, limit)
    vx = cov[0, 0] / (dx * dx)
    vy = cov[1, 1] / (dy * dy)
    cxy = cov[0, 1] / (dx * dy)
    offsets = jnp.arange(-r, r + 1, dtype=d.dtype)
    # Condition on the axis of larger variance, so |β| ≤ 1 and the rows stay on the stencil.
    y_outer = vy >= vx
    r_out, r_in = jnp.where(y_outer, res[1], res[0]), jnp.where(y_outer, res[0], res[1])
    v_out, v_in = jnp.where(y_outer, vy, vx), jnp.where(y_outer, vx, vy)
    kern = _row_conditional(offsets, r_out, v_out, r_in, v_in, cxy)  # [out, in]
    kern = jnp.where(y_outer, kern.T, kern)  # [x, y]
    total = jnp.sum(kern)
    safe_total = jnp.maximum(total, 1e-30)
    return shift.astype(jnp.int32), kern / safe_total, jnp.clip(1.0 - total, 0.0, 1.0)


def _heading_kernel(config: GridConfig, dth: jax.Array, var: jax.Array) -> jax.Array:
    """Row ``[nθ]``: mass a bin sends ``o`` bins ahead (circularly) for a move ``dth`` (rad), noise ``var`` (rad²)."""
    n = config.ntheta
    step = config.cell_size[2]
    mu = weights.wrap_angle(dth) / step  # in [-n/2, n/2)
    v = var / (step * step)
    windings = jnp.arange(-2, 3, dtype=dth.dtype)[:, None] * n  # ±2 turns: σ up to ~n/2 bins
    folded = jnp.sum(cic_1d(jnp.arange(n, dtype=dth.dtype) + windings, mu, v), axis=0)
    return folded / jnp.maximum(jnp.sum(folded), 1e-30)


def _motion_kernels(config: GridConfig, params: GridParams, control: jax.Array, dtype: Any) -> MotionKernels:
    model = get_motion_model(config.motion_model)
    _, _, ths = _axes(config, dtype)
    poses = jnp.stack([jnp.zeros_like(ths), jnp.zeros_like(ths), ths], axis=-1)  # translation-invariant: origin
    moved = model.mean(poses, control, params.motion)
    covs = jax.vmap(lambda p: model.process_cov(p, control, params.motion))(poses)
    d = moved[:, :2] - poses[:, :2]
    dth = weights.wrap_angle(moved[:, 2] - poses[:, 2])
    shift, xy, trunc = jax.vmap(lambda dd, cc: _xy_kernel(config, dd, cc))(d, covs)
    rows = jax.vmap(lambda a, v: _heading_kernel(config, a, v))(dth, covs[:, 2, 2])  # [k, offset]
    n = config.ntheta
    offset = (jnp.arange(n)[None, :] - jnp.arange(n)[:, None]) % n  # [source, destination]
    heading = jnp.take_along_axis(rows, offset, axis=1)
    return MotionKernels(shift, xy, heading, trunc)


# ---------------------------------------------------------------------------
# prediction


def _shifted_conv(config: GridConfig, planes: jax.Array, shifts: jax.Array, kernels: jax.Array) -> jax.Array:
    """Per heading slice ``k``: ``out[k, i, j] = Σ_ab planes[k, i − s_x − a, j − s_y − b] · kernels[k, R + a, R + b]``.

    Zero outside the grid. The integer shift is a ``dynamic_slice`` of the
    zero-padded slice; the stencil is a sum of ``(2R + 1)²`` shifted copies,
    which XLA fuses into one loop (on CPU much faster than a grouped ``lax.conv``).
    """
    nx, ny, r = config.nx, config.ny, config.kernel_radius
    px, py = nx + 2 * r, ny + 2 * r

    def window(plane, shift):
        padded = jnp.pad(plane, ((px, px), (py, py)))
        # A shift of nx + R cells or more moves everything off the grid; clamping keeps dynamic_slice exact.
        sx = jnp.clip(shift[0], -(nx + r), nx + r)
        sy = jnp.clip(shift[1], -(ny + r), ny + r)
        return jax.lax.dynamic_slice(padded, (px - sx - r, py - sy - r), (nx + 2 * r, ny + 2 * r))

    win = jax.vmap(window)(planes, shifts)  # win[k, i + R + a] = planes[k, i − s_x + a]
    flipped = kernels[:, ::-1, ::-1]
    out = jnp.zeros(planes.shape, planes.dtype)
    for a in range(2 * r + 1):  # static stencil loop, not a loop over cells or time
        for b in range(2 * r + 1):
            out = out + win[:, a : a + nx, b : b + ny] * flipped[:, a, b, None, None]
    return out


def _predict(config: GridConfig, params: GridParams, log_belief: jax.Array, control: jax.Array):
    """Unnormalised predicted log-belief, fraction of mass lost off the grid, max kernel truncation."""
    kernels = _motion_kernels(config, params, control, log_belief.dtype)
    top = jax.lax.stop_gradient(jnp.max(log_belief))
    top = jnp.where(jnp.isfinite(top), top, 0.0)
    p = jnp.exp(log_belief - top)  # max-shift: the largest cell is 1
    slices = jnp.moveaxis(p, 2, 0)  # [nθ, nx, ny]
    moved = _shifted_conv(config, slices, kernels.shift, kernels.xy)
    pred = jnp.einsum("kxy,kl->xyl", moved, kernels.heading, precision=jax.lax.Precision.HIGHEST)
    before = jnp.sum(p)
    mass_lost = jnp.clip(1.0 - jnp.sum(pred) / jnp.maximum(before, 1e-30), 0.0, 1.0)
    pred = jnp.maximum(pred, 0.0)
    log_pred = jnp.where(pred > 0, jnp.log(jnp.where(pred > 0, pred, 1.0)), -jnp.inf) + top
    return log_pred, mass_lost, jnp.max(kernels.truncation)


# ---------------------------------------------------------------------------
# correction


def _pair_log_density(config: GridConfig, params: GridParams, positions: jax.Array, z: jax.Array) -> jax.Array:
    """``log N(z_p; h(x, m_p), Q)`` at every cell for pairs ``p``: ``[nx, ny, nθ, P]``.

    ``positions [P, 2]`` and ``z [P, 2]`` pair landmarks with measurements.
    Factorised over the grid: range ``r`` and absolute bearing ``α`` depend on
    ``(x, y)`` only, so :func:`jaxnav.models.landmarks.predict` runs on the
    ``nx·ny`` positions (heading 0) and the bearing residual of heading ``θ`` is
    ``wrap(φ_z − α + θ)`` — ``nθ`` times fewer ``atan2``/``sqrt`` than
    evaluating :func:`~jaxnav.models.landmarks.log_likelihood` at every cell,
    with the same value (``tests/localization/test_grid.py`` checks it). The scoring is
    that of ``log_likelihood``: Gaussian in range and wrapped bearing,
    normalised densities.
    """
    dtype = positions.dtype
    xs, ys, ths = _axes(config, dtype)
    gx, gy = jnp.meshgrid(xs, ys, indexing="ij")
    origin = jnp.stack([gx, gy, jnp.zeros_like(gx)], axis=-1)  # [nx, ny, 3], heading 0
    expected = lm.predict(origin[:, :, None, :], positions)  # [nx, ny, P, 2]: (r, α)
    sd = params.sensor.sd
    log_norm = -jnp.log(sd[0]) - jnp.log(sd[1]) - math.log(2.0 * math.pi)
    range_term = log_norm - 0.5 * ((z[:, 0] - expected[..., 0]) / sd[0]) ** 2  # [nx, ny, P]
    bearing = weights.wrap_angle(z[:, 1] - expected[..., 1])  # φ_z − α, [nx, ny, P]
    resid_b = weights.wrap_angle(bearing[:, :, None, :] + ths[:, None])  # [nx, ny, nθ, P]
    return range_term[:, :, None, :] - 0.5 * (resid_b / sd[1]) ** 2


def cell_log_likelihood(config: GridConfig, params: GridParams, obs: lm.RangeBearingObs) -> tuple[jax.Array, jax.Array]:
    """``log f_landmark(m, x_k, z_t)`` at every cell ``[nx, ny, nθ]`` and the number of ignored slots."""
    if config.association == "known":
        positions, valid, num_ignored = lm.lookup(params.landmarks, obs)
        z = jnp.where(valid[:, None], obs.z, 0.0)  # invalid slots are never read (NaN-safe)
        per = _pair_log_density(config, params, positions, z)
        return jnp.sum(jnp.where(valid, per, 0.0), axis=-1), num_ignored

    # Identical landmarks: each valid slot is a mixture over the M map landmarks, prior 1/M each.
    m = params.landmarks.shape[0]

    def one_slot(carry, slot):
        z, valid = slot
        z = jnp.where(valid, z, 0.0)
        per = _pair_log_density(config, params, params.landmarks, jnp.broadcast_to(z, (m, 2)))
        return carry + jnp.where(valid, logsumexp(per, axis=-1) - math.log(m), 0.0), None

    zero = jnp.zeros(config.shape, params.landmarks.dtype)
    total, _ = jax.lax.scan(one_slot, zero, (obs.z, obs.mask))  # one slot at a time: memory O(M·cells)
    return total, jnp.zeros((), jnp.int32)


# ---------------------------------------------------------------------------
# host-side validation


def _validate_params(config: GridConfig, params: GridParams) -> None:
    if not isinstance(config, GridConfig):
        raise ValueError(f"config must be a GridConfig, got {type(config).__name__}")
    if not isinstance(params, GridParams):
        raise ValueError(f"params must be a GridParams, got {type(params).__name__}")
    lm.validate_map_params(config.motion_model, params)


def _validate_state(config: GridConfig, params: Any, state: GridState) -> None:
    if not isinstance(state, GridState):
        raise ValueError(f"state must be a GridState, got {type(state).__name__}")
    check_shape("state.log_belief", state.log_belief, config.shape)
    if is_concrete(state.log_belief) and np.any(np.isnan(np.asarray(state.log_belief))):
        raise ValueError("state.log_belief contains NaN values")


def _float_dtype(landmarks: Any) -> Any:
    """The grid's precision: that of the landmarks (the default float for integer landmarks)."""
    dt = jnp.result_type(landmarks)
    return dt if jnp.issubdtype(dt, jnp.floating) and np.dtype(dt).itemsize >= 4 else jnp.result_type(float)


# ---------------------------------------------------------------------------
# init


@memory.guard_init
def init(
    key: jax.Array | None,
    config: GridConfig,
    params: GridParams,
    initial_pose: jax.Array | None = None,
    initial_sd: jax.Array | None = None,
) -> GridState:
    """The prior belief: uniform over the grid, or a Gaussian assigned to the cells.

    Args:
        config, params: as everywhere.
        initial_pose: ``[3]`` (m, m, rad) inside ``config.bounds``; ``None``
            (the default) gives the uniform belief (global localization).
        initial_sd: ``[3]`` standard deviations (m, m, rad), default zeros.
            Cell ``(i, j, k)`` gets ``Π_axis E[tri((X − c)/Δ)]`` with
            ``X ~ N(pose, sd²)``: the Gaussian's mass shared among cells the same
            (cloud-in-cell) way the prediction moves mass, so ``sd = 0`` puts a
            known pose on the (at most 2 × 2 × 2) cells around it.
    """
    filter_api.check_key(key, allow_none=True)
    _validate_params(config, params)
    dtype = _float_dtype(params.landmarks)
    n = config.nx * config.ny * config.ntheta
    if initial_pose is None:
        if initial_sd is not None:
            raise ValueError("initial_sd needs an initial_pose")
        return GridState(jnp.full(config.shape, -math.log(n), dtype))
    pose = float_array("initial_pose", initial_pose, dtype)
    check_shape("initial_pose", pose, (3,))
    check_finite("initial_pose", pose)
    sd = jnp.zeros((3,), pose.dtype) if initial_sd is None else jnp.asarray(initial_sd, pose.dtype)
    check_shape("initial_sd", sd, (3,))
    check_nonnegative("initial_sd", sd)
    x0, x1, y0, y1 = config.bounds
    if is_concrete(pose):
        px, py = (float(v) for v in np.asarray(pose)[:2])
        if not (x0 <= px <= x1 and y0 <= py <= y1):
            raise ValueError(f"initial_pose must lie inside config.bounds {config.bounds}, got ({px}, {py})")
    return GridState(_gaussian_prior(config, pose, sd))


@partial(jax.jit, static_argnames=("config",))
def _gaussian_prior(config: GridConfig, pose: jax.Array, sd: jax.Array) -> jax.Array:
    dx, dy, dth = config.cell_size
    x0, _, y0, _ = config.bounds
    dt = pose.dtype
    ux = (pose[0] - x0) / dx - 0.5  # continuous cell coordinate: centre i ↔ i
    uy = (pose[1] - y0) / dy - 0.5
    ut = (weights.wrap_angle(pose[2]) + jnp.pi) / dth - 0.5
    px = cic_1d(jnp.arange(config.nx, dtype=dt), ux, (sd[0] / dx) ** 2)
    py = cic_1d(jnp.arange(config.ny, dtype=dt), uy, (sd[1] / dy) ** 2)
    n = config.ntheta
    windings = jnp.arange(-2, 3, dtype=dt)[:, None] * n
    pt = jnp.sum(cic_1d(jnp.arange(n, dtype=dt) + windings, ut, (sd[2] / dth) ** 2), axis=0)

    def log0(v):
        return jnp.where(v > 0, jnp.log(jnp.where(v > 0, v, 1.0)), -jnp.inf)

    log_b = log0(px)[:, None, None] + log0(py)[None, :, None] + log0(pt)[None, None, :]
    return weights.normalize(log_b.ravel()).log_weights.reshape(config.shape)


# ---------------------------------------------------------------------------
# step and run


@filter_api.guard_inputs(lm.filter_inputs_in_domain)
def kernel(
    key: jax.Array | None,
    state: GridState,
    config: GridConfig,
    params: GridParams,
    control: jax.Array,
    obs: lm.RangeBearingObs,
) -> tuple[GridState, GridInfo]:
    """One grid-localization step, pure and traceable (:func:`step` is it validated and jitted); the key is not used."""
    dtype = state.log_belief.dtype
    log_pred, mass_lost, trunc = _predict(config, params, state.log_belief, control)
    # a prediction that is not finite (an overflowing control inside a caller's jit) is not applied
    moved = jnp.isfinite(mass_lost) & jnp.isfinite(trunc)
    log_pred = jnp.where(moved, log_pred, state.log_belief)
    mass_lost, trunc = jnp.where(moved, mass_lost, 0.0), jnp.where(moved, trunc, 0.0)
    pred = weights.normalize(log_pred.ravel())  # uniform if every cell left the grid (mass_lost == 1)

    loglik, num_ignored = cell_log_likelihood(config, params, obs)
    post = weights.normalize(pred.log_weights + loglik.ravel())
    log_post = jnp.where(post.degenerate, pred.log_weights, post.log_weights)
    probs = jnp.exp(log_post).reshape(config.shape)

    xs, ys, ths = _axes(config, dtype)
    heading = weights.mean_from_probabilities(ths[:, None], jnp.sum(probs, axis=(0, 1)), (0,))[0]
    estimate = jnp.stack([jnp.sum(probs, axis=(1, 2)) @ xs, jnp.sum(probs, axis=(0, 2)) @ ys, heading])
    i, j, k = jnp.unravel_index(jnp.argmax(log_post), config.shape)
    map_estimate = jnp.stack([xs[i], ys[j], ths[k]])
    entropy = -jnp.sum(jnp.where(log_post > -jnp.inf, jnp.exp(log_post) * log_post, 0.0))
    degenerate = post.degenerate | ~moved
    info = GridInfo(estimate, map_estimate, entropy, post.log_norm, degenerate, num_ignored, mass_lost, trunc)
    return GridState(log_post.reshape(config.shape)), info


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="grid localization",
        kernel=kernel,
        config_type=GridConfig,
        state_type=GridState,
        check_params=_validate_params,
        check_state=_validate_state,
        check_inputs=lm.check_filter_inputs,
        valid_inputs=lm.filter_inputs_in_domain,
        time_inputs=("controls", "observations"),
        deterministic=True,
        step_doc="""One grid-localization update ([A] Alg. 2): convolution prediction with ``control [control_dim]``, then
        the correction by one step's observations. Deterministic: ``key`` is not used (``None`` is accepted).""",
        run_doc="""Grid localization over a sequence: ``controls [T, control_dim]``, observations with leading axis ``T``,
        ``state`` from :func:`init`; ``trace`` a :class:`GridInfo` (``trace.estimate`` is ``[T, 3]``).
        Deterministic: ``key`` is not used (``None`` is accepted).""",
    ),
    __name__,
)


# ---------------------------------------------------------------------------
# the prediction on its own (inspection, tests)


@partial(jax.jit, static_argnames=("config",))
def _motion_kernels_jit(config, params, control):
    return _motion_kernels(config, params, control, _float_dtype(params.landmarks))


def motion_kernels(config: GridConfig, params: GridParams, control: jax.Array) -> MotionKernels:
    """The convolution operator :func:`predict` applies for ``control`` (see :class:`MotionKernels`)."""
    _validate_params(config, params)
    control = validate_controls("control", control, config.motion_model, time_axis=False)
    return _motion_kernels_jit(config, params, control)


@partial(jax.jit, static_argnames=("config",))
def _predict_jit(config, params, log_belief, control):
    return _predict(config, params, log_belief, control)[0]


def predict(state: GridState, config: GridConfig, params: GridParams, control: jax.Array) -> jax.Array:
    """The prediction step alone: the *unnormalised* predicted log-belief ``[nx, ny, nθ]``.

    Its ``logsumexp`` is the log of the mass still on the grid (≤ 0 for a
    normalised ``state``); :func:`step` renormalises it.
    """
    _validate_params(config, params)
    _validate_state(config, params, state)
    control = validate_controls("control", control, config.motion_model, time_axis=False)
    return _predict_jit(config, params, state.log_belief, control)
