"""``UHFSetting.prior_margin`` and the ``uhf-prior`` experiment: a wider prior for [A] Alg. 6 in the same scenes."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxnav.experiments import catalog
from jaxnav.experiments.uhf import localization as ul
from jaxnav.sim import uhf_reader as S


def test_a_wider_prior_grows_the_filter_s_box_and_not_the_room():
    lo, hi = (np.asarray(b) for b in S.SEARCH_BOX_A)
    same = ul.run_inputs(ul.UHFSetting())
    wide = ul.run_inputs(ul.UHFSetting(prior_margin=0.5))
    np.testing.assert_array_equal(np.asarray(same.filter.box_lo), lo)  # [A]'s prior by default
    np.testing.assert_array_equal(np.asarray(same.filter.box_hi), hi)
    np.testing.assert_allclose(np.asarray(wide.filter.box_lo), lo - np.array([0.5, 0.5, 0.0]))  # floor kept
    np.testing.assert_allclose(np.asarray(wide.filter.box_hi), hi + 0.5)
    for inputs in (same, wide):
        np.testing.assert_array_equal(np.asarray(inputs.room_lo), lo)
        np.testing.assert_array_equal(np.asarray(inputs.room_hi), hi)


def test_the_scene_does_not_depend_on_the_prior():
    key = jax.random.PRNGKey(11)
    a = ul.draw_scene(key, ul.run_inputs(ul.UHFSetting()))
    b = ul.draw_scene(key, ul.run_inputs(ul.UHFSetting(prior_margin=1.0)))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_a_negative_prior_margin_is_refused_by_name():
    with pytest.raises(ValueError, match="prior_margin"):
        ul.UHFSetting(prior_margin=-0.1)


def test_the_cells_with_a_s_prior_are_fig_5_5_s_and_uhf_refresh_s():
    """Same cell ids, so the same seeded runs: the run fig-5.5's combined weighting loses is among them."""
    experiments = catalog.experiments()
    prior = {c.id for c in experiments["uhf-prior"].cells(False)}
    assert len(prior) == 6
    shared = {c.id for c in experiments["uhf-refresh"].cells(False) if c.setting.multipath == "light"}
    assert shared < prior
    assert {c.id for c in experiments["fig-5.5"].cells(False) if c.setting.multipath == "light"} < prior
    assert sum("prior=+" in c for c in prior) == 4
