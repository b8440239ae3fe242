"""What a filter's ``step`` and ``run`` check on the host before they call the compiled program.

The rules are those of :mod:`jaxnav.core.filter` (its docstring lists them); this module holds
their machinery, which :func:`jaxnav.core.filter.build` wires into every filter:

* :class:`ParamsMemo`: the parameters are checked once per ``(config, values)`` pair;
* :func:`check_params_arrays` and :func:`check_state_arrays`: the checks every filter's parameters
  and state pass (finite, within :data:`~jaxnav.core.validation.MAX_MAGNITUDE`, one precision);
* :func:`check_not_donated` and :func:`check_state_precision`: a state whose buffers were donated,
  or that is in another precision than the filter computes in, is refused by name;
* :class:`KnownStates`: a state the filter itself just returned or checked is not read again;
* :func:`plain_sequences_as_arrays`: a list of numbers given as an input is an array.
"""

from __future__ import annotations

import hashlib
import threading
import weakref
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import MAX_MAGNITUDE, check_magnitude, dtype_of, first_index, is_array_value


class ParamsMemo:
    """The ``(config, params)`` values that passed ``check``: each distinct pair is checked once.

    The memo is keyed on values (``_fingerprint``). Hashing the values at every call of an
    online loop would cost more than a small step, so the leaves of the last parameters are kept:
    when a call passes the very same leaves again and all of them are JAX arrays (immutable), their
    values are those already hashed. Leaves that can change in place (NumPy arrays) are hashed at
    every call.
    """

    def __init__(self, check: Callable[[Any, Any], None], maxsize: int = 64) -> None:
        self._check = check
        self._maxsize = maxsize
        self._passed: OrderedDict[tuple, np.dtype | None] = OrderedDict()  # memo key -> widest float dtype
        self._lock = threading.Lock()
        self._last: tuple | None = None  # (treedef, leaves, memo key, float dtype) of the last immutable params

    def __call__(self, config: Any, params: Any) -> np.dtype | None:
        """Checks ``params`` unless these values passed with ``config`` before; returns the widest
        floating-point dtype among their leaves (``None`` if none), for :func:`check_state_precision`."""
        leaves, treedef = jax.tree_util.tree_flatten(params)
        last = self._last
        if (
            last is not None
            and last[0] == treedef
            and len(last[1]) == len(leaves)
            and all(a is b for a, b in zip(last[1], leaves))
            and (last[2][0] is config or last[2][0] == config)
        ):
            return last[3]  # the same immutable arrays as the last call, already checked with this config
        fingerprint = _fingerprint(leaves, treedef)
        if fingerprint is None:  # tracers (values unknown) or leaves that are not arrays
            self._check(config, params)
            return _widest_float(leaves)
        memo_key = (config, fingerprint)
        with self._lock:
            known = memo_key in self._passed
            if known:
                self._passed.move_to_end(memo_key)
                float_dtype = self._passed[memo_key]
        if not known:
            self._check(config, params)
            float_dtype = _widest_float(leaves)
            with self._lock:
                self._passed[memo_key] = float_dtype
                while len(self._passed) > self._maxsize:
                    self._passed.popitem(last=False)
        immutable = all(isinstance(leaf, jax.Array) for leaf in leaves)
        self._last = (treedef, leaves, memo_key, float_dtype) if immutable else None
        return float_dtype


def _widest_float(leaves: Sequence[Any]) -> np.dtype | None:
    """The widest floating-point dtype among the array ``leaves`` that set the precision of the
    arithmetic (``None`` if none): Python numbers and weakly typed JAX scalars take the dtype of
    the arrays they meet, so they are left out."""
    dtypes = [getattr(leaf, "dtype", None) for leaf in leaves if not getattr(leaf, "weak_type", False)]
    floats = [np.dtype(d) for d in dtypes if d is not None and np.dtype(d).kind == "f"]
    return max(floats, key=lambda d: d.itemsize) if floats else None


