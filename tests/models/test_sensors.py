"""The library's sensors are instances of the one protocol, :class:`jaxnav.models.sensor.ParticleSensor`.

Each built-in sensor is checked on the inputs of the filter that weighs with it (the settings of
``tests/test_bad_input.py``): it is hashable (a static argument of ``jit``), its likelihood is ``[N]``,
finite and differentiable in a parameter, it counts a corrupted slot as ignored, its host check
refuses a bad parameter by name, and it is the function its filter weighs with.
"""

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.localization import mcl, rfid_anchor, rfid_tag
from jaxnav.models import landmarks as lm
from jaxnav.models.ir_sensor import IR_RECEIVERS
from jaxnav.models.sensor import ParticleSensor
from jaxnav.models.uhf_sensor import anchor_reads_sensor, tag_reads_sensor
from tests.test_bad_input import setups


class Case(NamedTuple):
    sensor: ParticleSensor
    filter_name: str
    particles: Any  # the filter's particles, from its initial state
    observation: Any  # the first step's observation
    grad_field: str  # a scalar parameter to differentiate by
    corrupt: Any  # observation -> the same with one valid slot made unusable
    bad_params: Any  # params -> params the host check refuses
    bad_name: str


def _first(tree):
    return jax.tree_util.tree_map(lambda x: x[0], tree)


def _cases() -> dict[str, Case]:
    s = setups()
    out = {}
    m = s["mcl"]
    out["range_bearing"] = Case(
        lm.RANGE_BEARING_SENSOR,
        "mcl",
        m.state.particles,
        _first(m.inputs[1]),
        "sensor",
        lambda o: o._replace(z=o.z.at[0, 0].set(jnp.nan)),
        lambda p: p._replace(sensor=lm.RangeBearingNoise(jnp.asarray([-0.1, 0.05]))),
        "params.sensor.sd",
    )
    ir_setup = s["ir_mcl"]
    det = jax.tree_util.tree_map(lambda x: x[-1], ir_setup.inputs[1])  # the drive's last window sees emitters
    out["ir_receivers"] = Case(
        IR_RECEIVERS,
        "ir_mcl",
        ir_setup.state.particles,
        det,
        "sigma_v",
        lambda d: d._replace(voltage=d.voltage.at[jnp.argmax(d.valid)].set(jnp.nan)),
        lambda p: p._replace(sigma_v=jnp.asarray(-0.2)),
        "params.sigma_v",
    )
    t = s["rfid_tag"]
    out["uhf_tag_reads"] = Case(
        t.config.sensor,
        "rfid_tag",
        t.state.particles,
        _first(t.inputs[0]),
        "phase_sigma",
        lambda r: r._replace(rssi=r.rssi.at[0].set(jnp.nan)),
        lambda p: p._replace(phase_sigma=jnp.asarray(-1.0)),
        "phase_sigma",
    )
    a = s["rfid_anchor"]
    out["uhf_anchor_reads"] = Case(
        a.config.sensor,
        "rfid_anchor",
        a.state.particles,
        _first(a.inputs[1]),
        "phase_sigma",
        lambda r: r._replace(phase=r.phase.at[0].set(jnp.inf)),
        lambda p: p._replace(phase_sigma=jnp.asarray(-1.0)),
        "phase_sigma",
    )
    return out


CASES = ("range_bearing", "ir_receivers", "uhf_tag_reads", "uhf_anchor_reads")


@pytest.fixture(scope="module")
def cases():
    return _cases()


@pytest.mark.parametrize("name", CASES)
def test_a_built_in_sensor_is_a_hashable_particle_sensor(cases, name):
    sensor = cases[name].sensor
    assert isinstance(sensor, ParticleSensor) and hash(sensor) == hash(sensor)
    assert repr(sensor).startswith("ParticleSensor(")


@pytest.mark.parametrize("name", CASES)
def test_its_likelihood_is_finite_per_particle_and_differentiable_in_a_parameter(cases, name):
    c = cases[name]
    params = setups()[c.filter_name].params
    ll = jax.jit(c.sensor.log_likelihood)(c.particles, c.observation, params)
    assert ll.shape == c.particles.shape[:1] and np.all(np.isfinite(np.asarray(ll)))
    assert np.ptp(np.asarray(ll)) > 0  # the observation tells the particles apart

    def total(value):
        field = getattr(params, c.grad_field)
        new = jax.tree_util.tree_map(lambda leaf: leaf * value, field)
        return jnp.sum(c.sensor.log_likelihood(c.particles, c.observation, params._replace(**{c.grad_field: new})))

    g = jax.grad(total)(jnp.asarray(1.0))
    assert np.isfinite(float(g)) and float(g) != 0.0


@pytest.mark.parametrize("name", CASES)
def test_it_drops_and_counts_an_unusable_slot(cases, name):
    c = cases[name]
    params = setups()[c.filter_name].params
    assert int(c.sensor.num_ignored(c.observation, params)) == 0
    bad = c.corrupt(c.observation)
    assert int(c.sensor.num_ignored(bad, params)) == 1
    assert np.all(np.isfinite(np.asarray(c.sensor.log_likelihood(c.particles, bad, params))))


@pytest.mark.parametrize("name", CASES)
def test_its_host_check_refuses_a_bad_parameter_by_name(cases, name):
    c = cases[name]
    params = setups()[c.filter_name].params
    c.sensor.check_params(params)
    with pytest.raises(ValueError, match=c.bad_name):
        c.sensor.check_params(c.bad_params(params))
    assert bool(c.sensor.params_in_domain(params)) and not bool(c.sensor.params_in_domain(c.bad_params(params)))


