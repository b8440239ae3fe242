"""Simulated UHF-RFID reader: RSSI and phase reads of passive tags under light and strong multipath ([A] §4.1.2, §5.2).

**Overview**

A reader antenna on a robot moves along a known path of poses
``r_t = (x, y, z, ψ)`` (m, m, m, rad; ``ψ`` the yaw of the boresight) and
reads ``G`` static tags at ``p_g = (x, y, z)`` (m), ``J`` times per step. The
output is a :class:`~jaxnav.models.uhf_reads.UHFReads` with leading axes
``[G, T, J]`` (RSSI in W, phase in rad in ``[0, 2π)``, wavelength in m, a
validity mask). The sensor model it builds on is
:mod:`jaxnav.models.uhf_rfid` (monostatic power ``y = P_T η_T G_R² G_T² L² |h|⁴``
with the two-ray ``L``, phase ``φ = −4πD/λ + θ_off``); its functions
(:func:`~jaxnav.models.uhf_channel.power_scale`,
:func:`~jaxnav.models.uhf_channel.sample_rssi`,
:func:`~jaxnav.models.uhf_channel.phase`,
:func:`~jaxnav.models.uhf_antenna.antenna_gain`) are used here, not re-derived.

.. rubric:: Equations implemented (per tag ``p``, reader pose ``r``, wavelength ``λ``, read ``j``)

Let ``D = |p − r_xyz|`` and ``a = P_T η_T G_R(p − r)² G_T² L(D, h_R, h_T, λ)²``
(:func:`~jaxnav.models.uhf_channel.power_scale`: the deterministic part of
[A] §4.1.2). Wall reflections use the **image method**: the room is the box
``[lo, hi]``; its four vertical walls and its ceiling (indices ``0 … 4`` =
``x = lo_x, x = hi_x, y = lo_y, y = hi_y, z = hi_z``) reflect with real
amplitude coefficients ``Γ_w``. The floor is *not* an image wall: the ground
reflection is already inside the two-ray ``L`` of the model. Image ``i`` is
the tag reflected across a sequence of walls ``w_1 … w_n`` (a reflection
across the plane ``x_a = c`` maps ``x_a ↦ 2c − x_a``); its coefficient is
``Γ_i = Π Γ_w``, its path length ``d_i = |p_i − r_xyz|``. ``order = 1`` uses the
5 first-order images, ``order = 2`` adds the 12 distinct second-order ones
(two reflections across different walls; ``x⁻x⁺`` and ``x⁺x⁻`` differ, two
perpendicular walls in either order give one image). The **composite one-way
channel relative to the direct ray** is::

    h_mp = 1 + Σ_i Γ_i · √(G_R(p_i − r) / G_R(p − r)) · (D / d_i) · exp(−j 2π (d_i − D) / λ)

(each ray: amplitude ∝ reflection coefficient · √(reader antenna gain toward
its image) / path length, phase −2π·path/λ, all relative to the direct ray,
whose free-space amplitude is ``√G_R · λ/(4πD)``; the tag gain ``G_T`` is
taken isotropic, the same for every ray). With no walls (all ``Γ_w = 0``)
``h_mp = 1`` exactly. By reciprocity the monostatic round-trip channel is the
square of the one-way channel, so ``|h_mp|`` enters like [A]'s ``|h|``::

    y_j = a · |h_mp|⁴ · g_j²,            g_j = |h_f|² ~ Gamma(k, θ),  k θ = 1      (RSSI, W)
    φ_j = (−4πD/λ + 2·arg h_mp + θ_off + ε_j)  mod 2π,   ε_j ~ N(0, σ_φ²)            (phase, rad)

i.e. [A]'s ``|h|⁴ = |h_mp|⁴ · |h_f|⁴``: deterministic multipath from the
walls times an i.i.d. Gamma fading ``g_j`` (:func:`~jaxnav.models.uhf_channel.sample_rssi`
with ``a·|h_mp|⁴``), and the phase is the angle of the composite round-trip
channel ``(h_mp e^{−j2πD/λ})²`` plus the offset and a Gaussian noise
(:func:`~jaxnav.models.uhf_channel.phase` with offset ``θ_off + 2 arg h_mp + ε``).
The squared-Gamma model of [A] is exact for ``h_mp = 1`` ("light") and
mis-specified otherwise ("strong"): along a path ``|h_mp|⁴`` has fading dips
and several maxima, so RSSI vs reader position is multimodal ([A] Fig. 5.2,
§5.2).

Detection. The power incident on the tag is
``P_inc = P_T G_R G_T L |h_mp|² g = √(y P_T / η_T)``; a read exists when the tag
is powered, ``P_inc ≥ tag_sensitivity``, the reader hears it,
``y ≥ sensitivity``, and an independent Bernoulli(``read_probability``)
succeeds (collisions, protocol losses). Missing reads are masked (never
zeros): their slots hold the finite dummies ``rssi = MASKED_RSSI = 1 W``,
``phase = 0`` and the true reader pose and wavelength, which pass
:func:`~jaxnav.models.uhf_reads.validate_reads`.

.. rubric:: Spatially correlated fading (option, off by default)

With ``Multipath.correlation_length = ℓ`` (m; :func:`correlated_fading`,
default :data:`FADING_CORRELATION_LENGTH` = λ/2 of
:data:`~jaxnav.models.uhf_channel.DEFAULT_CHANNEL`) the fading ``g_j`` of the
equations above is no longer drawn independently for every tag: it is the
value at the tag of a random field drawn afresh for every read slot
``(t, j)`` and shared by all the tags, so two tags closer than ``ℓ`` fade
together and two tags farther apart fade nearly independently (the anchor
tag's fading describes the tag's only when it is close, [A] §5.2)::

    g_j(p) = θ · B_j · Σ_{i=1…m} |z_ij(p)|²,        m = ⌈k⌉,  B_j ~ Beta(k, m − k)  (B_j = 1 for a whole k)
    z_ij(p) = Σ_{n=1…N} c_ijn · exp(j (π/ℓ) u_ijn · p),   c_ijn ~ CN(0, 1/N),  u_ijn uniform on the unit sphere

(``p`` in m, ``π/ℓ`` in rad/m; ``N`` = ``fading_waves``, default
:data:`FADING_WAVES` = 64). Each ``z`` is a sum of ``N`` plane waves of
wavenumber ``π/ℓ`` from random directions with complex Gaussian amplitudes: the
random-phasor (spectral) form of a diffuse 3D field, a random version of the
image sources above. At one point ``z ~ CN(0, 1)`` exactly, whatever the
directions, so ``Σ|z|² ~ Gamma(m, 1)`` and ``B·Gamma(m, 1) ~ Gamma(k, 1)``:
``g ~ Gamma(k, θ)``, the preset's marginal, exactly. Between two points a
distance ``d`` (m) apart, ``E[z(p) z*(p')] = ρ(d) = sin(πd/ℓ)/(πd/ℓ)``
(the isotropic 3D field; ``ℓ = λ/2`` gives the classical
``sin(2πd/λ)/(2πd/λ)`` of waves at the carrier, first zero at ``d = λ/2``),
and the fading powers are correlated by (:func:`fading_correlation`)::

    corr(g(p), g(p')) = (m − k)/(m + 1) + (k + 1)/(m + 1) · [ρ(d)² + (1 − ρ(d)²)/N]

(``ρ² + (1 − ρ²)/N`` for a whole ``k``; the ``1/N`` floor is the finite
number of waves). We chose this field over a Gaussian field on a grid or a
Cholesky factor over the tags because it is exact at any point without a
grid, its correlation is closed form, a tag's value depends on its own
position only (a subset of the tags with their ``tag_ids`` still reproduces
the full run's reads), and it is a sum of cosines: jittable, vmappable and
differentiable in the positions, ``θ`` and ``ℓ`` (``k`` fixes the number of
fields, a shape: it must be concrete, or ``fading_fields = m ≥ k`` given).
The phase and the wall term ``h_mp`` are unchanged; so are the read
and phase keys, so switching the option on changes the RSSI only.

Channel hopping: ``wavelengths`` is one λ or an array ``[C]`` cycled over
steps (step ``t`` uses ``λ[t mod C]`` for its ``J`` reads).

Keys: tag ``g`` with id ``tag_ids[g]`` (default ``g``) and step ``t`` draw from
``k_gt = fold_in(fold_in(key, tag_ids[g]), t)``, split into
``(k_fade, k_phase, k_read)``. A tag's reads therefore depend only on its own
id, position and offset, never on the other tags or their order. The
correlated fading field of step ``t`` draws from ``fold_in(k_field, t)``, ``k_field``
made of two words of ``key``'s own stream (no tag's ``fold_in`` gives it).

.. rubric:: Multipath presets (all numbers **ours**; [A] gives none)

* ``"light"`` (:data:`LIGHT_MULTIPATH`): no walls (``Γ = 0``); fading
  ``k = 20, θ = 0.05`` (``kθ = 1``, RSSI spread ≈ 1.9 dB); phase noise
  ``σ_φ = 3°``.
* ``"strong"`` (:data:`STRONG_MULTIPATH`): the room :data:`DEFAULT_ROOM`
  ``[−1, 3] × [−1.5, 3.5] × [0, 2.8]`` m around [A]'s 2 × 3 × 2 m search box
  :data:`SEARCH_BOX_A` (0.5–1.5 m of clearance, a 2.8 m ceiling) with
  ``Γ = −0.6`` on the four walls (between concrete, ``|Γ| ≈ 0.3–0.5``, and
  metal shelving, ``|Γ| → 1``; the sign is the phase inversion of a horizontally
  polarised reflection) and ``Γ = −0.4`` on the ceiling, second-order images; a smaller-``k`` (stronger)
  diffuse fading ``k = 8, θ = 0.125``; phase noise ``σ_φ = 10°``.
* Reader sensitivity :data:`DEFAULT_SENSITIVITY` = −80 dBm (typical of UHF
  readers, −70 to −85 dBm); tag chip sensitivity
  :data:`DEFAULT_TAG_SENSITIVITY` = −18 dBm (a typical passive UHF chip). With
  :data:`~jaxnav.models.uhf_channel.DEFAULT_CHANNEL` the forward link binds first
  (as in real passive systems): in the main lobe tags are read to ≈ 11 m, in
  the back lobe only to ≈ 1.1 m.

**Paths**

The reader's paths are defined in :mod:`jaxnav.sim.trajectories` (its
"Paths of a UHF reader") and re-exported here:
:func:`~jaxnav.sim.trajectories.line_path`, the straight pass of [A]
Fig. 5.2, and :func:`~jaxnav.sim.trajectories.lawnmower_path`, parallel
passes that make a tag observable in 3D.

Units: SI (m, rad, W). All array functions are jittable and differentiable in
the continuous parameters (positions, ``Γ``, room, ``k``, ``θ``, ``σ_φ``, λ, and
the correlated fading's ``ℓ``; with correlated fading ``k`` sets the number of
fields, a shape, and is not differentiated); the detection mask and the
piecewise-constant antenna gain are steps (pass ``softness`` for a smooth gain).
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.filter import check_key
from jaxnav.core.validation import (
    check_finite,
    check_magnitude,
    check_nonnegative,
    check_positive,
    check_positive_int,
    check_shape,
    is_concrete,
)
from jaxnav.core.weights import wrap_angle
from jaxnav.models import uhf_rfid
from jaxnav.models.uhf_rfid import DEFAULT_CHANNEL, ChannelParams, GammaParams, UHFReads
from jaxnav.sim.trajectories import DEFAULT_READER_HEIGHT, lawnmower_path, line_path

__all__ = [
    "SEARCH_BOX_A",
    "DEFAULT_READER_HEIGHT",
    "DEFAULT_SENSITIVITY",
    "DEFAULT_TAG_SENSITIVITY",
    "MASKED_RSSI",
    "MASKED_PHASE",
    "WALL_NAMES",
    "Room",
    "DEFAULT_ROOM",
    "Multipath",
    "LIGHT_MULTIPATH",
    "STRONG_MULTIPATH",
    "MULTIPATH_NAMES",
    "get_multipath",
    "FADING_CORRELATION_LENGTH",
    "FADING_WAVES",
    "correlated_fading",
    "fading_correlation",
    "image_sequences",
    "line_path",
    "lawnmower_path",
    "anchor_position",
    "CompositeChannel",
    "composite_channel",
    "expected_rssi",
    "simulate_reads",
    "anchor_power_scale",
    "validate_multipath",
    "multipath_gain",
]

SEARCH_BOX_A = (np.array([0.0, 0.0, 0.0]), np.array([2.0, 3.0, 2.0]))
"""[A] §5.2's 2 m × 3 m × 2 m search box ``(lo, hi)`` (m); the placement at the origin is ours."""

