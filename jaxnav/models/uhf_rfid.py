"""UHF-RFID sensor models: RSSI and phase of a passive tag seen by a monostatic reader ([A] ch. 4).

**Overview**

A reader at ``g = (x_g, y_g, z_g, ψ_g)`` (m, m, m, rad: position and the yaw of
its antenna boresight, [A] §4.3.1) interrogates a passive tag at
``X = (x, y, z)`` (m). Ground is the plane ``z = 0``, so the heights of the
two-ray model are ``h_R = z_g`` and ``h_T = z``. Each read gives an RSSI
``y`` (a received power, **W**) and a phase ``φ`` (**rad**, in ``[0, 2π)``).
Every function here is pure, broadcasts over leading axes, and is
differentiable in its continuous arguments (tag position, ``k``, ``θ``, ``λ``,
``σ``, phase offset); :func:`jax.grad` never returns NaN for valid inputs.

**Received power ([A] §4.1.2, App. A, monostatic)**

::

    y = P_T · η_T · G_R² · G_T² · L² · |h|⁴,     |h|² ~ Gamma(k, θ)  (shape k, scale θ)

* ``P_T`` transmit power (W), ``η_T`` tag scattering efficiency, ``G_T`` tag
  antenna gain (linear), ``G_R`` the reader antenna gain towards the tag
  (:func:`antenna_gain`).
* Two-ray path loss ([A] §4.1.2 and App. A; :func:`two_ray_path_loss`), with
  ``D`` the reader–tag distance (m) and breakpoint ``D_c = 4π h_R h_T / λ``::

      L = (λ / (4π D))²        if D < D_c
      L = (h_R h_T / D²)²      if D ≥ D_c

  The two branches are equal at ``D = D_c`` (both are
  ``(λ² / (16π² h_R h_T))²``), so ``L`` is continuous; its slope jumps from
  ``D⁻²`` to ``D⁻⁴``.
* ``a = P_T η_T G_R² G_T² L²`` (:func:`power_scale`) is the deterministic
  part, so ``y = a·(|h|²)²`` ([A] §4.3.1) and ``E[y] = a·k(k+1)θ²``
  (:func:`mean_power`).

**Reader antenna gain ([A] §4.3.1, Fig. 4.2)**

The antenna vector is horizontal with yaw ``ψ``. [A] gives the gain at the
tag's direction angles ``(φ_T1, φ_T2, φ_T3)``: ``G_0`` when all three lie in
``[φ − φ_s, φ + φ_s]``, ``G_BLL`` when one lies outside
``[φ − 2φ_s, φ + 2φ_s]``, ``G_SLL`` elsewhere (with [A]'s simplification
``φ_s1 = φ_s2 = φ_s``: a main lobe of opening ``2φ_s`` and two side lobes of
``φ_s`` each). The thesis does not define the triple further; we read it as
the direction angles of the reader→tag vector against the axes of the
**antenna frame** (boresight, horizontal-left, up), compared with those of the
boresight ``(0, π/2, π/2)``, so that the pattern turns with the antenna. In
that frame the first direction angle is the off-boresight angle ``γ`` and the
other two deviate from ``π/2`` by at most ``γ``, so the rule is exactly::

    G_R = G_0      if γ ≤ φ_s
    G_R = G_SLL    if φ_s < γ ≤ 2φ_s
    G_R = G_BLL    if γ > 2φ_s,        γ = ∠(tag − reader, (cos ψ, sin ψ, 0)) ∈ [0, π]

(a cone pattern). :func:`antenna_gain` implements it; the test suite checks the
equivalence with the three-angle rule written out literally. The model is
piecewise constant, so its gradient with respect to positions is zero (never
NaN). For gradient work, ``softness=τ`` (rad) replaces each step by a logistic
``σ((edge − γ)/τ)``; ``τ → 0`` recovers the thesis's model.

**RSSI likelihood ([A] §4.3.1, App. C)**

With ``g = |h|² ~ Gamma(k, θ)`` and ``y = a·g²`` the density of ``y`` is::

    W_RSSI = f(y) = 1 / (2 θ^k Γ(k) a^{k/2}) · y^{(k−2)/2} · exp(−√(y/a) / θ),

computed in log form by :func:`log_w_rssi` (``gammaln``, no raw product).

**Phase ([A] §4.1.2) and the phase weight ([A] §4.3.2)**

::

    φ = (−4π D / λ + θ_off) mod 2π  ∈ [0, 2π)          (:func:`phase`)

``θ_off`` is the constant offset of cables and tag; [A]'s multipath term
``φ_n`` is the noise, not part of the prediction. The weight of a particle
uses [A]'s distance metric ``Δ`` (Alg. of §4.3.2, lines 1–4): phases are
turned into radii on circles of circumference ``λ/2`` and ``Δ`` is the distance
to the nearest peak, ``Δ = min(|ρ_φ − ρ_d|, λ/2 − |ρ_φ − ρ_d|) ∈ [0, λ/4]``.
That equals::

    Δ = (λ / 4π) · |wrap(φ_meas − φ_pred)|     (m),  wrap to [−π, π)

(:func:`phase_distance`), so a read just below ``2π`` and one just above ``0``
are both close to a prediction of ``0``. The weight is
``W_PHASE = N(Δ; 0, σ²)`` (:func:`log_w_phase`, normalised Gaussian density
in log form).

**σ convention.** ``Δ`` is a distance, so ``σ`` is in **metres**, as in
[A]: "σ_phase ≈ 0.05λ–0.2λ". The default is
``σ = DEFAULT_PHASE_SIGMA_FRACTION · λ = 0.1 λ``. In phase units this is
``σ_φ = 4π σ / λ`` rad (0.1 λ ↔ 1.26 rad).

The estimation of ``(k, θ)`` from an anchor tag ([A] §4.3.1, App. D–E) is
:mod:`jaxnav.models.uhf_calibration`.

**Units and helpers**

SI everywhere: m, rad, W; gains are linear (dimensionless). Readers report
dBm and antenna sheets dBi: :func:`dbm_to_watt`, :func:`watt_to_dbm`,
:func:`db_to_linear`, :func:`linear_to_db`. :func:`wrap_phase` maps a reader's
``[−π, π)`` phase to ``[0, 2π)``.

**Where the thesis is ambiguous, and what we chose**

* **Wavelength.** [A] §5.2 states λ = 0.173 m; a European UHF reader (866 MHz)
  has λ = c/f ≈ 0.346 m, so 0.173 m is likely λ/2. λ is a parameter
  of every function (per read, to allow channel hopping); the default
  :data:`DEFAULT_WAVELENGTH` is the thesis's 0.173 m (:data:`A_WAVELENGTH`) so
  that reproductions match [A]; real 866 MHz data should pass
  :data:`WAVELENGTH_866MHZ` (or :func:`wavelength_from_frequency`).
* **Antenna direction angles**: the antenna-frame reading above (a cone pattern).
* **Phase sign.** §4.1.2 has ``φ = −4πD/λ + θ``, but the Δ algorithm of §4.3.2
  compares ``(φ − θ) mod 2π`` with ``+4π (D mod λ/2)/λ``, which matches
  ``φ = +4πD/λ + θ`` instead. We keep §4.1.2's sign and compare the measured
  phase with the *predicted* one, which is [A]'s Δ for a consistent sign.
* **Numbers [A] does not give** (our choices, all parameters):
  ``G_0 = 8 dBi``, ``G_SLL = −2 dBi``, ``G_BLL = −12 dBi``, ``φ_s = 30°``
  (a typical UHF patch antenna: 60° main lobe, side lobes 10 dB and back lobe
  20 dB below the main lobe); ``P_T = 30 dBm = 1 W``, ``η_T = 0.25``,
  ``G_T = 1.64`` (a half-wave dipole, 2.15 dBi); :data:`DEFAULT_GAMMA`
  ``k = 2, θ = 0.5`` (unit mean fading power ``E|h|² = kθ = 1``, Nakagami
  m = 2); :data:`jaxnav.models.uhf_calibration.DEFAULT_MIN_READS` = 30.
* [A] writes the §4.3.1 weight as a product over time; here each function
  returns a log-density and the filter adds them.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaln

from jaxnav.core.validation import (
    all_positive,
    check_finite,
    check_nonnegative,
    check_positive,
    check_real,
    check_shape,
    check_type,
    is_concrete,
)
from jaxnav.core.weights import wrap_angle

__all__ = [
    "SPEED_OF_LIGHT",
    "A_WAVELENGTH",
    "WAVELENGTH_866MHZ",
    "DEFAULT_WAVELENGTH",
    "DEFAULT_PHASE_SIGMA_FRACTION",
    "AntennaParams",
    "DEFAULT_ANTENNA",
    "ChannelParams",
    "DEFAULT_CHANNEL",
    "GammaParams",
    "DEFAULT_GAMMA",
    "UHFReads",
    "validate_reads",
    "read_log_likelihood",
    "read_log_terms",
    "read_model_float32",
    "validate_read_model",
    "read_model_in_domain",
    "dbm_to_watt",
    "watt_to_dbm",
    "db_to_linear",
    "linear_to_db",
    "wavelength_from_frequency",
    "off_boresight_angle",
    "antenna_gain",
    "two_ray_breakpoint",
    "two_ray_path_loss",
    "power_scale",
    "received_power",
    "mean_power",
    "sample_rssi",
    "log_w_rssi",
    "rssi_log_likelihood",
    "wrap_phase",
    "phase",
    "phase_distance",
    "log_w_phase",
    "validate_antenna",
    "validate_channel",
    "validate_gamma",
    "validate_rssi",
    "valid_values",
    "read_mask",
    "validate_phase",
    "MAX_RSSI_W",
    "usable_reads",
    "UsableReads",
]

_TWO_PI = 2.0 * math.pi

SPEED_OF_LIGHT = 299_792_458.0
"""m/s."""

A_WAVELENGTH = 0.173
"""λ stated in [A] §5.2 (m); likely λ/2 of an 866 MHz reader (module docstring)."""

WAVELENGTH_866MHZ = SPEED_OF_LIGHT / 866e6
"""λ of a European UHF reader at 866 MHz, ≈ 0.3462 m."""

DEFAULT_WAVELENGTH = A_WAVELENGTH
"""Default λ (m), the thesis's value, for reproductions of [A]."""

