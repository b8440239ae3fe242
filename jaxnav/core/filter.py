"""The skeleton every jaxnav filter is built from.

A filter is written as pure parts, collected in a :class:`FilterSpec`:

* ``kernel(key, state, config, params, *inputs) -> (state, info)``: one step, a pure
  traceable function (not jitted, not validated). It is public in every filter module
  (``mcl.kernel``, ``pf_slam.kernel``, …), so it can be used inside a caller's own
  ``jit``, ``vmap``, ``grad`` or ``lax.scan``;
* host-side checks of the parameters, the state and the step's inputs, raising
  ``ValueError`` with the argument's name;
* optionally a host-side ``prepare`` of the inputs (dtype casts) and the number of
  steps per scan iteration.

:func:`build` turns a spec into the public ``step`` and ``run``, with one argument order
for every filter::

    state, info = step(key, state, config, params, *inputs)
    final_state, trace = run(key, state, config, params, *inputs_over_time, donate_state=False)

``run`` is one ``lax.scan`` of the kernel over the leading (time) axis of the inputs
(:func:`scan`); step ``t`` uses the key ``jax.random.fold_in(key, t)``, so a Python loop
of ``step`` calls with those keys gives the same result. Deterministic filters (EKF, UKF,
grid, EKF-SLAM) take the key too, so that every filter can be called the same way, and
accept ``None``.

What the skeleton guarantees:

* **Validation once per configuration and parameters.** ``config`` is checked when it is
  constructed (its ``__post_init__``); ``params`` are checked the first time a
  ``(config, params)`` pair with those *values* is seen, not at every call (an online loop
  passes the same parameters at every step). The memo is keyed on the parameters' tree
  structure, shapes, dtypes and a hash of their bytes, never on object identity, so a
  NumPy array changed in place is checked again. The inputs are checked at every call, the
  state unless it is the one the filter just returned (below). Value checks are skipped for tracers (inside a
  caller's ``jit``/``vmap`` the values are unknown); shape checks always run.
* **No state a filter could not have made.** Besides the filter's own checks, the state
  must be of the filter's state type, its floating-point arrays float32 or float64 (one
  precision throughout), with no NaN and no ``+inf`` (``-inf`` only in log-domain fields,
  those named ``log_…``), and no magnitude above
  :data:`~jaxnav.core.validation.MAX_MAGNITUDE`. Its precision must be the one the filter
  computes in: float32 with ``jax_enable_x64`` off (a float64 state is refused, not cast), and
  with x64 on not float32 beside float64 parameters (the step would change its dtype). A state
  whose buffers were donated to an earlier call (``run(..., donate_state=True)``, or the
  ``step`` of a filter that donates) is refused by name, at every call. A state the filter
  itself just returned or just checked (the very same JAX arrays, with the same ``config`` and
  x64 setting) is not read again: an online loop, or a benchmark running from one initial
  state, pays nothing for the check.
  The parameters' floating-point values must be finite and at most
  :data:`~jaxnav.core.validation.MAX_MAGNITUDE` (log-domain fields, ``log_…``, may be ``-inf``).
* **Lists are arrays.** An input passed as a Python list or plain tuple of numbers is
  read as an array.
* **Invalid inputs inside a caller's jit.** There the host checks see tracers; the kernel
  itself tests what matters numerically (``FilterSpec.valid_inputs`` and
  :func:`params_in_domain`: a negative time step or noise level, a control or parameter that
  is not finite or exceeds :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), sets
  ``info.invalid_inputs`` and carries the state over unchanged (:func:`guard_inputs`).
* **Compiled once per configuration and shapes.** ``config`` is the only static argument;
  new keys, parameters, data or states of the same shapes reuse the compiled program
  (``step.trace_count()`` and ``run.trace_count()`` count the traces, for tests).
* **Donation.** A spec with ``donate_step`` donates the state to the jitted ``step`` (the
  tables of PF-SLAM, PS-SLAM and FastSLAM are then updated in place: do not use the old
  state after the call); ``run(..., donate_state=True)`` reuses the initial state's
  buffers for the scan's carry instead of copying them in.

The host-side checks above are implemented in :mod:`jaxnav.core.host_checks`. The jitted
functions are reachable as ``step.jitted`` and ``run.jitted`` (and ``run.jitted_donated``),
e.g. to ``.lower()`` them and read the compiled program.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.host_checks import (
    KnownStates,
    ParamsMemo,
    check_not_donated,
    check_params_arrays,
    check_state_arrays,
    check_state_precision,
    is_log_domain,
    named_leaves,
    plain_sequences_as_arrays,
)
from jaxnav.core.memory import check_run_fits
from jaxnav.core.validation import (
    all_finite_within,
    is_concrete,
)

__all__ = [
    "FilterSpec",
    "Filter",
    "build",
    "scan",
    "check_key",
    "check_params_arrays",
    "check_state_arrays",
    "guard_inputs",
    "inputs_in_domain",
    "params_in_domain",
    "flag_invalid_inputs",
    "promote_half_precision",
]


def _no_check(*args: Any, **kwargs: Any) -> None:
    return None


def promote_half_precision(config: Any, *inputs: Any) -> tuple:
    """The default ``prepare``: floating-point input arrays in half precision (float16, bfloat16)
    become float32 (a filter's arithmetic, log-weights and squared distances, is not meaningful in
    half precision, as :func:`~jaxnav.core.validation.float_array` states); the rest is unchanged."""

    def promote(x: Any) -> Any:
        return jnp.asarray(x, jnp.float32) if _is_half_float(getattr(x, "dtype", None)) else x

    if not any(_is_half_float(getattr(leaf, "dtype", None)) for leaf in jax.tree_util.tree_leaves(inputs)):
        return inputs  # the common case, tested once per leaf without rebuilding the inputs
    return tuple(jax.tree_util.tree_map(promote, x) for x in inputs)


_HALF_FLOAT: dict[Any, bool] = {None: False}
"""dtype -> whether it is a half-precision float (float16, bfloat16), filled as dtypes are met."""


def _is_half_float(dtype: Any) -> bool:
    half = _HALF_FLOAT.get(dtype)
    if half is None:
        half = _HALF_FLOAT[dtype] = bool(jnp.issubdtype(dtype, jnp.floating) and np.dtype(dtype).itemsize < 4)
    return half


def _identity(x: Any) -> Any:
    return x


def _one_step_per_iteration(config: Any) -> int:
    return 1


def _always_valid(config: Any, params: Any, *inputs: Any) -> jax.Array:
    return jnp.asarray(True)


@dataclass(frozen=True)
class FilterSpec:
    """A filter's pure parts, from which :func:`build` makes its ``step`` and ``run``.

    Attributes:
        name: the filter's name, for the generated docstrings (e.g. ``"MCL"``).
        kernel: ``(key, state, config, params, *inputs) -> (state, info)``, pure and traceable.
        config_type: the configuration's class; anything else is refused.
        inputs: the names of the per-step inputs, in order (e.g. ``("control", "observation")``);
            ``run`` takes them with a leading time axis, under the same names.
        check_params: ``(config, params)``, raises ``ValueError``; memoised by value (module docstring).
        check_state: ``(config, params, state)``, raises ``ValueError``.
        check_inputs: ``(config, params, *inputs, time_axis=bool)``, raises ``ValueError``.
        prepare: ``(config, *inputs) -> inputs`` on the host after the checks (dtype casts; the
            default promotes half-precision inputs, float16 and bfloat16, to float32).
        deterministic: the kernel ignores its key; ``None`` is accepted as the key.
        donate_step: ``step`` donates its state (in-place tables).
        unroll: ``config -> int``, steps per ``lax.scan`` iteration in ``run``.
        step_doc, run_doc: the first paragraphs of the generated functions' docstrings.
        time_inputs: the names ``run`` gives the same inputs with a time axis (default: ``inputs``).
        state_type: the state's class (e.g. ``MCLState``); anything else is refused.
        state_values: ``state -> pytree``, the part of a concrete state whose values are checked
            (default all of it; KLD-MCL: its active slots, the others are never read).
        valid_inputs: ``(config, params, *inputs) -> bool[]``, traceable: the step's inputs are in
            the model's domain (default: always). The twin of the value checks of ``check_params``
            and ``check_inputs`` that matter numerically (``Δt ≥ 0``, noise levels ``≥ 0``, controls
            finite and at most :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), written with
            ``jnp`` so that it runs inside a caller's ``jit``/``vmap``, where the host checks see
            tracers. The kernel applies it (:func:`guard_inputs`, with :func:`params_in_domain`):
            a step whose inputs are outside the domain sets ``info.invalid_inputs`` and returns
            its state unchanged, so the caller's loop can tell. Measurements are not part of it:
            an unusable measurement slot is dropped and counted in ``info.num_ignored`` instead.
    """

    name: str
    kernel: Callable[..., tuple[Any, Any]]
    config_type: type
    inputs: tuple[str, ...] = ("control", "observation")
    check_params: Callable[[Any, Any], None] = _no_check
    check_state: Callable[[Any, Any, Any], None] = _no_check
    check_inputs: Callable[..., None] = _no_check
    prepare: Callable[..., tuple] = promote_half_precision
    deterministic: bool = False
    donate_step: bool = False
    unroll: Callable[[Any], int] = _one_step_per_iteration
    step_doc: str = ""
    run_doc: str = ""
    time_inputs: tuple[str, ...] | None = None
    state_type: type | tuple[type, ...] | None = None
    state_values: Callable[[Any], Any] = _identity
    valid_inputs: Callable[..., jax.Array] = _always_valid

    @property
    def run_inputs(self) -> tuple[str, ...]:
        """The names ``run`` gives its inputs (by default those of ``step``)."""
        return self.inputs if self.time_inputs is None else self.time_inputs


class Filter(NamedTuple):
    """A filter's public ``step`` and ``run`` (see :func:`build`)."""

    step: Callable[..., tuple[Any, Any]]
    run: Callable[..., tuple[Any, Any]]