DEFAULT_SENSITIVITY = 1e-11
"""Reader sensitivity −80 dBm = 1e-11 W (ours, as typical UHF readers hear −70 to −85 dBm)."""

DEFAULT_TAG_SENSITIVITY = 10.0 ** (-4.8)
"""Tag chip sensitivity −18 dBm ≈ 1.58e-5 W of incident power (ours, a typical passive UHF chip)."""

MASKED_RSSI = 1.0
"""RSSI (W) written in masked slots, finite, positive (passes validation) and absurdly large, so misuse shows."""

MASKED_PHASE = 0.0
"""Phase (rad) written in masked slots."""

WALL_NAMES = ("x_lo", "x_hi", "y_lo", "y_hi", "ceiling")
"""The reflecting surfaces of a :class:`Room`, in the order of ``Room.reflection``."""

_WALL_AXIS_SIDE = ((0, 0), (0, 1), (1, 0), (1, 1), (2, 1))  # (axis, 0 = lo / 1 = hi)


class Room(NamedTuple):
    """A box room for the image method (a differentiable pytree).

    Attributes:
        lo: ``[3]`` lower corner (m); ``lo[2]`` is the floor, ``0`` (the floor is
            the two-ray ground of the model, never an image wall).
        hi: ``[3]`` upper corner (m); ``hi[2]`` is the ceiling height.
        reflection: ``[5]`` real amplitude reflection coefficients ``Γ_w`` of
            :data:`WALL_NAMES` (``|Γ| ≤ 1``; 0 = no wall).
    """

    lo: Any
    hi: Any
    reflection: Any