DEFAULT_PHASE_SIGMA_FRACTION = 0.1
"""σ_phase = 0.1·λ (m), inside [A] §4.3.2's 0.05λ–0.2λ."""


# --------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------


class AntennaParams(NamedTuple):
    """Reader antenna of [A] §4.3.1 (a differentiable pytree).

    Attributes:
        g0: main-lobe gain ``G_0`` (linear).
        g_sll: side-lobe gain ``G_SLL`` (linear).
        g_bll: back-lobe gain ``G_BLL`` (linear).
        phi_s: ``φ_s`` (rad): main lobe within ``φ_s`` of the boresight (opening
            ``2φ_s``), side lobes from ``φ_s`` to ``2φ_s``; ``0 < φ_s ≤ π/2``.
    """

    g0: Any
    g_sll: Any
    g_bll: Any
    phi_s: Any


DEFAULT_ANTENNA = AntennaParams(g0=10.0**0.8, g_sll=10.0**-0.2, g_bll=10.0**-1.2, phi_s=math.pi / 6)
"""8 dBi main lobe, −2 dBi side lobes, −12 dBi back lobe, φ_s = 30° (our choice; [A] gives none)."""


class ChannelParams(NamedTuple):
    """Constants of the monostatic power model of [A] §4.1.2 / App. A (a pytree).

    Attributes:
        tx_power: ``P_T`` (W).
        tag_efficiency: ``η_T``, tag scattering efficiency (0 < η_T ≤ 1).
        tag_gain: ``G_T`` (linear).
        wavelength: ``λ`` (m).
        antenna: :class:`AntennaParams` of the reader.
    """

    tx_power: Any
    tag_efficiency: Any
    tag_gain: Any
    wavelength: Any
    antenna: AntennaParams


