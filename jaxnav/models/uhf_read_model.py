"""UHF-RFID read model: the log-likelihood of an RSSI and phase read ([A] §4.3.1–4.3.2, App. C).

**RSSI likelihood ([A] §4.3.1, App. C)**

With the received power ``y = a·g²``, ``g = |h|² ~ Gamma(k, θ)`` and
``a = P_T η_T G_R² G_T² L²`` (:func:`jaxnav.models.uhf_channel.power_scale`),
the density of ``y`` is::

    W_RSSI = f(y) = 1 / (2 θ^k Γ(k) a^{k/2}) · y^{(k−2)/2} · exp(−√(y/a) / θ),

computed in log form by :func:`log_w_rssi` (``gammaln``, no raw product).

**Phase weight ([A] §4.3.2)**

The weight of a particle uses [A]'s distance metric ``Δ`` (Alg. of §4.3.2,
lines 1–4): phases are turned into radii on circles of circumference ``λ/2``
and ``Δ`` is the distance to the nearest peak,
``Δ = min(|ρ_φ − ρ_d|, λ/2 − |ρ_φ − ρ_d|) ∈ [0, λ/4]``. That equals::

    Δ = (λ / 4π) · |wrap(φ_meas − φ_pred)|     (m),  wrap to [−π, π)

(:func:`phase_distance`, with ``φ_pred`` from
:func:`jaxnav.models.uhf_channel.phase`), so a read just below ``2π`` and one
just above ``0`` are both close to a prediction of ``0``. The weight is
``W_PHASE = N(Δ; 0, σ²)`` (:func:`log_w_phase`, normalised Gaussian density
in log form).

**σ convention.** ``Δ`` is a distance, so ``σ`` is in **metres**, as in
[A]: "σ_phase ≈ 0.05λ–0.2λ". The default is
``σ = DEFAULT_PHASE_SIGMA_FRACTION · λ = 0.1 λ``. In phase units this is
``σ_φ = 4π σ / λ`` rad (0.1 λ ↔ 1.26 rad).

**Phase sign.** §4.1.2 has ``φ = −4πD/λ + θ``, but the Δ algorithm of §4.3.2
compares ``(φ − θ) mod 2π`` with ``+4π (D mod λ/2)/λ``, which matches
``φ = +4πD/λ + θ`` instead. We keep §4.1.2's sign and compare the measured
phase with the *predicted* one, which is [A]'s Δ for a consistent sign.

**The filter's likelihood.** [A] writes the §4.3.1 weight as a product over
time; here each function returns a log-density and the filter adds them.
:func:`read_log_terms` and :func:`read_log_likelihood` give ``log W_RSSI +
log W_PHASE`` of masked reads in one fused, traceable expression;
:func:`validate_read_model` checks their parameters on the host and
:func:`read_model_in_domain` inside a ``jit``; :func:`read_model_float32` casts
them to a filter's float32 pytree.

The estimation of ``(k, θ)`` from an anchor tag ([A] §4.3.1, App. D–E) is
:mod:`jaxnav.models.uhf_calibration`.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
from jax.scipy.special import gammaln

from jaxnav.core.validation import all_positive, check_finite, check_positive, check_shape, check_type
from jaxnav.core.weights import wrap_angle
from jaxnav.models.uhf_antenna import AntennaParams, _gain_nocheck, _log_gain_stepped
from jaxnav.models.uhf_channel import (
    _TINY_DISTANCE,
    DEFAULT_WAVELENGTH,
    ChannelParams,
    GammaParams,
    validate_channel,
    validate_gamma,
)
from jaxnav.models.uhf_reads import _TWO_PI, MAX_RSSI_W, read_mask, validate_phase, validate_rssi

__all__ = [
    "DEFAULT_PHASE_SIGMA_FRACTION",
    "log_w_rssi",
    "rssi_log_likelihood",
    "phase_distance",
    "log_w_phase",
    "read_model_float32",
    "validate_read_model",
    "read_model_in_domain",
    "read_log_terms",
    "read_log_likelihood",
]

DEFAULT_PHASE_SIGMA_FRACTION = 0.1
"""σ_phase = 0.1·λ (m), inside [A] §4.3.2's 0.05λ–0.2λ."""