def check_key(key: Any, *, allow_none: bool = False, name: str = "key") -> None:
    """``key`` must be one PRNG key: ``jax.random.key(seed)`` (a scalar typed key) or
    ``jax.random.PRNGKey(seed)`` (a raw ``uint32`` array of shape ``(2,)``).

    A raw key of another length, a batch of keys (``(5, 2)`` raw or ``(5,)`` typed), a number
    or ``None`` (unless ``allow_none``, for the deterministic filters) raise ``ValueError``
    naming the argument, ``name`` (JAX's own message for a wrong key names neither the argument
    nor the function). Only the dtype and shape are read, so a tracer key inside a caller's
    ``jit`` or ``vmap`` is checked too, at no cost.
    """
    if key is None:
        if allow_none:
            return
        raise ValueError(f"{name} must be a PRNG key (jax.random.key(seed) or jax.random.PRNGKey(seed)), got None")
    dtype = getattr(key, "dtype", None)
    if dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key):
        if np.shape(key) == ():
            return
    elif dtype == np.uint32 and np.shape(key) == (2,):
        return
    raise ValueError(
        f"{name} must be one PRNG key (jax.random.key(seed) or jax.random.PRNGKey(seed)), got "
        f"{type(key).__name__} of dtype {dtype} and shape {np.shape(key)}"
    )


