"""UHF-RFID channel: the power and phase a monostatic reader receives from a passive tag ([A] §4.1.2, App. A).

**Geometry**

A reader at ``g = (x_g, y_g, z_g, ψ_g)`` (m, m, m, rad: position and the yaw of
its antenna boresight, [A] §4.3.1) interrogates a passive tag at
``X = (x, y, z)`` (m). Ground is the plane ``z = 0``, so the heights of the
two-ray model are ``h_R = z_g`` and ``h_T = z``. Every function here is pure,
broadcasts over leading axes, and is differentiable in its continuous
arguments; :func:`jax.grad` never returns NaN for valid inputs.

**Received power ([A] §4.1.2, App. A, monostatic)**

::

    y = P_T · η_T · G_R² · G_T² · L² · |h|⁴,     |h|² ~ Gamma(k, θ)  (shape k, scale θ)

* ``P_T`` transmit power (W), ``η_T`` tag scattering efficiency, ``G_T`` tag
  antenna gain (linear), ``G_R`` the reader antenna gain towards the tag
  (:func:`jaxnav.models.uhf_antenna.antenna_gain`).
* Two-ray path loss ([A] §4.1.2 and App. A; :func:`two_ray_path_loss`), with
  ``D`` the reader–tag distance (m) and breakpoint ``D_c = 4π h_R h_T / λ``::

      L = (λ / (4π D))²        if D < D_c
      L = (h_R h_T / D²)²      if D ≥ D_c

  The two branches are equal at ``D = D_c`` (both are
  ``(λ² / (16π² h_R h_T))²``), so ``L`` is continuous; its slope jumps from
  ``D⁻²`` to ``D⁻⁴``.
* ``a = P_T η_T G_R² G_T² L²`` (:func:`power_scale`) is the deterministic
  part, so ``y = a·(|h|²)²`` ([A] §4.3.1) and ``E[y] = a·k(k+1)θ²``
  (:func:`mean_power`); :func:`sample_rssi` draws ``y``.

**Phase ([A] §4.1.2)**

::

    φ = (−4π D / λ + θ_off) mod 2π  ∈ [0, 2π)          (:func:`phase`)

``θ_off`` is the constant offset of cables and tag; [A]'s multipath term
``φ_n`` is the noise, not part of the prediction.

**Units**

SI everywhere: m, rad, W; gains are linear (dimensionless). Readers report
dBm and antenna sheets dBi: :func:`dbm_to_watt`, :func:`watt_to_dbm`,
:func:`db_to_linear`, :func:`linear_to_db`.

**Where the thesis is ambiguous, and what we chose**

* **Wavelength.** [A] §5.2 states λ = 0.173 m; a European UHF reader (866 MHz)
  has λ = c/f ≈ 0.346 m, so 0.173 m is likely λ/2. λ is a parameter
  of every function (per read, to allow channel hopping); the default
  :data:`DEFAULT_WAVELENGTH` is the thesis's 0.173 m (:data:`A_WAVELENGTH`) so
  that reproductions match [A]; real 866 MHz data should pass
  :data:`WAVELENGTH_866MHZ` (or :func:`wavelength_from_frequency`).
* **Numbers [A] does not give** (our choices, all parameters):
  ``P_T = 30 dBm = 1 W``, ``η_T = 0.25``, ``G_T = 1.64`` (a half-wave dipole,
  2.15 dBi), the antenna of :data:`jaxnav.models.uhf_antenna.DEFAULT_ANTENNA`;
  :data:`DEFAULT_GAMMA` ``k = 2, θ = 0.5`` (unit mean fading power
  ``E|h|² = kθ = 1``, Nakagami m = 2).

The likelihood of a read under this channel is :mod:`jaxnav.models.uhf_read_model`.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_finite, check_nonnegative, check_positive, is_concrete
from jaxnav.models.uhf_antenna import (
    DEFAULT_ANTENNA,
    AntennaParams,
    _check_last_dim,
    _gain_nocheck,
    _safe_sqrt,
    validate_antenna,
)
from jaxnav.models.uhf_reads import wrap_phase

__all__ = [
    "SPEED_OF_LIGHT",
    "A_WAVELENGTH",
    "WAVELENGTH_866MHZ",
    "DEFAULT_WAVELENGTH",
    "ChannelParams",
    "DEFAULT_CHANNEL",
    "GammaParams",
    "DEFAULT_GAMMA",
    "dbm_to_watt",
    "watt_to_dbm",
    "db_to_linear",
    "linear_to_db",
    "wavelength_from_frequency",
    "validate_channel",
    "validate_gamma",
    "two_ray_breakpoint",
    "two_ray_path_loss",
    "power_scale",
    "received_power",
    "mean_power",
    "sample_rssi",
    "phase",
]

SPEED_OF_LIGHT = 299_792_458.0
"""m/s."""

A_WAVELENGTH = 0.173
"""λ stated in [A] §5.2 (m); likely λ/2 of an 866 MHz reader (module docstring)."""

WAVELENGTH_866MHZ = SPEED_OF_LIGHT / 866e6
"""λ of a European UHF reader at 866 MHz, ≈ 0.3462 m."""

DEFAULT_WAVELENGTH = A_WAVELENGTH
"""Default λ (m), the thesis's value, for reproductions of [A]."""


