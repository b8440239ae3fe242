"""The IR receivers of [W] ch. 5 as a particle sensor: [W] eqs. 5.1–5.2 over pose particles.

**Overview**

A robot carries ``R`` upward-looking receivers at robot-frame ``offsets [R, 2]``; each window a
receiver reports at most one emitter ID and its level ``V`` (:class:`jaxnav.models.ir.IRDetection`).
A particle ``x`` (a pose ``(x, y, θ)``) is weighted by [W] eq. 5.2 for each usable detection,

    log w(x) = Σ_r ℓ_r(x),   ℓ_r(x) = max(log_floor, −(V_r − V̄(e_r(x)))² / (2σ_V²))   if e_r(x) ≤ range,
                             ℓ_r(x) = log_floor                                          otherwise,

with ``e_r(x)`` the horizontal distance (m) from the particle's receiver ``r`` to the emitter
``x_e`` the detection is attributed to, ``V̄`` the voltage curve of eq. 5.3
(:func:`jaxnav.models.ir.log_likelihood`), and ``log_floor ≤ 0`` the term of a particle that
contradicts the detection (finite, so that a detection no particle explains leaves the weights as
they were instead of producing NaN). A unique ID names its emitter; a repeated ID is attributed by
the belief of eq. 5.1 (:func:`jaxnav.models.ir.select_emitter`): the emitter of that ID nearest
the receiver's position estimated from the mean pose of the particles.

The functions here are the IR filter's own (:mod:`jaxnav.localization.ir_mcl`, which adds [W]'s
start at the first unique ID and the restart when lost), and :data:`IR_RECEIVERS` packs them as a
:class:`~jaxnav.models.sensor.ParticleSensor`, so that MCL, augmented MCL and KLD-MCL localize
under IR emitters too: ``MCLConfig(sensor=IR_RECEIVERS, motion_model="omni_body")`` with the
parameters of :func:`jaxnav.localization.ir_mcl.default_params` (any pytree with the fields of
:class:`IRReceiverParams` and ``motion``). As a sensor, it attributes a repeated ID by the
unweighted mean of the particles it weighs, which equals the IR filter's weighted mean when the
weights are uniform (a filter that resamples at every step, the default).

Units: m, rad, V (``e_d`` in mm only inside eq. 5.3's coefficients).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import weights
from jaxnav.core.validation import (
    all_positive,
    check_finite,
    check_magnitude,
    check_positive,
    check_real,
    check_shape,
    finite_within,
    is_concrete,
)
from jaxnav.models import ir
from jaxnav.models.ir import IRDetection
from jaxnav.models.sensor import ParticleSensor

__all__ = [
    "IRReceiverParams",
    "receiver_xy",
    "usable_detections",
    "known_detections",
    "attribute",
    "detections_log_likelihood",
    "validate_receiver_params",
    "check_detections",
    "receiver_params_in_domain",
    "IR_RECEIVERS",
]

_ANGLE_DIMS = (2,)


class IRReceiverParams(NamedTuple):
    """The fields of a parameter pytree that the IR receivers read (the IR filter's
    :class:`~jaxnav.localization.ir_mcl.IRMCLParams` has them all).

    Attributes:
        layout: the ceiling emitters (positions in m, ID bitmasks).
        voltage: the mean-voltage curve ``V̄(e_d)`` ([W] eq. 5.3; e_d in mm).
        sigma_v: σ of eq. 5.2 (V).
        offsets: ``[R, 2]`` receiver positions in the robot frame (m; x forward, y left).
        detection_range: horizontal receiver–emitter distance (m) beyond which a detection
            contradicts a particle.
        log_floor: log-likelihood of a contradicting particle, and the lowest per-receiver term.
    """

    layout: ir.EmitterLayout
    voltage: ir.VoltageModel
    sigma_v: jax.Array
    offsets: jax.Array
    detection_range: jax.Array
    log_floor: jax.Array


def receiver_xy(particles: jax.Array, offsets: jax.Array) -> jax.Array:
    """``[N, R, 2]`` world positions (m) of the receivers of every pose particle ``[N, 3]``."""
    c, s = jnp.cos(particles[:, 2])[:, None], jnp.sin(particles[:, 2])[:, None]
    ox, oy = offsets[None, :, 0], offsets[None, :, 1]
    return jnp.stack([particles[:, None, 0] + c * ox - s * oy, particles[:, None, 1] + s * ox + c * oy], axis=-1)


def usable_detections(det: IRDetection) -> tuple[IRDetection, jax.Array]:
    """``(det, num_unusable)``: ``det`` with a detection whose level is negative, not finite or beyond
    :data:`jaxnav.models.ir.MAX_VOLTAGE` made invalid (level 0), and how many valid ones that dropped.
    The host refuses such levels; inside a caller's ``jit`` they are dropped and counted."""
    readable = finite_within(det.voltage, ir.MAX_VOLTAGE) & (det.voltage >= 0)
    num_unusable = jnp.sum(det.valid & ~readable, dtype=jnp.int32)
    return det._replace(valid=det.valid & readable, voltage=jnp.where(readable, det.voltage, 0.0)), num_unusable


