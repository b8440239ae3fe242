"""Refuse, before anything is allocated, what the device cannot hold.

A filter of 2³¹ particles, a PF-SLAM table of a billion tags or a Monte Carlo chunk of a
million runs would otherwise end in XLA's ``RESOURCE_EXHAUSTED``, or, on the CPU, in a machine
that swaps or a process the kernel kills. The public entry points measure first and raise a
``ValueError`` instead, naming the configuration fields that size the request, the estimate and
the limit:

* every filter's ``init`` (:func:`guard_init`): the bytes of the state it would return;
* every filter's ``run`` (:func:`check_run_fits`, called by :func:`jaxnav.core.filter.build`'s
  ``run``): the initial state, the final state and the trace stacked over the ``T`` steps;
* :func:`jaxnav.core.batch.monte_carlo`: a chunk of ``chunk_size`` runs, as XLA counts its compiled
  program (inputs, outputs and working memory), or, without ``jit``, its inputs and
  ``chunk_size`` times one run's outputs.

**The estimate** is the size of the arrays the call returns, read from :func:`jax.eval_shape`,
which traces the call without allocating anything (a Monte Carlo chunk is compiled instead, which
allocates nothing either and is reused for the chunks). For a filter it is a lower bound: XLA's
temporaries come on top, so a request refused here could never run, while one just under the
limit may still fail.
The estimate is memoised per function, configuration and argument shapes (and dtypes), so an
online loop pays a dictionary look-up for it, not a trace.

**The limit** is that of the default device (:func:`limit_bytes`): on a GPU or TPU its
``memory_stats()["bytes_limit"]``, the memory XLA's allocator may use; on the CPU, where
``memory_stats()`` is ``None``, the memory this process may use: the machine's physical memory
(``os.sysconf``), lowered by the container's limit (cgroup ``memory.max``) and by the
address-space limit (``ulimit -v``, ``RLIMIT_AS``) when they are set. The physical total, not
the memory free at the moment: what fits must not depend on what else happens to run, and the
check is meant to refuse what can never fit.

**To go ahead anyway** (a machine with swap, a device whose limit is misreported), wrap the calls
in :func:`allow_large_allocations`, or set the environment variable ``JAXNAV_ALLOW_LARGE_ALLOCATIONS=1``
(:data:`ENV_VAR`) for the whole process. The grid filter's configuration check
(:class:`jaxnav.localization.grid.GridConfig`) honours both, the command line's memory check the
environment variable.

Nothing is checked for tracers: inside a caller's ``jit`` or ``vmap`` the allocation is that of
the caller's program.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
import inspect
import math
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

import jax
import numpy as np

__all__ = [
    "ENV_VAR",
    "allow_large_allocations",
    "guard_enabled",
    "tree_bytes",
    "host_memory_bytes",
    "limit_bytes",
    "size_fields",
    "check_fits",
    "guard_init",
    "check_run_fits",
    "output_bytes",
]

ENV_VAR = "JAXNAV_ALLOW_LARGE_ALLOCATIONS"
"""The environment variable that turns the check off for the whole process (``1``, ``true``, ``yes`` or ``on``)."""

_ALLOWED: contextvars.ContextVar[bool] = contextvars.ContextVar("jaxnav_allow_large_allocations", default=False)
_INSIDE: contextvars.ContextVar[bool] = contextvars.ContextVar("jaxnav_inside_guarded_call", default=False)
_F = TypeVar("_F", bound=Callable[..., Any])


@contextlib.contextmanager
def allow_large_allocations() -> Iterator[None]:
    """Within this block (in this thread), no call is refused for its size::

        with jaxnav.core.memory.allow_large_allocations():
            state = mcl.init(key, MCLConfig(num_particles=2**30), params, pose)

    For a machine with swap, or a device whose reported limit is too low. The process-wide
    equivalent is the environment variable :data:`ENV_VAR`.
    """
    token = _ALLOWED.set(True)
    try:
        yield
    finally:
        _ALLOWED.reset(token)


def guard_enabled() -> bool:
    """False inside :func:`allow_large_allocations` or when :data:`ENV_VAR` is set to ``1``/``true``/``yes``/``on``."""
    if _ALLOWED.get():
        return False
    return os.environ.get(ENV_VAR, "").strip().lower() not in ("1", "true", "yes", "on")


def tree_bytes(tree: Any) -> int:
    """Bytes of the arrays of a pytree (JAX or NumPy arrays, or ``jax.ShapeDtypeStruct``); numbers
    and other leaves count nothing."""
    total = 0
    for leaf in jax.tree_util.tree_leaves(tree):
        shape, dtype = getattr(leaf, "shape", None), getattr(leaf, "dtype", None)
        if shape is None or dtype is None:
            continue
        total += math.prod(shape) * np.dtype(dtype).itemsize if not _is_key(dtype) else math.prod(shape) * 8
    return total


def _is_key(dtype: Any) -> bool:
    try:
        return jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)
    except TypeError:
        return False


def _cgroup_limit() -> int | None:
    """The container's memory limit in bytes (cgroup v2 ``memory.max``, v1 ``memory.limit_in_bytes``), if any."""
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(path) as f:
                text = f.read().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < 2**60:  # "max", or v1's "no limit" (close to 2⁶³)
            return int(text)
    return None


