"""A battery of bad inputs for every public filter: none becomes a silent wrong answer.

Each case feeds one filter's ``run`` one bad argument — a parameter, a state field or an input
array set to NaN, an infinity or 1e30, set to ``None`` or given a wrong shape or dtype, a bad key,
a wrong config or state type, a list where an array was expected — and the outcome must be one
of two:

* refused before anything is traced, with a ``ValueError``/``TypeError`` whose message names the
  argument (:func:`_refused_naming`);
* accepted, with every output finite (``-inf`` only in log-domain fields, where it means "zero
  probability").

Anything else (another exception, a message naming nothing, a NaN in an output) fails the test.
The cases are generated from each filter's own pytrees, so a field added later is covered.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import memory
from jaxnav.demo import demo_setting
from jaxnav.localization import augmented_mcl, ekf, grid, ir_mcl, kld_mcl, mcl, rfid_anchor, rfid_tag, ukf
from jaxnav.models import hf_rfid
from jaxnav.models import uhf_rfid as U
from jaxnav.models.motion import OmniNoise
from jaxnav.sim import ir_world, tag_carpet, trajectories
from jaxnav.sim import landmark_world as world
from jaxnav.slam import ekf_slam, fastslam, pf_slam, ps_slam

T = 4
START = jnp.asarray([5.0, 1.5, 0.0])


class Setup(NamedTuple):
    run: Callable[..., Any]
    state: Any
    config: Any
    params: Any
    inputs: tuple
    input_names: tuple[str, ...]
    deterministic: bool = False


def _landmark_world():
    _, p = demo_setting(10)
    controls = trajectories.loop_controls(T, 0.5, 0.21, 0.25)
    sim = world.simulate(jax.random.PRNGKey(1), p.landmarks, START, controls, p.motion, p.sensor)
    return p, controls, sim.observations


def _key(i: int) -> jax.Array:
    return jax.random.PRNGKey(i)


def _landmark_setups() -> dict[str, Setup]:
    p, u, obs = _landmark_world()
    cov = jnp.diag(jnp.asarray([1e-3, 1e-3, 1e-4]))
    names = ("controls", "observations")
    out = {}
    for name, mod, cfg in (("ekf", ekf, ekf.EKFConfig()), ("ukf", ukf, ukf.UKFConfig())):
        out[name] = Setup(mod.run, mod.init(None, cfg, p, START, cov), cfg, p, (u, obs), names, True)
    c = mcl.MCLConfig(num_particles=32)
    out["mcl"] = Setup(mcl.run, mcl.init(_key(0), c, p, START, jnp.full(3, 0.05)), c, p, (u, obs), names)
    c = kld_mcl.KLDMCLConfig(max_particles=64, min_particles=16)
    out["kld_mcl"] = Setup(kld_mcl.run, kld_mcl.init(_key(0), c, p, START, jnp.full(3, 0.05)), c, p, (u, obs), names)
    c = augmented_mcl.AugmentedMCLConfig(num_particles=32)
    ap = augmented_mcl.AugmentedMCLParams(p.motion, p.sensor, p.landmarks, jnp.asarray([0.0, 10.0, 0.0, 10.0]))
    out["augmented_mcl"] = Setup(
        augmented_mcl.run, augmented_mcl.init(_key(0), c, ap, START, jnp.full(3, 0.05)), c, ap, (u, obs), names
    )
    c = grid.GridConfig((0.0, 10.0, 0.0, 10.0), 10, 10, 8, "velocity")
    out["grid"] = Setup(grid.run, grid.init(None, c, p, START), c, p, (u, obs), names, True)
    c = ekf_slam.EKFSLAMConfig(num_landmarks=p.landmarks.shape[0])
    sp = ekf_slam.EKFSLAMParams(p.motion, p.sensor)
    out["ekf_slam"] = Setup(ekf_slam.run, ekf_slam.init(None, c, sp, START, cov), c, sp, (u, obs), names, True)
    for version in (1, 2):
        c = fastslam.FastSLAMConfig(num_particles=8, num_landmarks=p.landmarks.shape[0], version=version)
        fp = fastslam.FastSLAMParams(p.motion, p.sensor)
        out[f"fastslam{version}"] = Setup(fastslam.run, fastslam.init(_key(0), c, fp, START), c, fp, (u, obs), names)
    return out


def _tag_slam_setups() -> dict[str, Setup]:
    sensor = hf_rfid.reader_params(0.06)
    carpet = tag_carpet.make_carpet(_key(3), (1.0, 1.0), density=16.0)
    controls = jnp.tile(jnp.asarray([[0.2, 0.0, 0.0, 0.5]]), (T, 1))
    sim = tag_carpet.simulate(_key(4), carpet, sensor, jnp.asarray([0.2, 0.5, 0.0]), controls, jnp.full(3, 0.01))
    params = pf_slam.PFSLAMParams(OmniNoise(jnp.full(3, 0.01)), sensor)
    names = ("controls", "detections")
    out = {}
    c = pf_slam.PFSLAMConfig(num_particles=8, num_tag_particles=8, max_tags=carpet.layout.num_tags)
    state = pf_slam.init(_key(0), c, params, sim.start_pose)
    out["pf_slam"] = Setup(pf_slam.run, state, c, params, (sim.odometry, sim.detections), names)
    c = ps_slam.PSSLAMConfig(num_particles=8, num_tag_particles=8, max_tags=carpet.layout.num_tags, lag=3)
    pp = ps_slam.PSSLAMParams(params.motion, sensor, tag_jitter_sd=jnp.asarray(0.015))
    state = ps_slam.init(_key(0), c, pp, sim.start_pose)
    out["ps_slam"] = Setup(ps_slam.run, state, c, pp, (sim.odometry, sim.detections), names)
    return out


def _ir_setup() -> Setup:
    layout = ir_world.experiment_layout()
    c = ir_mcl.IRMCLConfig(num_particles=32)
    params = ir_mcl.default_params(c, layout)
    # 16 steps: the receivers' first detections come at step 13
    poses = ir_world.polyline_path(ir_world.EXPERIMENT_WAYPOINTS, speed=0.2, dt=0.1, num_steps=16)
    sim = ir_world.simulate(_key(5), layout, poses, 0.1)
    state = ir_mcl.init(_key(0), c, params, ir_world.layout_area(layout))
    return Setup(ir_mcl.run, state, c, params, (sim.controls, sim.detections), ("controls", "detections"))


def _uhf_setups() -> dict[str, Setup]:
    lam = U.A_WAVELENGTH
    xs = np.linspace(0.0, 1.5, T)
    path = np.stack([xs, np.full(T, -0.3), np.full(T, 0.5), np.full(T, np.pi / 2)], 1).astype(np.float32)
    d = np.linalg.norm(path[:, :3] - np.asarray([1.0, 1.0, 0.8]), axis=1)
    rssi = np.asarray(U.power_scale(jnp.asarray(path), jnp.asarray([1.0, 1.0, 0.8]), U.DEFAULT_CHANNEL))
    phase = np.asarray(U.wrap_phase(jnp.asarray(-4 * np.pi * d / lam)))
    reads = U.UHFReads(
        jnp.asarray(path[:, None, :]),
        jnp.asarray(rssi[:, None]),
        jnp.asarray(phase[:, None]),
        jnp.full((T, 1), lam),
        jnp.ones((T, 1), bool),
    )
    out = {}
    c = rfid_tag.RFIDTagConfig(num_particles=32)
    params = rfid_tag.default_params(gamma=U.GammaParams(20.0, 0.05))
    out["rfid_tag"] = Setup(rfid_tag.run, rfid_tag.init(_key(0), c, params), c, params, (reads,), ("reads",))
    anchors = np.asarray([[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 3.0, 1.0]], np.float32)
    c = rfid_anchor.RFIDAnchorConfig(num_particles=32)
    params = rfid_anchor.default_params(
        anchors, gamma=U.GammaParams(20.0, 0.05), box_lo=(0, 0, 0.5), box_hi=(2, 3, 1.1)
    )
    da = np.linalg.norm(path[:, None, :3] - anchors[None], axis=-1)
    a = np.asarray(U.power_scale(jnp.asarray(path[:, None, :]), jnp.asarray(anchors)[None], U.DEFAULT_CHANNEL))
    areads = rfid_anchor.AnchorReads(
        jnp.asarray(a),
        U.wrap_phase(jnp.asarray(-4 * np.pi * da / lam)),
        jnp.full(da.shape, lam),
        jnp.ones(da.shape, bool),
    )
    controls = jnp.asarray(np.diff(np.concatenate([path[:1], path]), axis=0))
    out["rfid_anchor"] = Setup(
        rfid_anchor.run, rfid_anchor.init(_key(0), c, params), c, params, (controls, areads), ("controls", "reads")
    )
    return out


@functools.cache
def setups() -> dict[str, Setup]:
    return {**_landmark_setups(), **_tag_slam_setups(), "ir_mcl": _ir_setup(), **_uhf_setups()}


FILTERS = [
    "ekf",
    "ukf",
    "mcl",
    "kld_mcl",
    "augmented_mcl",
    "grid",
    "ekf_slam",
    "fastslam1",
    "fastslam2",
    "pf_slam",
    "ps_slam",
    "ir_mcl",
    "rfid_tag",
    "rfid_anchor",
]


# --------------------------------------------------------------------------- outcomes


def _names(path: tuple) -> list[str]:
    """The field names along a pytree path (``.sensor.sd`` → ``["sensor", "sd"]``)."""
    out = []
    for k in path:
        name = getattr(k, "name", None) or getattr(k, "key", None)
        if isinstance(name, str):
            out.append(name)
    return out


def _finite_outputs(outputs: Any) -> list[str]:
    """Paths of output leaves holding NaN or +inf (or -inf outside log-domain fields)."""
    bad = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(outputs)[0]:
        v = np.asarray(leaf)
        if v.dtype.kind != "f":
            continue
        names = _names(path)
        log_domain = any(n.startswith("log_") for n in names)
        if np.isnan(v).any() or (v == np.inf).any() or (not log_domain and (v == -np.inf).any()):
            bad.append(".".join(names) or str(path))
    return bad


def _refused_naming(err: Exception, tokens: tuple[str, ...]) -> bool:
    return isinstance(err, (ValueError, TypeError)) and any(t in str(err) for t in tokens)


def check_outcome(call: Callable[[], Any], tokens: tuple[str, ...]) -> str:
    """``"refused"`` or ``"accepted"``; fails the test on any other outcome."""
    try:
        outputs = call()
    except Exception as err:  # noqa: BLE001  (the point is to see every kind)
        assert _refused_naming(err, tokens), f"{type(err).__name__} naming none of {tokens}: {err}"
        return "refused"
    bad = _finite_outputs(outputs)
    assert not bad, f"accepted, but these outputs are not finite: {bad}"
    return "accepted"


def _call(s: Setup, *, key=None, state=None, config=None, params=None, inputs=None) -> Callable[[], Any]:
    run_key = _key(7) if key is None else key
    if isinstance(key, str) and key == "none":
        run_key = None
    return lambda: s.run(
        run_key,
        s.state if state is None else state,
        s.config if config is None else config,
        s.params if params is None else params,
        *(s.inputs if inputs is None else inputs),
    )


# --------------------------------------------------------------------------- cases


def _float_leaves(tree: Any) -> list[tuple[tuple, Any]]:
    return [
        (path, leaf)
        for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]
        if np.asarray(leaf).dtype.kind == "f" and np.size(leaf) > 0
    ]


def _set_first(tree: Any, path: tuple, value: float) -> Any:
    def put(p, leaf):
        if p != path:
            return leaf
        a = np.array(leaf)
        a.reshape(-1)[0] = value
        return jnp.asarray(a)

    return jax.tree_util.tree_map_with_path(put, tree)


def _add_axis(tree: Any, path: tuple) -> Any:
    return jax.tree_util.tree_map_with_path(lambda p, x: x[..., None] if p == path else x, tree)


def _replace_field(tree: Any, name: str, value: Any) -> Any:
    if dataclasses.is_dataclass(tree):
        return dataclasses.replace(tree, **{name: value})
    return tree._replace(**{name: value})


def _fields(tree: Any) -> tuple[str, ...]:
    if dataclasses.is_dataclass(tree):
        return tuple(f.name for f in dataclasses.fields(tree))
    return getattr(tree, "_fields", ())


def _half(tree: Any) -> Any:
    return jax.tree_util.tree_map(lambda x: x.astype(jnp.float16) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


BAD_VALUES = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf, "huge": 1e30}

# A case: (id, call, tokens the message must contain one of, whether it must be refused)
Case = tuple[str, Callable[[], Any], tuple[str, ...], bool]


def _argument_cases(s: Setup) -> list[Case]:
    """The key, the config, and the types of the state and the parameters."""
    return [
        ("key-int", _call(s, key=0), ("key",), True),
        ("key-float", _call(s, key=jnp.zeros(2)), ("key",), True),
        ("key-batch", _call(s, key=jax.random.split(_key(0), 3)), ("key",), True),
        ("key-none", _call(s, key="none"), ("key",), not s.deterministic),
        ("config-wrong-type", _call(s, config=object()), ("config",), True),
        ("state-wrong-type", _call(s, state=tuple(s.state)), ("state",), True),
        ("state-float16", _call(s, state=_half(s.state)), ("state",), True),
        ("params-wrong-type", _call(s, params=tuple(s.params)), ("params",), True),
    ]


def _leaf_cases(s: Setup, field: str) -> list[Case]:
    """Every floating-point leaf of the params or the state: each bad value, and a wrong shape."""
    tree = getattr(s, field)
    out = []
    for path, _ in _float_leaves(tree):
        names = _names(path)
        tokens = (field, *names) if field == "state" else (*names, "params")
        leaf = ".".join(names)
        for kind, value in BAD_VALUES.items():
            must_refuse = not (kind == "-inf" and names[-1].startswith("log_"))
            out.append((f"{leaf}={kind}", _call(s, **{field: _set_first(tree, path, value)}), tokens, must_refuse))
        out.append((f"{leaf}-wrong-shape", _call(s, **{field: _add_axis(tree, path)}), tokens, True))
    return out


def _param_field_cases(s: Setup) -> list[Case]:
    """Every field of the parameters set to ``None``."""
    return [
        (f"params.{name}=None", _call(s, params=_replace_field(s.params, name, None)), (name,), True)
        for name in _fields(s.params)
    ]


def _input_cases(s: Setup) -> list[Case]:
    """Every floating-point leaf of every input: each bad value (refused, or accepted with finite
    outputs, e.g. in a masked slot) and a wrong shape; each input one step short; arrays as lists."""
    out = []
    for i, x in enumerate(s.inputs):
        name = s.input_names[i]

        def swap(new, i=i):
            return tuple(new if j == i else y for j, y in enumerate(s.inputs))

        for path, _ in _float_leaves(x):
            names = _names(path)
            leaf = ".".join([name, *names])
            for kind, value in BAD_VALUES.items():
                out.append((f"{leaf}={kind}", _call(s, inputs=swap(_set_first(x, path, value))), (name, *names), False))
            out.append((f"{leaf}-wrong-shape", _call(s, inputs=swap(_add_axis(x, path))), (name, *names), True))
        if len(s.inputs) > 1:
            short = jax.tree_util.tree_map(lambda a: a[:-1], x)
            out.append((f"{name}-one-step-short", _call(s, inputs=swap(short)), ("steps", *s.input_names), True))
        if not _fields(x):
            out.append((f"{name}-as-list", _call(s, inputs=swap(np.asarray(x).tolist())), (name,), False))
    return out


CATEGORIES = {
    "arguments": _argument_cases,
    "params": lambda s: _leaf_cases(s, "params") + _param_field_cases(s),
    "state": lambda s: _leaf_cases(s, "state"),
    "inputs": _input_cases,
}


@pytest.mark.parametrize("category", list(CATEGORIES))
@pytest.mark.parametrize("f", FILTERS)
def test_bad_input_is_refused_by_name_or_handled(f, category):
    """Each case of the category: refused naming the argument, or accepted with finite outputs."""
    cases = CATEGORIES[category](setups()[f])
    failures = []
    for cid, call, tokens, must_refuse in cases:
        try:
            outcome = check_outcome(call, tokens)
            if must_refuse and outcome != "refused":
                failures.append(f"{cid}: accepted")
        except AssertionError as err:
            failures.append(f"{cid}: {err}")
    assert not failures, f"{len(failures)} of {len(cases)} cases:\n" + "\n".join(failures)


def test_lists_give_the_same_result_as_arrays():
    s = setups()["mcl"]
    _, expected = _call(s)()
    _, from_list = _call(s, inputs=(np.asarray(s.inputs[0]).tolist(), s.inputs[1]))()
    np.testing.assert_array_equal(np.asarray(from_list.estimate), np.asarray(expected.estimate))


def test_the_battery_holds_at_least_300_cases():
    total = sum(len(build(setups()[f])) for f in FILTERS for build in CATEGORIES.values())
    assert total >= 300, total


# --------------------------------------------------------------------------- under a caller's jit


def _jit_run(s: Setup, inputs: tuple) -> Any:
    """``run`` inside a caller's ``jit``: the host sees tracers and cannot check the values."""
    key = None if s.deterministic else _key(7)
    return jax.jit(lambda *xs: s.run(key, s.state, s.config, s.params, *xs))(*inputs)


