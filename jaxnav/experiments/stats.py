"""Summary statistics of per-run results: means, 95 % intervals and runs with nothing to score.

Every experiment reports a quantity over ``R`` seeded runs as the mean of the
runs and its Student-t interval

    mean ± t_{(1+level)/2, n−1} · s / √n,

with ``s`` the sample standard deviation (``ddof = 1``) of the ``n`` runs
that have a value (:func:`mean_ci`; ``level = 0.95`` by default).

A run with nothing to score (a tag-map error when the run mapped no tag, a
curve point no run reached) holds NaN, never 0: a 0 would pass for a
perfect score and pull the mean down. NaN runs are left out of the mean and
the interval and *counted* (:func:`summarize`, :class:`Summary`), so that a
table can say how many runs had no value instead of dropping them
silently. When no run has a value, the mean and the interval are NaN.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import numpy as np

__all__ = [
    "Summary",
    "student_t_quantile",
    "mean_ci",
    "mean_ci_columns",
    "summarize",
    "column_summary",
    "finite_mean",
    "finite_median",
    "count_nonfinite",
]


def student_t_quantile(p: float, dof: int) -> float:
    """``t_{p, dof}``, the ``p`` quantile of Student's t (bisection on its CDF, ``1e-10`` accurate)."""
    if dof < 1:
        raise ValueError(f"dof must be ≥ 1, got {dof}")
    from jax.scipy.special import betainc

    def cdf(t: float) -> float:
        x = dof / (dof + t * t)
        with jax.enable_x64(True):
            tail = 0.5 * float(betainc(0.5 * dof, 0.5, np.float64(x)))
        return 1.0 - tail if t > 0 else tail

    lo, hi = -1e3, 1e3
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if cdf(mid) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-10:
            break
    return 0.5 * (lo + hi)


@functools.cache
def _t975(dof: int) -> float:
    return student_t_quantile(0.975, dof)


def count_nonfinite(values: Sequence[float] | np.ndarray) -> int:
    """The number of runs without a value (NaN or ±inf) in ``values``."""
    return int(np.sum(~np.isfinite(np.asarray(values, np.float64))))


def mean_ci(values: Sequence[float] | np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    """``(mean, lo, hi)``: the mean of the finite runs and its Student-t ``level`` interval.

    Non-finite runs are left out (count them with :func:`count_nonfinite`, or use
    :func:`summarize`); no finite run gives ``(nan, nan, nan)``; a single one
    ``lo = hi = mean``.
    """
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan, math.nan
    m = float(v.mean())
    if v.size < 2:
        return m, m, m
    half = student_t_quantile(0.5 + level / 2, v.size - 1) * float(v.std(ddof=1)) / math.sqrt(v.size)
    return m, m - half, m + half


class Summary(NamedTuple):
    """One quantity over the runs.

    Attributes:
        mean, lo, hi: :func:`mean_ci` of the finite runs (NaN when none).
        runs: all runs.
        unscored: runs without a value (NaN): left out of ``mean``, ``lo``, ``hi``.
    """

    mean: float
    lo: float
    hi: float
    runs: int
    unscored: int

    @property
    def scored(self) -> int:
        """Runs with a value."""
        return self.runs - self.unscored


def summarize(values: Sequence[float] | np.ndarray, level: float = 0.95) -> Summary:
    """:func:`mean_ci` of ``values`` with the number of runs and of runs without a value."""
    v = np.asarray(values, np.float64).ravel()
    m, lo, hi = mean_ci(v, level)
    return Summary(m, lo, hi, int(v.size), count_nonfinite(v))


def column_summary(values: Sequence[float] | np.ndarray) -> dict:
    """The JSON of one quantity over the runs: ``{"mean", "ci95": [lo, hi]}`` (95 % interval).

    With runs that have no value the dict also holds ``"unscored_runs"``, their
    number (the key is absent when every run has a value).
    """
    s = summarize(values)
    out = {"mean": s.mean, "ci95": [s.lo, s.hi]}
    if s.unscored:
        out["unscored_runs"] = s.unscored
    return out


def finite_mean(values: Sequence[float] | np.ndarray) -> tuple[float, int]:
    """``(mean of the finite runs, number of non-finite runs)``; the mean is NaN when no run is finite."""
    v = np.asarray(values, np.float64)
    ok = np.isfinite(v)
    if ok.all():
        return float(np.mean(v)), 0
    return (float(np.mean(v[ok])) if ok.any() else math.nan), int(np.sum(~ok))


def finite_median(values: Sequence[float] | np.ndarray) -> float:
    """The median of the finite runs (NaN when none is finite)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else math.nan


def mean_ci_columns(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`mean_ci` (95 %) of every column of ``values [R, n]`` at once: ``(mean, lo, hi)``, each ``[n]``.

    Every run counts (a NaN run makes its column NaN): for quantities every
    run has, such as a position error over time.
    """
    v = np.asarray(values, np.float64)
    r = v.shape[0]
    m = v.mean(axis=0)
    if r < 2:
        return m, m.copy(), m.copy()
    half = _t975(r - 1) * v.std(axis=0, ddof=1) / math.sqrt(r)
    return m, m - half, m + half