DEFAULT_CHANNEL = ChannelParams(
    tx_power=1.0, tag_efficiency=0.25, tag_gain=1.64, wavelength=DEFAULT_WAVELENGTH, antenna=DEFAULT_ANTENNA
)
"""P_T = 1 W (30 dBm), η_T = 0.25, G_T = 1.64 (dipole), λ = 0.173 m ([A] §5.2), :data:`DEFAULT_ANTENNA`."""


class GammaParams(NamedTuple):
    """``|h|² ~ Gamma(k, θ)``: shape ``k`` > 0, scale ``θ`` > 0 ([A] §4.1.2)."""

    k: Any
    theta: Any


DEFAULT_GAMMA = GammaParams(k=2.0, theta=0.5)
"""Fading parameters used until enough anchor reads exist, with unit mean fading power kθ = 1 (our choice)."""


class UHFReads(NamedTuple):
    """Reads of one tag in fixed slots: ``J`` per time step (a pytree; leading axes ``[..., T]`` allowed).

    Attributes:
        reader: ``[..., J, 4]`` reader pose ``(x, y, z, ψ)`` of each read (m, m, m, rad).
        rssi: ``[..., J]`` received power (W, > 0 where valid).
        phase: ``[..., J]`` phase (rad, in ``[0, 2π)``; see :func:`wrap_phase`).
        wavelength: ``[..., J]`` carrier wavelength of the read's channel (m).
        mask: ``[..., J]`` bool: the slot holds a read. Missing reads are masked,
            never zeros; masked slots may hold any finite value.
    """

    reader: Any
    rssi: Any
    phase: Any
    wavelength: Any
    mask: Any


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


