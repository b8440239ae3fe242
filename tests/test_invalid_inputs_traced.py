"""Inputs outside a model's domain inside a caller's ``jit``: every filter's kernel flags the step
and carries its state over unchanged.

The host refuses a negative time step, a negative noise level, and a control or parameter that is
not finite or exceeds ``MAX_MAGNITUDE`` (``test_bad_input.py``). Under ``jax.jit(kernel)`` the host
sees tracers, so the kernel itself must test them: ``info.invalid_inputs`` is set and the state it
returns is the state it was given, leaf for leaf. With valid inputs the flag is off and the kernel
gives what ``step`` gives. Each filter's kernel is compiled once (module-scoped) and called with
inputs of the same shapes, so the cases cost no further compilation.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import filter as filter_api
from jaxnav.localization import augmented_mcl, ekf, grid, ir_mcl, kld_mcl, mcl, rfid_anchor, rfid_tag, ukf
from jaxnav.slam import ekf_slam, fastslam, pf_slam, ps_slam
from tests.test_bad_input import FILTERS, Setup, setups

MODULES = {
    "ekf": ekf,
    "ukf": ukf,
    "mcl": mcl,
    "kld_mcl": kld_mcl,
    "augmented_mcl": augmented_mcl,
    "grid": grid,
    "ekf_slam": ekf_slam,
    "fastslam1": fastslam,
    "fastslam2": fastslam,
    "pf_slam": pf_slam,
    "ps_slam": ps_slam,
    "ir_mcl": ir_mcl,
    "rfid_tag": rfid_tag,
    "rfid_anchor": rfid_anchor,
}

# Filters whose control carries a time step Δt, and its column.
DT_COLUMN = {
    **{f: 2 for f in ("ekf", "ukf", "mcl", "kld_mcl", "augmented_mcl", "grid", "ekf_slam", "fastslam1", "fastslam2")},
    **{f: 3 for f in ("pf_slam", "ps_slam", "ir_mcl")},
}


def _with(tree: Any, path: tuple[str, ...], fn: Callable[[Any], Any]) -> Any:
    """``tree`` with the field at ``path`` (NamedTuple field names) replaced by ``fn(field)``."""
    if not path:
        return fn(tree)
    head, rest = path[0], path[1:]
    return tree._replace(**{head: _with(getattr(tree, head), rest, fn)})


# A noise level of each filter's parameters, made negative in the "negative noise" case.
NOISE_FIELD = {
    **{
        f: ("motion", "alphas")
        for f in ("ekf", "ukf", "mcl", "kld_mcl", "augmented_mcl", "grid", "ekf_slam", "fastslam1", "fastslam2")
    },
    "pf_slam": ("motion", "sd"),
    "ps_slam": ("tag_jitter_sd",),
    "ir_mcl": ("sigma_v",),
    "rfid_tag": ("phase_sigma",),
    "rfid_anchor": ("odometry_sd",),
}


class Kernel:
    """One filter's setup, its jitted kernel and its first step's inputs."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.setup: Setup = setups()[name]
        self.module = MODULES[name]
        self.jitted = jax.jit(self.module.kernel, static_argnums=2)
        self.key = None if self.setup.deterministic else jax.random.PRNGKey(11)
        self.inputs = tuple(jax.tree_util.tree_map(lambda x: jnp.asarray(x)[0], x) for x in self.setup.inputs)

    def __call__(self, params: Any = None, inputs: tuple | None = None) -> tuple[Any, Any]:
        s = self.setup
        return self.jitted(
            self.key, s.state, s.config, s.params if params is None else params, *(inputs or self.inputs)
        )

    def control_case(self, fn: Callable[[jax.Array], jax.Array]) -> tuple[Any, ...]:
        return (fn(self.inputs[0]), *self.inputs[1:])


@pytest.fixture(scope="module")
def kernels() -> dict[str, Kernel]:
    return {}


def _kernel(kernels: dict[str, Kernel], name: str) -> Kernel:
    if name not in kernels:
        kernels[name] = Kernel(name)
    return kernels[name]


def _same_state(a: Any, b: Any) -> list[str]:
    """Paths of the leaves where states ``a`` and ``b`` differ (NaN equal to NaN)."""
    out = []
    for (path, x), y in zip(jax.tree_util.tree_flatten_with_path(a)[0], jax.tree_util.tree_leaves(b)):
        if not np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True):
            out.append(jax.tree_util.keystr(path))
    return out


def _cases(k: Kernel) -> dict[str, dict[str, Any]]:
    """``case id -> keyword arguments of Kernel.__call__`` for every domain violation of a filter."""
    s = k.setup
    cases: dict[str, dict[str, Any]] = {}
    col = DT_COLUMN.get(k.name)
    if col is not None:
        cases["negative-dt"] = dict(inputs=k.control_case(lambda u: u.at[col].set(-0.1)))
    cases["negative-noise"] = dict(params=_with(s.params, NOISE_FIELD[k.name], lambda x: -jnp.abs(x) - 0.01))
    if k.name == "rfid_tag":  # no control: a parameter that is not finite, or absurd
        cases["nan-parameter"] = dict(params=_with(s.params, ("phase_sigma",), lambda x: x * jnp.nan))
        cases["huge-parameter"] = dict(params=_with(s.params, ("box_hi",), lambda x: x.at[0].set(1e30)))
    else:
        cases["nan-control"] = dict(inputs=k.control_case(lambda u: u.at[0].set(jnp.nan)))
        cases["huge-control"] = dict(inputs=k.control_case(lambda u: u.at[0].set(1e30)))
    return cases