def params_in_domain(params: Any) -> jax.Array:
    """``bool[]``, traceable: the check every filter's parameters pass on the host
    (:func:`~jaxnav.core.host_checks.check_params_arrays`) as a ``jnp`` expression, for a caller's ``jit``: every
    floating-point leaf finite and at most :data:`~jaxnav.core.validation.MAX_MAGNITUDE` in
    magnitude, ``-inf`` allowed in log-domain fields (``log_…``)."""
    ok = jnp.asarray(True)
    for name, leaf in named_leaves(params, "params"):
        if not jnp.issubdtype(jnp.result_type(leaf), jnp.floating):
            continue
        x = jnp.asarray(leaf)
        if is_log_domain(name):
            x = jnp.where(x == -jnp.inf, 0.0, x)
        ok = ok & all_finite_within(x)
    return ok


def inputs_in_domain(valid_inputs: Callable[..., jax.Array], config: Any, params: Any, *inputs: Any) -> jax.Array:
    """``bool[]``: :func:`params_in_domain` and the filter's own ``valid_inputs`` (see
    :class:`FilterSpec`) for one step's inputs."""
    return params_in_domain(params) & jnp.asarray(valid_inputs(config, params, *inputs), bool)


def flag_invalid_inputs(info: Any, ok: jax.Array) -> Any:
    """``info`` (a NamedTuple or a dataclass) with its field ``invalid_inputs`` set to ``~ok``."""
    flag = ~jnp.asarray(ok, bool)
    if dataclasses.is_dataclass(info):
        return dataclasses.replace(info, invalid_inputs=flag)
    return info._replace(invalid_inputs=flag)


