"""Summary statistics of per-run results (jaxnav.experiments.stats): Student-t intervals and runs without a value."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats as scipy_stats

from jaxnav.experiments import stats


@pytest.mark.parametrize("dof", [1, 2, 5, 19, 99])
def test_student_t_quantile_matches_scipy(dof):
    assert stats.student_t_quantile(0.975, dof) == pytest.approx(scipy_stats.t.ppf(0.975, dof), rel=1e-7)


def test_mean_ci_is_the_student_t_interval():
    v = np.array([1.0, 2.0, 4.0, 7.0])
    m, lo, hi = stats.mean_ci(v)
    half = scipy_stats.t.ppf(0.975, 3) * v.std(ddof=1) / 2.0
    assert m == pytest.approx(3.5) and lo == pytest.approx(3.5 - half) and hi == pytest.approx(3.5 + half)
    assert stats.mean_ci([5.0]) == (5.0, 5.0, 5.0)


def test_a_run_with_nothing_to_score_is_counted_not_dropped_or_zero():
    """Runs 10, 20, NaN, 30: the mean is that of the three scored runs (20, not the 15 a 0 would give),
    its interval that of three runs, and the NaN run is counted."""
    v = [10.0, 20.0, math.nan, 30.0]
    s = stats.summarize(v)
    assert s.mean == pytest.approx(20.0) and s.runs == 4 and s.unscored == 1 and s.scored == 3
    half = scipy_stats.t.ppf(0.975, 2) * 10.0 / math.sqrt(3)
    assert (s.lo, s.hi) == pytest.approx((20.0 - half, 20.0 + half))
    assert stats.count_nonfinite(v) == 1
    column = stats.column_summary(v)
    assert column["unscored_runs"] == 1 and column["mean"] == pytest.approx(20.0)
    # every run scored: no count in the JSON
    assert set(stats.column_summary([1.0, 2.0])) == {"mean", "ci95"}


def test_no_run_with_a_value_gives_nan_never_zero():
    s = stats.summarize([math.nan, math.nan])
    assert math.isnan(s.mean) and math.isnan(s.lo) and math.isnan(s.hi) and s.unscored == 2
    column = stats.column_summary([math.nan] * 3)
    assert math.isnan(column["mean"]) and column["unscored_runs"] == 3
    assert "NaN" in json.dumps(column)  # the JSON holds NaN, not 0
    mean, missing = stats.finite_mean([math.nan])
    assert math.isnan(mean) and missing == 1
    median, missing = stats.finite_median([math.nan, math.nan])
    assert math.isnan(median) and missing == 2


def test_finite_mean_and_median_leave_out_and_count_the_unscored_runs():
    assert stats.finite_mean([1.0, 2.0, 6.0]) == (3.0, 0)
    assert stats.finite_mean([1.0, math.nan, 5.0]) == (3.0, 1)
    assert stats.finite_median([1.0, math.nan, 5.0, 100.0]) == (5.0, 1)
    assert stats.finite_median([4.0, 1.0]) == (2.5, 0)
    mean, missing = stats.finite_mean([])
    assert math.isnan(mean) and missing == 0


def test_mean_ci_leaves_no_run_out():
    """mean_ci takes every run: a non-finite one makes the mean and interval NaN instead of vanishing;
    summarize is what leaves runs out, and it says how many."""
    for bad in (math.nan, math.inf, -math.inf):
        assert all(math.isnan(x) for x in stats.mean_ci([1.0, 2.0, bad]))
    assert all(math.isnan(x) for x in stats.mean_ci([]))
    s = stats.summarize([1.0, 2.0, math.inf])
    assert s.mean == pytest.approx(1.5) and s.unscored == 1 and s.runs == 3


def test_diverged_runs_are_left_out_of_every_quantity_and_counted():
    """Runs 1 and 3 of four diverged (a robot error of NaN / inf): they are found from the quantities
    every run has, left out of a quantity whatever its value there, and counted apart from the runs
    with nothing to score."""
    robot = np.array([10.0, np.nan, 30.0, np.inf])
    curve = np.ones((4, 3))
    curve[2, 1] = np.nan  # run 2 diverged in its error over time
    gone = stats.diverged_runs(robot)
    assert gone.tolist() == [False, True, False, True]
    assert stats.diverged_runs(robot, curve).tolist() == [False, True, True, True]
    tag = np.array([5.0, 7.0, np.nan, 9.0])  # run 2 mapped nothing; run 3's tag value is finite but it diverged
    s = stats.summarize(tag, diverged=gone)
    assert (s.runs, s.unscored, s.diverged, s.scored) == (4, 1, 2, 1) and s.mean == 5.0
    assert stats.column_summary(tag, gone) == {"mean": 5.0, "ci95": [5.0, 5.0], "unscored_runs": 1, "diverged_runs": 2}
    assert "diverged_runs" not in stats.column_summary(tag)
    none = stats.summarize(robot, diverged=np.ones(4, bool))
    assert math.isnan(none.mean) and none.diverged == 4 and none.unscored == 0
    with pytest.raises(ValueError, match="4 booleans"):
        stats.summarize(tag, diverged=[True, False])
    with pytest.raises(ValueError, match="leading axis of 4"):
        stats.diverged_runs(robot, np.ones(3))


def test_mean_ci_columns_of_no_run_is_nan():
    m, lo, hi = stats.mean_ci_columns(np.empty((0, 3)))
    assert m.shape == lo.shape == hi.shape == (3,) and np.all(np.isnan(m)) and np.all(np.isnan(hi))


def test_mean_ci_columns_is_mean_ci_per_column():
    rng = np.random.default_rng(0)
    v = rng.uniform(0.0, 1.0, (6, 4))
    m, lo, hi = stats.mean_ci_columns(v)
    for j in range(4):
        assert (m[j], lo[j], hi[j]) == pytest.approx(stats.mean_ci(v[:, j]), rel=1e-12)
    m1, lo1, hi1 = stats.mean_ci_columns(v[:1])
    np.testing.assert_array_equal(m1, v[0])
    np.testing.assert_array_equal(lo1, v[0])
    np.testing.assert_array_equal(hi1, v[0])