# --------------------------------------------------------------------------------------
# Validation (host-side; value checks skipped for tracers)
# --------------------------------------------------------------------------------------


def validate_antenna(params: AntennaParams) -> None:
    """Gains finite and > 0; ``0 < φ_s ≤ π/2`` (so that ``2φ_s ≤ π`` leaves a back lobe)."""
    check_positive("antenna.g0", params.g0)
    check_positive("antenna.g_sll", params.g_sll)
    check_positive("antenna.g_bll", params.g_bll)
    check_positive("antenna.phi_s", params.phi_s)
    if is_concrete(params.phi_s) and np.any(np.asarray(params.phi_s) > math.pi / 2 + 1e-7):
        raise ValueError(
            f"antenna.phi_s must be in (0, π/2] rad (main lobe 2φ_s, side lobes up to 2φ_s ≤ π), "
            f"got {np.asarray(params.phi_s)}"
        )


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


def valid_values(x: Any, mask: Any) -> np.ndarray | None:
    """The values of ``x`` where ``mask`` is true (all of them for ``mask=None``) on the host; ``None`` for tracers."""
    if not (is_concrete(x) and is_concrete(mask)):
        return None
    v = np.asarray(x)
    if mask is None:
        return v.ravel()
    return np.broadcast_to(v, np.broadcast_shapes(v.shape, np.shape(mask)))[
        np.broadcast_to(np.asarray(mask, bool), np.broadcast_shapes(v.shape, np.shape(mask)))
    ]


MAX_RSSI_W = 1.0
"""The largest received power an RSSI may report, in W (1 W = 30 dBm). A UHF reader transmits at most
4 W EIRP, and a backscattered read is many orders of magnitude weaker."""


def validate_rssi(y: Any, mask: Any = None, name: str = "y", max_w: float | None = None) -> None:
    """An RSSI must be a received power: finite and > 0 (W), and with ``max_w`` at most that (a
    reader's reads: :data:`MAX_RSSI_W`; the density :func:`log_w_rssi` takes any positive ``y``).
    Masked entries are not checked."""
    v = valid_values(y, mask)
    if v is None:
        return
    ok = np.isfinite(v) & (v > 0) & (v <= (np.inf if max_w is None else max_w))
    if not np.all(ok):
        bad = v[~ok]
        most = "" if max_w is None else f" of at most {max_w:g} W"
        raise ValueError(
            f"{name} (RSSI) must be a positive received power in W{most}, got {bad[:5].tolist()}; convert "
            "dBm with dbm_to_watt, and mask missing reads instead of writing 0"
        )


def validate_phase(phi: Any, name: str = "phi_meas") -> None:
    """A measured phase must be finite and in ``[0, 2π)`` rad (use :func:`wrap_phase` first)."""
    if not is_concrete(phi):
        return
    v = np.asarray(phi)
    if not np.all(np.isfinite(v)) or np.any(v < 0) or np.any(v >= _TWO_PI):
        raise ValueError(
            f"{name} must be a phase in [0, 2π) rad, got values in [{np.nanmin(v):.6g}, {np.nanmax(v):.6g}]"
            f"{' (with NaN/inf)' if not np.all(np.isfinite(v)) else ''}; readers reporting [-π, π) "
            "need wrap_phase"
        )