def guard_inputs(
    valid_inputs: Callable[..., jax.Array],
) -> Callable[[Callable[..., tuple[Any, Any]]], Callable[..., tuple[Any, Any]]]:
    """A decorator that makes a kernel keep its state on a step whose inputs are outside the domain.

    The decorated ``kernel(key, state, config, params, *inputs)`` computes
    ``ok = inputs_in_domain(valid_inputs, config, params, *inputs)`` and the update as before,
    then returns ``(where(ok, new_state, state), info)`` with ``info.invalid_inputs = ~ok``
    (the info's other fields describe the rejected update). The host refuses such inputs
    before tracing; this is what happens to them inside a caller's ``jit``/``vmap``, where
    their values are unknown until the program runs. The select reads the whole state, which
    costs a pass over it per step: filters whose step updates a large table in place (PF-SLAM,
    PS-SLAM, FastSLAM) neutralise their measurements instead, so that nothing is written.
    """

    def decorate(update: Callable[..., tuple[Any, Any]]) -> Callable[..., tuple[Any, Any]]:
        @functools.wraps(update)
        def kernel(key: Any, state: Any, config: Any, params: Any, *inputs: Any) -> tuple[Any, Any]:
            ok = inputs_in_domain(valid_inputs, config, params, *inputs)
            new_state, info = update(key, state, config, params, *inputs)
            kept = jax.tree_util.tree_map(lambda new, old: jnp.where(ok, new, old), new_state, state)
            return kept, flag_invalid_inputs(info, ok)

        kernel.__doc__ = (update.__doc__ or "") + _GUARD_NOTE
        return kernel

    return decorate


_GUARD_NOTE = """

    A step whose inputs are outside the model's domain (a negative time step or noise level, a
    control or parameter that is not finite or exceeds :data:`~jaxnav.core.validation.MAX_MAGNITUDE`),
    which the host refuses before tracing, returns the state unchanged and sets
    ``info.invalid_inputs`` (:func:`jaxnav.core.filter.guard_inputs`)."""


def scan(
    kernel: Callable[..., tuple[Any, Any]],
    key: jax.Array | None,
    state: Any,
    config: Any,
    params: Any,
    *inputs: Any,
    unroll: int = 1,
) -> tuple[Any, Any]:
    """The pure ``run``: one ``lax.scan`` of ``kernel`` over the leading axis of ``inputs``.

    Step ``t`` is ``kernel(fold_in(key, t), state, config, params, *inputs_t)``; with
    ``key=None`` (deterministic filters) the kernel gets ``None``. Returns
    ``(final_state, trace)``, the trace being the kernel's info stacked over time.
    ``unroll`` steps share one loop iteration (``lax.scan``'s ``unroll``): with 2, a state
    that a step rebuilds out of place (a gather) is written straight into the loop's buffer
    every second step instead of being copied back at every step, for a longer compilation.
    Traceable: call it inside your own ``jit``, ``vmap`` or ``grad``.
    """
    if key is None:
        return jax.lax.scan(lambda s, x: kernel(None, s, config, params, *x), state, inputs, unroll=unroll)
    num_steps = jax.tree_util.tree_leaves(inputs)[0].shape[0]

    def body(carry: Any, xs: tuple) -> tuple[Any, Any]:
        t, step_inputs = xs
        return kernel(jax.random.fold_in(key, t), carry, config, params, *step_inputs)

    return jax.lax.scan(body, state, (jnp.arange(num_steps), inputs), unroll=unroll)