@pytest.mark.parametrize("f", ["ekf", "ukf", "ekf_slam", "mcl", "grid", "fastslam1", "fastslam2"])
def test_an_overflowing_control_under_jit_is_not_applied_and_is_flagged(f):
    """v = 1e30 m/s at step 1 (refused on the host) overflows the motion model inside a jit: the
    Gaussian filters keep their state and flag the step, the particle filters give the overflowing
    particles zero weight (all of them here: a degenerate step), and every output stays finite."""
    s = setups()[f]
    controls = s.inputs[0].at[1, 0].set(1e30)
    final, trace = _jit_run(s, (controls, s.inputs[1]))
    assert not _finite_outputs((final, trace)), _finite_outputs((final, trace))
    if hasattr(trace, "degenerate"):
        assert bool(trace.degenerate[1]) and not bool(trace.degenerate[0])
    if f in ("ekf", "ukf", "ekf_slam"):  # the step was not applied: step 1 reports step 0's state
        np.testing.assert_array_equal(np.asarray(trace.estimate[1]), np.asarray(trace.estimate[0]))


@pytest.mark.parametrize("f", ["ekf", "ukf", "ekf_slam", "fastslam1", "fastslam2", "mcl"])
def test_a_huge_measurement_under_jit_never_reaches_the_state(f):
    """A range of 1e20 m in a valid slot (refused on the host): under jit the slot is dropped and
    counted, and the outputs stay finite."""
    s = setups()[f]
    obs = s.inputs[1]
    assert bool(obs.mask[1, 0])
    bad = obs._replace(z=obs.z.at[1, 0, 0].set(1e20))
    final, trace = _jit_run(s, (s.inputs[0], bad))
    assert not _finite_outputs((final, trace)), _finite_outputs((final, trace))
    _, clean = _jit_run(s, s.inputs)
    np.testing.assert_array_equal(np.asarray(trace.num_ignored), np.asarray(clean.num_ignored) + (np.arange(T) == 1))


