"""Fixed-lag ring buffers with static capacity.

**Overview**

A fixed-lag smoother ([W] §4.1–4.2, Kitagawa 1996) keeps the last ``L``
states of every particle. Shifting an ``[L, ...]`` array each step costs
O(L·size); a ring buffer writes one slot at ``head`` and advances
``head = (head + 1) mod L``, so a push costs O(size) and updates in place
inside ``lax.scan``.

Layout: ``data`` has shape ``[L, *item_shape]``; ``head`` is the slot the next
push writes; ``count`` is how many slots hold valid entries (``≤ L``). Slots
not yet written hold zeros (never NaN) and are excluded by ``count`` — the same
contract as diffrax's padded ``max_steps`` outputs: the buffer's shape is
fixed, validity is data.

Batched buffers (one ring per particle, per tag) are these functions under a
plain ``vmap``; the lag axis is then axis 1, 2, … of the stacked arrays.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["RingBuffer", "ring_init", "ring_push", "ring_ordered", "ring_valid_mask", "ring_mean", "ring_latest"]


class RingBuffer(NamedTuple):
    """A fixed-capacity ring of the last ``L`` items.

    Attributes:
        data: ``[L, *item_shape]`` storage.
        head: int32 scalar, slot the next push writes.
        count: int32 scalar, number of valid entries, ``0 ≤ count ≤ L``.
    """

    data: jax.Array
    head: jax.Array
    count: jax.Array

    @property
    def capacity(self) -> int:
        return self.data.shape[0]


def ring_init(capacity: int, item_shape: tuple[int, ...] = (), dtype: Any = jnp.float32) -> RingBuffer:
    """An empty ring holding up to ``capacity`` items of ``item_shape``."""
    if int(capacity) < 1:
        raise ValueError(f"capacity must be a positive integer (the lag L), got {capacity!r}")
    return RingBuffer(
        jnp.zeros((int(capacity),) + tuple(item_shape), dtype),
        jnp.zeros((), jnp.int32),
        jnp.zeros((), jnp.int32),
    )


def ring_push(ring: RingBuffer, item: jax.Array) -> RingBuffer:
    """Write ``item`` at ``head`` (overwriting the oldest entry once full)."""
    cap = ring.data.shape[0]
    data = jax.lax.dynamic_update_index_in_dim(ring.data, item.astype(ring.data.dtype), ring.head, 0)
    return RingBuffer(data, (ring.head + 1) % cap, jnp.minimum(ring.count + 1, cap))


def ring_ordered(ring: RingBuffer) -> jax.Array:
    """The stored items oldest first: ``[L, *item_shape]``.

    When the ring is not yet full the valid entries come *last* (the leading
    ``L − count`` rows are unwritten zeros); combine with :func:`ring_valid_mask`.
    """
    cap = ring.data.shape[0]
    order = (ring.head + jnp.arange(cap)) % cap
    return jnp.take(ring.data, order, axis=0)


def ring_valid_mask(ring: RingBuffer) -> jax.Array:
    """``[L]`` bool, True for valid rows of :func:`ring_ordered`."""
    cap = ring.data.shape[0]
    return jnp.arange(cap) >= cap - ring.count


def ring_latest(ring: RingBuffer) -> jax.Array:
    """The most recently pushed item (zeros if the ring is empty)."""
    cap = ring.data.shape[0]
    return jax.lax.dynamic_index_in_dim(ring.data, (ring.head - 1) % cap, 0, keepdims=False)


def ring_mean(ring: RingBuffer, last: int | None = None) -> jax.Array:
    """Mean over the last ``min(last, count)`` valid items (all valid ones by default).

    This is the fixed-lag smoothed estimate of [W] §4.2 (mean over the last
    L states). Returns zeros for an empty ring rather than NaN.
    """
    cap = ring.data.shape[0]
    window = cap if last is None else min(int(last), cap)
    if window < 1:
        raise ValueError(f"last must be a positive integer, got {last!r}")
    # Slot s holds the item pushed (head - 1 - s) mod L pushes ago (age 0 = newest).
    age = (ring.head - 1 - jnp.arange(cap)) % cap
    valid = age < jnp.minimum(ring.count, window)
    n = jnp.maximum(jnp.sum(valid), 1).astype(ring.data.dtype)
    # a select, not a product with 0/1 weights: XLA:CPU runs the weighted sum as a YNNPACK
    # reduction, several times slower than this (it dominated PS-SLAM's step)
    mask = valid.reshape((cap,) + (1,) * (ring.data.ndim - 1))
    return jnp.sum(jnp.where(mask, ring.data, 0.0), axis=0) / n
