"""IR emitter positioning: frequency-coded IDs, emitter layouts, voltage model, belief ([W] ch. 5).

**Overview**

IR LEDs on the ceiling are landmarks with known positions ([W] §5.1). Each
LED is on-off keyed (OOK) at one of the nine frequencies of [W] Table 5.1::

    code            1     2     3     4     5     6     7     8     9
    frequency (Hz)  100   150   250   350   550   650   850   950   1150

(:data:`FREQUENCIES_HZ`). An emitter's **ID is a non-empty set of codes**:

* a *repeated ID* is one code (a single LED, [W] Fig. 5.2b); the same ID is
  used by many emitters of the lattice and is disambiguated by the belief of
  [W] eq. 5.1 (:func:`select_emitter`);
* a *unique ID* is a set of two or more codes (an LED array, one LED per
  code, [W] Fig. 5.2a), used once in a layout.

[W] writes an ID as its codes in increasing order: ID ``39`` is codes 3 and 9
(0.25 kHz and 1.15 kHz). :func:`id_name` / :func:`parse_name` give that
readable form.

**Canonical numbering**

The 2⁹ − 1 = 511 non-empty subsets are numbered ``0 … 510`` in order of
(size, lexicographic order of the sorted codes): IDs 0–8 are the repeated
IDs of codes 1–9 (``id = code − 1``), IDs 9–44 the 36 pairs
(``{1,2}, {1,3}, …, {8,9}``), then the 84 triples, and so on up to ID 510 =
``{1,…,9}``. :func:`encode` / :func:`decode` are this bijection (host-side;
IDs are static data). Inside jitted code an ID travels as a **bitmask**
(``int32``, bit ``c−1`` set for code ``c``; ID 39 → ``0b100000100`` = 260):
:func:`to_mask`, :func:`from_mask` on the host, :func:`mask_to_id`,
:func:`id_to_mask`, :func:`mask_bits` as jnp table look-ups / bit tests.

**Capacity and memory ([W] §5.3)**

With ``n`` frequencies and at most ``p`` LEDs (microcontroller pins) per array
there are ``Σ_{k=1}^{min(n,p)} C(n, k)`` IDs (:func:`capacity`): 511 for
``n = p = 9``, 768,211 for ``n = 30``, ``p = 6``. With an ``L_r × W_r``
lattice of repeated-ID emitters, Fig. 5.1 puts ``(L_r − 1)(W_r − 1)``
unique arrays at the square centres; the map needs ``(L_r−1)(W_r−1) + 9``
entries with 9 repeated IDs, against ``(L_r−1)(W_r−1) + L_r·W_r`` if every
emitter had a unique ID (:func:`memory_size`; 239,010 vs 479,001 for
600 × 400).

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

import itertools
import math
from collections.abc import Iterable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxnav.core.optim import lbfgs_minimize
from jaxnav.core.validation import (
    check_finite,
    check_positive,
    check_positive_int,
    check_shape,
    first_index,
    is_concrete,
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
# Codebook ([W] Table 5.1)
# --------------------------------------------------------------------------------------

FREQUENCIES_HZ: tuple[float, ...] = (100.0, 150.0, 250.0, 350.0, 550.0, 650.0, 850.0, 950.0, 1150.0)
"""OOK frequency of code ``c`` is ``FREQUENCIES_HZ[c − 1]`` (Hz), [W] Table 5.1."""

CODES: tuple[int, ...] = tuple(range(1, 10))
"""The code numbers 1–9 of [W] Table 5.1."""

NUM_CODES = 9
NUM_IDS = 2**NUM_CODES - 1  # 511

_ALL_SETS: tuple[tuple[int, ...], ...] = tuple(
    s for k in range(1, NUM_CODES + 1) for s in itertools.combinations(CODES, k)
)
_SET_TO_ID: dict[tuple[int, ...], int] = {s: i for i, s in enumerate(_ALL_SETS)}


def _mask_of(codes: Iterable[int]) -> int:
    m = 0
    for c in codes:
        m |= 1 << (c - 1)
    return m


ID_TO_MASK: np.ndarray = np.array([_mask_of(s) for s in _ALL_SETS], dtype=np.int32)
"""``[511]`` int32, the bitmask of canonical ID ``i``."""

MASK_TO_ID: np.ndarray = np.full(2**NUM_CODES, -1, dtype=np.int32)
"""``[512]`` int32, the canonical ID of bitmask ``m`` (−1 for the empty mask 0)."""
MASK_TO_ID[ID_TO_MASK] = np.arange(NUM_IDS, dtype=np.int32)


def _check_codes(codes: Any, name: str = "codes") -> tuple[int, ...]:
    """Validate a code set: non-empty, integers in 1–9, no repeats; returns it sorted."""
    if isinstance(codes, (int, np.integer)) and not isinstance(codes, bool):
        codes = (int(codes),)
    try:
        items = list(codes)
    except TypeError:
        raise ValueError(f"{name} must be a non-empty set of codes 1–9, got {codes!r}") from None
    if not items:
        raise ValueError(f"{name} must be a non-empty set of codes 1–9 ([W] Table 5.1), got an empty set")
    out = []
    for c in items:
        if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or not 1 <= int(c) <= NUM_CODES:
            raise ValueError(
                f"{name}: {c!r} is not in the codebook; codes are the integers 1–9 of [W] Table 5.1 "
                f"(frequencies {', '.join(f'{f:g}' for f in FREQUENCIES_HZ)} Hz)"
            )
        out.append(int(c))
    if len(set(out)) != len(out):
        raise ValueError(f"{name} repeats a code: {tuple(out)}; an ID is a set of distinct codes")
    return tuple(sorted(out))


def encode(codes: Iterable[int] | int) -> int:
    """Canonical ID (0–510) of a non-empty set of codes (host-side).

    Ordering: by set size, then lexicographically (module docstring). A single
    code ``c`` (a repeated ID) gives ``c − 1``. Raises ``ValueError`` for codes
    outside 1–9, an empty set or a repeated code.
    """
    return _SET_TO_ID[_check_codes(codes)]


def decode(id_: int) -> tuple[int, ...]:
    """Sorted codes of canonical ID ``id_`` (0–510); the inverse of :func:`encode`."""
    if isinstance(id_, bool) or not isinstance(id_, (int, np.integer)) or not 0 <= int(id_) < NUM_IDS:
        raise ValueError(f"id must be an integer in 0–{NUM_IDS - 1}, got {id_!r}")
    return _ALL_SETS[int(id_)]


def to_mask(codes: Iterable[int] | int) -> int:
    """Bitmask of a code set (bit ``c − 1`` for code ``c``), host-side, validated."""
    return _mask_of(_check_codes(codes))


def from_mask(mask: int) -> tuple[int, ...]:
    """Sorted codes of a non-zero bitmask in 1–511 (host-side)."""
    m = int(mask)
    if not 1 <= m < 2**NUM_CODES:
        raise ValueError(f"mask must be an integer in 1–{2**NUM_CODES - 1}, got {mask!r}")
    return tuple(c for c in CODES if m >> (c - 1) & 1)


def id_name(codes_or_id: Iterable[int] | int, *, is_id: bool = False) -> str:
    """[W]'s readable name: the sorted code digits, e.g. ``{3, 9}`` → ``"39"``.

    Pass a code set, a single code, or (``is_id=True``) a canonical ID.
    """
    codes = decode(codes_or_id) if is_id else _check_codes(codes_or_id)
    return "".join(str(c) for c in codes)


def parse_name(name: str) -> tuple[int, ...]:
    """Codes of a readable ID name such as ``"39"`` (digits 1–9, each at most once)."""
    s = str(name).strip()
    if not s or not s.isdigit():
        raise ValueError(f"an ID name is a string of code digits 1–9 such as '39', got {name!r}")
    return _check_codes([int(ch) for ch in s], name=f"ID name {name!r}")


def mask_to_id(mask: jax.Array) -> jax.Array:
    """Canonical ID of an int bitmask (−1 for 0 or out of range); jit-friendly table look-up."""
    mask = jnp.asarray(mask, jnp.int32)
    ok = (mask > 0) & (mask < 2**NUM_CODES)
    return jnp.where(ok, jnp.asarray(MASK_TO_ID)[jnp.clip(mask, 0, 2**NUM_CODES - 1)], -1)


def id_to_mask(id_: jax.Array) -> jax.Array:
    """Bitmask of a canonical ID (0 for an ID outside 0–510); jit-friendly."""
    id_ = jnp.asarray(id_, jnp.int32)
    ok = (id_ >= 0) & (id_ < NUM_IDS)
    return jnp.where(ok, jnp.asarray(ID_TO_MASK)[jnp.clip(id_, 0, NUM_IDS - 1)], 0)


def mask_bits(mask: jax.Array) -> jax.Array:
    """``[..., 9]`` bool: which codes (1–9, in order) a bitmask holds."""
    mask = jnp.asarray(mask, jnp.int32)
    return ((mask[..., None] >> jnp.arange(NUM_CODES, dtype=jnp.int32)) & 1).astype(bool)


def popcount(mask: jax.Array) -> jax.Array:
    """Number of codes in a bitmask (int32)."""
    return jnp.sum(mask_bits(mask), axis=-1, dtype=jnp.int32)


def bits_to_mask(bits: jax.Array) -> jax.Array:
    """Inverse of :func:`mask_bits`: ``[..., 9]`` bool → int32 bitmask."""
    weights = (2 ** jnp.arange(NUM_CODES)).astype(jnp.int32)
    return jnp.sum(jnp.where(bits, weights, 0), axis=-1, dtype=jnp.int32)


# --------------------------------------------------------------------------------------
# Capacity and memory ([W] §5.3)
# --------------------------------------------------------------------------------------


def capacity(n_frequencies: int, max_pins: int | None = None) -> int:
    """Number of IDs from ``n`` frequencies with at most ``max_pins`` LEDs per array ([W] §5.3).

    ``Σ_{k=1}^{min(n, pins)} C(n, k)``; ``= 2ⁿ − 1`` without a pin limit.
    ``capacity(9) == 511``, ``capacity(30, 6) == 768211``.
    """
    n = check_positive_int("n_frequencies", n_frequencies)
    p = n if max_pins is None else check_positive_int("max_pins", max_pins)
    return sum(math.comb(n, k) for k in range(1, min(n, p) + 1))


def memory_size(lines_x: int, lines_y: int, n_repeated_ids: int = 9) -> tuple[int, int]:
    """Map entries needed by the proposed layout and by a unique-ID-only layout ([W] §5.3).

    ``lines_x × lines_y`` (``L_r × W_r``) repeated-ID emitters with
    ``(L_r−1)(W_r−1)`` unique arrays at the square centres (Fig. 5.1). The
    proposed system stores each unique emitter and one entry per repeated ID,
    ``(L_r−1)(W_r−1) + n_repeated_ids``; a unique-only system stores every
    emitter, ``(L_r−1)(W_r−1) + L_r·W_r``. ``memory_size(600, 400) ==
    (239010, 479001)``.
    """
    lx = check_positive_int("lines_x", lines_x)
    ly = check_positive_int("lines_y", lines_y)
    k = check_positive_int("n_repeated_ids", n_repeated_ids)
    squares = (lx - 1) * (ly - 1)
    return squares + k, squares + lx * ly


def harmonic_collisions(
    frequencies_hz: Sequence[float] = FREQUENCIES_HZ, max_hz: float = 5000.0, tol_hz: float = 1e-6
) -> list[tuple[float, int, float]]:
    """Harmonics ``h·f`` (``h ≥ 2``, up to ``max_hz``) that land on another code frequency.

    Returns ``(f, h, f')`` triples. For Table 5.1 the list is empty at any
    ``max_hz``: in units of 50 Hz the codes are 2, 3, 5, 7, 11, 13, 17, 19, 23
    — 2 and odd primes — so ``h·c = c'`` forces ``h = 1``. This is why a plain
    FFT read of the nine bins decodes square waves (whose odd, and for a duty
    cycle ≠ ½ also even, harmonics are strong) without any harmonic
    subtraction (:mod:`jaxnav.sim.ir_receiver`).
    """
    out = []
    for f in frequencies_hz:
        h = 2
        while h * f <= max_hz + tol_hz:
            for g in frequencies_hz:
                if abs(h * f - g) <= tol_hz:
                    out.append((float(f), h, float(g)))
            h += 1
    return out


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
# Layouts
# --------------------------------------------------------------------------------------


class EmitterLayout(NamedTuple):
    """Ceiling emitters (a pytree of arrays; ``E`` emitters).

    Attributes:
        positions: ``[E, 2]`` float32 emitter positions in the world frame (m).
        masks: ``[E]`` int32 ID bitmasks (bit ``c−1`` for code ``c``).
        unique: ``[E]`` bool, True for a unique ID (an LED array of ≥ 2 codes).
        ids: ``[E]`` int32 canonical IDs (:func:`encode`).
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
