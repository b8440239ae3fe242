"""Fit a filter's parameters to data by maximising its log marginal likelihood.

Every jaxnav filter reports ``info.log_likelihood``, the increment ``log p(z_t | z_{1:t−1})`` of
the log marginal likelihood of its observations (an estimate for the particle filters, exact for
the EKF and UKF up to their linearisation). Its sum over a run, ``log Ẑ(θ)``, is a function of
the filter's ``params`` θ that JAX differentiates:

* a particle filter's gradient passes the moves pathwise and the resampling by its config's
  ``gradient`` estimator (:mod:`jaxnav.core.gradients`: by default stop-gradient resampling,
  whose ``∇Ẑ`` is unbiased for ``∇Z`` with multinomial resampling), so ``∇ log Ẑ`` is a noisy, consistent estimate of the
  score, averaged here over ``num_seeds`` independent filters per sequence;
* a Gaussian filter's log-likelihood is deterministic: its gradient is exact, and L-BFGS
  (``optimizer="lbfgs"``) converges in a few dozen steps.

Two functions make a fit::

    objective = calibration.log_likelihood_objective(mcl.kernel, config, state, (controls, observations),
                                                      num_seeds=8)
    result = calibration.fit(objective, key, params, trainable=..., steps=300)

:func:`log_likelihood_objective` turns a filter's kernel and one or many sequences into a function
``(key, params) -> mean log-likelihood per step``; :func:`fit` maximises it over the ``trainable``
leaves of ``params``, positive ones through a log (or softplus) transform, with optax (Adam by
default), one compiled update for every step, and returns the fitted parameters with the loss and
parameter traces (:class:`FitResult`). A fit is deterministic for a fixed key.

Which filters can be fitted: those whose ``log_likelihood`` is the marginal likelihood of their
observations, with the score gradient — MCL with any sensor, FastSLAM, the EKF and UKF (KLD-MCL's
is a likelihood, but it resamples by its own rule and its gradient is the naive one). Augmented MCL (random poses
injected without a weight) and IR MCL (particles redrawn when lost) report a likelihood increment
only at the steps without an injection or a restart. PF-SLAM and PS-SLAM report a pseudo-likelihood
(the robot weighted against tag estimates already updated with the same detections); it is not a
likelihood and must not be maximised.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxnav.core import filter as filter_api
from jaxnav.core.progress import Progress

__all__ = [
    "TRANSFORMS",
    "FitResult",
    "log_likelihood",
    "log_likelihood_objective",
    "fit",
]

TRANSFORMS = ("log", "softplus", "identity")
"""How a trainable leaf ``θ`` is reached from the unconstrained ``u`` the optimiser moves:
``"log"``: ``θ = exp(u)`` (a positive parameter, a noise level); ``"softplus"``:
``θ = log(1 + exp(u))`` (positive, gentler near zero); ``"identity"``: ``θ = u`` (a position)."""


@dataclasses.dataclass(frozen=True)
class FitResult:
    """What :func:`fit` returns.

    Attributes:
        params: the fitted parameters (the whole pytree; the leaves not trained are the ones passed).
        losses: ``[steps]`` the loss at each step, ``−objective`` at the parameters before the step.
        trace: the parameters before each step and after the last, every leaf stacked on a leading
            axis of ``steps + 1`` (a leaf not trained repeats its value).
    """

    params: Any
    losses: np.ndarray
    trace: Any


def log_likelihood(
    kernel: Callable,
    key: jax.Array | None,
    state: Any,
    config: Any,
    params: Any,
    *inputs: Any,
    checkpoint: bool = True,
):
    """``Σ_t info.log_likelihood`` of the filter ``kernel`` run over ``inputs`` (leading axis: time).

    The pure counterpart of ``run(...)[1].log_likelihood.sum()``: no host checks, traceable and
    differentiable in ``params`` (:func:`jaxnav.core.filter.scan`; step ``t`` uses
    ``fold_in(key, t)``, as ``run``). ``kernel`` is a filter module's ``kernel`` (``mcl.kernel``,
    ``ekf.kernel``, …). ``checkpoint`` (default): recompute each step in the backward pass instead of
    storing its intermediate values (``jax.checkpoint``), so that a gradient keeps only the state of
    every step. Measured by ``python -m benchmarks.grad_mcl`` (MCL, 100 steps, 2-core CPU): the
    gradient's temporaries fall from 415 MB to 20 MB at 10⁴ particles, at no cost in time (2.2×
    the forward run, against 2.5× without).
    """
    step = jax.checkpoint(kernel, static_argnums=(2,)) if checkpoint else kernel
    _, trace = filter_api.scan(step, key, state, config, params, *inputs)
    return jnp.sum(trace.log_likelihood)


def log_likelihood_objective(
    kernel: Callable,
    config: Any,
    state: Any,
    inputs: Sequence[Any],
    *,
    num_seeds: int = 1,
    batched: bool = False,
    batch_size: int | None = None,
    checkpoint: bool = True,
) -> Callable[[jax.Array, Any], jax.Array]:
    """``objective(key, params)``: the filter's mean log-likelihood per step over sequences and seeds.

    Args:
        kernel: the filter's ``kernel`` (``mcl.kernel``, ``ekf.kernel``, …).
        config: its static configuration (for a particle filter, ``config.gradient`` chooses how the
            gradient passes resampling).
        state: the initial state (from the filter's ``init``), or with ``batched`` one per sequence
            (every leaf with a leading axis ``S``).
        inputs: the filter's inputs over time, as ``run`` takes them (``(controls, observations)``),
            every leaf ``[T, ...]``; with ``batched``, ``[S, T, ...]`` for ``S`` sequences of one
            length ``T``.
        num_seeds: independent filters per sequence (particle filters; their estimates are averaged,
            which divides the gradient's variance by ``num_seeds``).
        batched: ``state`` and ``inputs`` carry a leading sequence axis.
        batch_size: with ``batched``, the number of sequences drawn (without replacement, from the
            key) at each call: a minibatch; ``None`` uses all of them.
        checkpoint: recompute every step in the backward pass (:func:`log_likelihood`; default):
            a gradient's memory grows with the state, not with all of a step's intermediate values.

    Returns:
        A pure function ``objective(key, params) -> scalar``:
        ``(1 / (B·R·T)) Σ_b Σ_r log Ẑ_{b,r}(params)``, ``B`` the sequences used, ``R = num_seeds``.
        Per step, so that a learning rate suits runs of any length.
    """
    if isinstance(num_seeds, bool) or not isinstance(num_seeds, int) or num_seeds < 1:
        raise ValueError(f"num_seeds must be a positive int, got {num_seeds!r}")
    inputs = tuple(inputs)
    leaves = jax.tree_util.tree_leaves(inputs)
    if not leaves:
        raise ValueError("inputs must hold the filter's inputs over time, got none")
    if batched:
        num_sequences, num_steps = leaves[0].shape[:2]
    else:
        num_sequences, num_steps = 1, leaves[0].shape[0]
        state, inputs = jax.tree_util.tree_map(lambda x: jnp.asarray(x)[None], (state, inputs))
    if num_steps < 1:
        raise ValueError("inputs must have at least one time step")
    if batch_size is not None and (
        isinstance(batch_size, bool) or not isinstance(batch_size, int) or not 1 <= batch_size <= num_sequences
    ):
        raise ValueError(f"batch_size must be an int in [1, {num_sequences}] (the sequences), got {batch_size!r}")

    def one_sequence(key, params, seq_state, seq_inputs):
        keys = jax.random.split(key, num_seeds)
        per_seed = jax.vmap(
            lambda k: log_likelihood(kernel, k, seq_state, config, params, *seq_inputs, checkpoint=checkpoint)
        )(keys)
        return jnp.mean(per_seed)

    def objective(key: jax.Array, params: Any) -> jax.Array:
        k_pick, k_runs = jax.random.split(key)
        states, seqs = state, inputs
        if batch_size is not None and batch_size < num_sequences:
            pick = jax.random.choice(k_pick, num_sequences, (batch_size,), replace=False)
            states, seqs = jax.tree_util.tree_map(lambda x: jnp.take(x, pick, axis=0), (state, inputs))
        used = jax.tree_util.tree_leaves(seqs)[0].shape[0]
        keys = jax.random.split(k_runs, used)
        totals = jax.vmap(one_sequence, (0, None, 0, 0))(keys, params, states, seqs)
        return jnp.mean(totals) / num_steps

    return objective


# --------------------------------------------------------------------------- the fit


def _broadcast(prefix: Any, params: Any, name: str) -> list:
    """``prefix`` (a value, or a pytree prefix of ``params``) repeated over ``params``' leaves, as a list."""
    if callable(prefix) and not isinstance(prefix, str):
        prefix = prefix(params)
    try:
        full = jax.tree_util.tree_map(
            lambda p, sub: jax.tree_util.tree_map(lambda _: p, sub), prefix, params, is_leaf=lambda x: x is None
        )
    except ValueError as err:
        raise ValueError(f"{name} must be a value or a pytree prefix of params: {err}") from None
    return jax.tree_util.tree_leaves(full, is_leaf=lambda x: x is None)


def _forward(transform: str, u: jax.Array) -> jax.Array:
    if transform == "log":
        return jnp.exp(u)
    if transform == "softplus":
        return jax.nn.softplus(u)
    return u


def _inverse(transform: str, theta: np.ndarray) -> np.ndarray:
    if transform == "log":
        return np.log(theta)
    if transform == "softplus":
        return theta + np.log(-np.expm1(-theta))  # softplus⁻¹, stable for large θ
    return theta


def _optimizer(optimizer: Any, learning_rate: Any) -> tuple[optax.GradientTransformationExtraArgs, bool]:
    """The optax transformation, and whether it searches a line (it then gets the objective, with one key)."""
    if optimizer is None or (isinstance(optimizer, str) and optimizer == "adam"):
        number = isinstance(learning_rate, (int, float)) and not isinstance(learning_rate, bool)
        if not (callable(learning_rate) or (number and math.isfinite(learning_rate) and learning_rate > 0)):
            raise ValueError(f"learning_rate must be a positive number or an optax schedule, got {learning_rate!r}")
        return optax.with_extra_args_support(optax.adam(learning_rate)), False
    if isinstance(optimizer, str) and optimizer == "lbfgs":
        return optax.lbfgs(), True
    if isinstance(optimizer, optax.GradientTransformationExtraArgs):  # optax.lbfgs(...), a line search
        return optimizer, True
    if isinstance(optimizer, optax.GradientTransformation):
        return optax.with_extra_args_support(optimizer), False
    raise ValueError(f"optimizer must be 'adam', 'lbfgs' or an optax.GradientTransformation, got {optimizer!r}")


def _is_float(value: Any) -> bool:
    return jnp.issubdtype(np.asarray(value).dtype, jnp.floating)


def _strongly_typed(leaf: Any) -> Any:
    """``leaf`` with JAX's weak type dropped (same dtype and values); other leaves unchanged."""
    return jnp.asarray(leaf, dtype=leaf.dtype) if isinstance(leaf, jax.Array) and leaf.weak_type else leaf


def fit(
    objective: Callable[[jax.Array, Any], jax.Array],
    key: jax.Array,
    params: Any,
    *,
    trainable: Any = True,
    transform: Any = "log",
    steps: int = 200,
    optimizer: Any = None,
    learning_rate: float = 0.05,
    progress: bool = False,
) -> FitResult:
    """Maximise ``objective(key, params)`` over the ``trainable`` leaves of ``params``.

    Each step ``i`` evaluates the objective and its gradient with the key ``fold_in(key, i)``
    (fresh particle filters every step: a stochastic gradient) and lets the optimiser move the
    unconstrained values ``u`` (``θ = transform(u)``). One program is compiled for all steps.

    Args:
        objective: ``(key, params) -> scalar`` to maximise, pure and differentiable in ``params``
            (:func:`log_likelihood_objective`, or any function of that form).
        key: one PRNG key.
        params: the starting parameters (any pytree of float arrays).
        trainable: which leaves to fit: ``True`` (every float leaf), or a pytree prefix of ``params`` with a bool
            per leaf or subtree (``MCLParams(motion=False, sensor=True, landmarks=False)``) or a bool
            array of a leaf's shape (its entries to fit, the others kept), or a function
            ``params -> prefix``.
        transform: a name in :data:`TRANSFORMS` for every trainable leaf, or a pytree prefix of names.
            ``"log"`` (default) requires the leaf's starting values to be positive.
        steps: optimiser steps.
        optimizer: ``"adam"`` (default, with ``learning_rate``), ``"lbfgs"`` (``optax.lbfgs`` with its
            zoom line search: for a deterministic objective, the EKF's or UKF's; it calls the
            objective several times per step, every step with the key of step 0), an
            ``optax.GradientTransformationExtraArgs`` that searches a line the same way (such as
            ``optax.lbfgs(memory_size=5)``), or any other ``optax.GradientTransformation``. The zoom
            search puts the objective and its gradient three times into the compiled step;
            ``optax.lbfgs(linesearch=optax.scale_by_backtracking_linesearch(max_backtracking_steps=15))``
            puts them twice: 8 L-BFGS steps of the EKF over 100 time steps take 8 s with it against
            20 s with zoom on a 2-core CPU, compilation nearly all of it, at the price of the
            curvature condition the zoom search enforces.
        learning_rate: Adam's step size, a number or an optax schedule (in the unconstrained values:
            about the relative change of a log-transformed parameter per step); unused otherwise.
        progress: show a progress bar over the steps (tqdm when installed).

    Returns:
        :class:`FitResult`: the fitted parameters, the losses (``−objective``) and the parameter trace.
    """
    filter_api.check_key(key)
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise ValueError(f"steps must be a non-negative int, got {steps!r}")
    opt, line_search = _optimizer(optimizer, learning_rate)
    flat, treedef = jax.tree_util.tree_flatten_with_path(params)
    if not flat:
        raise ValueError("params has no leaves: nothing to fit")
    paths = [jax.tree_util.keystr(path) for path, _ in flat]
    leaves = [leaf for _, leaf in flat]
    mask = _broadcast(trainable, params, "trainable")
    names = _broadcast(transform, params, "transform")
    index, masks, u0 = [], [], []
    for i, (path, leaf, train, name) in enumerate(zip(paths, leaves, mask, names, strict=True)):
        value = np.asarray(leaf)
        train = np.asarray(train)
        if train.dtype != np.bool_ or train.shape not in ((), value.shape):
            raise ValueError(
                f"trainable must hold a bool, or a bool array of the leaf's shape {value.shape}, for params{path}; "
                f"got {train!r}"
            )
        if not train.any() or (trainable is True and not _is_float(value)):  # True: every float leaf
            continue
        if name not in TRANSFORMS:
            raise ValueError(f"transform must be one of {list(TRANSFORMS)}, got {name!r} for params{path}")
        if not _is_float(value):
            raise ValueError(f"params{path} is trained but is not a float array (dtype {value.dtype})")
        chosen = np.broadcast_to(train, value.shape)
        if not np.all(np.isfinite(value[chosen])):
            raise ValueError(f"params{path} must be finite to be trained")
        if name != "identity" and not np.all(value[chosen] > 0):
            raise ValueError(
                f"params{path} has trained values <= 0, which the {name!r} transform cannot reach; "
                "start from positive values or pass transform='identity' for it"
            )
        index.append(i)
        masks.append(None if chosen.all() else jnp.asarray(chosen))
        safe = np.where(chosen, value, 1.0)  # the entries not trained keep their value; u is unused there
        u0.append(jnp.asarray(_inverse(name, safe), value.dtype))
    if not index:
        raise ValueError("trainable selects no leaf of params: nothing to fit")

    def assemble(u: list) -> Any:
        full = list(leaves)
        for i, value, chosen in zip(index, u, masks, strict=True):
            fitted = _forward(names[i], value)
            full[i] = fitted if chosen is None else jnp.where(chosen, fitted, leaves[i])
        return jax.tree_util.tree_unflatten(treedef, full)

    def loss(u: list, step_key: jax.Array) -> jax.Array:
        return -objective(step_key, assemble(u))

    @jax.jit
    def update(u, opt_state, step_key):
        value, grad = jax.value_and_grad(loss)(u, step_key)
        updates, opt_state = opt.update(
            grad, opt_state, u, value=value, grad=grad, value_fn=lambda v: loss(v, step_key)
        )
        return optax.apply_updates(u, updates), opt_state, value

    # optax initialises some counters as weak-typed scalars (L-BFGS's line-search step count) that come
    # back from the first update strongly typed: fix their types now, or step 2 compiles `update` again.
    u, opt_state = u0, jax.tree_util.tree_map(_strongly_typed, opt.init(u0))
    losses, trace = [], [[np.asarray(x) for x in u0]]
    bar = Progress(steps, "fit", enabled=progress, note="compiling the objective and its gradient…", unit="step")
    try:
        for i in range(steps):
            step_key = jax.random.fold_in(key, 0 if line_search else i)  # a line search needs one objective
            u, opt_state, value = update(u, opt_state, step_key)
            losses.append(float(value))
            trace.append([np.asarray(x) for x in u])
            bar.update(1)
    finally:
        bar.close()
    trace_leaves = [np.broadcast_to(np.asarray(leaf), (len(trace), *np.shape(leaf))) for leaf in leaves]
    for j, i in enumerate(index):
        fitted = np.array(_forward(names[i], jnp.asarray(np.stack([t[j] for t in trace]))))
        fitted[0] = np.asarray(leaves[i])  # the values passed, not their round trip through the transform
        trace_leaves[i] = fitted if masks[j] is None else np.where(np.asarray(masks[j]), fitted, np.asarray(leaves[i]))
    return FitResult(assemble(u), np.asarray(losses), jax.tree_util.tree_unflatten(treedef, trace_leaves))