def test_tag_slam_under_jit_survives_a_nan_odometry_row():
    """A NaN odometry row inside a caller's jit: every moved particle is NaN, so the step keeps the
    previous particles with uniform weights and is flagged; nothing non-finite reaches the state."""
    s = setups()["pf_slam"]
    final, trace = _jit_run(s, (s.inputs[0].at[1, 0].set(jnp.nan), s.inputs[1]))
    assert not _finite_outputs((final, trace)), _finite_outputs((final, trace))
    assert bool(trace.degenerate[1])


def _poison_reading(f: str, s: Setup, value: float) -> tuple[tuple, int]:
    """``(inputs, t)``: the inputs with ``value`` in the first valid reading, at step ``t``."""
    if f == "rfid_tag":
        (reads,) = s.inputs
        return (reads._replace(rssi=reads.rssi.at[1, 0].set(value)),), 1
    if f == "rfid_anchor":
        controls, reads = s.inputs
        return (controls, reads._replace(phase=reads.phase.at[1, 0].set(value))), 1
    controls, det = s.inputs
    t, r = (int(i) for i in np.argwhere(np.asarray(det.valid))[0])
    return (controls, det._replace(voltage=det.voltage.at[t, r].set(value))), t


@pytest.mark.parametrize("value", [np.nan, 1e30])
@pytest.mark.parametrize("f", ["rfid_tag", "rfid_anchor", "ir_mcl"])
def test_an_unusable_reading_under_jit_is_dropped_and_counted(f, value):
    """A NaN or absurd RSSI, phase or receiver level in a valid slot (refused on the host): under jit
    the reading is dropped and counted in ``num_ignored``, and the outputs stay finite."""
    s = setups()[f]
    inputs, t = _poison_reading(f, s, value)
    final, trace = _jit_run(s, inputs)
    assert not _finite_outputs((final, trace)), _finite_outputs((final, trace))
    _, clean = _jit_run(s, s.inputs)
    steps = np.arange(np.shape(trace.num_ignored)[0])
    np.testing.assert_array_equal(np.asarray(trace.num_ignored), np.asarray(clean.num_ignored) + (steps == t))