DEFAULT_ROOM = Room(
    lo=np.array([-1.0, -1.5, 0.0], np.float32),
    hi=np.array([3.0, 3.5, 2.8], np.float32),
    reflection=np.array([-0.6, -0.6, -0.6, -0.6, -0.4], np.float32),
)
"""The room of the strong preset (ours), 4 × 5 × 2.8 m around :data:`SEARCH_BOX_A` (walls Γ = −0.6, ceiling
Γ = −0.4)."""


class Multipath(NamedTuple):
    """Multipath environment (a differentiable pytree; module docstring for the equations).

    Attributes:
        gamma: :class:`~jaxnav.models.uhf_channel.GammaParams` of the diffuse fading
            ``g = |h_f|² ~ Gamma(k, θ)``.
        phase_sigma: ``σ_φ`` (rad), sd of the Gaussian phase noise ``ε``.
        room: :class:`Room`; all ``Γ = 0`` gives the light (two-ray + Gamma) model.
        correlation_length: ``None`` (default): the fading ``g`` is drawn
            independently for every tag; ``ℓ > 0`` (m): the spatially correlated
            fading field of the module docstring, correlation length ``ℓ`` (the first
            zero of the field's correlation ``sin(πd/ℓ)/(πd/ℓ)``).
    """

    gamma: GammaParams
    phase_sigma: Any
    room: Room
    correlation_length: Any = None


LIGHT_MULTIPATH = Multipath(
    gamma=GammaParams(k=20.0, theta=0.05),
    phase_sigma=math.radians(3.0),
    room=DEFAULT_ROOM._replace(reflection=np.zeros(5, np.float32)),
)
"""Two-ray mean power × Gamma(20, 0.05) fading, 3° phase noise, no walls (ours)."""

STRONG_MULTIPATH = Multipath(
    gamma=GammaParams(k=8.0, theta=0.125),
    phase_sigma=math.radians(10.0),
    room=DEFAULT_ROOM,
)
"""Wall images of :data:`DEFAULT_ROOM` × Gamma(8, 0.125) fading, 10° phase noise (ours)."""

MULTIPATH_NAMES = {"light": LIGHT_MULTIPATH, "strong": STRONG_MULTIPATH}
"""The multipath presets by name (``"light"``, ``"strong"``)."""

FADING_CORRELATION_LENGTH = DEFAULT_CHANNEL.wavelength / 2.0
"""Default correlation length ``ℓ`` of the correlated fading (m): λ/2 of :data:`~jaxnav.models.uhf_channel.DEFAULT_CHANNEL`
(0.0865 m for [A]'s λ = 0.173 m), where [A] §5.2 says two tags stop being correlated."""

FADING_WAVES = 64
"""Plane waves ``N`` per Gaussian field of the correlated fading: the power correlation keeps a floor of about
``1/N`` (0.016) beyond ``ℓ``; the cost per read is ``⌈k⌉·N`` cosines per tag."""