# --------------------------------------------------------------------------------------
# RSSI weight ([A] §4.3.1, App. C)
# --------------------------------------------------------------------------------------


def _log_w_rssi(y, a, k, theta):
    # (k−2)/2·log y − (k/2)·log a = k·log u − log y with u = √(y/a), the Gamma variable.
    # y ≤ 0 (no read) or a = 0 (a tag on the ground, h_T = 0) give −inf, never NaN, and a
    # zero gradient (the double where keeps inf − inf out of the unselected branch).
    ok = (y > 0) & (a > 0)
    log_y = jnp.log(jnp.where(ok, y, 1.0))
    log_u = 0.5 * (log_y - jnp.log(jnp.where(ok, a, 1.0)))
    lw = -jnp.log(2.0) - k * jnp.log(theta) - gammaln(k) - log_y + k * log_u - jnp.exp(log_u) / theta
    return jnp.where(ok, lw, -jnp.inf)


def log_w_rssi(y: Any, a: Any, k: Any, theta: Any) -> jax.Array:
    """``log W_RSSI = log f(y)`` of the scaled squared-Gamma density, [A] §4.3.1 / App. C.

        log f = −log 2 − k log θ − log Γ(k) − (k/2) log a + ((k−2)/2) log y − √(y/a)/θ

    for ``y = a·g²``, ``g ~ Gamma(k, θ)``; integrates to 1 over ``y > 0``.
    Host-side, ``y ≤ 0`` and ``a ≤ 0`` are refused; under ``jit`` (values
    unchecked) they give ``−inf`` (zero weight), never NaN. Missing reads should
    be masked by the caller.

    Args:
        y: RSSI (W), > 0. Any broadcastable shape.
        a: ``P_T η_T G_R² G_T² L²`` (W), > 0 (:func:`~jaxnav.models.uhf_channel.power_scale`).
        k, theta: Gamma shape and scale, > 0.
    """
    validate_rssi(y)
    check_positive("a", a)
    validate_gamma(GammaParams(k, theta))
    return _log_w_rssi(jnp.asarray(y), jnp.asarray(a), jnp.asarray(k), jnp.asarray(theta))


def rssi_log_likelihood(reads: Any, a: Any, gamma: GammaParams, mask: Any = None) -> jax.Array:
    """``ℓ(k, θ) = Σ_i log f(y_i; a_i, k, θ)`` over valid reads, [A] App. D.

    Masked entries contribute 0 whatever they hold (NaN and 0 included).
    """
    validate_rssi(reads, mask, "reads", max_w=MAX_RSSI_W)
    validate_gamma(gamma)
    y = jnp.asarray(reads)
    valid = read_mask(y.shape, mask)
    a_b = jnp.broadcast_to(jnp.asarray(a), y.shape)
    lw = _log_w_rssi(jnp.where(valid, y, 1.0), jnp.where(valid, a_b, 1.0), gamma.k, gamma.theta)
    return jnp.sum(jnp.where(valid, lw, 0.0))


# --------------------------------------------------------------------------------------
# Phase weight ([A] §4.3.2)
# --------------------------------------------------------------------------------------


def phase_distance(phi_meas: Any, phi_pred: Any, wavelength: Any = DEFAULT_WAVELENGTH) -> jax.Array:
    """[A]'s distance metric ``Δ`` (m), §4.3.2: ``(λ/4π)·|wrap(φ_meas − φ_pred)| ∈ [0, λ/4]``.

    The distance, on a circle of circumference ``λ/2``, between the radius of the
    measured phase and the particle's (module docstring): symmetric across the
    ``0/2π`` wrap, zero for a noiseless read.

    Args:
        phi_meas: measured phase (rad) in ``[0, 2π)``.
        phi_pred: predicted phase (rad), e.g. :func:`~jaxnav.models.uhf_channel.phase` of the particle.
        wavelength: ``λ`` (m), > 0, broadcastable (per read).
    """
    validate_phase(phi_meas)
    check_finite("phi_pred", phi_pred)
    check_positive("wavelength", wavelength)
    diff = wrap_angle(jnp.asarray(phi_meas) - jnp.asarray(phi_pred))
    return jnp.asarray(wavelength) / (4.0 * jnp.pi) * jnp.abs(diff)


