"""IR emitter layouts of [W] ch. 5: which emitter, with which ID, sits where on the ceiling.

**Layouts**

:class:`EmitterLayout` holds ``positions [E, 2]`` (m, world frame, on the
ceiling), ``masks [E]`` (ID bitmasks), ``unique [E]`` and ``ids [E]``
(canonical IDs). Builders: :func:`make_layout` (validated, from code sets),
:func:`lattice_layout` ([W] Fig. 5.1), :func:`without_emitters` (failed
emitters, [W] §5.4.5). The particular layouts of [W]'s experiments (§5.4,
Fig. 5.9 and Table 5.2) are :func:`jaxnav.sim.ir_world.experiment_layout` and
:func:`jaxnav.sim.ir_world.unique11_layout`.

Decodability. A receiver that sees two emitters at once receives the union
of their codes, and where two emitters share a code the two square waves in
that bin add with a random phase and can cancel, leaving the other codes. The
builders keep three rules, under which such a set is never an ID of the
layout, so the receiver reports no detection
(:func:`jaxnav.sim.ir_receiver.decode`), never a wrong emitter:

* (i) all unique arrays of a layout have the same number of codes ``k ≥ 2``
  (a union with another emitter's codes has more than ``k`` codes or is the
  array's own set; one cancelled code leaves fewer than ``k``);
* (ii) two emitters closer than ``conflict_radius`` share no code if
  ``k = 2`` and at most one if ``k ≥ 3`` (a cancelled shared code then
  leaves ``k − 1`` codes: for ``k = 2`` a single code, a repeated ID;
  :func:`code_conflicts` lists violations);
* (iii) repeated emitters are at least ``conflict_radius`` apart (two
  singletons in range together would read as a pair).

``conflict_radius`` defaults to 0.70 m. The decoder counts a code as absent
only below half the strongest code (its relative guard), so a cancellation
by a farther emitter needs that emitter to be more than half as bright as
one inside the range, i.e. within 0.66 m of it at 1.2 m; and two emitters
are in range together only within 2 × 0.283 m. The price is capacity: one
lattice holds at most ``C(9, 4) = 126`` unique arrays instead of [W]'s 502
sets of ≥ 2 codes.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_finite, check_positive, check_positive_int, check_shape
from jaxnav.models.ir_codebook import (
    CODES,
    MASK_TO_ID,
    NUM_CODES,
    _check_codes,
    _mask_of,
    from_mask,
    id_name,
    parse_name,
)

__all__ = [
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
]

# --------------------------------------------------------------------------------------
# Layouts
# --------------------------------------------------------------------------------------


class EmitterLayout(NamedTuple):
    """Ceiling emitters (a pytree of arrays; ``E`` emitters).

    Attributes:
        positions: ``[E, 2]`` float32 emitter positions in the world frame (m).
        masks: ``[E]`` int32 ID bitmasks (bit ``c−1`` for code ``c``).
        unique: ``[E]`` bool, True for a unique ID (an LED array of ≥ 2 codes).
        ids: ``[E]`` int32 canonical IDs (:func:`~jaxnav.models.ir_codebook.encode`).
    """

    positions: jax.Array
    masks: jax.Array
    unique: jax.Array
    ids: jax.Array

    @property
    def num_emitters(self) -> int:
        return int(np.shape(self.masks)[0])


def validate_layout(layout: EmitterLayout) -> None:
    """Host-side checks: shapes, finite positions, masks in 1–511, unique IDs used once.

    Raises ``ValueError`` for a unique ID (≥ 2 codes) carried by two emitters
    ("a layout that must be unique"), and for ``unique``/``ids`` inconsistent
    with ``masks``.
    """
    check_shape("layout.positions", layout.positions, (None, 2))
    e = int(np.shape(layout.positions)[0])
    if e < 1:
        raise ValueError("layout must hold at least one emitter")
    for name in ("masks", "unique", "ids"):
        check_shape(f"layout.{name}", getattr(layout, name), (e,))
    check_finite("layout.positions", layout.positions)
    masks = np.asarray(layout.masks)
    if np.any((masks < 1) | (masks >= 2**NUM_CODES)):
        raise ValueError(f"layout.masks must be bitmasks in 1–{2**NUM_CODES - 1}, got {masks.tolist()}")
    pop = np.array([bin(int(m)).count("1") for m in masks])
    if not np.array_equal(np.asarray(layout.unique, bool), pop >= 2):
        raise ValueError("layout.unique must be True exactly for masks with two or more codes")
    if not np.array_equal(np.asarray(layout.ids), MASK_TO_ID[masks]):
        raise ValueError("layout.ids must be the canonical IDs of layout.masks (use make_layout)")
    uniq = masks[pop >= 2]
    vals, counts = np.unique(uniq, return_counts=True)
    if np.any(counts > 1):
        dup = [id_name(from_mask(int(v))) for v in vals[counts > 1]]
        idx = [np.flatnonzero(masks == v).tolist() for v in vals[counts > 1]]
        raise ValueError(
            f"duplicate unique IDs in the layout: {dup} at emitter indices {idx}; a unique ID "
            "(two or more codes) must be used by one emitter only ([W] §5.1)"
        )


def make_layout(positions: Any, code_sets: Sequence[Iterable[int] | int | str]) -> EmitterLayout:
    """Validated :class:`EmitterLayout` from positions ``[E, 2]`` (m) and one code set per emitter.

    A code set is an iterable of codes, a single code (repeated ID) or a name
    such as ``"39"``. Raises ``ValueError`` for codes outside the codebook or
    a unique ID used twice.
    """
    pos = np.asarray(positions, dtype=np.float64)
    check_shape("positions", pos, (None, 2))
    if len(code_sets) != pos.shape[0]:
        raise ValueError(f"code_sets has {len(code_sets)} entries for {pos.shape[0]} positions")
    sets = [
        parse_name(s) if isinstance(s, str) else _check_codes(s, name=f"code_sets[{i}]")
        for i, s in enumerate(code_sets)
    ]
    masks = np.array([_mask_of(s) for s in sets], dtype=np.int32)
    layout = EmitterLayout(
        positions=jnp.asarray(pos, jnp.float32),
        masks=jnp.asarray(masks),
        unique=jnp.asarray(np.array([len(s) >= 2 for s in sets])),
        ids=jnp.asarray(MASK_TO_ID[masks]),
    )
    validate_layout(layout)
    return layout


def layout_names(layout: EmitterLayout) -> list[str]:
    """[W]-style readable ID names of a layout's emitters (host-side), e.g. ``['1', '39', …]``."""
    return [id_name(from_mask(int(m))) for m in np.asarray(layout.masks)]