def get_multipath(multipath: str | Multipath) -> Multipath:
    """``"light"`` / ``"strong"`` → the preset :class:`Multipath`; a :class:`Multipath` is validated and returned."""
    if isinstance(multipath, str):
        if multipath not in MULTIPATH_NAMES:
            raise ValueError(f"multipath must be one of {sorted(MULTIPATH_NAMES)} or a Multipath, got {multipath!r}")
        return MULTIPATH_NAMES[multipath]
    if not isinstance(multipath, Multipath):
        raise ValueError(
            f"multipath must be one of {sorted(MULTIPATH_NAMES)} or a Multipath, got {type(multipath).__name__}"
        )
    validate_multipath(multipath)
    return multipath


def correlated_fading(multipath: str | Multipath = "strong", length: Any = FADING_CORRELATION_LENGTH) -> Multipath:
    """The preset (or :class:`Multipath`) ``multipath`` with spatially correlated fading of correlation length ``length`` (m).

    ``simulate_reads(key, path, tags, multipath=correlated_fading("strong"))``: the
    module docstring's field, ``ℓ = λ/2`` by default.
    """
    mp = get_multipath(multipath)._replace(correlation_length=length)
    validate_multipath(mp)
    return mp


def fading_correlation(
    distance: Any, k: Any, length: Any = FADING_CORRELATION_LENGTH, waves: int = FADING_WAVES
) -> jax.Array:
    """Correlation coefficient of the correlated fading ``g`` at two points ``distance`` (m) apart (module docstring).

    ``corr = (m − k)/(m + 1) + (k + 1)/(m + 1) · [ρ² + (1 − ρ²)/N]`` with
    ``ρ(d) = sin(πd/ℓ)/(πd/ℓ)``, ``m = ⌈k⌉``, ``N = waves``, ``ℓ = length`` (m);
    ``k`` is the fading's Gamma shape (a concrete number: it sets ``m``). Broadcasts over
    ``distance``; traceable in ``distance`` and ``length``.
    """
    check_nonnegative("distance", distance)
    check_positive("length", length)
    check_positive("k", k)
    n = check_positive_int("waves", waves)
    k = float(np.asarray(k))
    m = math.ceil(k)
    rho = jnp.sinc(jnp.asarray(distance) / jnp.asarray(length))  # numpy's sinc: sin(πx)/(πx)
    power = rho * rho + (1.0 - rho * rho) / n
    return (m - k) / (m + 1) + (k + 1) / (m + 1) * power


def validate_multipath(mp: Multipath) -> None:
    """``k, θ > 0``, ``σ_φ ≥ 0``, room ``lo < hi`` (``[3]`` each) with the floor at 0, ``|Γ| ≤ 1`` (``[5]``),
    ``correlation_length`` ``None`` or a scalar ``> 0``."""
    if not isinstance(mp, Multipath):
        raise ValueError(f"multipath must be a Multipath, got {type(mp).__name__}")
    uhf_rfid.validate_gamma(mp.gamma)
    if mp.correlation_length is not None:
        check_shape("multipath.correlation_length", mp.correlation_length, ())
        check_positive("multipath.correlation_length", mp.correlation_length)
    check_nonnegative("multipath.phase_sigma", mp.phase_sigma)
    check_shape("multipath.room.lo", mp.room.lo, (3,))
    check_shape("multipath.room.hi", mp.room.hi, (3,))
    check_shape("multipath.room.reflection", mp.room.reflection, (5,))
    for name in ("lo", "hi", "reflection"):
        check_finite(f"multipath.room.{name}", getattr(mp.room, name))
    if is_concrete(mp.room):
        lo, hi, refl = (np.asarray(x, np.float64) for x in mp.room)
        if not np.all(hi > lo):
            raise ValueError(f"multipath.room must have lo < hi on every axis, got lo={lo}, hi={hi}")
        if lo[2] != 0.0:
            raise ValueError(f"multipath.room.lo[2] is the floor and must be 0 (the two-ray ground), got {lo[2]}")
        if np.any(np.abs(refl) > 1.0):
            raise ValueError(f"multipath.room.reflection must be amplitude coefficients with |Γ| ≤ 1, got {refl}")


# --------------------------------------------------------------------------------------
# Image sequences (static)
# --------------------------------------------------------------------------------------


def image_sequences(order: int) -> tuple[tuple[int, ...], ...]:
    """The wall sequences of the distinct images up to ``order`` (0, 1 or 2): 0, 5 or 5 + 12 images.

    Second order: every ordered pair of different walls, keeping one of the two
    orders for perpendicular walls (which give the same image).
    """
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order not in (0, 1, 2):
        raise ValueError(f"order (image-method reflection order) must be 0, 1 or 2, got {order!r}")
    seqs: list[tuple[int, ...]] = []
    if order >= 1:
        seqs += [(w,) for w in range(5)]
    if order >= 2:
        for w1 in range(5):
            for w2 in range(5):
                if w1 == w2:
                    continue
                same_axis = _WALL_AXIS_SIDE[w1][0] == _WALL_AXIS_SIDE[w2][0]
                if same_axis or w1 < w2:
                    seqs.append((w1, w2))
    return tuple(seqs)


