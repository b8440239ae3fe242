"""Every filter's ``init`` (and ``init_uniform``) and ``run`` under ``jax_enable_x64``.

The suite runs in float32 (conftest), so a filter that pins a fresh array to
float32 (a log-weight, a control cast, a uniform draw) goes unnoticed there.
Under x64 that array meets float64 particles and the scan's carry changes type
between steps ("carry input and carry output must have equal types"), or the
estimate silently drops to float32. Each case builds small float64 inputs with
the library's own simulators and checks that ``run`` completes from every
initial state the module can make, that the states' float leaves and the
trace's estimates are float64, and that the estimates are finite.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.demo import demo_setting
from jaxnav.localization import (
    augmented_mcl,
    ekf,
    grid,
    ir_mcl,
    kld_mcl,
    mcl,
    rfid_anchor,
    rfid_tag,
    ukf,
)
from jaxnav.models import hf_rfid
from jaxnav.models.motion import OmniNoise
from jaxnav.sim import ir_world, tag_carpet, trajectories, uhf_reader
from jaxnav.sim import landmark_world as world
from jaxnav.slam import ekf_slam, fastslam, pf_slam, ps_slam

STEPS = 6
START = (5.0, 1.5, 0.0)
ROOM = (0.0, 10.0, 0.0, 10.0)


class Case(NamedTuple):
    """Initial states of one filter and the ``run`` that filters from any of them."""

    states: tuple[Any, ...]
    run: Callable[[Any], tuple[Any, Any]]


def _f64(tree):
    """``tree`` with every floating leaf cast to float64 (others untouched)."""

    def cast(x):
        x = jnp.asarray(x)
        return x.astype(jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x

    return jax.tree_util.tree_map(cast, tree)


def _float_leaves(tree):
    return [x for x in jax.tree_util.tree_leaves(tree) if jnp.issubdtype(jnp.result_type(x), jnp.floating)]


# --------------------------------------------------------------------------- landmark worlds


def _landmark_world(key):
    """The demo room's models and a short simulated drive, all float64."""
    _, p = demo_setting(10)  # built under x64: float64 already
    controls = _f64(trajectories.loop_controls(STEPS, 0.5, 0.21, 0.25))  # float32 by design
    return p, world.simulate(key, p.landmarks, jnp.asarray(START), controls, p.motion, p.sensor)


def _kalman_case(module, config, key):
    p, sim = _landmark_world(key)
    params = ekf.KalmanParams(p.motion, p.sensor, p.landmarks)
    state = module.init(None, config, params, jnp.asarray(START), jnp.diag(jnp.asarray([0.01, 0.01, 0.001])))
    return Case((state,), lambda s: module.run(None, s, config, params, sim.controls, sim.observations))


def _ekf(key):
    return _kalman_case(ekf, ekf.EKFConfig(), key)


def _ukf(key):
    return _kalman_case(ukf, ukf.UKFConfig(), key)


def _grid(key):
    p, sim = _landmark_world(key)
    config = grid.GridConfig(ROOM, 10, 10, 8, "velocity")
    params = grid.GridParams(p.motion, p.sensor, p.landmarks)
    states = (
        grid.init(None, config, params),
        grid.init(None, config, params, jnp.asarray(START), jnp.asarray([0.3, 0.3, 0.1])),
    )
    return Case(states, lambda s: grid.run(None, s, config, params, sim.controls, sim.observations))


def _mcl_like(module, config, make_params, key):
    """``init`` around the start and ``init_uniform`` over the room, then ``run`` on the drive."""
    p, sim = _landmark_world(key)
    params = make_params(p)
    k_init, k_uniform, k_run = jax.random.split(key, 3)
    states = (
        module.init(k_init, config, params, jnp.asarray(START), jnp.asarray([0.3, 0.3, 0.1])),
        module.init_uniform(k_uniform, config, params, ROOM),
    )
    return Case(states, lambda s: module.run(k_run, s, config, params, sim.controls, sim.observations))


def _mcl(key):
    return _mcl_like(mcl, mcl.MCLConfig(num_particles=32), lambda p: p, key)


