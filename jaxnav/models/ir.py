"""IR emitter positioning ([W] ch. 5): detections, receivers, the voltage model and the belief.

**Overview**

IR LEDs on the ceiling are landmarks with known positions ([W] §5.1), each
blinking an ID made of the nine frequency codes of [W] Table 5.1. This module
holds what the receivers observe and how it is weighed; the rest of the IR
system lives in two modules whose names are re-exported here:

* :mod:`jaxnav.models.ir_codebook`: the codes, the canonical numbering of IDs
  and their bitmasks, the capacity and memory figures of [W] §5.3;
* :mod:`jaxnav.models.ir_layouts`: the emitter layouts (:class:`~jaxnav.models.ir_layouts.EmitterLayout`,
  the lattice of [W] Fig. 5.1) and the rules that keep them decodable.

**Observation model**

[W] eq. 5.3, the mean receiver voltage at horizontal receiver–emitter
distance ``e_d`` (mm) for a 1.2 m emitter–receiver height,

    V̄(e_d) = −3.27·10⁻⁵ e_d² + 2.855·10⁻³ e_d + 1.81997   [V],

is :data:`W_VOLTAGE_MODEL` (:class:`VoltageModel`, coefficients in [W]'s mm
units; :func:`expected_voltage` takes ``e_d`` in metres). It crosses zero at
e_d ≈ 283.6 mm, the detection range ("within 280 mm", [W] §5.4).
:func:`fit_voltage_model` refits it by least squares with optax from a
calibration sweep, as [W] did from 0–300 mm at 10 mm steps (Fig. 5.7).

The likelihood of [W] eq. 5.2 in log form is
``log w = log α − (V − V̄(e_d))² / (2σ²)`` (:func:`log_likelihood`). The
belief of [W] eq. 5.1, ``bel_n = exp(−|x_n − x_r|² / (2σ²))`` with σ = 30 mm,
is maximal at the emitter nearest the position estimate, so
:func:`select_emitter` returns the nearest emitter carrying the detected ID
(for a unique ID: the only one), with a validity flag.

Units: metres, radians, volts, hertz, except the coefficients of
:class:`VoltageModel` and the arguments of :func:`fit_voltage_model`, which are
in [W]'s millimetres.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxnav.core.optim import lbfgs_minimize
from jaxnav.core.validation import check_finite, check_positive_int, check_shape, first_index, is_concrete
from jaxnav.models.ir_codebook import (
    CODES,
    FREQUENCIES_HZ,
    ID_TO_MASK,
    MASK_TO_ID,
    NUM_CODES,
    NUM_IDS,
    bits_to_mask,
    capacity,
    decode,
    encode,
    from_mask,
    harmonic_collisions,
    id_name,
    id_to_mask,
    mask_bits,
    mask_to_id,
    memory_size,
    parse_name,
    popcount,
    to_mask,
)
from jaxnav.models.ir_layouts import (
    CONFLICT_RADIUS,
    EmitterLayout,
    assign_unique_sets,
    code_conflicts,
    lattice_layout,
    layout_names,
    make_layout,
    min_separation,
    validate_layout,
    without_emitters,
)

__all__ = [
    "IRDetection",
    "FREQUENCIES_HZ",
    "CODES",
    "NUM_CODES",
    "NUM_IDS",
    "ID_TO_MASK",
    "MASK_TO_ID",
    "encode",
    "decode",
    "to_mask",
    "from_mask",
    "id_name",
    "parse_name",
    "mask_to_id",
    "id_to_mask",
    "mask_bits",
    "popcount",
    "bits_to_mask",
    "capacity",
    "memory_size",
    "harmonic_collisions",
    "EmitterLayout",
    "make_layout",
    "validate_layout",
    "layout_names",
    "lattice_layout",
    "assign_unique_sets",
    "without_emitters",
    "min_separation",
    "code_conflicts",
    "CONFLICT_RADIUS",
    "DEFAULT_RECEIVER_OFFSETS",
    "receiver_positions",
    "VoltageModel",
    "W_VOLTAGE_MODEL",
    "expected_voltage",
    "fit_voltage_model",
    "log_likelihood",
    "BELIEF_SIGMA",
    "log_belief",
    "select_emitter",
    "MAX_VOLTAGE",
    "check_levels",
]

# --------------------------------------------------------------------------------------
# Observations
# --------------------------------------------------------------------------------------


class IRDetection(NamedTuple):
    """One window's decoding, per receiver ``R``.

    Attributes:
        mask: ``[R]`` int32 ID bitmask of the detected emitter (0 when invalid).
        valid: ``[R]`` bool, True for a clean detection (the rules of :mod:`jaxnav.sim.ir_receiver`).
        voltage: ``[R]`` float32 level V ≥ 0 (V) of the detected emitter (0 when invalid):
            the receiver detects an emitter only when its level is positive
            (:mod:`jaxnav.sim.ir_receiver`), so a negative level is refused (:func:`check_levels`).
        amplitude: ``[R, 9]`` float32 on-amplitude estimate â per code (V).
    """

    mask: jax.Array
    valid: jax.Array
    voltage: jax.Array
    amplitude: jax.Array


# --------------------------------------------------------------------------------------
# Receivers
# --------------------------------------------------------------------------------------

DEFAULT_RECEIVER_OFFSETS = np.array([[0.0, 0.10], [0.0, -0.10]], dtype=np.float32)
"""``[2, 2]`` receiver positions in the robot frame (m; x forward, y left), one on each
side of the robot top ([W] §5.1, Fig. 5.4). [W] gives no distances; ±0.10 m is our choice."""


def receiver_positions(pose: jax.Array, offsets: jax.Array) -> jax.Array:
    """World positions ``[R, 2]`` (m) of receivers at robot-frame ``offsets [R, 2]`` for ``pose (x, y, θ)``."""
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    rot = jnp.array([[c, -s], [s, c]])
    return pose[:2] + offsets @ rot.T


# --------------------------------------------------------------------------------------
# Voltage model ([W] eq. 5.3) and likelihood ([W] eq. 5.2)
# --------------------------------------------------------------------------------------


class VoltageModel(NamedTuple):
    """Quadratic mean voltage ``V̄(e_d) = c2·e_d² + c1·e_d + c0`` ([W] eq. 5.3).

    Attributes (a differentiable pytree; **e_d in mm** as in [W]):
        c2: V/mm².
        c1: V/mm.
        c0: V.
    """

    c2: jax.Array
    c1: jax.Array
    c0: jax.Array


MAX_VOLTAGE = 100.0
"""The largest level a receiver may report (V). [W]'s receiver runs on an 8 V rail (Fig. 5.5), so a
level beyond ±100 V is a unit or data error, not a reading."""

W_VOLTAGE_MODEL = VoltageModel(c2=-3.27e-5, c1=2.855e-3, c0=1.81997)
"""[W] eq. 5.3, fitted by [W] at 1.2 m emitter–receiver height."""


def check_levels(name: str, voltage: Any) -> None:
    """Host-side check of receiver levels ``voltage`` (V): none negative. The receiver reports a
    detection only when its level ``V = V_sat·tanh(a/V_sat) − V_off`` is positive, and 0 in an
    empty slot (:mod:`jaxnav.sim.ir_receiver`), so a negative level is a sign or unit error.
    Raises ``ValueError`` naming ``name``, the first negative level and its index; skipped for
    tracers (inside a caller's ``jit`` the filter drops such a detection and counts it)."""
    if not is_concrete(voltage):
        return
    v = np.asarray(voltage, np.float64)
    negative = v < 0
    if negative.any():
        where = first_index(negative)
        raise ValueError(
            f"{name} holds {int(negative.sum())} negative level(s), the first ({float(v[where]):g} V) at index "
            f"{where}: a receiver level is ≥ 0 V (a detection needs V > 0; an empty slot holds 0)"
        )


def expected_voltage(model: VoltageModel, e_d_m: jax.Array) -> jax.Array:
    """V̄ (V) at horizontal receiver–emitter distance ``e_d_m`` (**m**), [W] eq. 5.3."""
    e = jnp.asarray(e_d_m) * 1000.0
    return (model.c2 * e + model.c1) * e + model.c0


def log_likelihood(
    v: jax.Array, e_d_m: jax.Array, model: VoltageModel, sigma_v: jax.Array, log_alpha: jax.Array = 0.0
) -> jax.Array:
    """``log w = log α − (V − V̄(e_d))² / (2σ_V²)``, [W] eq. 5.2 in log form.

    Args:
        v: measured receiver voltage (V).
        e_d_m: horizontal distance receiver–emitter (m), any broadcastable shape.
        model: the V̄ curve (:data:`W_VOLTAGE_MODEL` by default in callers).
        sigma_v: σ of eq. 5.2 (V; [W] gives none for eq. 5.2).
        log_alpha: ``log α`` ([W]: "a constant"); it cancels on normalisation.
    """
    r = (v - expected_voltage(model, e_d_m)) / sigma_v
    return log_alpha - 0.5 * r * r


def _fit_impl(e, v, init, steps):
    mu = jnp.mean(e)
    s = jnp.maximum(jnp.std(e), 1e-12)
    u = (e - mu) / s
    # raw (c2, c1, c0) -> normalised (b2, b1, b0):  V = b0 + b1 u + b2 u², e = mu + s u
    c2, c1, c0 = init
    b = jnp.stack([c2 * mu * mu + c1 * mu + c0, (2 * c2 * mu + c1) * s, c2 * s * s])

    def loss(b):
        r = b[0] + b[1] * u + b[2] * u * u - v
        return jnp.mean(r * r)

    # backtracking (Armijo) line search: as reliable here as the default zoom search and
    # three times cheaper to compile
    b = lbfgs_minimize(loss, b, steps, optax.scale_by_backtracking_linesearch(max_backtracking_steps=20))
    rms = jnp.sqrt(loss(b))
    c2 = b[2] / (s * s)
    c1 = b[1] / s - 2.0 * b[2] * mu / (s * s)
    c0 = b[0] - b[1] * mu / s + b[2] * mu * mu / (s * s)
    return VoltageModel(c2, c1, c0), rms


_fit_jit = jax.jit(_fit_impl, static_argnames=("steps",))


def fit_voltage_model(
    e_d_mm: Any, volts: Any, init: VoltageModel | None = None, steps: int = 50
) -> tuple[VoltageModel, jax.Array]:
    """Least-squares refit of [W] eq. 5.3 with optax L-BFGS.

    Minimises ``mean((c2·e² + c1·e + c0 − V)²)`` over a calibration sweep
    (``e_d_mm [n]`` in mm, ``volts [n]`` in V; [W] used 0–300 mm at 10 mm
    steps, Fig. 5.7). ``e_d`` is centred and scaled internally (the
    normal equations in raw mm have condition number ~10¹⁰, hopeless in
    float32), L-BFGS (backtracking line search) runs ``steps`` iterations from
    ``init`` (default zeros) — the problem is a convex quadratic in three
    unknowns, so a few tens of iterations reach float32 precision — and the
    coefficients are mapped back to mm units.

    Returns:
        ``(model, rms)``: the fitted :class:`VoltageModel` (V, V/mm, V/mm²) and
        the RMS residual (V).
    """
    e = np.asarray(e_d_mm)
    v = np.asarray(volts)
    check_shape("e_d_mm", e, (None,))
    check_shape("volts", v, (e.shape[0],))
    if e.shape[0] < 3:
        raise ValueError(f"fit_voltage_model needs at least 3 sweep points, got {e.shape[0]}")
    check_finite("e_d_mm", e)
    check_finite("volts", v)
    if np.unique(e).size < 3:
        raise ValueError("e_d_mm must hold at least 3 distinct distances to fit a quadratic")
    steps = check_positive_int("steps", steps)
    if init is None:
        init = VoltageModel(0.0, 0.0, 0.0)
    init = VoltageModel(*(jnp.asarray(c, jnp.float32) for c in init))
    return _fit_jit(jnp.asarray(e, jnp.float32), jnp.asarray(v, jnp.float32), init, steps)


# --------------------------------------------------------------------------------------
# Belief ([W] eq. 5.1)
# --------------------------------------------------------------------------------------

BELIEF_SIGMA = 0.030
"""σ of [W] eq. 5.1 ("σ is set at 30", in mm), here in m."""


def log_belief(emitter_positions: jax.Array, position: jax.Array, sigma: jax.Array = BELIEF_SIGMA) -> jax.Array:
    """``log bel_n = −|x_n − x_r|² / (2σ²)`` for emitters ``[E, 2]`` and an estimate ``[2]`` (m), [W] eq. 5.1."""
    d = emitter_positions - position
    return -jnp.sum(d * d, axis=-1) / (2.0 * sigma * sigma)


def select_emitter(position: jax.Array, mask: jax.Array, layout: EmitterLayout) -> tuple[jax.Array, jax.Array]:
    """Which emitter carrying ID bitmask ``mask`` was seen, by the belief of [W] eq. 5.1.

    Among the emitters whose ID equals ``mask``, the one with the largest
    belief — the nearest to ``position`` (m, world frame; the receiver's or
    robot's position estimate) — is returned (Alg. 3 lines 6–10). For a unique
    ID it is the single match. Pure and jit/vmap-friendly.

    Returns:
        ``(index, valid)``: int32 emitter index (−1 when invalid) and a bool,
        False when ``mask`` is 0 or no emitter of the layout carries it.
    """
    mask = jnp.asarray(mask, jnp.int32)
    match = (layout.masks == mask) & (mask != 0)
    d2 = jnp.sum((layout.positions - position) ** 2, axis=-1)
    d2 = jnp.where(match, d2, jnp.inf)
    idx = jnp.argmin(d2).astype(jnp.int32)
    valid = jnp.any(match)
    return jnp.where(valid, idx, -1), valid