CONFLICT_RADIUS = 0.70
"""Decodability radius (m) of the layout rules (module docstring, "Decodability")."""


def _neighbours(positions: np.ndarray, radius: float) -> list[list[int]]:
    d = np.sqrt(((positions[:, None, :] - positions[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    return [np.flatnonzero(row < radius).tolist() for row in d]


def assign_unique_sets(
    positions: np.ndarray,
    sets: list[tuple[int, ...] | None],
    size: int | None,
    radius: float,
) -> list[tuple[int, ...]]:
    """Fill the ``None`` entries of ``sets`` with unique-ID code sets of one size.

    Greedy in emitter order, canonical order of candidates: each gets the first
    unused ``k``-set sharing no code (``k = 2``) or at most one (``k ≥ 3``)
    with any emitter within ``radius`` (rule (ii) of the module docstring). Tries
    ``k = 2, 3, …`` (or only ``size``) until every emitter is served.
    """
    nbrs = _neighbours(positions, radius)
    fixed_unique = {s for s in sets if s is not None and len(s) >= 2}
    sizes = range(2, NUM_CODES + 1) if size is None else [size]
    need = sum(s is None for s in sets)
    for k in sizes:
        if not 2 <= k <= NUM_CODES:
            raise ValueError(f"unique_size must be in 2–9, got {k}")
        if any(len(s) != k for s in fixed_unique):
            continue
        allowed = 0 if k == 2 else 1
        pool = list(itertools.combinations(CODES, k))
        used = set(fixed_unique)
        out = list(sets)
        ok = True
        for i, s in enumerate(out):
            if s is not None:
                continue
            near = [set(out[j]) for j in nbrs[i] if out[j] is not None]
            choice = next(
                (t for t in pool if t not in used and all(len(b.intersection(t)) <= allowed for b in near)), None
            )
            if choice is None:
                ok = False
                break
            out[i] = choice
            used.add(choice)
        if ok:
            return out  # type: ignore[return-value]
    raise ValueError(
        f"cannot give {need} emitters unique IDs of one size"
        f"{'' if size is None else f' ({size} codes)'} that share no code with emitters closer than "
        f"{radius} m: the codebook has C(9, k) sets of k codes (at most 126); use a smaller lattice"
    )


def code_conflicts(layout: EmitterLayout, radius: float = CONFLICT_RADIUS) -> list[tuple[int, int]]:
    """Pairs ``(i, j)``, ``i < j``, of emitters closer than ``radius`` (m) breaking rule (ii).

    Rule (ii) of the module docstring ("Decodability"): such emitters share
    no code when the unique arrays have ``k = 2`` codes (or there are none)
    and at most one when ``k ≥ 3`` (the largest array size is used). Empty
    for every layout built here. Host-side.
    """
    pos = np.asarray(layout.positions, np.float64)
    masks = np.asarray(layout.masks)
    k = max(bin(int(m)).count("1") for m in masks)
    allowed = 0 if k <= 2 else 1
    nbrs = _neighbours(pos, radius)
    return [
        (i, j)
        for i in range(len(nbrs))
        for j in nbrs[i]
        if i < j and bin(int(masks[i]) & int(masks[j])).count("1") > allowed
    ]


def lattice_layout(
    nx: int = 5,
    ny: int = 5,
    pitch: float = 0.80,
    origin: Sequence[float] = (0.0, 0.0),
    repeated_codes: Sequence[int] = CODES,
    unique_size: int | None = None,
    conflict_radius: float = CONFLICT_RADIUS,
) -> EmitterLayout:
    """The emitter lattice of [W] Fig. 5.1.

    ``nx × ny`` repeated-ID single LEDs at ``origin + pitch·(i, j)`` (m;
    default pitch 0.80 m, [W] §5.1), and a unique-ID LED array at the centre
    of each square of four, ``(nx−1)(ny−1)`` of them (repeated emitter
    ``(i, j)`` has index ``j·nx + i``; unique ``(i, j)`` has index
    ``nx·ny + j·(nx−1) + i``).

    Repeated IDs: with ``K = len(repeated_codes)`` codes (≥ 4), a
    ``kx × ky`` tile (``kx = ⌊√K⌋``, ``ky = ⌊K/kx⌋``; 3 × 3 for the nine codes)
    is repeated over the lattice, code ``repeated_codes[(i mod kx) + kx·(j mod
    ky)]``, so that all eight neighbours of an emitter carry different IDs
    (as in the figure) and two emitters with one ID are ≥ ``2·pitch`` apart.

    Unique IDs: sets of ``unique_size`` codes (default: the smallest size
    that works — pairs for up to a 5 × 5 lattice, then triples, then
    4-sets up to 126 arrays), each used once, chosen greedily in canonical
    order; pairs share no code with the emitters closer than
    ``conflict_radius`` (the four corners at the default pitch: a square's pair
    draws from the five codes its corners do not use), larger sets at most
    one. Module docstring, "Decodability".

    Raises ``ValueError`` for a non-positive pitch, a pitch below
    ``conflict_radius`` (two repeated LEDs could be seen at once), ``nx`` or
    ``ny`` < 2, or more squares than the codebook can serve.
    """
    nx = check_positive_int("nx", nx)
    ny = check_positive_int("ny", ny)
    if nx < 2 or ny < 2:
        raise ValueError(f"the lattice needs at least 2 × 2 repeated emitters, got nx={nx}, ny={ny}")
    check_positive("pitch", pitch)
    check_positive("conflict_radius", conflict_radius)
    if float(pitch) < float(conflict_radius):
        raise ValueError(
            f"pitch {float(pitch)} m is below conflict_radius {float(conflict_radius)} m: two emitters "
            "with one ID could be seen (or cancel each other) at once; use a wider pitch "
            "(module docstring, 'Decodability')"
        )
    org = np.asarray(origin, dtype=np.float64)
    check_shape("origin", org, (2,))
    check_finite("origin", org)
    rc = list(repeated_codes)
    for c in rc:
        _check_codes((c,), name="repeated_codes")
    if len(set(rc)) != len(rc) or len(rc) < 4:
        raise ValueError(
            f"repeated_codes must hold at least 4 distinct codes so that neighbours differ, got {tuple(rc)}"
        )
    kx = math.isqrt(len(rc))
    ky = len(rc) // kx
    p = float(pitch)
    positions: list[np.ndarray] = []
    sets: list[tuple[int, ...] | None] = []
    for j in range(ny):
        for i in range(nx):
            positions.append(org + p * np.array([i, j]))
            sets.append((rc[(i % kx) + kx * (j % ky)],))
    for j in range(ny - 1):
        for i in range(nx - 1):
            positions.append(org + p * np.array([i + 0.5, j + 0.5]))
            sets.append(None)
    pos = np.array(positions)
    return make_layout(pos, assign_unique_sets(pos, sets, unique_size, float(conflict_radius)))


def without_emitters(layout: EmitterLayout, indices: Iterable[int]) -> EmitterLayout:
    """The layout with the emitters at ``indices`` removed (failed emitters, [W] §5.4.5).

    Host-side; the remaining emitters keep their order. Raises ``ValueError``
    for an index out of range, a repeated index or removing every emitter.
    """
    e = layout.num_emitters
    idx = [int(i) for i in indices]
    bad = [i for i in idx if not -e <= i < e]
    if bad:
        raise ValueError(f"emitter indices {bad} out of range for a layout of {e} emitters")
    idx = sorted({i % e for i in idx})
    if len(idx) != len(list(indices)):
        raise ValueError(f"indices repeats an emitter: {list(indices)}")
    keep = np.setdiff1d(np.arange(e), idx)
    if keep.size == 0:
        raise ValueError("without_emitters would remove every emitter")
    out = EmitterLayout(*(jnp.asarray(np.asarray(a)[keep]) for a in layout))
    return out


def min_separation(layout: EmitterLayout) -> float:
    """Smallest distance between two emitters (m; ``inf`` for one emitter), host-side.

    Two emitters are in range at once only if closer than twice the range
    (2 × 283 mm ≈ 0.566 m, the diagonal of the 0.80 m lattice); the layout
    rules of the module docstring keep that harmless.
    """
    p = np.asarray(layout.positions, np.float64)
    if p.shape[0] < 2:
        return math.inf
    d = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(-1))
    d[np.diag_indices_from(d)] = np.inf
    return float(d.min())