# --------------------------------------------------------------------------- one argument at a time


def test_fastslam_init_refuses_a_prior_map_covariance_that_is_not_positive_definite():
    p, _, _ = _landmark_world()
    m = p.landmarks.shape[0]
    c = fastslam.FastSLAMConfig(num_particles=8, num_landmarks=m)
    fp = fastslam.FastSLAMParams(p.motion, p.sensor)
    covs = np.stack([0.01 * np.eye(2)] * m)
    covs[3] = -covs[3]
    with pytest.raises(ValueError, match=r"landmark_covs\[3\] must be positive definite"):
        fastslam.init(_key(0), c, fp, START, landmark_means=p.landmarks, landmark_covs=covs)
    with pytest.raises(ValueError, match=r"landmark_covs\[0\] contains NaN"):
        fastslam.init(_key(0), c, fp, START, landmark_means=p.landmarks, landmark_covs=np.full((m, 2, 2), np.nan))


def test_negative_time_steps_are_refused_by_the_filters_and_the_simulator():
    s = setups()["mcl"]
    controls = s.inputs[0].at[2, 2].set(-0.25)
    with pytest.raises(ValueError, match=r"negative time step .* index \(2, 2\)"):
        _call(s, inputs=(controls, s.inputs[1]))()
    p, _, _ = _landmark_world()
    with pytest.raises(ValueError, match="negative time step"):
        world.simulate(_key(0), p.landmarks, START, controls, p.motion, p.sensor)