def log_w_phase(phi_meas: Any, phi_pred: Any, sigma: Any, wavelength: Any = DEFAULT_WAVELENGTH) -> jax.Array:
    """``log W_PHASE = log N(Δ; 0, σ²)``, [A] §4.3.2, ``Δ`` from :func:`phase_distance`.

        log W = −Δ²/(2σ²) − log σ − ½ log 2π

    Args:
        phi_meas: measured phase (rad) in ``[0, 2π)``.
        phi_pred: predicted phase (rad).
        sigma: ``σ_phase`` in **metres** (the unit of Δ); [A]: 0.05λ–0.2λ, default
            choice ``DEFAULT_PHASE_SIGMA_FRACTION·λ``. ``σ_φ = 4πσ/λ`` rad.
        wavelength: ``λ`` (m), > 0, broadcastable (per read).

    Smooth in ``φ_pred``, ``σ`` and ``λ`` (the wrapped difference is squared,
    so no ``|·|`` kink at Δ = 0).
    """
    validate_phase(phi_meas)
    check_finite("phi_pred", phi_pred)
    check_positive("sigma", sigma)
    check_positive("wavelength", wavelength)
    diff = wrap_angle(jnp.asarray(phi_meas) - jnp.asarray(phi_pred))
    r = jnp.asarray(wavelength) / (4.0 * jnp.pi) * diff / jnp.asarray(sigma)
    return -0.5 * r * r - jnp.log(jnp.asarray(sigma)) - 0.5 * math.log(_TWO_PI)


# --------------------------------------------------------------------------------------
# Parameters of the read likelihood
# --------------------------------------------------------------------------------------


def read_model_float32(channel: ChannelParams, gamma: GammaParams) -> tuple[ChannelParams, GammaParams]:
    """``(channel, gamma)`` with every leaf a float32 array (a filter's differentiable params)."""
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return (
        ChannelParams(*(f32(c) for c in channel[:4]), AntennaParams(*(f32(c) for c in channel.antenna))),
        GammaParams(f32(gamma.k), f32(gamma.theta)),
    )


def validate_read_model(channel: ChannelParams, gamma: GammaParams, phase_sigma: Any, prefix: str = "params") -> None:
    """Host-side checks of the parameters :func:`read_log_likelihood` takes: a
    :class:`~jaxnav.models.uhf_channel.ChannelParams` and a :class:`~jaxnav.models.uhf_channel.GammaParams`
    of scalars, and σ_phase a positive scalar (m)."""
    check_type(f"{prefix}.channel", channel, ChannelParams)
    check_type(f"{prefix}.channel.antenna", channel.antenna, AntennaParams)
    check_type(f"{prefix}.gamma", gamma, GammaParams)
    for group, fields in (
        ("channel", channel._replace(antenna=None)),
        ("channel.antenna", channel.antenna),
        ("gamma", gamma),
    ):
        for field, value in zip(fields._fields, fields):
            if field != "antenna":
                check_shape(f"{prefix}.{group}.{field}", value, ())
    validate_channel(channel)
    validate_gamma(gamma)
    check_shape(f"{prefix}.phase_sigma", phase_sigma, ())
    check_positive(f"{prefix}.phase_sigma (σ_phase, m)", phase_sigma)


