"""UHF-RFID reads: what a reader reports, and the checks a read must pass ([A] ch. 4).

A monostatic reader at pose ``(x, y, z, ψ)`` (m, m, m, rad) reads a passive tag and reports a
received power ``y`` (the RSSI, **W**) and a phase ``φ`` (**rad**, in ``[0, 2π)``) on a carrier of
wavelength ``λ`` (m, per read to allow channel hopping). The reads of one tag come in fixed slots,
``J`` per time step (:class:`UHFReads`); a missing read is masked, never written as zeros.

This module holds that container and what keeps its values in their domain:

* :class:`UHFReads` and its host-side checks (:func:`validate_reads`, :func:`validate_rssi`,
  :func:`validate_phase`, :func:`valid_values`), with :data:`MAX_RSSI_W` the largest power a
  read may report;
* :func:`wrap_phase`, which maps a reader's ``[−π, π)`` phase to the ``[0, 2π)`` used here;
* :func:`read_mask`, a mask broadcast to the reads' shape;
* :func:`usable_reads` (:class:`UsableReads`): the traceable counterpart of the host checks, which
  drops the slots a filter must not use inside a ``jit``.

Host-side checks skip their value checks for tracers. The models that weigh the reads are
:mod:`jaxnav.models.uhf_channel` and :mod:`jaxnav.models.uhf_read_model`.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_positive, check_real, is_concrete
from jaxnav.core.weights import wrap_angle

__all__ = [
    "UHFReads",
    "MAX_RSSI_W",
    "valid_values",
    "validate_rssi",
    "validate_phase",
    "validate_reads",
    "wrap_phase",
    "read_mask",
    "UsableReads",
    "usable_reads",
]

_TWO_PI = 2.0 * math.pi


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


MAX_RSSI_W = 1.0
"""The largest received power an RSSI may report, in W (1 W = 30 dBm). A UHF reader transmits at most
4 W EIRP, and a backscattered read is many orders of magnitude weaker."""


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


def validate_rssi(y: Any, mask: Any = None, name: str = "y", max_w: float | None = None) -> None:
    """An RSSI must be a received power: finite and > 0 (W), and with ``max_w`` at most that (a
    reader's reads: :data:`MAX_RSSI_W`; the density :func:`~jaxnav.models.uhf_read_model.log_w_rssi`
    takes any positive ``y``). Masked entries are not checked."""
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


def wrap_phase(phi: Any) -> jax.Array:
    """Wrap angles to ``[0, 2π)`` (rad): the reader's phase convention used here."""
    r = wrap_angle(jnp.asarray(phi) - jnp.pi) + jnp.pi
    # float rounding can give exactly 2π for inputs just below a multiple of 2π
    return jnp.where(r >= _TWO_PI, r - _TWO_PI, r)


def read_mask(shape: tuple[int, ...], mask: Any) -> jax.Array:
    """``mask`` broadcast to ``shape`` as bool (every read valid for ``mask=None``)."""
    if mask is None:
        return jnp.ones(shape, bool)
    return jnp.broadcast_to(jnp.asarray(mask, bool), shape)


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
