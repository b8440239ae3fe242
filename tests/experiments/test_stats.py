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
    assert math.isnan(stats.finite_median([math.nan, math.nan]))


def test_finite_mean_and_median_leave_out_and_count_the_unscored_runs():
    assert stats.finite_mean([1.0, 2.0, 6.0]) == (3.0, 0)
    assert stats.finite_mean([1.0, math.nan, 5.0]) == (3.0, 1)
    assert stats.finite_median([1.0, math.nan, 5.0, 100.0]) == 5.0
    assert stats.finite_median([4.0, 1.0]) == 2.5


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