def read_model_in_domain(channel: ChannelParams, gamma: GammaParams, phase_sigma: Any) -> jax.Array:
    """``bool[]``, traceable: the value checks of :func:`validate_read_model` as a ``jnp`` expression,
    for use inside a ``jit``: every power, gain, wavelength, ``φ_s``, ``k``, ``θ`` and ``σ_phase``
    positive, ``η_T ≤ 1`` and ``φ_s ≤ π/2`` (a zero or negative one makes a logarithm NaN)."""
    positive = [all_positive(leaf) for leaf in jax.tree_util.tree_leaves((channel, gamma, phase_sigma))]
    return (
        jnp.all(jnp.stack(positive))
        & jnp.all(jnp.asarray(channel.tag_efficiency) <= 1.0)
        & jnp.all(jnp.asarray(channel.antenna.phi_s) <= math.pi / 2 + 1e-7)
    )


# --------------------------------------------------------------------------------------
# Fused read likelihood
# --------------------------------------------------------------------------------------


def _log_power_scale_from_geometry(d, d2, reader_pose, tag_xyz, params: ChannelParams, wavelength, softness):
    """``log a`` (a in W) with ``d = (dx, dy, dz) = tag − reader`` and ``d2 = |d|²`` (≥ the clamp); one ``log`` per pair.

    ``log a = log(P_T η_T G_T²) + 2 log G_R + 2 log L`` with ``log L = 2 log(λ/4π) − log D²``
    (free space) or ``2 log(h_R h_T) − 2 log D²`` (plane earth), the branch chosen by
    ``D² < D_c²`` ([A] §4.1.2): the same number as ``log`` :func:`~jaxnav.models.uhf_channel.power_scale`,
    without its powers and square roots. ``−inf`` for a zero height in the plane-earth branch.
    """
    if softness is None:
        c, s_ = jnp.cos(reader_pose[..., 3]), jnp.sin(reader_pose[..., 3])
        dot = d[0] * c + d[1] * s_
        log_g = _log_gain_stepped(dot, jnp.sqrt(d2), params.antenna)
    else:
        log_g = jnp.log(
            _gain_nocheck(jnp.stack(jnp.broadcast_arrays(*d), -1), reader_pose[..., 3], params.antenna, softness)
        )
    h_r, h_t = reader_pose[..., 2], tag_xyz[..., 2]
    hh = h_r * h_t
    log_d2 = jnp.log(d2)
    near = 2.0 * jnp.log(wavelength / (4.0 * jnp.pi)) - log_d2
    far = 2.0 * jnp.log(jnp.where(hh > 0, hh, 1.0)) - 2.0 * log_d2
    far = jnp.where(hh > 0, far, -jnp.inf)
    d_c = 4.0 * jnp.pi * hh / wavelength
    log_l = jnp.where(d2 < d_c * d_c, near, far)
    const = jnp.log(params.tx_power * params.tag_efficiency * params.tag_gain**2)
    return const + 2.0 * log_g + 2.0 * log_l


def _log_w_rssi_from_logs(log_y, log_a, k, theta):
    """:func:`log_w_rssi` from ``log y`` and ``log a`` (one ``exp``): ``log_a = −inf`` gives ``−inf``, never NaN."""
    ok = log_a > -jnp.inf
    log_u = 0.5 * (log_y - jnp.where(ok, log_a, 0.0))
    lw = -jnp.log(2.0) - k * jnp.log(theta) - gammaln(k) - log_y + k * log_u - jnp.exp(log_u) / theta
    return jnp.where(ok, lw, -jnp.inf)


def _wrap_round(x):
    """``x`` wrapped to ``[−π, π]`` by ``x − 2π·round(x/2π)`` (cheaper than ``%``; the ends only matter squared)."""
    return x - _TWO_PI * jnp.round(x * (1.0 / _TWO_PI))