def test_the_uhf_filters_weigh_with_their_sensors():
    """The static-tag filter's log-likelihoods are its sensor's, bitwise; equal configurations share one
    cached sensor object (one compiled program)."""
    s = setups()["rfid_tag"]
    reads = _first(s.inputs[0])
    ours = rfid_tag.log_likelihoods(s.config, s.params, s.state.particles, reads)
    np.testing.assert_array_equal(
        np.asarray(ours), np.asarray(s.config.sensor.log_likelihood(s.state.particles, reads, s.params))
    )
    assert rfid_tag.RFIDTagConfig(weighting="phase").sensor is tag_reads_sensor("phase", None)
    assert rfid_anchor.RFIDAnchorConfig(weighting="rssi").sensor is anchor_reads_sensor("rssi", None)
    with pytest.raises(ValueError, match="weighting"):
        tag_reads_sensor("both")


def test_mcl_weighs_with_its_configured_sensor():
    """MCL's step is the sensor's likelihood: a sensor that ignores every observation leaves the weights
    uniform, the default one does not."""
    s = setups()["mcl"]
    flat = ParticleSensor("flat", lambda particles, obs, params: jnp.zeros(particles.shape[:1]))
    for sensor, uniform in ((flat, True), (lm.RANGE_BEARING_SENSOR, False)):
        config = mcl.MCLConfig(num_particles=s.config.num_particles, ess_threshold=0.01, sensor=sensor)
        _, info = mcl.step(jax.random.PRNGKey(0), s.state, config, s.params, s.inputs[0][0], _first(s.inputs[1]))
        assert (float(info.ess) == pytest.approx(config.num_particles, rel=1e-5)) is uniform


def test_the_generic_known_map_sensor_agrees_with_the_range_bearing_one():
    """known_map_sensor(RANGE_BEARING) evaluates h and factorises R; the built-in sensor uses one atan2 per
    pair: the same density, to float32 rounding, and the same dropped slots."""
    from jaxnav.models.observation import RANGE_BEARING, known_map_sensor

    s = setups()["mcl"]
    generic = known_map_sensor(RANGE_BEARING)
    assert known_map_sensor(RANGE_BEARING) is generic  # cached: one compiled program per model
    for t in range(s.inputs[0].shape[0]):
        obs = jax.tree_util.tree_map(lambda x: x[t], s.inputs[1])
        obs = obs._replace(ids=obs.ids.at[0].set(99))  # a slot outside the map: dropped by both
        ours = generic.log_likelihood(s.state.particles, obs, s.params)
        ref = lm.RANGE_BEARING_SENSOR.log_likelihood(s.state.particles, obs, s.params)
        np.testing.assert_allclose(np.asarray(ours), np.asarray(ref), rtol=1e-5, atol=1e-3)
        assert int(generic.num_ignored(obs, s.params)) == int(lm.RANGE_BEARING_SENSOR.num_ignored(obs, s.params)) == 1


def test_mcl_localizes_on_a_tag_carpet_with_the_hf_footprint_sensor():
    """HF detections of surveyed tags weigh poses through the HF footprint model ([W] §3.2): MCL with
    HF_FOOTPRINT_MAP_SENSOR keeps the robot within a few cm over a lap of a 100 tags/m² carpet, where
    the odometry alone drifts by several times as much (second half-lap, four seeds: 12–16 mm against
    the odometry's 50–121 mm)."""
    from jaxnav.models import hf_rfid
    from jaxnav.models.motion import OmniNoise
    from jaxnav.models.observation import HF_FOOTPRINT_MAP_SENSOR
    from jaxnav.sim import tag_carpet, trajectories

    readers = hf_rfid.reader_params(0.06)
    carpet = tag_carpet.make_carpet(jax.random.PRNGKey(3), (2.0, 2.0), density=100.0)
    start, controls = trajectories.rectangle_controls(1.6, 1.6, speed=0.2, dt=0.1, laps=1, start=(0.2, 0.2))
    noise = OmniNoise(jnp.asarray([0.05, 0.05, 0.05]))
    sim = tag_carpet.simulate(jax.random.PRNGKey(4), carpet, readers, start, controls, noise)
    obs = hf_rfid.landmark_observations(sim.detections, readers)

    class CarpetParams(NamedTuple):
        motion: Any
        sensor: Any
        landmarks: jax.Array

    params = CarpetParams(noise, readers, tag_carpet.tag_positions(carpet))
    config = mcl.MCLConfig(num_particles=500, motion_model="omni", sensor=HF_FOOTPRINT_MAP_SENSOR)
    state = mcl.init(jax.random.PRNGKey(5), config, params, start, jnp.asarray([0.01, 0.01, 0.01]))
    _, trace = mcl.run(jax.random.PRNGKey(6), state, config, params, sim.odometry, obs)
    err = np.linalg.norm(np.asarray(trace.estimate)[:, :2] - np.asarray(sim.true_poses)[:, :2], axis=1)
    odometry = np.cumsum(np.asarray(sim.odometry)[:, :2] * np.asarray(sim.odometry)[:, 3:4], axis=0) + np.asarray(
        start[:2]
    )
    odo = np.linalg.norm(odometry - np.asarray(sim.true_poses)[:, :2], axis=1)
    late = slice(len(err) // 2, None)
    assert err[late].mean() < 0.03 and err[late].mean() < 0.5 * odo[late].mean(), (err[late].mean(), odo[late].mean())
    assert int(np.sum(trace.num_ignored)) == 0 and not np.any(trace.degenerate)