def _augmented_mcl(key):
    def make_params(p):
        return augmented_mcl.AugmentedMCLParams(p.motion, p.sensor, p.landmarks, jnp.asarray(ROOM))

    return _mcl_like(augmented_mcl, augmented_mcl.AugmentedMCLConfig(num_particles=32), make_params, key)


def _kld_mcl(key):
    config = kld_mcl.KLDMCLConfig(max_particles=64, min_particles=16)
    return _mcl_like(kld_mcl, config, lambda p: p, key)


def _ekf_slam(key):
    p, sim = _landmark_world(key)
    config = ekf_slam.EKFSLAMConfig(num_landmarks=p.landmarks.shape[0])
    params = ekf_slam.EKFSLAMParams(p.motion, p.sensor)
    state = ekf_slam.init(None, config, params, jnp.asarray(START), jnp.diag(jnp.asarray([1e-4, 1e-4, 1e-5])))
    return Case((state,), lambda s: ekf_slam.run(None, s, config, params, sim.controls, sim.observations))


def _fastslam(key):
    p, sim = _landmark_world(key)
    config = fastslam.FastSLAMConfig(num_particles=8, num_landmarks=p.landmarks.shape[0], version=2)
    params = fastslam.FastSLAMParams(p.motion, p.sensor)
    k_init, k_run = jax.random.split(key)
    state = fastslam.init(k_init, config, params, jnp.asarray(START))
    return Case((state,), lambda s: fastslam.run(k_run, s, config, params, sim.controls, sim.observations))


# --------------------------------------------------------------------------- HF-RFID tag carpet


def _carpet_drive(key):
    """A 1 × 1 m rectangle over a 100 tags/m² carpet: odometry and detections, float64."""
    k_carpet, k_sim = jax.random.split(key)
    carpet = tag_carpet.make_carpet(k_carpet, (1.2, 1.2), density=100, origin=(-0.1, -0.1))
    sensor = _f64(hf_rfid.reader_params(0.06, beta=0.1))
    start, controls = trajectories.rectangle_controls(1.0, 1.0, speed=0.2, dt=0.1, laps=1)
    return sensor, tag_carpet.simulate(k_sim, carpet, sensor, start, controls[:STEPS], jnp.asarray([0.01, 0.01, 0.01]))


def _tag_slam_case(module, config, make_params, key):
    """``init`` near the known start, then ``run`` on the carpet drive; ``make_params(sensor)``."""
    sensor, drive = _carpet_drive(key)
    params = make_params(sensor)
    k_init, k_run = jax.random.split(key)
    state = module.init(k_init, config, params, drive.start_pose, jnp.asarray([0.005, 0.005, 0.005]))
    return Case((state,), lambda s: module.run(k_run, s, config, params, drive.odometry, drive.detections))


def _odometry_noise():
    return OmniNoise(jnp.asarray([0.01, 0.01, 0.01]))


def _pf_slam(key):
    config = pf_slam.PFSLAMConfig(num_particles=16, num_tag_particles=8, max_tags=256)
    return _tag_slam_case(pf_slam, config, lambda sensor: pf_slam.PFSLAMParams(_odometry_noise(), sensor), key)


def _ps_slam(key):
    config = ps_slam.PSSLAMConfig(num_particles=16, num_tag_particles=8, max_tags=256, lag=4)

    def make_params(sensor):
        return ps_slam.PSSLAMParams(_odometry_noise(), sensor, ps_slam.default_jitter(sensor))

    return _tag_slam_case(ps_slam, config, make_params, key)


# --------------------------------------------------------------------------- UHF-RFID


def _rfid_tag(key):
    k_reads, k_init, k_run = jax.random.split(key, 3)
    path = uhf_reader.line_path((-0.5, -0.3), (2.5, -0.3), STEPS, height=1.0, facing=(1.2, 1.4))
    reads = uhf_reader.simulate_reads(k_reads, path, np.asarray([[1.2, 1.4, 0.9]]), reads_per_step=2)
    reads = _f64(jax.tree_util.tree_map(lambda x: x[0], reads))
    config = rfid_tag.RFIDTagConfig(num_particles=64)
    params = _f64(rfid_tag.default_params())
    state = rfid_tag.init(k_init, config, params)
    return Case((state,), lambda s: rfid_tag.run(k_run, s, config, params, reads))