def read_log_terms(
    reader_pose: jax.Array,
    tag_xyz: jax.Array,
    theta_offset: jax.Array,
    rssi: jax.Array,
    phi: jax.Array,
    wavelength: jax.Array,
    mask: jax.Array,
    channel: ChannelParams,
    gamma: GammaParams,
    phase_sigma: jax.Array,
    use_rssi: bool = True,
    use_phase: bool = True,
    softness: Any = None,
) -> jax.Array:
    """``log W_RSSI + log W_PHASE`` of each read (0 where ``mask`` is False), broadcast, not summed.

    Arguments as :func:`read_log_likelihood`, every one broadcastable against the others
    (``reader_pose [..., 4]``, ``tag_xyz [..., 3]``, the rest ``[...]``). A filter with few
    read slots calls it once per slot with that slot's scalars against the particle arrays
    (:func:`jaxnav.localization.rfid_tag.log_likelihoods`): each call is then a flat loop over
    the particles with scalar operands, which XLA:CPU runs several times faster inside a scan
    than one ``[M, J]`` broadcast whose read operands are sliced from the scanned arrays.
    Per particle and read it costs one ``log`` (of ``D²``), one ``exp`` and one ``sqrt``:
    ``log a`` is assembled in the log domain (``_log_power_scale_from_geometry``), the
    stepped antenna's lobe test compares ``d·b`` with ``cos φ_s·|d|`` instead of computing the
    angle, and ``D²`` is summed component by component (a reduction over a trailing axis of 3
    is slow on XLA:CPU).
    """
    dx = tag_xyz[..., 0] - reader_pose[..., 0]
    dy = tag_xyz[..., 1] - reader_pose[..., 1]
    dz = tag_xyz[..., 2] - reader_pose[..., 2]
    d2 = jnp.maximum(dx * dx + dy * dy + dz * dz, _TINY_DISTANCE * _TINY_DISTANCE)
    total = jnp.zeros(jnp.broadcast_shapes(jnp.shape(mask), jnp.shape(d2)))
    if use_rssi:
        log_a = _log_power_scale_from_geometry((dx, dy, dz), d2, reader_pose, tag_xyz, channel, wavelength, softness)
        log_y = jnp.log(jnp.where(mask, rssi, 1.0))  # per read, not per particle
        total = total + _log_w_rssi_from_logs(log_y, log_a, gamma.k, gamma.theta)
    if use_phase:
        pred = (-4.0 * jnp.pi / wavelength) * jnp.sqrt(d2) + theta_offset
        r = (wavelength / (4.0 * jnp.pi * phase_sigma)) * _wrap_round(phi - pred)  # Δ/σ, [A] §4.3.2
        total = total + (-0.5 * r * r - jnp.log(phase_sigma) - 0.5 * math.log(_TWO_PI))
    return jnp.where(mask, total, 0.0)


def read_log_likelihood(
    reader_pose: jax.Array,
    tag_xyz: jax.Array,
    theta_offset: jax.Array,
    rssi: jax.Array,
    phi: jax.Array,
    wavelength: jax.Array,
    mask: jax.Array,
    channel: ChannelParams,
    gamma: GammaParams,
    phase_sigma: jax.Array,
    use_rssi: bool = True,
    use_phase: bool = True,
    softness: Any = None,
) -> jax.Array:
    """``Σ_j log W_RSSI + log W_PHASE`` over the last (read) axis, valid reads only ([A] Alg. 6 lines 11–14, Alg. 8 lines 14–18).

    Jit-side (no host checks; validate the reads with :func:`~jaxnav.models.uhf_reads.validate_reads`).
    Everything broadcasts to ``[..., J]``: ``reader_pose [..., J, 4]``,
    ``tag_xyz [..., J, 3]``, ``theta_offset``, ``rssi``, ``phi``,
    ``wavelength``, ``mask`` ``[..., J]``. A particle filter over tags
    broadcasts the tag (``[M, 1, 3]``) against fixed readers (``[1, J, 4]``);
    one over the robot broadcasts the reader against fixed anchors. The
    static flags ``use_rssi`` / ``use_phase`` pick the weighting. Returns ``[...]``.
    The per-read terms are :func:`read_log_terms`; the tests check them against
    :func:`log_w_rssi` of :func:`~jaxnav.models.uhf_channel.power_scale` plus :func:`log_w_phase`.
    """
    return jnp.sum(
        read_log_terms(
            reader_pose,
            tag_xyz,
            theta_offset,
            rssi,
            phi,
            wavelength,
            mask,
            channel,
            gamma,
            phase_sigma,
            use_rssi,
            use_phase,
            softness,
        ),
        axis=-1,
    )