def host_memory_bytes() -> tuple[int, str] | None:
    """``(bytes, source)``: the memory this process may use on the host, the smallest of the
    physical memory, the container's limit and the address-space limit (module docstring);
    ``None`` when none is known (not a POSIX system)."""
    bounds = []
    try:
        bounds.append(
            (int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES")), "this machine's physical memory")
        )
    except (AttributeError, ValueError, OSError):
        pass
    cgroup = _cgroup_limit()
    if cgroup is not None:
        bounds.append((cgroup, "this container's memory limit (cgroup)"))
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft != resource.RLIM_INFINITY and soft > 0:
            bounds.append((int(soft), "this process's address-space limit (ulimit -v)"))
    except (ImportError, ValueError, OSError):
        pass
    return min(bounds) if bounds else None


def _default_device() -> Any:
    device = jax.config.jax_default_device
    if isinstance(device, str):
        return jax.devices(device)[0]
    return device if device is not None else jax.devices()[0]


@functools.lru_cache(maxsize=16)
def _device_limit(device: Any) -> tuple[int, str] | None:
    try:
        stats = device.memory_stats()
    except Exception:  # noqa: BLE001  (a backend without memory statistics)
        stats = None
    if stats and stats.get("bytes_limit"):
        return int(stats["bytes_limit"]), f"the memory of {device} (its bytes_limit)"
    host = host_memory_bytes()
    return host


def limit_bytes(device: Any = None) -> tuple[int, str] | None:
    """``(bytes, description)``: what ``device`` (default: JAX's default device) can hold, as the
    module docstring says; ``None`` when unknown (nothing is then refused)."""
    return _device_limit(_default_device() if device is None else device)


def size_fields(config: Any) -> str:
    """The configuration fields that size a filter's state, with their values, for messages:
    ``"MCLConfig.num_particles (2147483648)"``. A configuration class lists them in its
    ``SIZE_FIELDS``; without it, its integer fields are named; ``""`` when there are none."""
    cls = type(config)
    names = getattr(cls, "SIZE_FIELDS", None)
    if names is None and dataclasses.is_dataclass(config):
        names = [
            f.name
            for f in dataclasses.fields(config)
            if isinstance(getattr(config, f.name), (int, np.integer)) and not isinstance(getattr(config, f.name), bool)
        ]
    if not names:
        return ""
    return ", ".join(f"{cls.__name__}.{n} ({getattr(config, n)!r})" for n in names)


def _size(n: int) -> str:
    """``n`` bytes in GiB, MiB or KiB, three significant digits."""
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} bytes"


def check_fits(nbytes: int, *, what: str, fields: str, device: Any = None) -> None:
    """Raise ``ValueError`` when ``nbytes`` exceed :func:`limit_bytes` of ``device``, unless the
    check is off (:func:`guard_enabled`). ``what`` says what would be allocated
    (``"jaxnav.localization.mcl.init (the state)"``), ``fields`` what to lower."""
    if not guard_enabled():
        return
    limit = limit_bytes(device)
    if limit is None or nbytes <= limit[0]:
        return
    raise ValueError(
        f"{what} would need about {_size(nbytes)} ({nbytes} bytes), more than the {_size(limit[0])} of "
        f"{limit[1]}: lower {fields}. To try anyway, call it inside "
        f"jaxnav.core.memory.allow_large_allocations() or set {ENV_VAR}=1"
    )


class _Memo:
    """A bounded, thread-safe ``signature -> bytes`` memo."""

    def __init__(self, maxsize: int = 256) -> None:
        self._data: OrderedDict[Any, int] = OrderedDict()
        self._maxsize = maxsize
        self._lock = threading.Lock()

    def get(self, key: Any) -> int | None:
        with self._lock:
            return self._data.get(key)

    def put(self, key: Any, value: int) -> None:
        with self._lock:
            self._data[key] = value
            while len(self._data) > self._maxsize:
                self._data.popitem(last=False)


_INIT_MEMO = _Memo()
_RUN_MEMO = _Memo()
_OUTPUT_MEMO = _Memo()


def _signature(leaves: list) -> tuple | None:
    """Shapes and dtypes of array leaves, the values of other hashable leaves (a configuration,
    a number); ``None`` when a leaf is a tracer (nothing is checked under a caller's trace)."""
    out = []
    for leaf in leaves:
        if isinstance(leaf, jax.core.Tracer):
            return None
        shape = getattr(leaf, "shape", None)
        if shape is not None and hasattr(leaf, "dtype"):
            out.append((tuple(shape), str(leaf.dtype)))
            continue
        try:
            hash(leaf)
        except TypeError:
            out.append(type(leaf).__name__)
        else:
            out.append((type(leaf).__name__, leaf))
    return tuple(out)


