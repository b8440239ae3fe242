"""The IR emitter codebook of [W] ch. 5: frequency-coded IDs, their numbering, capacity and memory.

**Overview**

IR LEDs on the ceiling are landmarks with known positions ([W] §5.1). Each
LED is on-off keyed (OOK) at one of the nine frequencies of [W] Table 5.1::

    code            1     2     3     4     5     6     7     8     9
    frequency (Hz)  100   150   250   350   550   650   850   950   1150

(:data:`FREQUENCIES_HZ`). An emitter's **ID is a non-empty set of codes**:

* a *repeated ID* is one code (a single LED, [W] Fig. 5.2b); the same ID is
  used by many emitters of the lattice and is disambiguated by the belief of
  [W] eq. 5.1 (:func:`~jaxnav.models.ir.select_emitter`);
* a *unique ID* is a set of two or more codes (an LED array, one LED per
  code, [W] Fig. 5.2a), used once in a layout (:mod:`jaxnav.models.ir_layouts`).

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
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_positive_int

__all__ = [
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