def test_the_landmark_simulator_validates_like_the_filters():
    p, controls, _ = _landmark_world()
    sim = functools.partial(world.simulate, _key(0))
    with pytest.raises(ValueError, match=r"controls must have shape \(\*, 3\)"):
        sim(p.landmarks, START, controls[:, :2], p.motion, p.sensor)
    with pytest.raises(ValueError, match="motion noise alphas must be finite and non-negative"):
        sim(p.landmarks, START, controls, p.motion._replace(alphas=-p.motion.alphas), p.sensor)
    with pytest.raises(ValueError, match="initial_pose holds 1 value"):
        sim(p.landmarks, START.at[0].set(jnp.nan), controls, p.motion, p.sensor)
    with pytest.raises(ValueError, match="sensor_noise must be RangeBearingNoise"):
        sim(p.landmarks, START, controls, p.motion, None)
    with pytest.raises(ValueError, match="fov must be"):
        sim(p.landmarks, START, controls, p.motion, p.sensor, fov=7.0)
    listed = sim(p.landmarks.tolist(), START.tolist(), controls.tolist(), p.motion, p.sensor)
    arrays = sim(p.landmarks, START, controls, p.motion, p.sensor)
    np.testing.assert_array_equal(np.asarray(listed.true_poses), np.asarray(arrays.true_poses))


