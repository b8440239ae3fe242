"""UHF-RFID reads as particle sensors: [A]'s RSSI and phase weights over tag and robot hypotheses.

**Overview**

A UHF read gives an RSSI ``y`` (W) and a phase ``φ`` (rad). [A] weighs a hypothesis by
``W_RSSI · W_PHASE`` (Alg. 6 lines 12–13, Alg. 8): the scaled squared-Gamma density of the RSSI,
with the power scale ``a`` of the two-ray model at the hypothesised geometry
(:func:`jaxnav.models.uhf_read_model.log_w_rssi`), and ``N(Δ; 0, σ²)`` on the distance metric of the
phase (:func:`jaxnav.models.uhf_read_model.log_w_phase`). In log form, summed over the valid reads,

    log w = Σ_j [log W_RSSI(y_j | a(geometry_j)) + log W_PHASE(φ_j | d(geometry_j), θ_off)],

either term alone with ``weighting="rssi"`` or ``"phase"`` ([A] Figs. 5.5–5.6). Two sensors, for
the two filters of [A]:

* :func:`tag_reads_sensor`: particles ``[N, 4]`` are hypotheses ``(x, y, z, θ_off)`` of a static
  tag, read by a reader at known poses (:class:`~jaxnav.models.uhf_reads.UHFReads`, ``J`` slots per
  step); the static-tag filter :mod:`jaxnav.localization.rfid_tag` weighs with it;
* :func:`anchor_reads_sensor`: particles ``[N, 4 + G]`` are robot poses ``(x, y, z, φ)`` and the
  phase offsets of ``G`` anchor tags at known positions ``params.anchors [G, 3]``, each read in its
  own slot (:class:`AnchorReads`); the anchor filter :mod:`jaxnav.localization.rfid_anchor` weighs
  with it.

Both are :class:`~jaxnav.models.sensor.ParticleSensor` objects, the same seam as the pose filters'
sensors; the factories are cached, so equal arguments give the same (hashable) object and a
filter's configuration compiles once. A read slot whose values are unusable (not finite or out of
range, refused on the host) is dropped inside a caller's ``jit`` and counted.

Units: m, rad, W.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_choice, check_positive, check_real, is_concrete
from jaxnav.models import uhf_rfid as U
from jaxnav.models.sensor import ParticleSensor

__all__ = [
    "WEIGHTINGS",
    "AnchorReads",
    "usable_tag_reads",
    "tag_reads_log_likelihood",
    "check_tag_reads",
    "as_tag_reads",
    "tag_reads_sensor",
    "usable_anchor_reads",
    "anchor_reads_log_likelihood",
    "check_anchor_reads",
    "as_anchor_reads",
    "anchor_reads_sensor",
]

WEIGHTINGS = ("combined", "rssi", "phase")
"""The weights a read multiplies in, by name. ``"combined"`` multiplies both ([A]'s proposal), ``"rssi"``
the RSSI weight only, ``"phase"`` the phase weight only."""

_OFFSET = 3  # column of θ_off in a tag hypothesis


def _terms(weighting: str) -> dict[str, bool]:
    return {"use_rssi": weighting in ("combined", "rssi"), "use_phase": weighting in ("combined", "phase")}


# --------------------------------------------------------------------------- a static tag


def usable_tag_reads(reads: U.UHFReads) -> tuple[U.UHFReads, jax.Array]:
    """``(reads, num_ignored)``: the slots a filter may use (:func:`jaxnav.models.uhf_reads.usable_reads`)
    with harmless values in the others (a reader pose that is not finite becomes 0), and how many valid
    slots were dropped."""
    u = U.usable_reads(reads.rssi, reads.phase, reads.wavelength, reads.mask)
    reader = jnp.where(u.mask[..., None] & jnp.isfinite(reads.reader), reads.reader, 0.0)
    return U.UHFReads(reader, u.rssi, u.phase, u.wavelength, u.mask), u.num_ignored


def tag_reads_log_likelihood(
    particles: jax.Array, reads: U.UHFReads, params: Any, weighting: str = "combined", softness: Any = None
) -> jax.Array:
    """``[N]`` Σ over the valid read slots of ``log W_RSSI + log W_PHASE`` (or one of them) for tag
    hypotheses ``particles [N, 4]`` (m, m, m, rad), [A] Alg. 6 lines 11–14; ``params`` has the fields
    ``channel``, ``gamma`` and ``phase_sigma`` (m). ``reads`` must be usable (:func:`usable_tag_reads`).

    One :func:`~jaxnav.models.uhf_read_model.read_log_terms` call per read slot (``J`` is static and
    small), each a flat loop over the particles with the slot's scalars: see that function for
    why this is faster inside a scan than one ``[N, J]`` broadcast.
    """
    xyz, offset = particles[:, :3], particles[:, _OFFSET]
    total = jnp.zeros(particles.shape[:1], particles.dtype)
    for j in range(reads.mask.shape[-1]):
        total = total + U.read_log_terms(
            reads.reader[j],
            xyz,
            offset,
            reads.rssi[j],
            reads.phase[j],
            reads.wavelength[j],
            reads.mask[j],
            params.channel,
            params.gamma,
            params.phase_sigma,
            **_terms(weighting),
            softness=softness,
        )
    return total


def _check_read_model(params: Any) -> None:
    U.validate_read_model(params.channel, params.gamma, params.phase_sigma)


def _read_model_in_domain(params: Any) -> jax.Array:
    return U.read_model_in_domain(params.channel, params.gamma, params.phase_sigma)


def check_tag_reads(reads: Any, time_axis: bool, params: Any = None) -> None:
    """Host-side check of a tag's reads (:func:`jaxnav.models.uhf_reads.validate_reads`) with mask shape
    ``[J]``, or ``[T, J]`` with ``time_axis``."""
    del params
    U.validate_reads(reads)
    lead = 1 if time_axis else 0
    if len(np.shape(reads.mask)) != lead + 1:
        axes = ("T, " * lead) + "J"
        raise ValueError(f"reads must have shape [{axes}], got mask shape {np.shape(reads.mask)}")


def as_tag_reads(reads: U.UHFReads) -> U.UHFReads:
    """``reads`` with float32 values and a bool mask (the filter's host-side conversion)."""
    return U.UHFReads(*(jnp.asarray(x, jnp.float32) for x in reads[:4]), jnp.asarray(reads.mask, bool))


@functools.cache
def tag_reads_sensor(weighting: str = "combined", softness: float | None = None) -> ParticleSensor:
    """The reads of a static tag as a :class:`~jaxnav.models.sensor.ParticleSensor` over tag hypotheses
    ``[N, 4]`` (module docstring): observations :class:`~jaxnav.models.uhf_reads.UHFReads` ``[J]`` per
    step, parameters with the fields ``channel``, ``gamma`` and ``phase_sigma``. ``weighting`` is one of
    :data:`WEIGHTINGS`; ``softness`` (rad) the optional relaxation of the antenna pattern's steps
    (:func:`jaxnav.models.uhf_antenna.antenna_gain`), None for [A]'s stepped model."""
    check_choice("weighting", weighting, WEIGHTINGS)

    def log_likelihood(particles: jax.Array, reads: U.UHFReads, params: Any) -> jax.Array:
        return tag_reads_log_likelihood(particles, usable_tag_reads(reads)[0], params, weighting, softness)

    return ParticleSensor(
        f"uhf_tag_reads[{weighting}]",
        log_likelihood,
        check_params=_check_read_model,
        check_observations=check_tag_reads,
        params_in_domain=_read_model_in_domain,
        num_ignored=lambda reads, params: usable_tag_reads(reads)[1],
        prepare=as_tag_reads,
    )


# --------------------------------------------------------------------------- anchor tags read from a robot


class AnchorReads(NamedTuple):
    """One step's reads of the anchor tags, slot ``j`` = anchor ``j`` (leading ``[T]`` allowed).

    Attributes:
        rssi: ``[..., G]`` received power (W, > 0 where valid).
        phase: ``[..., G]`` phase (rad, in ``[0, 2π)``).
        wavelength: ``[..., G]`` channel wavelength (m).
        mask: ``[..., G]`` bool: anchor ``j`` was read.
    """

    rssi: Any
    phase: Any
    wavelength: Any
    mask: Any


def usable_anchor_reads(reads: AnchorReads) -> tuple[AnchorReads, jax.Array]:
    """``(reads, num_ignored)``: the anchor slots a filter may use, harmless values in the others."""
    u = U.usable_reads(reads.rssi, reads.phase, reads.wavelength, reads.mask)
    return AnchorReads(u.rssi, u.phase, u.wavelength, u.mask), u.num_ignored


def anchor_reads_log_likelihood(
    particles: jax.Array, reads: AnchorReads, params: Any, weighting: str = "combined", softness: Any = None
) -> jax.Array:
    """``[N]`` Σ over the read anchors of ``log W_RSSI + log W_PHASE`` (or one of them), [A] Alg. 8, for
    ``particles [N, 4 + G]`` = robot ``(x, y, z, φ)`` and the anchors' phase offsets (rad); ``params`` has
    the fields ``anchors [G, 3]`` (m), ``channel``, ``gamma`` and ``phase_sigma``. ``reads`` must be
    usable (:func:`usable_anchor_reads`)."""
    return U.read_log_likelihood(
        particles[:, None, :4],
        params.anchors[None, :, :],
        particles[:, 4:],
        reads.rssi[None, :],
        reads.phase[None, :],
        reads.wavelength[None, :],
        reads.mask[None, :],
        params.channel,
        params.gamma,
        params.phase_sigma,
        **_terms(weighting),
        softness=softness,
    )


def check_anchor_reads(reads: Any, lead_shape: tuple, num_anchors: int) -> None:
    """Host-side check of :class:`AnchorReads` with fields of shape ``lead_shape + (G,)``: real and finite
    everywhere, and on the read slots a positive RSSI of at most
    :data:`~jaxnav.models.uhf_reads.MAX_RSSI_W` W, a phase in ``[0, 2π)`` and a positive wavelength."""
    if not isinstance(reads, AnchorReads):
        raise ValueError(f"reads must be an AnchorReads, got {type(reads).__name__}")
    shape = tuple(lead_shape) + (num_anchors,)
    for name in AnchorReads._fields:
        check_real(f"reads.{name}", getattr(reads, name))
        if np.shape(getattr(reads, name)) != shape:
            raise ValueError(
                f"reads.{name} must have shape {shape} (one slot per anchor), got {np.shape(getattr(reads, name))}"
            )
    if is_concrete(reads):
        mask = np.asarray(reads.mask, bool)
        for name in ("rssi", "phase", "wavelength"):
            if not np.all(np.isfinite(np.asarray(getattr(reads, name)))):
                raise ValueError(f"reads.{name} must be finite everywhere (fill masked slots with any finite value)")
        if mask.any():
            U.validate_rssi(np.asarray(reads.rssi)[mask], name="reads.rssi", max_w=U.MAX_RSSI_W)
            U.validate_phase(np.asarray(reads.phase)[mask], name="reads.phase")
            check_positive("reads.wavelength", np.asarray(reads.wavelength)[mask])


def _check_anchor_observations(reads: Any, time_axis: bool, params: Any) -> None:
    lead = (np.shape(reads.mask)[0],) if time_axis and hasattr(reads, "mask") else ()
    check_anchor_reads(reads, lead, np.shape(params.anchors)[0])


def as_anchor_reads(reads: AnchorReads) -> AnchorReads:
    """``reads`` with float32 values and a bool mask (the filters' host-side conversion)."""
    return AnchorReads(*(jnp.asarray(x, jnp.float32) for x in reads[:3]), jnp.asarray(reads.mask, bool))


@functools.cache
def anchor_reads_sensor(weighting: str = "combined", softness: float | None = None) -> ParticleSensor:
    """The reads of anchor tags as a :class:`~jaxnav.models.sensor.ParticleSensor` over robot hypotheses
    ``[N, 4 + G]`` (module docstring): observations :class:`AnchorReads` ``[G]`` per step, parameters
    with the fields ``anchors``, ``channel``, ``gamma`` and ``phase_sigma``; ``weighting`` and
    ``softness`` as for :func:`tag_reads_sensor`."""
    check_choice("weighting", weighting, WEIGHTINGS)

    def log_likelihood(particles: jax.Array, reads: AnchorReads, params: Any) -> jax.Array:
        return anchor_reads_log_likelihood(particles, usable_anchor_reads(reads)[0], params, weighting, softness)

    return ParticleSensor(
        f"uhf_anchor_reads[{weighting}]",
        log_likelihood,
        check_params=_check_read_model,
        check_observations=_check_anchor_observations,
        params_in_domain=_read_model_in_domain,
        num_ignored=lambda reads, params: usable_anchor_reads(reads)[1],
        prepare=as_anchor_reads,
    )
