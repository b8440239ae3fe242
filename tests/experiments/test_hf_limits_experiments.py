"""The two HF experiments that explain a difference from [W]: ``fig-3.7-limits`` (what holds PF-SLAM's
error flat in robot particles) and ``fastslam-rfid-readings`` (FastSLAM-RFID's Gaussian). Their full
runs are committed; here their cells, their summaries and the surveyed map they use."""

from __future__ import annotations

from dataclasses import replace

import jax
import numpy as np
import pytest

from jaxnav.experiments import catalog
from jaxnav.experiments.hf_slam import figures, tables
from jaxnav.experiments.hf_slam import simulation as xp
from jaxnav.sim import tag_carpet as tc
from jaxnav.slam import pf_slam


def test_the_limits_cells_lift_one_limit_each():
    cells = catalog.experiments()["fig-3.7-limits"].cells(False)
    assert len(cells) == len(figures.LIMITS) * len(figures.LIMIT_PARTICLES)
    assert {c.method for c in cells} == {"pf_slam"}
    by_curve = {label: [c.setting for c in cells if c.row == label] for label, _ in figures.LIMITS}
    base, more, known = by_curve.values()
    assert [s.robot_particles for s in base] == list(figures.LIMIT_PARTICLES)
    assert all(s.tag_particles == 100 and not s.map_known for s in base)
    assert all(s.tag_particles == 1000 and not s.map_known for s in more)
    assert all(s.tag_particles == 100 and s.map_known for s in known)
    # otherwise Fig. 3.7's setting
    assert {replace(s, robot_particles=500, tag_particles=100, map_known=False) for s in base + more + known} == {
        xp.HFSetting(density=16.0, reader_side=0.06, trajectory="rectangle")
    }


def test_the_limits_summary_has_no_tag_error_for_the_surveyed_map():
    exp = catalog.experiments()["fig-3.7-limits"]
    cells = exp.cells(True)
    rng = np.random.default_rng(0)
    raw = {c.id: {col: rng.uniform(10, 50, 4) for col in xp.ERROR_COLUMNS} for c in cells}
    curves = exp.summarize(raw, cells, True)["curves"]
    quantities = {(c["method"], c["quantity"]) for c in curves}
    assert ("PF-SLAM, map known", "tag error dt (mm)") not in quantities
    assert ("PF-SLAM, J = 1000", "tag error dt (mm)") in quantities
    first = next(c for c in curves if c["method"] == "PF-SLAM, J = 100" and c["quantity"].startswith("robot"))
    np.testing.assert_allclose(
        first["mean"][0], np.mean(raw[f"PF-SLAM, J = 100|{cells[0].setting.robot_particles}"]["dr_mm"])
    )


def test_the_fastslam_readings_cells_are_table_4_1_and_4_2_under_each_gaussian():
    cells = catalog.experiments()["fastslam-rfid-readings"].cells(False)
    assert {c.method for c in cells} == {"fastslam"}
    assert len(cells) == 4 * (len(tables.FIVE_RECTANGLES) + 1)
    readings = {(c.setting.fastslam_gaussian, c.setting.fastslam_version) for c in cells}
    assert readings == {("footprint", 1), ("half_side", 1), ("small_reader", 1), ("footprint", 2)}
    assert {c.setting.reader_side for c in cells} == {0.3}


def _tiny(**change):
    return xp.HFSetting(
        density=16.0,
        carpet=(1.5, 1.5),
        rectangle=(0.4, 0.4, 0.6, 0.6),
        laps=1,
        robot_particles=64,
        tag_particles=8,
        **change,
    )


def test_a_surveyed_map_stays_where_it_was_surveyed():
    """PF-SLAM never jitters its tag particles: started on the true positions, every tag ends there (its
    estimate ``Σ w_j m_j`` of equal points within float32 rounding: the weights sum to 1 to an ulp)."""
    setting = _tiny(map_known=True)
    world = xp.make_world(jax.random.PRNGKey(2), setting)
    result, trace = xp.filter_world(jax.random.PRNGKey(3), "pf_slam", setting, world)
    truth = np.asarray(tc.tag_positions(world.carpet))
    assert np.asarray(result.seen).all()
    np.testing.assert_allclose(np.asarray(result.tags), truth, rtol=0, atol=1e-6)
    assert int(np.asarray(trace.num_new).sum()) == 0  # nothing to initialise: every tag is known
    assert int(np.asarray(trace.num_updated).sum()) > 0


def test_surveyed_tags_refuses_what_does_not_fit_by_name():
    config = pf_slam.PFSLAMConfig(16, 4, max_tags=3)
    with pytest.raises(ValueError, match="positions must be"):
        pf_slam.surveyed_tags(config, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="positions"):
        pf_slam.surveyed_tags(config, np.full((2, 2), np.nan))
    with pytest.raises(ValueError, match="map_known is read by PF-SLAM only"):
        setting = _tiny(map_known=True)
        xp.filter_world(jax.random.PRNGKey(3), "ps_slam", setting, xp.make_world(jax.random.PRNGKey(2), setting))
    with pytest.raises(ValueError, match="map_known"):
        _tiny(map_known=1)