class ChannelParams(NamedTuple):
    """Constants of the monostatic power model of [A] §4.1.2 / App. A (a pytree).

    Attributes:
        tx_power: ``P_T`` (W).
        tag_efficiency: ``η_T``, tag scattering efficiency (0 < η_T ≤ 1).
        tag_gain: ``G_T`` (linear).
        wavelength: ``λ`` (m).
        antenna: :class:`~jaxnav.models.uhf_antenna.AntennaParams` of the reader.
    """

    tx_power: Any
    tag_efficiency: Any
    tag_gain: Any
    wavelength: Any
    antenna: AntennaParams


DEFAULT_CHANNEL = ChannelParams(
    tx_power=1.0, tag_efficiency=0.25, tag_gain=1.64, wavelength=DEFAULT_WAVELENGTH, antenna=DEFAULT_ANTENNA
)
"""P_T = 1 W (30 dBm), η_T = 0.25, G_T = 1.64 (dipole), λ = 0.173 m ([A] §5.2),
:data:`~jaxnav.models.uhf_antenna.DEFAULT_ANTENNA`."""


class GammaParams(NamedTuple):
    """``|h|² ~ Gamma(k, θ)``: shape ``k`` > 0, scale ``θ`` > 0 ([A] §4.1.2)."""

    k: Any
    theta: Any


DEFAULT_GAMMA = GammaParams(k=2.0, theta=0.5)
"""Fading parameters used until enough anchor reads exist, with unit mean fading power kθ = 1 (our choice)."""


# --------------------------------------------------------------------------------------
# Units
# --------------------------------------------------------------------------------------


def dbm_to_watt(p_dbm: Any) -> jax.Array:
    """Power in dBm → W: ``10^((p − 30)/10)`` (30 dBm = 1 W)."""
    return 10.0 ** ((jnp.asarray(p_dbm) - 30.0) / 10.0)


def watt_to_dbm(p_w: Any) -> jax.Array:
    """Power in W → dBm: ``10·log10(p) + 30``."""
    return 10.0 * jnp.log10(jnp.asarray(p_w)) + 30.0


def db_to_linear(x_db: Any) -> jax.Array:
    """Gain in dB (dBi) → linear ratio ``10^(x/10)``."""
    return 10.0 ** (jnp.asarray(x_db) / 10.0)


def linear_to_db(x: Any) -> jax.Array:
    """Linear gain → dB: ``10·log10(x)``."""
    return 10.0 * jnp.log10(jnp.asarray(x))


def wavelength_from_frequency(frequency_hz: Any) -> jax.Array:
    """``λ = c / f`` (m) for a carrier frequency in Hz (866e6 → 0.3462 m)."""
    return SPEED_OF_LIGHT / jnp.asarray(frequency_hz)