def _fingerprint(leaves: list, treedef: Any) -> tuple | None:
    """Tree structure, shapes, dtypes and a 128-bit hash of the values of a pytree's ``leaves``;
    ``None`` when a leaf is a tracer or not an array of numbers."""
    digest = hashlib.blake2b(digest_size=16)
    meta = []
    for leaf in leaves:
        if isinstance(leaf, jax.core.Tracer):
            return None
        try:
            values = np.asarray(leaf)
        except Exception:  # noqa: BLE001  (a leaf NumPy cannot read: check every call)
            return None
        if values.dtype.kind not in "biufc":
            return None
        meta.append((values.shape, values.dtype.str, type(leaf).__name__))
        digest.update(np.ascontiguousarray(values).tobytes())
    return treedef, tuple(meta), digest.digest()


def named_leaves(tree: Any, root: str = "state") -> list[tuple[str, Any]]:
    """``("state.field.sub", leaf)`` for every leaf of ``tree``."""
    named = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        parts = [getattr(k, "name", None) or str(getattr(k, "key", getattr(k, "idx", k))) for k in path]
        named.append((".".join([root, *parts]), leaf))
    return named


def check_params_arrays(params: Any) -> None:
    """The checks every filter's parameters pass (module docstring): floating-point leaves finite
    and at most :data:`~jaxnav.core.validation.MAX_MAGNITUDE` in magnitude; log-domain fields
    (named ``log_…``) may also be ``-inf`` (zero probability).
    Complex and half-precision (float16, bfloat16) leaves are refused by their dtype, also for
    tracers. Values are skipped for tracers. Raises ``ValueError`` naming the field and index."""
    for name, leaf in named_leaves(params, "params"):
        dtype = np.dtype(dtype_of(leaf))
        if jnp.issubdtype(dtype, jnp.complexfloating) or (jnp.issubdtype(dtype, jnp.floating) and dtype.itemsize < 4):
            raise ValueError(
                f"{name} has dtype {dtype.name}: parameters are real numbers in float32 or float64 (cast it "
                "with .astype(jnp.float32))"
            )
        if isinstance(leaf, jax.core.Tracer) or dtype.kind != "f":
            continue
        v, log_field = np.asarray(leaf), is_log_domain(name)
        if not _host_leaf_ok(v, log_field):
            _raise_bad_values(name, v, log_field)


def check_state_arrays(state: Any) -> None:
    """The checks every filter state passes (module docstring): floating-point leaves of one
    precision, float32 or float64, with no NaN, no ``+inf``, and ``-inf`` only in fields named
    ``log_…``, and no magnitude above :data:`~jaxnav.core.validation.MAX_MAGNITUDE`.
    Values are skipped for tracers. Raises ``ValueError`` naming the field and index."""
    floats = [(name, leaf) for name, leaf in named_leaves(state) if np.dtype(dtype_of(leaf)).kind == "f"]
    for name, leaf in floats:
        dtype = np.dtype(dtype_of(leaf))
        if dtype.itemsize < 4:
            raise ValueError(
                f"{name} has dtype {dtype}: filter states are float32 or float64 (make the state with the "
                "filter's init, or cast it with .astype(jnp.float32))"
            )
    if len({np.dtype(dtype_of(leaf)) for _, leaf in floats}) > 1:
        found = ", ".join(f"{name} {np.dtype(dtype_of(leaf))}" for name, leaf in floats)
        raise ValueError(f"the state's arrays must share one floating-point dtype, got {found}")
    concrete = [(name, leaf) for name, leaf in floats if not isinstance(leaf, jax.core.Tracer)]
    if not concrete:
        return
    log_domain = tuple(is_log_domain(name) for name, _ in concrete)
    leaves = tuple(leaf for _, leaf in concrete)
    if sum(np.size(leaf) for leaf in leaves) <= _HOST_CHECK_MAX_SIZE:
        ok = [_host_leaf_ok(np.asarray(leaf), f) for leaf, f in zip(leaves, log_domain)]
    else:
        # A large state is checked where it lives, one fused reduction per leaf (PS-SLAM's state
        # at 100,000 tags is 1.7 GB, which takes many times longer to read to the host and scan
        # with NumPy); only a bad leaf is read back, to find and name its first bad value.
        ok = np.asarray(_leaves_ok(leaves, log_domain))
    for (name, leaf), fine, log_field in zip(concrete, ok, log_domain):
        if not fine:
            _raise_bad_values(name, np.asarray(leaf), log_field)