def validate_reads(reads: UHFReads, name: str = "reads") -> None:
    """Host-side checks of :class:`UHFReads`: consistent shapes, a bool mask, and on the valid
    slots a positive RSSI (W), a phase in ``[0, 2π)`` and a positive wavelength (value checks
    are skipped for tracers)."""
    if not isinstance(reads, UHFReads):
        raise ValueError(f"{name} must be a UHFReads, got {type(reads).__name__}")
    shape = np.shape(reads.mask)
    if len(shape) < 1:
        raise ValueError(f"{name}.mask must have a read-slot axis, got shape {shape}")
    for field in ("rssi", "phase", "wavelength"):
        if np.shape(getattr(reads, field)) != shape:
            raise ValueError(
                f"{name}.{field} must have the mask's shape {shape}, got {np.shape(getattr(reads, field))}"
            )
    if np.shape(reads.reader) != shape + (4,):
        raise ValueError(f"{name}.reader must have shape {shape + (4,)}, got {np.shape(reads.reader)}")
    mask_dtype = getattr(reads.mask, "dtype", None)  # a tracer has a dtype but no value
    if mask_dtype is None:
        mask_dtype = np.asarray(reads.mask).dtype
    if np.result_type(mask_dtype) != np.bool_:
        raise ValueError(f"{name}.mask must be boolean, got {mask_dtype}")
    for field in ("reader", "rssi", "phase", "wavelength"):
        check_real(f"{name}.{field}", getattr(reads, field))
    if not is_concrete(reads):
        return
    m = np.asarray(reads.mask)
    for field in ("reader", "rssi", "phase", "wavelength"):
        if not np.all(np.isfinite(np.asarray(getattr(reads, field)))):
            raise ValueError(
                f"{name}.{field} must be finite everywhere (masked slots too: fill them with any finite value)"
            )
    if m.any():
        validate_rssi(np.asarray(reads.rssi)[m], name=f"{name}.rssi", max_w=MAX_RSSI_W)
        validate_phase(np.asarray(reads.phase)[m], name=f"{name}.phase")
        check_positive(f"{name}.wavelength", np.asarray(reads.wavelength)[m])
        if np.any(np.asarray(reads.reader)[..., 2][m] < 0):
            raise ValueError(f"{name}.reader z (the reader's height above the ground z = 0) must be ≥ 0")


def _check_last_dim(name: str, x: Any, n: int) -> None:
    shape = np.shape(x)
    if len(shape) < 1 or shape[-1] != n:
        raise ValueError(f"{name} must have shape (..., {n}), got {tuple(shape)}")


# --------------------------------------------------------------------------------------
# Antenna gain ([A] §4.3.1)
# --------------------------------------------------------------------------------------


