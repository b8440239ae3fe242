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
