"""FastSLAM-RFID's Gaussian detection read three ways (``HFSetting.fastslam_gaussian``, [W] §3.2 gives no σ)."""

from __future__ import annotations

import math
from dataclasses import replace

import jax
import numpy as np
import pytest

from jaxnav.experiments.hf_slam import simulation as xp
from jaxnav.experiments.hf_slam import tables
from jaxnav.models import hf_rfid

_TINY = xp.HFSetting(
    density=4.0, reader_side=0.3, trajectory="random", carpet=(1.5, 1.5), random_steps=60, robot_particles=50
)


@pytest.mark.parametrize(
    "reading, sd",
    [("footprint", 0.3 / math.sqrt(12.0)), ("half_side", 0.15), ("small_reader", 0.06 / math.sqrt(12.0))],
)
def test_each_reading_gives_fastslam_its_sigma(reading, sd):
    """The covariance FastSLAM's EKFs take is σ² per axis, σ as the reading says; nothing else changes."""
    setting = replace(_TINY, fastslam_gaussian=reading)
    sensor = xp.fastslam_sensor(setting)
    np.testing.assert_allclose(np.asarray(hf_rfid.footprint_cov(sensor)), sd * sd * np.eye(2), rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(sensor.offsets), np.asarray(setting.sensor().offsets))
    np.testing.assert_array_equal(np.asarray(sensor.log_beta), np.asarray(setting.sensor().log_beta))


def test_the_default_reading_is_the_setting_s_own_sensor():
    assert xp.HFSetting().fastslam_gaussian == "footprint"
    for a, b in zip(xp.fastslam_sensor(_TINY), _TINY.sensor(), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_reading_changes_fastslam_only():
    """Same world and key: an overconfident Gaussian moves FastSLAM's estimates; PF-SLAM does not read it."""
    key = jax.random.PRNGKey(4)
    small = replace(_TINY, fastslam_gaussian="small_reader")
    fast_default, _, _ = xp.run_once(key, "fastslam", _TINY)
    fast_small, _, _ = xp.run_once(key, "fastslam", small)
    assert not np.array_equal(np.asarray(fast_default.dr_mm), np.asarray(fast_small.dr_mm))
    pf_default, _, _ = xp.run_once(key, "pf_slam", replace(_TINY, tag_particles=20))
    pf_small, _, _ = xp.run_once(key, "pf_slam", replace(small, tag_particles=20))
    for a, b in zip(pf_default, pf_small, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_an_unknown_reading_is_refused_by_name():
    with pytest.raises(ValueError, match="fastslam_gaussian"):
        xp.HFSetting(fastslam_gaussian="narrow")


def test_tables_name_fastslam_s_reading():
    assert "fastslam_gaussian" not in tables.setting_label(_TINY, "pf_slam")
    assert tables.setting_label(_TINY, "fastslam")["fastslam_gaussian"] == "footprint"
    # the committed tables were written before FastSLAM's rows named their Gaussian: read as they are
    assert tables._setting_text(tables.setting_label(_TINY), short=False) == "4 tags/m², 300 mm, random"
    label = tables.setting_label(replace(_TINY, fastslam_gaussian="half_side", fastslam_version=2), "fastslam")
    assert label["fastslam_gaussian"] == "half_side" and label["fastslam_version"] == 2
    assert tables._setting_text(label, short=False).endswith("σ = s/2, FastSLAM 2.0")