def validate_channel(params: ChannelParams) -> None:
    """``P_T``, ``η_T``, ``G_T``, ``λ`` finite and > 0 (``η_T ≤ 1``), and the antenna."""
    check_positive("tx_power", params.tx_power)
    check_positive("tag_efficiency", params.tag_efficiency)
    if is_concrete(params.tag_efficiency) and np.any(np.asarray(params.tag_efficiency) > 1.0):
        raise ValueError(f"tag_efficiency must be in (0, 1], got {np.asarray(params.tag_efficiency)}")
    check_positive("tag_gain", params.tag_gain)
    check_positive("wavelength", params.wavelength)
    validate_antenna(params.antenna)


def validate_gamma(params: GammaParams) -> None:
    """Gamma shape ``k`` and scale ``θ`` must be finite and > 0."""
    check_positive("k", params.k)
    check_positive("theta", params.theta)


# --------------------------------------------------------------------------------------
# Path loss and received power ([A] §4.1.2, App. A)
# --------------------------------------------------------------------------------------


def two_ray_breakpoint(h_reader: Any, h_tag: Any, wavelength: Any) -> jax.Array:
    """Breakpoint distance ``D_c = 4π h_R h_T / λ`` (m) of the two-ray model ([A] §4.1.2)."""
    return 4.0 * jnp.pi * jnp.asarray(h_reader) * jnp.asarray(h_tag) / jnp.asarray(wavelength)


_TINY_DISTANCE = 1e-6  # m; distances are clamped here so 1/D never overflows


def _two_ray(distance, h_reader, h_tag, wavelength):
    d = jnp.maximum(jnp.asarray(distance), _TINY_DISTANCE)
    near = (wavelength / (4.0 * jnp.pi * d)) ** 2
    far = (h_reader * h_tag / (d * d)) ** 2
    return jnp.where(d < two_ray_breakpoint(h_reader, h_tag, wavelength), near, far)


def two_ray_path_loss(distance: Any, h_reader: Any, h_tag: Any, wavelength: Any = DEFAULT_WAVELENGTH) -> jax.Array:
    """Two-ray path loss ``L`` (power ratio, one way), [A] §4.1.2 and App. A.

    ``L = (λ/(4πD))²`` for ``D < D_c = 4π h_R h_T/λ`` (free space, Friis), else
    ``(h_R h_T / D²)²`` (plane earth). Continuous at ``D_c``. Both branches are
    finite for every ``D`` (``D`` is clamped to ≥ 1 µm), so the ``where`` switch
    passes no NaN to the gradient.

    Args:
        distance: reader–tag distance ``D`` (m), ≥ 0.
        h_reader, h_tag: heights above the ground (m), ≥ 0.
        wavelength: ``λ`` (m), > 0; may differ per read.
    """
    check_nonnegative("distance", distance)
    check_nonnegative("h_reader", h_reader)
    check_nonnegative("h_tag", h_tag)
    check_positive("wavelength", wavelength)
    return _two_ray(jnp.asarray(distance), jnp.asarray(h_reader), jnp.asarray(h_tag), jnp.asarray(wavelength))


def _norm(v: jax.Array) -> jax.Array:
    return _safe_sqrt(jnp.sum(v * v, axis=-1))


def _power_scale(reader_pose, tag_xyz, params, softness, wavelength):
    d = tag_xyz - reader_pose[..., :3]
    dist = _norm(d)
    g_r = _gain_nocheck(d, reader_pose[..., 3], params.antenna, softness)
    loss = _two_ray(dist, reader_pose[..., 2], tag_xyz[..., 2], wavelength)
    return params.tx_power * params.tag_efficiency * (g_r * params.tag_gain) ** 2 * loss * loss


def _check_geometry(reader_pose, tag_xyz):
    _check_last_dim("reader_pose", reader_pose, 4)
    _check_last_dim("tag_xyz", tag_xyz, 3)
    check_finite("reader_pose", reader_pose)
    check_finite("tag_xyz", tag_xyz)
    if is_concrete(reader_pose) and np.any(np.asarray(reader_pose)[..., 2] < 0):
        raise ValueError("reader_pose z (the reader's height above the ground z = 0) must be ≥ 0")
    if is_concrete(tag_xyz) and np.any(np.asarray(tag_xyz)[..., 2] < 0):
        raise ValueError("tag_xyz z (the tag's height above the ground z = 0) must be ≥ 0")