def is_log_domain(name: str) -> bool:
    """A field named ``log_…`` holds log-probabilities: ``-inf`` (zero probability) is a value there."""
    return name.rsplit(".", 1)[-1].startswith("log_")


_HOST_CHECK_MAX_SIZE = 1 << 20
"""States of at most this many numbers are checked with NumPy on the host (no compilation)."""


def _host_leaf_ok(v: np.ndarray, log_domain: bool) -> bool:
    finite_part = np.where(v == -np.inf, 0.0, v) if log_domain else v
    return bool(np.all(np.isfinite(finite_part) & (np.abs(finite_part) <= MAX_MAGNITUDE)))


@jax.jit(static_argnums=1)
def _leaves_ok(leaves: tuple, log_domain: tuple[bool, ...]) -> jax.Array:
    """``[L]`` bool: leaf ``l`` holds no NaN, no ``+inf``, no ``-inf`` unless ``log_domain[l]``, and
    no magnitude above ``MAX_MAGNITUDE``."""

    def ok(x: jax.Array, log_field: bool) -> jax.Array:
        finite_part = jnp.where(x == -jnp.inf, 0.0, x) if log_field else x
        # Not max|x| <= limit, which is several times faster on the CPU but misses a NaN there
        # (XLA:CPU's vectorised max drops NaNs); the NaN-safe alternatives (a NaN flag beside the
        # max, an integer max of the bits) are as slow as this one.
        return jnp.all(jnp.isfinite(finite_part) & (jnp.abs(finite_part) <= MAX_MAGNITUDE))

    return jnp.stack([ok(x, f) for x, f in zip(leaves, log_domain)])


def _raise_bad_values(name: str, v: np.ndarray, log_domain: bool) -> None:
    """The message for a leaf ``_host_leaf_ok`` or ``_leaves_ok`` found bad (read on the host)."""
    bad = np.isnan(v) | (v == np.inf) | ((v == -np.inf) & (not log_domain))
    if bad.any():
        where = first_index(bad)
        raise ValueError(
            f"{name} holds {int(bad.sum())} NaN or infinite value(s), the first ({float(v[where])}) at "
            f"index {where}: no filter step can recover from it"
        )
    check_magnitude(name, np.where(v == -np.inf, 0.0, v) if log_domain else v)


def plain_sequences_as_arrays(inputs: tuple) -> tuple:
    """Inputs given as a Python list or a plain tuple of numbers (not a NamedTuple of fields)
    become NumPy arrays, so that ``run(..., controls.tolist(), ...)`` means what it says; other
    lists are left for the filter's checks to name."""
    return tuple(_numbers_as_array(x) if type(x) in (list, tuple) else x for x in inputs)


def _numbers_as_array(x: Any) -> Any:
    try:
        a = np.asarray(x)
    except (TypeError, ValueError):  # ragged, or not numbers
        return x
    return a if a.dtype.kind in "biuf" else x


def check_not_donated(state_leaves: Sequence[Any], state: Any, donating_step: bool) -> None:
    """A state whose buffers were donated to an earlier call (``run(..., donate_state=True)``, or the
    ``step`` of a filter that donates its state) holds no values any more: ``ValueError`` naming the
    field, instead of XLA's message about a deleted buffer."""
    if not any(is_array_value(leaf) and leaf.is_deleted() for leaf in state_leaves):
        return
    name = next(n for n, leaf in named_leaves(state) if is_array_value(leaf) and leaf.is_deleted())
    keep = (
        "this filter's step donates its state, so copy a state you want to keep before passing it "
        "(jax.tree_util.tree_map(jnp.copy, state)), and run keeps its initial state with donate_state=False"
        if donating_step
        else "run(..., donate_state=False), the default, keeps the initial state"
    )
    raise ValueError(
        f"state has been donated to an earlier call ({name} is deleted: its buffer was reused for the state "
        f"that call returned): pass the state that call returned instead; {keep}"
    )


