"""Small deterministic optimisers used by the model fits (optax inside one ``lax.scan``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import optax

__all__ = ["lbfgs_minimize"]


def lbfgs_minimize(loss: Callable[[Any], Any], x0: Any, steps: int, linesearch: Any) -> Any:
    """``steps`` iterations of optax L-BFGS on ``loss`` from ``x0``, in one ``lax.scan`` (jittable).

    ``linesearch`` is an optax line search (e.g. ``optax.scale_by_zoom_linesearch(20)``);
    a fixed number of steps keeps the shapes static. Returns the last iterate.
    """
    opt = optax.lbfgs(linesearch=linesearch)

    def body(carry, _):
        x, st = carry
        val, g = jax.value_and_grad(loss)(x)
        upd, st = opt.update(g, st, x, value=val, grad=g, value_fn=loss)
        return (optax.apply_updates(x, upd), st), None

    (x, _), _ = jax.lax.scan(body, (x0, opt.init(x0)), None, length=steps)
    return x