def known_detections(det: IRDetection, layout: ir.EmitterLayout) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(mask [R], match [R, E], known [R])``: each receiver's ID bitmask (0 when invalid), which
    emitters carry it, and whether the detection is valid with an ID of the layout ([W] Alg. 3 line 5)."""
    mask = jnp.where(det.valid, det.mask, 0).astype(jnp.int32)
    match = mask[:, None] == layout.masks[None, :]
    return mask, match, det.valid & jnp.any(match, axis=-1)


def attribute(
    particles: jax.Array, probs: jax.Array, mask: jax.Array, usable: jax.Array, params: Any
) -> tuple[jax.Array, jax.Array]:
    """[W] eq. 5.1 / Alg. 3 lines 6–11 for every receiver: ``(index [R], ok [R])``, the emitter carrying
    the detected ID nearest the receiver's position estimated from the weighted mean pose of
    ``particles`` (weights ``probs``), and whether receiver ``r``'s detection is used (``usable``)."""
    est = weights.mean_from_probabilities(particles, probs, _ANGLE_DIMS)
    rx_est = ir.receiver_positions(est, params.offsets)  # [R, 2]
    idx, ok = jax.vmap(ir.select_emitter, in_axes=(0, 0, None))(rx_est, mask, params.layout)
    return idx, ok & usable


def detections_log_likelihood(
    particles: jax.Array, idx: jax.Array, apply: jax.Array, voltage: jax.Array, params: Any
) -> jax.Array:
    """``[N]`` Σ over the receivers with ``apply [R]`` of eq. 5.2, floored at ``params.log_floor``, and
    ``log_floor`` for a particle whose receiver is beyond ``params.detection_range`` of emitter ``idx``."""
    rx = receiver_xy(particles, params.offsets)  # [N, R, 2]
    d = rx - params.layout.positions[jnp.maximum(idx, 0)][None, :, :]
    e_d = jnp.sqrt(jnp.maximum(jnp.sum(d * d, axis=-1), 1e-12))  # [N, R] m
    ll = ir.log_likelihood(voltage[None, :], e_d, params.voltage, params.sigma_v)
    ll = jnp.where(e_d <= params.detection_range, jnp.maximum(ll, params.log_floor), params.log_floor)
    return jnp.sum(jnp.where(apply[None, :], ll, 0.0), axis=-1)


# --------------------------------------------------------------------------- checks


def validate_receiver_params(params: Any) -> None:
    """Host-side check of the fields of :class:`IRReceiverParams` in ``params``; raises ``ValueError``
    naming the field."""
    if not isinstance(params.layout, ir.EmitterLayout):
        raise ValueError(f"params.layout must be an EmitterLayout, got {type(params.layout).__name__}")
    if is_concrete(params.layout):
        ir.validate_layout(params.layout)
    else:
        check_shape("params.layout.positions", params.layout.positions, (None, 2))
    if not isinstance(params.voltage, ir.VoltageModel):
        raise ValueError(f"params.voltage must be a VoltageModel, got {type(params.voltage).__name__}")
    for name, c in zip(ir.VoltageModel._fields, params.voltage):
        check_shape(f"params.voltage.{name}", c, ())
        check_finite(f"params.voltage.{name}", c)
    check_shape("params.sigma_v", params.sigma_v, ())
    check_positive("params.sigma_v (σ of [W] eq. 5.2, V)", params.sigma_v)
    check_shape("params.offsets", params.offsets, (None, 2))
    if np.shape(params.offsets)[0] < 1:
        raise ValueError("params.offsets must hold at least one receiver")
    check_finite("params.offsets", params.offsets)
    check_shape("params.detection_range", params.detection_range, ())
    check_positive("params.detection_range (m)", params.detection_range)
    check_shape("params.log_floor", params.log_floor, ())
    check_finite("params.log_floor", params.log_floor)
    if is_concrete(params.log_floor) and float(params.log_floor) > 0.0:
        raise ValueError(f"params.log_floor must be ≤ 0 (a log-likelihood floor), got {float(params.log_floor)}")