def check_state_precision(state: Any, compute_dtype: np.dtype, params_dtype: np.dtype | None) -> None:
    """The state's floating-point arrays must be in the precision the filter computes in.

    With 64-bit floats off (``jax_enable_x64`` False, ``compute_dtype`` float32) JAX computes in
    float32, and a float64 state (made with x64 on) would be cast on the way in: refused. With x64
    on, parameters holding float64 arrays (``params_dtype``) make the step compute in float64, and a
    float32 state (made with x64 off) would change dtype in the step (``run``'s scan refuses a carry
    that does): refused too. A float32 state with float32 parameters under x64 is one consistent
    precision and accepted, as is a float64 state with float32 parameters (float64 throughout).
    """
    floats = [(name, np.dtype(dtype_of(leaf))) for name, leaf in named_leaves(state)]
    floats = [(name, dtype) for name, dtype in floats if dtype.kind == "f"]
    if compute_dtype.itemsize < 8:
        wide = next(((name, dtype) for name, dtype in floats if dtype.itemsize > compute_dtype.itemsize), None)
        if wide is not None:
            raise ValueError(
                f"state is in 64-bit floats ({wide[0]} is {wide[1].name}: made with x64 on, or from NumPy's default "
                f"float64), but jax_enable_x64 is off, so the filter computes in {compute_dtype.name}. Make the "
                "state again with x64 off (the filter's init), cast it (jax.tree_util.tree_map(lambda x: "
                "x.astype(jnp.float32), state)), or turn x64 on for this call too (jax.enable_x64(True) or "
                "jax.config.update('jax_enable_x64', True))"
            )
    elif params_dtype is not None and params_dtype.itemsize == 8:
        narrow = next(((name, dtype) for name, dtype in floats if dtype.itemsize < 8), None)
        if narrow is not None:
            raise ValueError(
                f"state is in 32-bit floats ({narrow[0]} is {narrow[1].name}: made with x64 off), but "
                "jax_enable_x64 is on and params hold float64 arrays, so the filter computes in float64. Make the "
                "state again with x64 on (the filter's init), cast it (jax.tree_util.tree_map(lambda x: "
                "x.astype(jnp.float64), state)), or pass float32 params to compute in float32"
            )


class KnownStates:
    """Weak references to the leaves of the last states a filter returned or checked, each with its
    context (``config`` and the precision, see ``build``): passing one of these very states (an
    online loop, or a benchmark that runs from one initial state again and again) skips the value
    checks, which would read the state back to the host. Only states made of JAX arrays are
    remembered: they are immutable, so the same objects hold the same values; a NumPy leaf could
    have been changed in place."""

    def __init__(self, size: int = 2) -> None:
        self._size = size
        self._known: list[tuple[Any, tuple]] = []  # replaced, never changed in place: read without the lock
        self._lock = threading.Lock()

    def remember(self, context: Any, leaves: Sequence[Any]) -> None:
        """Remember the state whose leaves are ``leaves`` as checked in ``context``."""
        if not all(is_array_value(leaf) for leaf in leaves):
            return
        entry = (context, tuple(weakref.ref(leaf) for leaf in leaves))
        with self._lock:
            self._known = [entry, *self._known][: self._size]

    def known(self, context: Any, leaves: Sequence[Any]) -> bool:
        """Whether the state whose leaves are ``leaves`` is one of those remembered in ``context``;
        a state found is moved to the front, so that one initial state passed again and again stays
        known beside the states the calls return."""
        known = self._known
        for i, entry in enumerate(known):
            c, refs = entry
            if c == context and len(refs) == len(leaves) and all(r() is leaf for r, leaf in zip(refs, leaves)):
                if i:
                    with self._lock:
                        self._known = [entry, *(e for e in self._known if e is not entry)][: self._size]
                return True
        return False