def test_plausible_inputs_are_accepted():
    """A list as the pose, a float16 pose (promoted to float32), lists of controls."""
    s = setups()["mcl"]
    p = s.params
    for pose in ([5.0, 1.5, 0.0], np.float16([5.0, 1.5, 0.0]), jnp.asarray([5.0, 1.5, 0.0], jnp.bfloat16)):
        state = mcl.init(_key(0), s.config, p, pose)
        assert state.particles.dtype == jnp.float32
        _, trace = mcl.run(_key(1), state, s.config, p, np.asarray(s.inputs[0]).tolist(), s.inputs[1])
        assert np.all(np.isfinite(np.asarray(trace.estimate)))
    g = setups()["grid"]
    assert grid.init(None, g.config, g.params, [5.0, 1.5, 0.0]).log_belief.shape == g.config.shape


def test_a_grid_too_large_to_index_or_to_hold_is_refused_before_allocation(monkeypatch):
    with pytest.raises(ValueError, match="more than the 2³¹ − 1 a grid can index"):
        grid.GridConfig((0.0, 10.0, 0.0, 10.0), 100_000, 100_000, 8)
    monkeypatch.setattr(memory, "limit_bytes", lambda device=None: (2**30, "a machine of 1 GiB"))
    with pytest.raises(ValueError, match=r"grid \(2e\+08 cells\) would need about 2.98 GiB .*more than the 1 GiB of"):
        grid.GridConfig((0.0, 10.0, 0.0, 10.0), 10_000, 10_000, 2)
    grid.GridConfig((0.0, 10.0, 0.0, 10.0), 1_000, 1_000, 36)  # 0.54 GiB: fits
    with memory.allow_large_allocations():  # the opt-out
        grid.GridConfig((0.0, 10.0, 0.0, 10.0), 10_000, 10_000, 2)