def check_detections(name: str, det: Any, lead: tuple, num_receivers: int) -> None:
    """Host-side check of detections ``det`` named ``name``: an :class:`~jaxnav.models.ir.IRDetection`
    with ``mask``, ``valid`` and ``voltage`` of shape ``lead + (R,)``, real amplitudes, and levels in
    ``[0, MAX_VOLTAGE]`` V."""
    if not isinstance(det, IRDetection):
        raise ValueError(f"{name} must be an IRDetection (jaxnav.models.ir), got {type(det).__name__}")
    for field in ("mask", "valid", "voltage"):
        check_shape(f"{name}.{field}", getattr(det, field), lead + (num_receivers,))
    check_shape(f"{name}.amplitude", det.amplitude, lead + (num_receivers, None))
    check_real(f"{name}.amplitude", det.amplitude)
    check_magnitude(f"{name}.voltage", det.voltage, limit=ir.MAX_VOLTAGE)
    ir.check_levels(f"{name}.voltage", det.voltage)


def receiver_params_in_domain(params: Any, ok: Any = True) -> jax.Array:
    """``bool[]``, traceable: ``ok`` and ``σ_V > 0``, ``detection_range > 0`` and ``log_floor ≤ 0``, the
    value checks of :func:`validate_receiver_params` that matter numerically, as ``jnp``. ``ok`` (the
    filter's other conditions) comes first so that the conjunction is built in one order everywhere:
    another order is another program for XLA, which may round a float elsewhere differently."""
    return ok & all_positive(params.sigma_v) & all_positive(params.detection_range) & (params.log_floor <= 0)


# --------------------------------------------------------------------------- the particle-sensor instance


def _sensor_log_likelihood(particles: jax.Array, det: IRDetection, params: Any) -> jax.Array:
    det, _ = usable_detections(det)
    mask, _, known = known_detections(det, params.layout)
    n = particles.shape[0]
    idx, ok = attribute(particles, jnp.full((n,), 1.0 / n, particles.dtype), mask, known, params)
    return detections_log_likelihood(particles, idx, ok, det.voltage, params)


def _sensor_num_ignored(det: IRDetection, params: Any) -> jax.Array:
    det, num_unusable = usable_detections(det)
    _, _, known = known_detections(det, params.layout)
    return jnp.sum(det.valid & ~known, dtype=jnp.int32) + num_unusable


def _sensor_check_observations(det: Any, time_axis: bool, params: Any) -> None:
    name = "detections" if time_axis else "detection"
    check_detections(name, det, (None,) if time_axis else (), int(np.shape(params.offsets)[0]))


def _sensor_prepare(det: IRDetection) -> IRDetection:
    return IRDetection(
        jnp.asarray(det.mask, jnp.int32),
        jnp.asarray(det.valid, bool),
        jnp.asarray(det.voltage, jnp.float32),
        jnp.asarray(det.amplitude, jnp.float32),
    )


IR_RECEIVERS = ParticleSensor(
    "ir_receivers",
    _sensor_log_likelihood,
    check_params=validate_receiver_params,
    check_observations=_sensor_check_observations,
    params_in_domain=receiver_params_in_domain,
    num_ignored=_sensor_num_ignored,
    prepare=_sensor_prepare,
)
"""The IR receivers as a :class:`~jaxnav.models.sensor.ParticleSensor` (module docstring): observations
:class:`~jaxnav.models.ir.IRDetection` ``[R]`` per step, parameters with the fields of
:class:`IRReceiverParams`. A detection whose ID no emitter carries, or whose level is unusable, is
dropped and counted."""