@pytest.mark.parametrize("f", FILTERS)
def test_invalid_inputs_under_jit_are_flagged_and_keep_the_state(kernels, f):
    k = _kernel(kernels, f)
    failures = []
    for cid, kwargs in _cases(k).items():
        state, info = k(**kwargs)
        if not bool(info.invalid_inputs):
            failures.append(f"{cid}: info.invalid_inputs is False")
        changed = _same_state(state, k.setup.state)
        if changed:
            failures.append(f"{cid}: the state changed at {changed}")
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize("f", FILTERS)
def test_valid_inputs_under_jit_are_not_flagged_and_match_step(kernels, f):
    k = _kernel(kernels, f)
    state, info = k()
    assert not bool(info.invalid_inputs)
    assert np.shape(info.invalid_inputs) == () and jnp.result_type(info.invalid_inputs) == jnp.bool_
    s = k.setup
    fresh = jax.tree_util.tree_map(jnp.copy, s.state)  # step donates the state of the SLAM filters
    expected_state, expected_info = k.module.step(k.key, fresh, s.config, s.params, *k.inputs)
    assert _same_state(state, expected_state) == []
    np.testing.assert_array_equal(np.asarray(info.estimate), np.asarray(expected_info.estimate))


def test_a_filter_in_a_vmap_flags_each_run_on_its_own():
    """Two runs in one ``vmap``, the second with a negative Δt: only it is flagged and kept."""
    s = setups()["mcl"]
    control = jnp.asarray(s.inputs[0])[0]
    obs = jax.tree_util.tree_map(lambda x: jnp.asarray(x)[0], s.inputs[1])
    controls = jnp.stack([control, control.at[2].set(-0.25)])
    keys = jax.random.split(jax.random.PRNGKey(2), 2)
    run = jax.jit(jax.vmap(mcl.kernel, in_axes=(0, None, None, None, 0, None)), static_argnums=2)
    state, info = run(keys, s.state, s.config, s.params, controls, obs)
    np.testing.assert_array_equal(np.asarray(info.invalid_inputs), [False, True])
    np.testing.assert_array_equal(np.asarray(state.particles[1]), np.asarray(s.state.particles))
    assert not np.array_equal(np.asarray(state.particles[0]), np.asarray(s.state.particles))


def test_a_scan_skips_the_invalid_step_and_goes_on():
    """``filter.scan`` (the pure run) over 4 steps with a NaN control at step 1: step 1 is flagged
    and leaves the state as step 0 made it; the other steps run."""
    s = setups()["ekf"]
    controls = jnp.asarray(s.inputs[0]).at[1, 0].set(jnp.nan)
    final, trace = jax.jit(lambda u: filter_api.scan(ekf.kernel, None, s.state, s.config, s.params, u, s.inputs[1]))(
        controls
    )
    np.testing.assert_array_equal(np.asarray(trace.invalid_inputs), [False, True, False, False])
    np.testing.assert_array_equal(np.asarray(trace.estimate[1]), np.asarray(trace.estimate[0]))
    assert np.all(np.isfinite(np.asarray(final.mean)))


def test_params_in_domain_mirrors_the_host_check_of_every_filters_parameters():
    """``params_in_domain`` is the traced twin of ``check_params_arrays``: -inf only in ``log_…`` fields."""
    p = setups()["pf_slam"].params
    assert bool(filter_api.params_in_domain(p))
    assert bool(filter_api.params_in_domain(p._replace(sensor=p.sensor._replace(log_beta=jnp.asarray(-jnp.inf)))))
    assert not bool(filter_api.params_in_domain(p._replace(sensor=p.sensor._replace(half_width=jnp.asarray(jnp.inf)))))
    assert not bool(filter_api.params_in_domain(p._replace(motion=p.motion._replace(sd=jnp.full(3, 2e6)))))


def test_every_info_type_documents_the_flag():
    infos = {
        ekf.KalmanInfo,
        grid.GridInfo,
        ekf_slam.EKFSLAMInfo,
        mcl.MCLInfo,
        augmented_mcl.AugmentedMCLInfo,
        kld_mcl.KLDMCLInfo,
        fastslam.FastSLAMInfo,
        pf_slam.SLAMInfo,
        ir_mcl.IRMCLInfo,
        rfid_tag.RFIDTagInfo,
        rfid_anchor.RFIDAnchorInfo,
    }
    for info in infos:
        fields = [f.name for f in dataclasses.fields(info)] if dataclasses.is_dataclass(info) else info._fields
        assert "invalid_inputs" in fields, info.__name__
        assert "invalid_inputs" in (info.__doc__ or ""), info.__name__
