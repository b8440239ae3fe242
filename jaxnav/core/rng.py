"""``jax.random``'s bits, uniforms and normals, bit for bit, computed by arithmetic that XLA:CPU vectorises.

**Why this module exists**

``jax.random`` draws through the Threefry-2x32 hash. On the CPU, JAX lowers the
hash as a rolled loop of five iterations, each a separate XLA kernel over
the whole array, which makes the normal draws of a motion model the largest
part of an MCL step. The same hash written with ``jnp`` integer operations is one
elementwise expression that XLA fuses into a single vectorised loop (and into
the uniform transform after it), several times faster
(``benchmarks/profile_w2.py`` times the draw both ways, and the ``W2``
workload's ``jaxnav-plain`` row times the whole step with ``jax.random``).

**The numbers are jax.random's**

:func:`bits`, :func:`uniform` and :func:`normal` return exactly what
``jax.random.bits``, ``jax.random.uniform`` and ``jax.random.normal`` return
for the same key, shape and dtype, so a seed gives the same run with or
without this module. The defaults are jax.random's too: ``dtype=None`` is
``uint32`` for :func:`bits` and ``float32`` for :func:`uniform` and
:func:`normal`, or ``uint64`` and ``float64`` under ``jax_enable_x64``; a
64-bit dtype asked for without ``jax_enable_x64`` gives the 32-bit numbers
``jax.random`` gives for it. The fast form applies when the key is a Threefry key
(the default ``jax.random.key``/``PRNGKey``) and ``jax_threefry_partitionable``
is on (JAX's default), on the CPU; any other key implementation, setting or
backend calls ``jax.random`` itself, as does
:func:`jaxnav.core.fastmath.use_plain_forms`. ``tests/core/test_rng.py`` checks the
equality bit for bit, in float32 and float64, under ``jit``, ``vmap`` and
``lax.scan``.

Threefry-2x32 is Salmon et al., *Parallel random numbers: as easy as 1, 2, 3*
(SC 2011): 20 rounds of ``x₀ += x₁; x₁ = rotl(x₁, r) ⊕ x₀`` with a key
injection every 4. ``jax.random`` hashes the 64-bit position of each element
(as two 32-bit halves) and, for 32-bit output, XORs the hash's two words.
"""

from __future__ import annotations

import contextlib
import functools
import math
import threading
from collections.abc import Iterator, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import fastmath

__all__ = ["bits", "uniform", "normal", "particle_blocks"]

_U32 = np.uint32
_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_KEY_PARITY = 0x1BD11BDA


def _rotate_left(x: jax.Array, distance: int) -> jax.Array:
    return (x << _U32(distance)) | (x >> _U32(32 - distance))