def anchor_position(
    tag: Any, distance: float, direction: Any = None, key: jax.Array | None = None, box: Any = None, tries: int = 256
) -> np.ndarray:
    """A point at ``distance`` (m) from ``tag [3]``: along ``direction [3]``, or a random direction from ``key``.

    For [A] Fig. 5.3 (RMSE vs anchor-to-tag distance; correlation is lost
    beyond λ/2). The result must lie inside ``box = (lo [3], hi [3])`` if given,
    and above the ground (``z ≥ 0``). With ``key``, directions are drawn
    uniformly on the sphere (``tries`` candidates, the first one inside is
    returned; the same key gives the same point). Host-side; returns float64 ``[3]``.
    """
    p = np.asarray(tag, np.float64)
    check_shape("tag", p, (3,))
    check_finite("tag", p)
    if p[2] < 0:
        raise ValueError(f"tag z (height above the ground) must be ≥ 0, got {p[2]}")
    check_nonnegative("distance", distance)
    check_finite("distance", distance)
    if box is not None:
        lo, hi = (np.asarray(b, np.float64) for b in box)
        check_shape("box[0]", lo, (3,))
        check_shape("box[1]", hi, (3,))
        if not np.all(hi >= lo):
            raise ValueError(f"box must have lo ≤ hi, got lo={lo}, hi={hi}")
    else:
        lo = np.array([-np.inf, -np.inf, 0.0])
        hi = np.full(3, np.inf)
    lo = np.maximum(lo, [-np.inf, -np.inf, 0.0])

    def inside(q):
        return np.all(q >= lo - 1e-9, axis=-1) & np.all(q <= hi + 1e-9, axis=-1)

    if (direction is None) == (key is None):
        raise ValueError("give exactly one of direction (a [3] vector) and key (a random direction)")
    if direction is not None:
        u = np.asarray(direction, np.float64)
        check_shape("direction", u, (3,))
        check_finite("direction", u)
        nrm = np.linalg.norm(u)
        if nrm == 0:
            raise ValueError("direction must be a non-zero vector")
        q = p + float(distance) * u / nrm
        if not inside(q):
            raise ValueError(f"the anchor {q.tolist()} is outside the box / below the ground; choose another direction")
        return q
    check_key(key)
    tries = check_positive_int("tries", tries)
    u = np.asarray(rng.normal(key, (tries, 3), jnp.float32), np.float64)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-30)
    q = p + float(distance) * u
    ok = inside(q)
    if not ok.any():
        raise ValueError(f"no point at distance {distance} m from the tag lies inside the box in {tries} tries")
    return q[int(np.argmax(ok))]


# --------------------------------------------------------------------------------------
# Composite channel (jittable)
# --------------------------------------------------------------------------------------


class CompositeChannel(NamedTuple):
    """The wall multipath of a read, relative to the direct ray (module docstring).

    Attributes:
        power_ratio: ``|h_mp|²`` (one-way power ratio; the RSSI factor is its square).
        phase_shift: ``2·arg h_mp`` wrapped to ``[−π, π)`` (rad): the round-trip phase added to ``−4πD/λ``.
    """

    power_ratio: jax.Array
    phase_shift: jax.Array


def _images(tag, room, seqs):
    """Image positions ``[..., I, 3]`` and coefficients ``[I]`` of ``tag [..., 3]``."""
    lo, hi, refl = room
    pts, coefs = [], []
    for seq in seqs:
        q = [tag[..., 0], tag[..., 1], tag[..., 2]]
        c = 1.0
        for w in seq:
            axis, side = _WALL_AXIS_SIDE[w]
            plane = hi[axis] if side else lo[axis]
            q[axis] = 2.0 * plane - q[axis]
            c = c * refl[w]
        pts.append(jnp.stack(q, axis=-1))
        coefs.append(c)
    return jnp.stack(pts, axis=-2), jnp.stack(coefs)