def _article(name: str) -> str:
    """``name`` with "a" or "an" as it is read aloud ("an MCLConfig", "a GridConfig", "an EKFConfig")."""
    spelled = len(name) > 1 and name[:2].isupper()  # an initialism: its first letter is spelled out
    vowel_sound = name[0] in ("AEFHILMNORSX" if spelled else "AEIOU")
    return ("an " if vowel_sound else "a ") + name


def _signature(
    head: Sequence[str], inputs: Sequence[str], keyword_only: Sequence[tuple[str, Any]] = ()
) -> inspect.Signature:
    positional = [inspect.Parameter(n, inspect.Parameter.POSITIONAL_OR_KEYWORD) for n in (*head, *inputs)]
    keywords = [inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=d) for n, d in keyword_only]
    return inspect.Signature(positional + keywords)


_STEP_NOTE = """
Inputs are validated on the host first (the parameters once per value, see
:mod:`jaxnav.core.filter`); the step is then jitted with ``config`` static. The pure
step is :func:`kernel`, for use inside your own ``jit``/``vmap``/``grad``.
"""

_DONATED_NOTE = """
``state`` is *donated*: its buffers are reused for the new state (the tables are
updated in place), so do not use the old ``state`` after the call.
"""

_RUN_NOTE = """
One ``lax.scan`` of :func:`kernel` over the leading (time) axis of the inputs; step
``t`` uses the key ``jax.random.fold_in(key, t)``, so a loop of :func:`step` calls with
those keys gives the same result. With ``donate_state=True`` the initial state's buffers
are reused for the filter's state (do not use it after the call); without it XLA copies
the initial state into the scan once per call. Returns ``(final_state, trace)``, the
trace being the per-step info stacked over time. A run whose initial and final states and
trace would exceed the device's memory is refused with a ``ValueError`` before anything is
allocated (:mod:`jaxnav.core.memory`).
"""