def test_init_uniform_refuses_infinite_bounds():
    s = setups()["mcl"]
    with pytest.raises(ValueError, match="bounds holds 1 value"):
        mcl.init_uniform(_key(0), s.config, s.params, (0.0, np.inf, 0.0, 10.0))
    with pytest.raises(ValueError, match="x_min < x_max"):
        mcl.init_uniform(_key(0), s.config, s.params, (1.0, 0.0, 0.0, 10.0))


def test_absurd_sensor_readings_are_refused():
    s = setups()["rfid_tag"]
    reads = s.inputs[0]
    with pytest.raises(ValueError, match=r"reads.rssi \(RSSI\) must be a positive received power in W of at most 1 W"):
        _call(s, inputs=(reads._replace(rssi=reads.rssi.at[0, 0].set(1e30)),))()
    s = setups()["ir_mcl"]
    det = s.inputs[1]
    with pytest.raises(ValueError, match="detections.voltage holds 1 value.* exceed 100"):
        _call(s, inputs=(s.inputs[0], det._replace(voltage=det.voltage.at[0, 0].set(1e3))))()


def test_a_state_is_read_again_unless_it_is_the_one_just_returned():
    """An online loop pays no host read for its state; a state changed outside the filter is checked."""
    s = setups()["pf_slam"]
    u, det = s.inputs
    step = pf_slam.step
    one = jax.tree_util.tree_map(lambda x: x[0], det)
    state, _ = step(_key(0), jax.tree_util.tree_map(jnp.copy, s.state), s.config, s.params, u[0], one)
    state, _ = step(_key(1), state, s.config, s.params, u[1], one)  # the returned state: accepted
    poisoned = state._replace(poses=state.poses.at[0, 0].set(jnp.nan))
    with pytest.raises(ValueError, match=r"state.poses holds 1 NaN or infinite value\(s\)"):
        step(_key(2), poisoned, s.config, s.params, u[2], one)