def multipath_gain(
    reader: jax.Array,
    tag: jax.Array,
    wavelength: jax.Array,
    antenna: uhf_rfid.AntennaParams,
    room: Any,
    seqs: tuple,
    softness: Any,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(Re h_mp, Im h_mp, D)`` for reader ``[..., 4]``, tag ``[..., 3]``, λ broadcastable to ``[...]``.

    The strong-multipath channel relative to the line of sight (image method over ``room``'s
    reflections, the image sequences ``seqs`` of :func:`image_sequences`), and the reader–tag
    distance ``D`` (m). Traceable, not validated: :func:`composite_channel` is the checked call.
    """
    d_vec = tag - reader[..., :3]
    dist = jnp.sqrt(jnp.maximum(jnp.sum(d_vec * d_vec, axis=-1), 1e-12))
    if not seqs:
        one = jnp.ones_like(dist)
        return one, jnp.zeros_like(dist), dist
    imgs, coef = _images(tag, room, seqs)  # [..., I, 3], [I]
    v = imgs - reader[..., None, :3]
    d_i = jnp.sqrt(jnp.maximum(jnp.sum(v * v, axis=-1), 1e-12))
    psi = reader[..., 3]
    g0 = uhf_rfid.antenna_gain(d_vec, psi, antenna, softness)
    gi = uhf_rfid.antenna_gain(v, psi[..., None], antenna, softness)
    amp = coef * jnp.sqrt(gi / g0[..., None]) * dist[..., None] / d_i
    ph = -2.0 * jnp.pi * (d_i - dist[..., None]) / jnp.asarray(wavelength)[..., None]
    re = 1.0 + jnp.sum(amp * jnp.cos(ph), axis=-1)
    im = jnp.sum(amp * jnp.sin(ph), axis=-1)
    return re, im, dist


def _order_for(mp: Multipath, order: int) -> int:
    """Skip the images when every Γ is known to be 0 (the result is the same: h_mp = 1 exactly)."""
    if is_concrete(mp.room.reflection) and not np.any(np.asarray(mp.room.reflection)):
        return 0
    return order


def _check_inside_room(name: str, xyz: Any, mp: Multipath, order: int) -> None:
    if order == 0 or not (is_concrete(xyz) and is_concrete(mp.room)):
        return
    v = np.asarray(xyz, np.float64).reshape(-1, 3)
    lo, hi = np.asarray(mp.room.lo, np.float64), np.asarray(mp.room.hi, np.float64)
    out = ~(np.all(v >= lo - 1e-6, axis=1) & np.all(v <= hi + 1e-6, axis=1))
    if out.any():
        raise ValueError(
            f"{name} must lie inside the room [{lo.tolist()}, {hi.tolist()}] of the image method; "
            f"first outside: {v[np.argmax(out)].tolist()} (move the walls or set their reflection to 0)"
        )


def _check_poses(path: Any) -> None:
    check_shape("path", path, (None, 4))
    if np.shape(path)[0] < 1:
        raise ValueError("path must hold at least one pose")
    check_magnitude("path", path)
    if is_concrete(path) and np.any(np.asarray(path)[:, 2] < 0):
        raise ValueError("path z (the reader's height above the ground z = 0) must be ≥ 0")


def _check_tags(tags: Any, name: str = "tags") -> None:
    check_shape(name, tags, (None, 3))
    if np.shape(tags)[0] < 1:
        raise ValueError(f"{name} must hold at least one tag")
    check_magnitude(name, tags)
    if is_concrete(tags) and np.any(np.asarray(tags)[:, 2] < 0):
        raise ValueError(f"{name} z (height above the ground z = 0) must be ≥ 0: a tag below the ground")


def composite_channel(
    path: Any,
    tag: Any,
    multipath: str | Multipath = "strong",
    channel: ChannelParams = DEFAULT_CHANNEL,
    wavelength: Any = None,
    order: int = 2,
    softness: Any = None,
) -> CompositeChannel:
    """``|h_mp|²`` and ``2 arg h_mp`` (module docstring) of ``tag [3]`` seen from ``path [T, 4]``: ``[T]`` each.

    ``wavelength``: scalar or ``[T]`` (default ``channel.wavelength``).
    """
    mp = get_multipath(multipath)
    _check_poses(path)
    check_shape("tag", tag, (3,))
    _check_tags(jnp.reshape(jnp.asarray(tag), (1, 3)), "tag")
    uhf_rfid.validate_channel(channel)
    lam = channel.wavelength if wavelength is None else wavelength
    check_positive("wavelength", lam)
    if np.ndim(lam) not in (0, 1) or (np.ndim(lam) == 1 and np.shape(lam)[0] != np.shape(path)[0]):
        raise ValueError(f"wavelength must be a scalar or [T] = [{np.shape(path)[0]}], got shape {np.shape(lam)}")
    image_sequences(order)  # validates order
    seqs = image_sequences(_order_for(mp, order))
    _check_inside_room("path", np.asarray(path)[:, :3] if is_concrete(path) else path, mp, len(seqs))
    _check_inside_room("tag", tag, mp, len(seqs))
    re, im, _ = _composite_jit(
        jnp.asarray(path), jnp.asarray(tag), jnp.asarray(lam), channel.antenna, mp.room, seqs, softness
    )
    return CompositeChannel(re * re + im * im, wrap_angle(2.0 * jnp.arctan2(im, re)))


_composite_jit = jax.jit(multipath_gain, static_argnames=("seqs", "softness"))


def expected_rssi(
    path: Any,
    tag: Any,
    multipath: str | Multipath = "strong",
    channel: ChannelParams = DEFAULT_CHANNEL,
    wavelength: Any = None,
    order: int = 2,
) -> jax.Array:
    """Noise-free mean RSSI ``E[y] = a·|h_mp|⁴·k(k+1)θ²`` (W) along ``path [T, 4]`` for ``tag [3]``: ``[T]``.

    Under ``"light"`` this is :func:`jaxnav.models.uhf_channel.mean_power`
    (unimodal along a line); under ``"strong"`` it shows the wall fading dips.
    """
    mp = get_multipath(multipath)
    cc = composite_channel(path, tag, mp, channel, wavelength, order)
    lam = channel.wavelength if wavelength is None else wavelength
    mean = uhf_rfid.mean_power(jnp.asarray(path), jnp.asarray(tag), channel, mp.gamma, wavelength=jnp.asarray(lam))
    return mean * cc.power_ratio**2


# --------------------------------------------------------------------------------------
# Reads
# --------------------------------------------------------------------------------------


def _one(key, reader, tag, offset, lam, channel, mp, sens, tag_sens, p_read, num_reads, seqs, softness, field=None):
    """Reads of one tag at one step: ``[J]`` each (``field``: the step's correlated fading draws, or None)."""
    k_fade, k_phase, k_read = jax.random.split(key, 3)
    a = uhf_rfid.power_scale(reader, tag, channel, softness=softness, wavelength=lam)
    re, im, dist = multipath_gain(reader, tag, lam, channel.antenna, mp.room, seqs, softness)
    m2 = re * re + im * im
    a_eff = a * m2 * m2
    if field is None:
        # a_eff = 0 (a tag or reader on the ground) gives y = 0, masked below; keep sample_rssi's input > 0
        y = uhf_rfid.sample_rssi(k_fade, jnp.where(a_eff > 0, a_eff, 1.0), mp.gamma, (num_reads,))
    else:
        g = _field_fading(field, tag, mp)
        y = a_eff * g * g
    y = jnp.where(a_eff > 0, y, 0.0)
    eps = mp.phase_sigma * rng.normal(k_phase, (num_reads,), y.dtype)
    phi = uhf_rfid.phase(dist, lam, offset + 2.0 * jnp.arctan2(im, re) + eps)
    p_inc = jnp.sqrt(y * channel.tx_power / channel.tag_efficiency)
    ok = (y > 0) & (y >= sens) & (p_inc >= tag_sens) & (rng.uniform(k_read, (num_reads,)) < p_read)
    return (
        jnp.broadcast_to(reader, (num_reads, 4)),
        jnp.where(ok, y, MASKED_RSSI),
        jnp.where(ok, phi, MASKED_PHASE),
        jnp.full((num_reads,), lam, y.dtype),
        ok,
    )


class _Field(NamedTuple):
    """One step's draws of the correlated fading: directions ``u [J, m, N, 3]``, amplitudes ``c [J, m, N, 2]``
    (real, imaginary; variance ``1/(2N)`` each), the Beta factors ``b [J]`` (ones for a whole ``k``)."""

    u: jax.Array
    c: jax.Array
    b: jax.Array


def _field_key(key):
    """Two words of ``key``'s own stream as a key: no ``fold_in`` of a tag id or a step gives it."""
    data = jax.random.bits(key, (2,), jnp.uint32)
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return jax.random.wrap_key_data(data, impl=jax.random.key_impl(key))
    return data


def _field_draws(key, t, k, num_reads, fading, dtype):
    """The correlated fading field of step ``t`` (shared by every tag)."""
    m, waves, whole = fading
    k_dir, k_amp, k_a, k_b = jax.random.split(jax.random.fold_in(key, t), 4)
    u = rng.normal(k_dir, (num_reads, m, waves, 3), dtype)
    u = u / jnp.maximum(jnp.linalg.norm(u, axis=-1, keepdims=True), 1e-30)  # isotropic directions
    c = rng.normal(k_amp, (num_reads, m, waves, 2), dtype) * math.sqrt(0.5 / waves)
    if whole:
        b = jnp.ones((num_reads,), dtype)
    else:  # B = G_k / (G_k + G_{m−k}) ~ Beta(k, m − k); m − k = 0 (a whole k seen only at run time) gives B = 1
        rest = m - k
        ga = jax.random.gamma(k_a, jnp.broadcast_to(k, (num_reads,)), dtype=dtype)
        gb = jax.random.gamma(k_b, jnp.broadcast_to(jnp.maximum(rest, 1e-6), (num_reads,)), dtype=dtype)
        b = jnp.where(rest > 0, ga / (ga + gb), 1.0)
    return _Field(u, c, b)


def _field_fading(field: _Field, tag, mp):
    """``g [J] = θ B Σ_i |z_i(p)|²`` at the tag ``p [3]`` (module docstring)."""
    kappa = jnp.pi / mp.correlation_length
    # u·p written out: jax 0.10.2 on the CPU miscompiles sum(u * p, axis=-1) at these sizes, giving every tag the
    # first one's value (jax-ml/jax#39103)
    u = field.u
    ph = kappa * (u[..., 0] * tag[0] + u[..., 1] * tag[1] + u[..., 2] * tag[2])  # [J, m, N]
    cos, sin = jnp.cos(ph), jnp.sin(ph)
    cr, ci = field.c[..., 0], field.c[..., 1]
    z_re = jnp.sum(cr * cos - ci * sin, axis=-1)
    z_im = jnp.sum(cr * sin + ci * cos, axis=-1)
    return mp.gamma.theta * field.b * jnp.sum(z_re * z_re + z_im * z_im, axis=-1)


@partial(jax.jit, static_argnames=("num_reads", "seqs", "softness", "fading"))
def _simulate(
    key, path, tags, offsets, tag_ids, lam_t, channel, mp, sens, tag_sens, p_read, num_reads, seqs, softness, fading
):
    steps = jnp.arange(path.shape[0])
    if fading is None:
        fields = None
    else:
        k_field = _field_key(key)
        fields = jax.vmap(lambda t: _field_draws(k_field, t, mp.gamma.k, num_reads, fading, path.dtype))(steps)

    def per_tag(tid, tag, off):
        k_tag = jax.random.fold_in(key, tid)

        def per_step(t, reader, lam, field):
            return _one(
                jax.random.fold_in(k_tag, t),
                reader,
                tag,
                off,
                lam,
                channel,
                mp,
                sens,
                tag_sens,
                p_read,
                num_reads,
                seqs,
                softness,
                field,
            )

        return jax.vmap(per_step)(steps, path, lam_t, fields)

    out = jax.vmap(per_tag)(tag_ids, tags, offsets)
    return UHFReads(*out)


def simulate_reads(
    key: jax.Array,
    path: Any,
    tags: Any,
    theta_offset: Any = None,
    channel: ChannelParams = DEFAULT_CHANNEL,
    multipath: str | Multipath = "light",
    reads_per_step: int = 1,
    wavelengths: Any = None,
    sensitivity: Any = DEFAULT_SENSITIVITY,
    tag_sensitivity: Any = DEFAULT_TAG_SENSITIVITY,
    read_probability: Any = 1.0,
    tag_ids: Any = None,
    order: int = 2,
    softness: Any = None,
    fading_fields: int | None = None,
    fading_waves: int = FADING_WAVES,
) -> UHFReads:
    """RSSI and phase reads of ``G`` tags along a reader path: :class:`~jaxnav.models.uhf_reads.UHFReads` ``[G, T, J]``.

    Args:
        key: PRNG key (module docstring, "Keys").
        path: ``[T, 4]`` reader poses ``(x, y, z, ψ)`` (m, m, m, rad), ``z ≥ 0``
            (:func:`~jaxnav.sim.trajectories.line_path`, :func:`~jaxnav.sim.trajectories.lawnmower_path`).
        tags: ``[G, 3]`` tag positions (m), ``z ≥ 0``.
        theta_offset: ``[G]`` phase offsets ``θ_off`` (rad); default 0.
        channel: :class:`~jaxnav.models.uhf_channel.ChannelParams`
            (``channel.wavelength`` is the λ unless ``wavelengths`` is given).
        multipath: ``"light"``, ``"strong"`` or a :class:`Multipath`; one with a
            ``correlation_length`` (:func:`correlated_fading`) draws the spatially
            correlated fading of the module docstring instead of an independent one per tag.
        reads_per_step: ``J`` read slots per step (all at the step's pose).
        wavelengths: ``None``, one λ (m), or ``[C]`` λ's cycled over steps
            (step ``t`` uses ``λ[t mod C]``; channel hopping).
        sensitivity: reader sensitivity (W): reads with ``y`` below it are masked
            (default −80 dBm).
        tag_sensitivity: tag chip sensitivity (W of incident power, default −18 dBm).
        read_probability: independent success probability of a read, in [0, 1].
        tag_ids: ``[G]`` integer ids for the keys (default ``0 … G−1``); simulating
            a subset with its ids reproduces the full run's reads of those tags.
        order: image-method reflection order (0, 1 or 2; ignored without walls).
        softness: antenna-gain relaxation (rad), see
            :func:`jaxnav.models.uhf_antenna.antenna_gain`.
        fading_fields: correlated fading only: the number ``m ≥ k`` of Gaussian fields
            (a shape). Default ``⌈k⌉``, which needs a concrete ``k``; give it when
            ``k`` is traced (``B ~ Beta(k, m − k)`` then keeps the marginal exact).
        fading_waves: correlated fading only: plane waves ``N`` per field.

    Returns:
        ``UHFReads`` with ``reader [G, T, J, 4]``, ``rssi/phase/wavelength/mask
        [G, T, J]``; masked slots hold :data:`MASKED_RSSI`, :data:`MASKED_PHASE`,
        the true pose and λ. Jitted (same shapes, same ``order``/``J``: no retrace).
    """
    mp = get_multipath(multipath)
    check_key(key)
    _check_poses(path)
    _check_tags(tags)
    uhf_rfid.validate_channel(channel)
    num_reads = check_positive_int("reads_per_step", reads_per_step)
    n_tags, n_steps = np.shape(tags)[0], np.shape(path)[0]
    if theta_offset is None:
        theta_offset = np.zeros(n_tags, np.float32)
    check_shape("theta_offset", theta_offset, (n_tags,))
    check_finite("theta_offset", theta_offset)
    if tag_ids is None:
        tag_ids = np.arange(n_tags, dtype=np.int32)
    check_shape("tag_ids", tag_ids, (n_tags,))
    if not np.issubdtype(np.result_type(tag_ids), np.integer):
        raise ValueError(f"tag_ids must be integers, got dtype {np.result_type(tag_ids)}")
    if wavelengths is None:
        wavelengths = channel.wavelength
    if np.ndim(wavelengths) > 1 or (np.ndim(wavelengths) == 1 and np.shape(wavelengths)[0] < 1):
        raise ValueError(f"wavelengths must be one λ or a non-empty [C] array, got shape {np.shape(wavelengths)}")
    check_positive("wavelengths", wavelengths)
    check_nonnegative("sensitivity", sensitivity)
    check_nonnegative("tag_sensitivity", tag_sensitivity)
    check_shape("sensitivity", sensitivity, ())
    check_shape("tag_sensitivity", tag_sensitivity, ())
    check_shape("read_probability", read_probability, ())
    if is_concrete(read_probability) and not 0.0 <= float(read_probability) <= 1.0:
        raise ValueError(f"read_probability must be in [0, 1], got {float(read_probability)}")
    if softness is not None:
        check_positive("softness", softness)
    image_sequences(order)  # validates order
    seqs = image_sequences(_order_for(mp, order))
    _check_inside_room("path", np.asarray(path)[:, :3] if is_concrete(path) else path, mp, len(seqs))
    _check_inside_room("tags", tags, mp, len(seqs))
    fading = _fading_config(mp, fading_fields, fading_waves)

    f32 = jnp.float32
    lam = jnp.atleast_1d(jnp.asarray(wavelengths, f32))
    lam_t = lam[jnp.arange(n_steps) % lam.shape[0]]
    mp32 = jax.tree_util.tree_map(lambda x: jnp.asarray(x, f32), mp)
    ch32 = jax.tree_util.tree_map(lambda x: jnp.asarray(x, f32), channel)
    return _simulate(
        key,
        jnp.asarray(path, f32),
        jnp.asarray(tags, f32),
        jnp.asarray(theta_offset, f32),
        jnp.asarray(tag_ids, jnp.int32),
        lam_t,
        ch32,
        mp32,
        jnp.asarray(sensitivity, f32),
        jnp.asarray(tag_sensitivity, f32),
        jnp.asarray(read_probability, f32),
        num_reads,
        seqs,
        softness,
        fading,
    )


def _fading_config(mp: Multipath, fields: int | None, waves: int) -> tuple[int, int, bool] | None:
    """``(m, N, k is whole)`` of the correlated fading (static), or None for the independent fading."""
    if mp.correlation_length is None:
        return None
    waves = check_positive_int("fading_waves", waves)
    k = mp.gamma.k
    check_shape("multipath.gamma.k", k, ())
    concrete = is_concrete(k)
    if fields is None:
        if not concrete:
            raise ValueError(
                "correlated fading with a traced k needs fading_fields (the number m ≥ k of Gaussian fields, a shape)"
            )
        fields = math.ceil(float(np.asarray(k)))
    fields = check_positive_int("fading_fields", fields)
    if concrete and fields < float(np.asarray(k)):
        raise ValueError(f"fading_fields must be ≥ k = {float(np.asarray(k))}, got {fields}")
    return fields, waves, concrete and fields == float(np.asarray(k))


def anchor_power_scale(
    reads: UHFReads, anchor: Any, channel: ChannelParams = DEFAULT_CHANNEL, softness: Any = None
) -> jax.Array:
    """The true ``a = P_T η_T G_R² G_T² L²`` (W) of every read slot of an anchor at the known ``anchor [3]``.

    ``a`` is :func:`jaxnav.models.uhf_channel.power_scale` at each read's reader pose
    and wavelength; same shape as ``reads.rssi``. Feed it with the flattened
    reads and mask to :func:`jaxnav.models.uhf_calibration.estimate_gamma` to fit
    ``(k, θ)`` from the anchor ([A] §4.3.1). Under strong multipath the fit
    absorbs the wall term ``|h_mp|⁴`` into ``(k, θ)``, as it does on real data.
    """
    uhf_rfid.validate_reads(reads)
    check_shape("anchor", anchor, (3,))
    return uhf_rfid.power_scale(
        jnp.asarray(reads.reader),
        jnp.asarray(anchor),
        channel,
        softness=softness,
        wavelength=jnp.asarray(reads.wavelength),
    )