def _threefry2x32(k0: jax.Array, k1: jax.Array, x0: jax.Array, x1: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The Threefry-2x32 hash (20 rounds) of the counter pairs ``(x0, x1)`` under the key ``(k0, k1)``."""
    schedule = (k0, k1, k0 ^ k1 ^ _U32(_KEY_PARITY))
    x0, x1 = x0 + schedule[0], x1 + schedule[1]
    for block in range(5):
        for distance in _ROTATIONS[block % 2]:
            x0 = x0 + x1
            x1 = x0 ^ _rotate_left(x1, distance)
        x0 = x0 + schedule[(block + 1) % 3]
        x1 = x1 + schedule[(block + 2) % 3] + _U32(block + 1)
    return x0, x1


def _is_threefry(key: jax.Array) -> bool:
    if not jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return str(jax.config.jax_default_prng_impl) == "threefry2x32" and key.shape == (2,)
    return str(jax.random.key_impl(key)) == "threefry2x32" and key.shape == ()


def _fast_form_applies(key: jax.Array, shape: tuple[int, ...], width: int) -> bool:
    return (
        not fastmath.use_plain_forms()
        and bool(jax.config.jax_threefry_partitionable)
        and _is_threefry(key)
        and width in (32, 64)
        and math.prod(shape) < 2**32
    )


def _key_data(key: jax.Array) -> jax.Array:
    return jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key


def _hash_words(key: jax.Array, shape: tuple[int, ...], offset: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """The two hash words of each element of ``shape`` (the element's flat position is the counter),
    the positions starting at ``offset`` (a block of a larger draw) when given."""
    data = _key_data(key)
    position = jax.lax.iota(_U32, math.prod(shape)).reshape(shape)
    if offset is not None:
        position = position + offset
    return _threefry2x32(data[0], data[1], jnp.zeros(shape, _U32), position)


# The fast forms are jitted (inlined into an enclosing jit) as jax.random's are: called eagerly, each is
# then one compiled program, which XLA contracts and fuses as it does jax.random's, so the floats agree
# to the last bit.
@functools.partial(jax.jit, static_argnums=(1, 2), inline=True)
def _fast_bits(key: jax.Array, shape: tuple[int, ...], width: int, offset: jax.Array | None = None) -> jax.Array:
    hi, lo = _hash_words(key, shape, offset)
    if width == 32:
        return hi ^ lo
    return (hi.astype(jnp.uint64) << np.uint64(32)) | lo.astype(jnp.uint64)


def _cpu_only(fast, plain, *operands):
    """``fast(*operands)`` on the CPU, ``plain(*operands)`` elsewhere (JAX's own lowering there is not the rolled loop)."""
    return jax.lax.platform_dependent(*operands, cpu=fast, default=plain)


def _as_shape(shape: int | Sequence[int]) -> tuple[int, ...]:
    return (int(shape),) if isinstance(shape, int | np.integer) else tuple(int(s) for s in shape)


# --------------------------------------------------------------------------- blocks of a draw over devices

_BLOCKS = threading.local()  # .open: [(mesh axis, rows per device)] while particle_blocks is open, per thread


def _open_blocks() -> list[tuple[str, int]]:
    if not hasattr(_BLOCKS, "open"):
        _BLOCKS.open = []
    return _BLOCKS.open


@contextlib.contextmanager
def particle_blocks(axis_name: str, rows: int) -> Iterator[None]:
    """While tracing inside it (inside ``jax.shard_map``), a draw of :func:`bits`, :func:`uniform` or
    :func:`normal` whose leading axis is ``rows`` is this device's block of the draw of the whole
    array, ``(rows · D, ...)`` over the ``D`` devices of mesh axis ``axis_name``, bit for bit.

    A particle filter whose particles are spread over devices (``rows`` per device) traces its
    motion model in this context, so that every particle moves with the noise it gets on one
    device. A draw of another leading length is left as it is (the same on every device). Each
    device hashes only its own positions (the Threefry counters of its block), on every backend;
    where that form does not apply (another key implementation, ``jax_threefry_partitionable``
    off) the whole array is drawn with ``jax.random`` and the block sliced from it. A motion model
    that draws with ``jax.random`` directly would draw the same noise on every device: the models
    of :mod:`jaxnav.models.motion` draw with this module.

    The rule is applied while tracing, by shape, in the thread that opened the context: a
    per-particle draw laid out ``(k, rows)`` is not a block, a draw shared by all particles whose
    length happens to be ``rows`` is one, and a function jitted outside the context may reuse a
    trace made there. The built-in motion models draw ``(rows, k)`` and nothing else of length ``rows``.
    ``uniform``'s bounds must be scalars in a block.
    """
    blocks = _open_blocks()
    blocks.append((axis_name, int(rows)))
    try:
        yield
    finally:
        blocks.pop()


def _block_of(shape: tuple[int, ...]) -> tuple[tuple[int, ...], str] | None:
    """The whole draw's shape and the mesh axis when a draw of ``shape`` is a device's block."""
    blocks = _open_blocks()
    if not blocks or not shape or shape[0] != blocks[-1][1]:
        return None
    axis_name, rows = blocks[-1]
    return (rows * jax.lax.axis_size(axis_name), *shape[1:]), axis_name


def _block_draw(key: jax.Array, shape: tuple[int, ...], whole: tuple[int, ...], axis_name: str, fast, plain):
    """This device's block of a draw of ``whole``: ``fast(key, offset)`` over the block's own positions
    when the fast form applies to ``whole``, else ``plain(key)`` of ``whole``, sliced."""
    me = jax.lax.axis_index(axis_name)
    if fast is not None:  # the whole draw has fewer than 2³² elements: the offset fits in uint32
        return fast(key, me.astype(_U32) * _U32(math.prod(shape)))
    return jax.lax.dynamic_slice_in_dim(plain(key), me * shape[0], shape[0], axis=0)


def bits(key: jax.Array, shape: int | Sequence[int] = (), dtype=None) -> jax.Array:
    """Uniform random bits: ``jax.random.bits(key, shape, dtype)``, bit for bit (see the module docstring).

    ``dtype``: an unsigned integer type; ``None`` is JAX's default one, ``uint32``, or ``uint64``
    under ``jax_enable_x64``. Each element is ``b`` bits uniform on ``[0, 2ᵇ)``, ``b`` the width of
    the canonical dtype (``uint64`` without ``jax_enable_x64`` is ``uint32``, as in ``jax.random``).
    """
    requested = dtype
    shape = _as_shape(shape)
    dtype = jnp.dtype(jax.dtypes.canonicalize_dtype(jnp.uint64 if dtype is None else dtype))
    width = dtype.itemsize * 8
    block = _block_of(shape)
    if block is not None:
        whole, axis_name = block
        fast = jnp.issubdtype(dtype, jnp.unsignedinteger) and _fast_form_applies(key, whole, width)
        return _block_draw(
            key,
            shape,
            whole,
            axis_name,
            (lambda k, offset: _fast_bits(k, shape, width, offset)) if fast else None,
            lambda k: jax.random.bits(k, whole, requested),
        )
    if not (jnp.issubdtype(dtype, jnp.unsignedinteger) and _fast_form_applies(key, shape, width)):
        return jax.random.bits(key, shape, requested)
    return _cpu_only(lambda k: _fast_bits(k, shape, width), lambda k: jax.random.bits(k, shape, dtype), key)


def _fast_float_dtype(key: jax.Array, shape: tuple[int, ...], dtype) -> np.dtype | None:
    """The canonical ``dtype`` when the fast form computes the draw (float32 or float64), else ``None``."""
    dtype = jnp.dtype(jax.dtypes.canonicalize_dtype(float if dtype is None else dtype))
    if dtype not in (jnp.dtype(jnp.float32), jnp.dtype(jnp.float64)):
        return None
    return dtype if _fast_form_applies(key, shape, dtype.itemsize * 8) else None


def _unit_floats(raw: jax.Array, dtype: np.dtype) -> jax.Array:
    """``[1, 2) − 1`` from the high mantissa bits of ``raw``, as ``jax.random.uniform`` builds them."""
    info = jnp.finfo(dtype)
    mantissa = raw >> np.asarray(info.bits - info.nmant, raw.dtype)
    one = np.array(1.0, dtype).view(raw.dtype)
    return jax.lax.bitcast_convert_type(mantissa | one, dtype) - jnp.asarray(1.0, dtype)


def _uniform_from_bits(raw: jax.Array, minval, maxval, dtype: np.dtype) -> jax.Array:
    """``jax.random.uniform``'s floats in ``[minval, maxval)`` from its random words ``raw``."""
    floats = _unit_floats(raw, dtype)
    return jax.lax.max(minval, floats * (maxval - minval) + minval)


@functools.partial(jax.jit, static_argnums=(3, 4), inline=True)
def _fast_uniform(
    key: jax.Array, minval, maxval, shape: tuple[int, ...], dtype: np.dtype, offset: jax.Array | None = None
) -> jax.Array:
    return _uniform_from_bits(_fast_bits(key, shape, jnp.finfo(dtype).bits, offset), minval, maxval, dtype)


def uniform(
    key: jax.Array,
    shape: int | Sequence[int] = (),
    dtype=None,
    minval: float | jax.Array = 0.0,
    maxval: float | jax.Array = 1.0,
) -> jax.Array:
    """Uniform floats in ``[minval, maxval)``: ``jax.random.uniform(key, shape, dtype, minval, maxval)``, bit for bit.

    ``minval`` and ``maxval`` are scalars or arrays broadcastable to ``shape`` (as in ``jax.random``);
    ``dtype=None`` is JAX's default float, ``float32`` (``float64`` under ``jax_enable_x64``).
    """
    shape = _as_shape(shape)
    block = _block_of(shape)
    if block is not None:
        whole, axis_name = block
        if np.ndim(minval) or np.ndim(maxval):
            raise ValueError("uniform draws in particle_blocks take scalar minval and maxval")
        fast_dtype = _fast_float_dtype(key, whole, dtype)
        plain_dtype = float if dtype is None else dtype
        plain = lambda k: jax.random.uniform(k, whole, plain_dtype, minval, maxval)  # noqa: E731
        if fast_dtype is None:
            return _block_draw(key, shape, whole, axis_name, None, plain)
        lo, hi = (jnp.asarray(v).astype(fast_dtype) for v in (minval, maxval))
        fast = lambda k, offset: _fast_uniform(k, lo, hi, shape, fast_dtype, offset)  # noqa: E731
        return _block_draw(key, shape, whole, axis_name, fast, plain)
    fast_dtype = _fast_float_dtype(key, shape, dtype)
    if fast_dtype is None:
        return jax.random.uniform(key, shape, float if dtype is None else dtype, minval, maxval)
    dtype = fast_dtype
    lo = jax.lax.broadcast_to_rank(jnp.asarray(minval).astype(dtype), len(shape))
    hi = jax.lax.broadcast_to_rank(jnp.asarray(maxval).astype(dtype), len(shape))
    return _cpu_only(
        lambda k, a, b: _fast_uniform(k, a, b, shape, dtype),
        lambda k, a, b: jax.random.uniform(k, shape, dtype, a, b),
        key,
        lo,
        hi,
    )


def _kept_apart(x: jax.Array, key_data: jax.Array) -> jax.Array:
    """``x``, computed by XLA as a buffer of its own rather than inside its consumer's loop.

    A ``while`` loop is a boundary that XLA does not fuse across; this one never runs
    (its counter starts at ``key_data[0] >> 1``, which is ≥ 0, and runs while it is
    negative), but XLA cannot prove it, so it keeps the loop and ``x`` is written once.
    Were a compiler to remove the loop, the result would be the same, only slower.
    """
    start = (key_data[0] >> np.uint32(1)).astype(jnp.int32)
    never = lambda c: c[0] < 0  # noqa: E731
    step = lambda c: (c[0] + 1, c[1] ^ c[0].astype(c[1].dtype))  # noqa: E731
    return jax.lax.while_loop(never, step, (start, x))[1]


@functools.partial(jax.jit, static_argnums=(1, 2), inline=True)
def _fast_normal(key: jax.Array, shape: tuple[int, ...], dtype: np.dtype, offset: jax.Array | None = None) -> jax.Array:
    lo = np.nextafter(np.array(-1.0, dtype), np.array(0.0, dtype), dtype=dtype)
    # Fused into one loop, the hash and erf⁻¹ ran several times slower on XLA:CPU than the two as
    # separate loops (benchmarks/profile_w2.py, normal_jaxnav): the bits get a buffer of their own.
    raw = _kept_apart(_fast_bits(key, shape, jnp.finfo(dtype).bits, offset), _key_data(key))
    u = _uniform_from_bits(raw, jnp.asarray(lo), jnp.asarray(1.0, dtype), dtype)
    return jax.lax.mul(np.array(np.sqrt(2), dtype), jax.lax.erf_inv(u))


def normal(key: jax.Array, shape: int | Sequence[int] = (), dtype=None) -> jax.Array:
    """Standard normal draws: ``jax.random.normal(key, shape, dtype)``, bit for bit.

    ``√2·erf⁻¹(u)`` with ``u`` uniform on ``(−1, 1)``, as JAX computes it; ``dtype=None`` is JAX's
    default float, ``float32`` (``float64`` under ``jax_enable_x64``).
    """
    shape = _as_shape(shape)
    block = _block_of(shape)
    if block is not None:
        whole, axis_name = block
        fast_dtype = _fast_float_dtype(key, whole, dtype)
        fast = None if fast_dtype is None else (lambda k, offset: _fast_normal(k, shape, fast_dtype, offset))
        plain = lambda k: jax.random.normal(k, whole, float if dtype is None else dtype)  # noqa: E731
        return _block_draw(key, shape, whole, axis_name, fast, plain)
    fast_dtype = _fast_float_dtype(key, shape, dtype)
    if fast_dtype is None:
        return jax.random.normal(key, shape, float if dtype is None else dtype)
    dtype = fast_dtype
    return _cpu_only(
        lambda k: _fast_normal(k, shape, dtype),
        lambda k: jax.random.normal(k, shape, dtype),
        key,
    )