# --------------------------------------------------------------------------- the simulators


def _simulator_calls() -> dict[str, tuple[Callable[..., Any], dict[str, Any]]]:
    """``name -> (simulate, keyword arguments)`` of every simulator, with small valid arguments."""
    from jaxnav.sim import uhf_reader

    p, controls, _ = _landmark_world()
    path = np.stack([np.linspace(0, 1.5, T), np.full(T, -0.3), np.full(T, 0.5), np.full(T, np.pi / 2)], 1)
    layout = ir_world.experiment_layout()
    sensor = hf_rfid.reader_params(0.06)
    carpet = tag_carpet.make_carpet(_key(3), (1.0, 1.0), density=16.0)
    return {
        "landmark_world": (
            world.simulate,
            dict(
                key=_key(0),
                landmarks=np.asarray(p.landmarks),
                initial_pose=np.asarray(START),
                controls=np.asarray(controls),
                motion_noise=p.motion,
                sensor_noise=p.sensor,
            ),
        ),
        "uhf_reader": (
            uhf_reader.simulate_reads,
            dict(key=_key(0), path=path.astype(np.float32), tags=np.asarray([[1.0, 1.0, 0.8]], np.float32)),
        ),
        "ir_world": (
            ir_world.simulate,
            dict(
                key=_key(0),
                layout=layout,
                poses=np.asarray(ir_world.polyline_path(ir_world.EXPERIMENT_WAYPOINTS, speed=0.2, dt=0.1, num_steps=T)),
                dt=0.1,
            ),
        ),
        "tag_carpet": (
            tag_carpet.simulate,
            dict(
                key=_key(0),
                carpet=carpet,
                readers=sensor,
                start_pose=np.asarray([0.2, 0.5, 0.0]),
                controls=np.tile([[0.2, 0.0, 0.0, 0.5]], (T, 1)),
                odometry_sd=np.full(3, 0.01),
            ),
        ),
    }


@pytest.mark.parametrize("name", ["landmark_world", "uhf_reader", "ir_world", "tag_carpet"])
def test_the_simulators_refuse_bad_input_by_name_or_accept_lists(name):
    """Every array argument with NaN, ±inf or 1e30 in it, or a dimension too many; a bad key; and
    the arrays as lists (accepted, the same result)."""
    simulate, kwargs = _simulator_calls()[name]
    failures, count = [], 0

    def case(cid, changed, tokens):
        nonlocal count
        count += 1
        try:
            check_outcome(lambda: simulate(**{**kwargs, **changed}), tokens)
        except AssertionError as err:
            failures.append(f"{cid}: {err}")

    for arg, value in kwargs.items():
        if isinstance(value, np.ndarray):
            for kind, bad in BAD_VALUES.items():
                v = value.astype(float).copy()
                v.reshape(-1)[0] = bad
                case(f"{arg}={kind}", {arg: v}, (arg,))
            case(f"{arg}-wrong-shape", {arg: value[..., None]}, (arg,))
    for cid, key in (("key-int", 0), ("key-float", np.zeros(2)), ("key-batch", jax.random.split(_key(0), 2))):
        case(cid, {"key": key}, ("key",))
    assert not failures, f"{len(failures)} of {count} cases:\n" + "\n".join(failures)
    arrays = simulate(**kwargs)
    lists = simulate(**{k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in kwargs.items()})
    for a, b in zip(jax.tree_util.tree_leaves(arrays), jax.tree_util.tree_leaves(lists)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