def build(spec: FilterSpec, module: str | None = None) -> Filter:
    """The public ``step`` and ``run`` of the filter ``spec`` describes (module docstring)."""
    step_traces = [0]
    run_traces = [0]

    def counted(counter: list[int]) -> Callable[..., tuple[Any, Any]]:
        def kernel(*args: Any) -> tuple[Any, Any]:
            counter[0] += 1  # runs when JAX traces, not when the compiled program runs
            return spec.kernel(*args)

        return kernel

    step_kernel = counted(step_traces)
    run_kernel = counted(run_traces)

    def run_pure(key: Any, state: Any, config: Any, params: Any, *inputs: Any) -> tuple[Any, Any]:
        return scan(run_kernel, key, state, config, params, *inputs, unroll=spec.unroll(config))

    step_jit = jax.jit(step_kernel, static_argnums=(2,), donate_argnums=(1,) if spec.donate_step else ())
    run_jit = jax.jit(run_pure, static_argnums=(2,))
    run_jit_donated = jax.jit(run_pure, static_argnums=(2,), donate_argnums=(1,))
    check_params = ParamsMemo(lambda config, params: (spec.check_params(config, params), check_params_arrays(params)))
    known_states = KnownStates()
    good_keys: set[tuple] = set()  # (type, dtype, shape) of the keys that passed check_key
    head = ("key", "state", "config", "params")
    step_signature = _signature(head, spec.inputs)
    run_signature = _signature(head, spec.run_inputs, [("donate_state", False)])

    def checked(key: Any, state: Any, config: Any, params: Any, inputs: tuple, time_axis: bool) -> tuple:
        """Every host check of one call; returns the prepared inputs and the context in which the
        returned state is known (the config and the precision: a state checked with x64 on is
        checked again with it off)."""
        if not isinstance(config, spec.config_type):
            raise ValueError(f"config must be {_article(spec.config_type.__name__)}, got {type(config).__name__}")
        key_kind = (type(key), getattr(key, "dtype", None), getattr(key, "shape", None))  # all check_key reads
        try:
            known_key = key_kind in good_keys
        except TypeError:  # an object whose dtype or shape cannot be hashed: check_key names it
            known_key = False
        if not known_key:
            check_key(key, allow_none=spec.deterministic)
            good_keys.add(key_kind)
        params_dtype = check_params(config, params)
        if spec.state_type is not None and not isinstance(state, spec.state_type):
            types = spec.state_type if isinstance(spec.state_type, tuple) else (spec.state_type,)
            raise ValueError(
                f"state must be {' or '.join(_article(t.__name__) for t in types)} (from the filter's init or "
                f"a previous step), got {type(state).__name__}"
            )
        leaves = jax.tree_util.tree_leaves(state)
        check_not_donated(leaves, state, spec.donate_step)  # also for a known state: a donated one is known
        compute_dtype = jax.dtypes.canonicalize_dtype(np.float64)  # float32 unless x64 is on
        context = (config, compute_dtype, params_dtype)
        if not known_states.known(context, leaves):
            check_state_precision(state, compute_dtype, params_dtype)
            spec.check_state(config, params, state)
            check_state_arrays(spec.state_values(state) if is_concrete(state) else state)
            known_states.remember(context, leaves)
        inputs = plain_sequences_as_arrays(inputs)
        spec.check_inputs(config, params, *inputs, time_axis=time_axis)
        return spec.prepare(config, *inputs), context

    num_args = len(head) + len(spec.inputs)

    def step(*args: Any, **kwargs: Any) -> tuple[Any, Any]:
        if kwargs or len(args) != num_args:  # keywords or a wrong count: Python's own binding and errors
            args = step_signature.bind(*args, **kwargs).args
        key, state, config, params, *inputs = args
        inputs, context = checked(key, state, config, params, tuple(inputs), time_axis=False)
        out = step_jit(key, state, config, params, *inputs)
        known_states.remember(context, jax.tree_util.tree_leaves(out[0]))
        return out

    def run(*args: Any, donate_state: bool = False, **kwargs: Any) -> tuple[Any, Any]:
        if kwargs or len(args) != num_args:
            args = run_signature.bind(*args, donate_state=donate_state, **kwargs).args
        key, state, config, params, *inputs = args
        inputs, context = checked(key, state, config, params, tuple(inputs), time_axis=True)
        jitted = run_jit_donated if donate_state else run_jit
        check_run_fits(spec.name, jitted, key, state, config, params, inputs)  # memoised; before any allocation
        out = jitted(key, state, config, params, *inputs)
        known_states.remember(context, jax.tree_util.tree_leaves(out[0]))
        return out

    for fn, signature, doc, notes, jitted, counter in (
        (
            step,
            step_signature,
            spec.step_doc,
            _STEP_NOTE + (_DONATED_NOTE if spec.donate_step else ""),
            step_jit,
            step_traces,
        ),
        (run, run_signature, spec.run_doc, _RUN_NOTE, run_jit, run_traces),
    ):
        fn.__signature__ = signature  # type: ignore[attr-defined]
        fn.__qualname__ = fn.__name__
        fn.__doc__ = (inspect.cleandoc(doc) if doc else f"{fn.__name__} of {spec.name}.") + "\n" + notes
        fn.__module__ = module or fn.__module__
        fn.jitted = jitted  # type: ignore[attr-defined]
        fn.trace_count = lambda c=counter: c[0]  # type: ignore[attr-defined]
    run.jitted_donated = run_jit_donated  # type: ignore[attr-defined]

    def check_run(key: Any, state: Any, config: Any, params: Any, *inputs: Any) -> tuple:
        """``run``'s host checks of its arguments; returns the inputs as ``run`` passes them on."""
        return checked(key, state, config, params, inputs, time_axis=True)[0]

    run.check = check_run  # type: ignore[attr-defined]
    return Filter(step, run)