def guard_init(fn: _F) -> _F:
    """Decorate a filter's ``init``: refuse, before anything is allocated, a state larger than the
    device can hold (:func:`check_fits`, naming :func:`size_fields` of the ``config`` argument).

    The state's size comes from :func:`jax.eval_shape` of the call itself, memoised per
    configuration and argument shapes. An ``init`` called by another guarded one (KLD-MCL's
    calls MCL's) is not measured again, nor are calls with tracer arguments. A call the estimate
    cannot trace is not refused here: the call itself then reports what is wrong with it.
    A paragraph saying so is added to the docstring.
    """
    signature = inspect.signature(fn)
    what = f"{fn.__module__}.{fn.__qualname__} (the state it returns)"

    @functools.wraps(fn)
    def guarded(*args: Any, **kwargs: Any) -> Any:
        if _INSIDE.get() or not guard_enabled() or not _check_init(fn, signature, what, args, kwargs):
            return fn(*args, **kwargs)  # not measured here: the guarded inits it calls measure themselves
        token = _INSIDE.set(True)
        try:
            return fn(*args, **kwargs)
        finally:
            _INSIDE.reset(token)

    guarded.__doc__ = inspect.cleandoc(fn.__doc__ or "") + "\n\n" + _INIT_NOTE
    return guarded  # type: ignore[return-value]


_INIT_NOTE = """A state larger than the memory of the device is refused with a ``ValueError`` before
anything is allocated, naming the configuration fields that size it; see :mod:`jaxnav.core.memory`
for the limit and the opt-out (:func:`~jaxnav.core.memory.allow_large_allocations`)."""


def _check_init(fn: Callable, signature: inspect.Signature, what: str, args: tuple, kwargs: dict) -> bool:
    """Raise if the state of ``fn(*args, **kwargs)`` does not fit; False if it could not be measured."""
    leaves, treedef = jax.tree_util.tree_flatten((args, kwargs))
    shapes = _signature(leaves)
    if shapes is None:
        return False
    memo_key = (fn, treedef, shapes)
    nbytes = _INIT_MEMO.get(memo_key)
    if nbytes is None:
        token = _INSIDE.set(True)
        try:
            nbytes = tree_bytes(jax.eval_shape(lambda: fn(*args, **kwargs)))
        except Exception:  # noqa: BLE001  (bad arguments: the call itself names them)
            return False
        finally:
            _INSIDE.reset(token)
        _INIT_MEMO.put(memo_key, nbytes)
    try:
        config = signature.bind(*args, **kwargs).arguments.get("config")
    except TypeError:
        config = None
    check_fits(nbytes, what=what, fields=(size_fields(config) if config is not None else "") or "its sizes")
    return True


def check_run_fits(name: str, jitted: Any, key: Any, state: Any, config: Any, params: Any, inputs: tuple) -> None:
    """Refuse a filter's ``run`` whose initial state, final state and trace over the ``T`` steps
    exceed the device's memory (:func:`check_fits`). ``jitted`` is the jitted run
    (``jitted(key, state, config, params, *inputs)``): its ``eval_shape`` gives the sizes and
    shares its trace with the call that follows. Memoised per ``jitted``, configuration and
    argument shapes; skipped for tracers."""
    if not guard_enabled():
        return
    leaves, treedef = jax.tree_util.tree_flatten((key, state, params, inputs))
    shapes = _signature(leaves)
    if shapes is None:
        return
    memo_key = (jitted, config, treedef, shapes)
    nbytes = _RUN_MEMO.get(memo_key)
    if nbytes is None:
        nbytes = tree_bytes(state) + tree_bytes(jitted.eval_shape(key, state, config, params, *inputs))
        _RUN_MEMO.put(memo_key, nbytes)
    input_leaves = jax.tree_util.tree_leaves(inputs)
    steps = np.shape(input_leaves[0])[0] if input_leaves and np.ndim(input_leaves[0]) else None
    over = f" over {steps} steps" if steps is not None else ""
    check_fits(
        nbytes,
        what=f"{name} run{over} (the initial and final states and the trace)",
        fields=" or ".join(f for f in (size_fields(config), "the number of steps per call") if f),
    )


def output_bytes(fn: Callable[..., Any], *args: Any) -> int | None:
    """Bytes of what ``fn(*args)`` returns, from :func:`jax.eval_shape` (``args`` may be
    ``jax.ShapeDtypeStruct``), memoised per ``fn`` and argument shapes; ``None`` when ``fn``
    cannot be traced abstractly (the call itself then reports why)."""
    leaves, treedef = jax.tree_util.tree_flatten(args)
    shapes = _signature(leaves)
    if shapes is None:
        return None
    memo_key = (fn, treedef, shapes)
    nbytes = _OUTPUT_MEMO.get(memo_key)
    if nbytes is None:
        try:
            nbytes = tree_bytes(jax.eval_shape(fn, *args))
        except Exception:  # noqa: BLE001  (the call itself reports it)
            return None
        _OUTPUT_MEMO.put(memo_key, nbytes)
    return nbytes
