"""UHF-RFID reader antenna: the gain pattern of [A] §4.3.1 (Fig. 4.2).

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

[A] gives no numbers for the pattern; :data:`DEFAULT_ANTENNA` is our choice,
``G_0 = 8 dBi``, ``G_SLL = −2 dBi``, ``G_BLL = −12 dBi``, ``φ_s = 30°`` (a
typical UHF patch antenna: 60° main lobe, side lobes 10 dB and back lobe 20 dB
below the main lobe). Gains are linear (dimensionless), angles in rad. The gain
enters the received power of :mod:`jaxnav.models.uhf_channel`.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_positive, is_concrete

__all__ = [
    "AntennaParams",
    "DEFAULT_ANTENNA",
    "validate_antenna",
    "off_boresight_angle",
    "antenna_gain",
]


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


def _check_last_dim(name: str, x: Any, n: int) -> None:
    shape = np.shape(x)
    if len(shape) < 1 or shape[-1] != n:
        raise ValueError(f"{name} must have shape (..., {n}), got {tuple(shape)}")


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


def _gain_nocheck(direction, heading, params, softness):
    gamma = _off_boresight(direction, heading)
    g0, gs, gb, ps = params
    if softness is None:
        return jnp.where(gamma <= ps, g0, jnp.where(gamma <= 2.0 * ps, gs, gb))
    inner = jax.nn.sigmoid((ps - gamma) / softness)
    outer = jax.nn.sigmoid((2.0 * ps - gamma) / softness)
    return gb + (gs - gb) * outer + (g0 - gs) * inner


def _log_gain_stepped(dot, dist, params: AntennaParams):
    """``log G_R`` of the stepped cone model from ``d·b`` and ``|d|``: no angle is computed.

    ``γ ≤ φ`` ⟺ ``d·b ≥ cos(φ)·|d|`` for ``γ, φ ∈ [0, π]`` (cos decreases there), so the
    lobe test needs no ``atan2`` ([A] §4.3.1; :func:`antenna_gain` gives the same gain).
    """
    g0, gs, gb, ps = params
    main = dot >= jnp.cos(ps) * dist
    side = dot >= jnp.cos(2.0 * ps) * dist
    return jnp.where(main, jnp.log(g0), jnp.where(side, jnp.log(gs), jnp.log(gb)))