def _rfid_anchor(key):
    anchors = np.asarray([[1.0, 3.2, 1.0], [0.3, 3.2, 0.6], [1.7, 3.2, 1.4]])
    k_reads, k_init, k_run = jax.random.split(key, 3)
    path = uhf_reader.line_path((0.4, 0.5), (1.6, 0.9), STEPS + 1, heading=np.pi / 2, height=0.8)
    reads = uhf_reader.simulate_reads(k_reads, path[1:], anchors)  # [G, T, 1]
    slots = [getattr(reads, f)[..., 0].T for f in ("rssi", "phase", "wavelength", "mask")]
    reads = _f64(rfid_anchor.AnchorReads(*slots))
    controls = _f64(np.diff(path, axis=0))
    config = rfid_anchor.RFIDAnchorConfig(num_particles=64)
    params = _f64(rfid_anchor.default_params(anchors, box_lo=(0, 0, 0.5), box_hi=(2, 3, 1.1)))
    state = rfid_anchor.init(k_init, config, params)
    return Case((state,), lambda s: rfid_anchor.run(k_run, s, config, params, controls, reads))


# --------------------------------------------------------------------------- IR emitters


def _ir_mcl(key):
    layout = _f64(ir_world.experiment_layout())
    poses = ir_world.polyline_path(ir_world.EXPERIMENT_WAYPOINTS, speed=0.2, dt=0.1, num_steps=STEPS)
    k_sim, k_init, k_run = jax.random.split(key, 3)
    sim = _f64(ir_world.simulate(k_sim, layout, poses, 0.1))
    config = ir_mcl.IRMCLConfig(num_particles=32)
    params = _f64(ir_mcl.default_params(config, layout))
    state = ir_mcl.init(k_init, config, params, ir_world.layout_area(layout))
    return Case((state,), lambda s: ir_mcl.run(k_run, s, config, params, sim.controls, sim.detections))


CASES = {
    "ekf": _ekf,
    "ukf": _ukf,
    "grid": _grid,
    "mcl": _mcl,
    "augmented_mcl": _augmented_mcl,
    "kld_mcl": _kld_mcl,
    "rfid_tag": _rfid_tag,
    "rfid_anchor": _rfid_anchor,
    "ir_mcl": _ir_mcl,
    "ekf_slam": _ekf_slam,
    "fastslam": _fastslam,
    "pf_slam": _pf_slam,
    "ps_slam": _ps_slam,
}


def _field_names(trace) -> tuple[str, ...]:
    """A trace's fields: a dataclass (the particle filters' infos) or a NamedTuple (the Gaussian filters')."""
    if dataclasses.is_dataclass(trace):
        return tuple(f.name for f in dataclasses.fields(trace))
    return trace._fields


def _estimates(trace) -> dict[str, jax.Array]:
    """The trace's estimate fields (``estimate``, ``map_estimate``, ``slot_estimates``, ...)."""
    return {name: getattr(trace, name) for name in _field_names(trace) if "estimate" in name}


def _assert_float64(name: str, tree) -> None:
    dtypes = {str(jnp.result_type(x)) for x in _float_leaves(tree)}
    assert dtypes == {"float64"}, (name, dtypes)


@pytest.mark.parametrize("filt", sorted(CASES))
def test_init_and_run_stay_float64(filt, getkey):
    """``run`` completes from every initial state; states and estimates are float64 and finite."""
    with jax.enable_x64(True):
        case = CASES[filt](getkey())
        for i, state in enumerate(case.states):
            _assert_float64(f"initial state {i}", state)
            final, trace = case.run(state)
            _assert_float64(f"final state from initial state {i}", final)
            estimates = _estimates(trace)
            assert estimates, _field_names(trace)
            for field, est in estimates.items():
                assert jnp.result_type(est) == jnp.float64, (i, field, jnp.result_type(est))
                assert np.all(np.isfinite(np.asarray(est))), (i, field)