def power_scale(
    reader_pose: Any,
    tag_xyz: Any,
    params: ChannelParams = DEFAULT_CHANNEL,
    softness: Any = None,
    wavelength: Any = None,
) -> jax.Array:
    """``a = P_T η_T G_R² G_T² L²`` (W), so that ``RSSI = a·|h|⁴`` ([A] §4.3.1).

    Args:
        reader_pose: ``[..., 4]`` reader ``(x, y, z, ψ)`` (m, m, m, rad); ``z`` is
            its height ``h_R``.
        tag_xyz: ``[..., 3]`` tag position (m); ``z`` is its height ``h_T``.
            Broadcasts against ``reader_pose`` (e.g. ``[M, 3]`` particles against
            one ``[4]`` pose).
        params: :class:`ChannelParams`.
        softness: antenna step relaxation (rad), see :func:`~jaxnav.models.uhf_antenna.antenna_gain`.
        wavelength: optional per-read ``λ`` (m) overriding ``params.wavelength``
            (channel hopping).
    """
    _check_geometry(reader_pose, tag_xyz)
    validate_channel(params)
    lam = params.wavelength if wavelength is None else wavelength
    check_positive("wavelength", lam)
    if softness is not None:
        check_positive("softness", softness)
    return _power_scale(jnp.asarray(reader_pose), jnp.asarray(tag_xyz), params, softness, jnp.asarray(lam))


def received_power(reader_pose: Any, tag_xyz: Any, params: ChannelParams, h2: Any, **kwargs: Any) -> jax.Array:
    """Monostatic received power ``y = P_T η_T G_R² G_T² L² |h|⁴`` (W), [A] §4.1.2 / App. A.

    ``h2 = |h|²`` is the fading power (a ``Gamma(k, θ)`` draw in the model);
    ``kwargs`` go to :func:`power_scale`.
    """
    check_nonnegative("h2", h2)
    return power_scale(reader_pose, tag_xyz, params, **kwargs) * jnp.asarray(h2) ** 2


def mean_power(reader_pose: Any, tag_xyz: Any, params: ChannelParams, gamma: GammaParams, **kwargs: Any) -> jax.Array:
    """Expected received power ``E[y] = a·E[|h|⁴] = a·k(k+1)θ²`` (W)."""
    validate_gamma(gamma)
    k, th = gamma
    return power_scale(reader_pose, tag_xyz, params, **kwargs) * k * (k + 1.0) * th * th


def sample_rssi(key: jax.Array, a: Any, gamma: GammaParams, shape: tuple[int, ...] | None = None) -> jax.Array:
    """Draw ``y = a·g²``, ``g = |h|² ~ Gamma(k, θ)`` (W); ``shape`` defaults to the broadcast of ``a``, k, θ.

    ``jax.random.gamma`` is reparameterised, so the draw is differentiable in
    ``a``, ``k`` and ``θ``.
    """
    validate_gamma(gamma)
    check_positive("a", a)
    a = jnp.asarray(a)
    k = jnp.asarray(gamma.k, dtype=jnp.result_type(float))
    th = jnp.asarray(gamma.theta)
    if shape is None:
        shape = jnp.broadcast_shapes(a.shape, k.shape, th.shape)
    g = th * jax.random.gamma(key, jnp.broadcast_to(k, shape), shape)
    return a * g * g


def phase(distance: Any, wavelength: Any = DEFAULT_WAVELENGTH, theta_offset: Any = 0.0) -> jax.Array:
    """Predicted phase ``φ = (−4πD/λ + θ_off) mod 2π ∈ [0, 2π)`` (rad), [A] §4.1.2.

    Args:
        distance: reader–tag distance ``D`` (m).
        wavelength: ``λ`` (m), > 0; broadcasts (one λ per read for channel hopping).
        theta_offset: constant offset ``θ_off`` (rad) of cables and tag.

    A distance change of ``λ/2`` turns the phase once: the ambiguity of [A] §4.1.2.
    """
    check_positive("wavelength", wavelength)
    check_finite("theta_offset", theta_offset)
    raw = -4.0 * jnp.pi * jnp.asarray(distance) / jnp.asarray(wavelength) + jnp.asarray(theta_offset)
    return wrap_phase(raw)