def _safe_sqrt(x: jax.Array) -> jax.Array:
    """``sqrt(x)`` with a zero (not infinite) gradient at ``x = 0``."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def _off_boresight(direction: jax.Array, heading: jax.Array) -> jax.Array:
    d = jnp.asarray(direction)
    c, s = jnp.cos(heading), jnp.sin(heading)
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    dot = dx * c + dy * s
    # |d × b| for b = (c, s, 0): (−dz·s, dz·c, dx·s − dy·c)
    lateral = dx * s - dy * c
    cross = _safe_sqrt(dz * dz + lateral * lateral)
    zero = (cross == 0) & (dot == 0)
    return jnp.where(zero, 0.0, jnp.arctan2(cross, jnp.where(zero, 1.0, dot)))


def off_boresight_angle(direction: Any, heading: Any) -> jax.Array:
    """Angle ``γ ∈ [0, π]`` (rad) between ``direction [..., 3]`` and the boresight.

    ``direction`` is the reader→tag vector (any length, m); the boresight is the
    horizontal unit vector ``(cos ψ, sin ψ, 0)`` of yaw ``heading = ψ`` (rad),
    [A] §4.3.1 ("the antenna vector is always ... parallel to the ground").
    Computed as ``atan2(|d × b|, d·b)``: accurate near 0 and π, gradient finite
    everywhere (zero at ``d = 0``).
    """
    _check_last_dim("direction", direction, 3)
    return _off_boresight(direction, jnp.asarray(heading))


def antenna_gain(
    direction: Any, heading: Any, params: AntennaParams = DEFAULT_ANTENNA, softness: Any = None
) -> jax.Array:
    """Reader antenna gain ``G_R`` (linear) towards ``direction [..., 3]``, [A] §4.3.1.

    ``G_0`` for ``γ ≤ φ_s`` (main lobe, opening ``2φ_s``), ``G_SLL`` for
    ``φ_s < γ ≤ 2φ_s`` (side lobes), ``G_BLL`` beyond (back lobe), with ``γ``
    the off-boresight angle (:func:`off_boresight_angle`; module docstring for
    why this is [A]'s three-direction-angle rule). Piecewise constant: the
    gradient with respect to ``direction``/``heading`` is zero, never NaN.

    Args:
        direction: reader→tag vector ``tag − reader`` (m), shape ``[..., 3]``.
        heading: boresight yaw ``ψ`` (rad), broadcastable to ``direction[..., 0]``.
        params: :class:`AntennaParams`.
        softness: ``None`` for [A]'s step model, or ``τ > 0`` (rad): each step
            becomes a logistic ``σ((edge − γ)/τ)``, a smooth relaxation for
            gradient work.
    """
    _check_last_dim("direction", direction, 3)
    validate_antenna(params)
    if softness is not None:
        check_positive("softness", softness)
    params = AntennaParams(*(jnp.asarray(p) for p in params))
    return _gain_nocheck(jnp.asarray(direction), jnp.asarray(heading), params, softness)


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


def _gain_nocheck(direction, heading, params, softness):
    gamma = _off_boresight(direction, heading)
    g0, gs, gb, ps = params
    if softness is None:
        return jnp.where(gamma <= ps, g0, jnp.where(gamma <= 2.0 * ps, gs, gb))
    inner = jax.nn.sigmoid((ps - gamma) / softness)
    outer = jax.nn.sigmoid((2.0 * ps - gamma) / softness)
    return gb + (gs - gb) * outer + (g0 - gs) * inner


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
        softness: antenna step relaxation (rad), see :func:`antenna_gain`.
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
        a: ``P_T η_T G_R² G_T² L²`` (W), > 0 (:func:`power_scale`).
        k, theta: Gamma shape and scale, > 0.
    """
    validate_rssi(y)
    check_positive("a", a)
    validate_gamma(GammaParams(k, theta))
    return _log_w_rssi(jnp.asarray(y), jnp.asarray(a), jnp.asarray(k), jnp.asarray(theta))


def read_mask(shape: tuple[int, ...], mask: Any) -> jax.Array:
    """``mask`` broadcast to ``shape`` as bool (every read valid for ``mask=None``)."""
    if mask is None:
        return jnp.ones(shape, bool)
    return jnp.broadcast_to(jnp.asarray(mask, bool), shape)


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
# Phase ([A] §4.1.2) and phase weight ([A] §4.3.2)
# --------------------------------------------------------------------------------------


def wrap_phase(phi: Any) -> jax.Array:
    """Wrap angles to ``[0, 2π)`` (rad): the reader's phase convention used here."""
    r = wrap_angle(jnp.asarray(phi) - jnp.pi) + jnp.pi
    # float rounding can give exactly 2π for inputs just below a multiple of 2π
    return jnp.where(r >= _TWO_PI, r - _TWO_PI, r)


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


def phase_distance(phi_meas: Any, phi_pred: Any, wavelength: Any = DEFAULT_WAVELENGTH) -> jax.Array:
    """[A]'s distance metric ``Δ`` (m), §4.3.2: ``(λ/4π)·|wrap(φ_meas − φ_pred)| ∈ [0, λ/4]``.

    The distance, on a circle of circumference ``λ/2``, between the radius of the
    measured phase and the particle's (module docstring): symmetric across the
    ``0/2π`` wrap, zero for a noiseless read.

    Args:
        phi_meas: measured phase (rad) in ``[0, 2π)``.
        phi_pred: predicted phase (rad), e.g. :func:`phase` of the particle.
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


def read_model_float32(channel: ChannelParams, gamma: GammaParams) -> tuple[ChannelParams, GammaParams]:
    """``(channel, gamma)`` with every leaf a float32 array (a filter's differentiable params)."""
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return (
        ChannelParams(*(f32(c) for c in channel[:4]), AntennaParams(*(f32(c) for c in channel.antenna))),
        GammaParams(f32(gamma.k), f32(gamma.theta)),
    )


class UsableReads(NamedTuple):
    """Read slots with the unusable ones dropped (:func:`usable_reads`): ``rssi``, ``phase`` and
    ``wavelength`` (harmless values in dropped slots), the new ``mask`` and ``num_ignored``, the
    valid slots dropped."""

    rssi: jax.Array
    phase: jax.Array
    wavelength: jax.Array
    mask: jax.Array
    num_ignored: jax.Array


def usable_reads(rssi: Any, phase: Any, wavelength: Any, mask: Any) -> UsableReads:
    """The read slots a filter may use: ``mask`` and an RSSI in ``(0, MAX_RSSI_W]`` W, a phase in
    ``[0, 2π]`` rad and a finite positive wavelength. The host checks refuse other values in valid
    slots; inside a caller's ``jit`` the filters drop such slots, count them, and put harmless
    values (1 W, 0 rad, 1 m) in their place, so that no NaN reaches a likelihood."""
    mask = jnp.asarray(mask, bool)
    ok = jnp.isfinite(rssi) & (rssi > 0) & (rssi <= MAX_RSSI_W)
    ok &= (phase >= 0) & (phase <= 2.0 * math.pi) & jnp.isfinite(wavelength) & (wavelength > 0)
    usable = mask & ok
    return UsableReads(
        jnp.where(usable, rssi, 1.0),
        jnp.where(usable, phase, 0.0),
        jnp.where(usable, wavelength, 1.0),
        usable,
        jnp.sum(mask & ~usable, dtype=jnp.int32),
    )


def validate_read_model(channel: ChannelParams, gamma: GammaParams, phase_sigma: Any, prefix: str = "params") -> None:
    """Host-side checks of the parameters :func:`read_log_likelihood` takes: a :class:`ChannelParams`
    and a :class:`GammaParams` of scalars, and σ_phase a positive scalar (m)."""
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


def _log_gain_stepped(dot, dist, params: AntennaParams):
    """``log G_R`` of the stepped cone model from ``d·b`` and ``|d|``: no angle is computed.

    ``γ ≤ φ`` ⟺ ``d·b ≥ cos(φ)·|d|`` for ``γ, φ ∈ [0, π]`` (cos decreases there), so the
    lobe test needs no ``atan2`` ([A] §4.3.1; :func:`antenna_gain` gives the same gain).
    """
    g0, gs, gb, ps = params
    main = dot >= jnp.cos(ps) * dist
    side = dot >= jnp.cos(2.0 * ps) * dist
    return jnp.where(main, jnp.log(g0), jnp.where(side, jnp.log(gs), jnp.log(gb)))


def _log_power_scale_from_geometry(d, d2, reader_pose, tag_xyz, params: ChannelParams, wavelength, softness):
    """``log a`` (a in W) with ``d = (dx, dy, dz) = tag − reader`` and ``d2 = |d|²`` (≥ the clamp); one ``log`` per pair.

    ``log a = log(P_T η_T G_T²) + 2 log G_R + 2 log L`` with ``log L = 2 log(λ/4π) − log D²``
    (free space) or ``2 log(h_R h_T) − 2 log D²`` (plane earth), the branch chosen by
    ``D² < D_c²`` ([A] §4.1.2): the same number as ``log`` :func:`power_scale`, without its
    powers and square roots. ``−inf`` for a zero height in the plane-earth branch.
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

    Jit-side (no host checks; validate the reads with :func:`validate_reads`).
    Everything broadcasts to ``[..., J]``: ``reader_pose [..., J, 4]``,
    ``tag_xyz [..., J, 3]``, ``theta_offset``, ``rssi``, ``phi``,
    ``wavelength``, ``mask`` ``[..., J]``. A particle filter over tags
    broadcasts the tag (``[M, 1, 3]``) against fixed readers (``[1, J, 4]``);
    one over the robot broadcasts the reader against fixed anchors. The
    static flags ``use_rssi`` / ``use_phase`` pick the weighting. Returns ``[...]``.
    The per-read terms are :func:`read_log_terms`; the tests check them against
    :func:`log_w_rssi` of :func:`power_scale` plus :func:`log_w_phase`.
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
