"""Summary statistics of per-run results: means, 95 % intervals, runs with nothing to score, diverged runs.

Every experiment reports a quantity over ``R`` seeded runs as the mean of the
runs and its Student-t interval

    mean ± t_{(1+level)/2, n−1} · s / √n,

with ``s`` the sample standard deviation (``ddof = 1``) of the ``n`` runs
that have a value (:func:`mean_ci`; ``level = 0.95`` by default).

A run can lack a value for two reasons, and both are *counted*, never
dropped silently:

* **nothing to score** (a tag-map error when the run mapped no tag, a curve
  point no run reached): the study writes NaN, never 0 (a 0 would pass for a
  perfect score and pull the mean down). Such runs are ``unscored``.
* **diverged**: a quantity that every run has (a robot error, a position
  error over time) is not finite, so the run's filter broke down
  (:func:`diverged_runs` finds these runs from the quantities a study names).
  A diverged run is left out of *every* quantity of its row, and counted.

:func:`summarize` (:class:`Summary`) and :func:`column_summary` leave both
kinds out of the mean and the interval and return how many they left out;
:func:`finite_mean` and :func:`finite_median` return the count too. No
function here leaves a run out without returning how many: :func:`mean_ci`
and :func:`mean_ci_columns` take every run, so a non-finite run makes their
result NaN. When no run has a value, the mean and the interval are NaN.
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
    "diverged_runs",
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
def _t_quantile(p: float, dof: int) -> float:
    """:func:`student_t_quantile`, remembered (a summary asks for the same few quantiles many times)."""
    return student_t_quantile(p, dof)


def _t975(dof: int) -> float:
    return _t_quantile(0.975, dof)


def count_nonfinite(values: Sequence[float] | np.ndarray) -> int:
    """The number of runs without a value (NaN or ±inf) in ``values``."""
    return int(np.sum(~np.isfinite(np.asarray(values, np.float64))))


def _per_run_finite(values: Sequence[float] | np.ndarray, runs: int) -> np.ndarray:
    """``[R]``: whether every entry of a run's value (a scalar or an array) is finite; ``values [R, ...]``."""
    v = np.asarray(values, np.float64)
    if v.ndim == 0 or v.shape[0] != runs:
        raise ValueError(f"per-run values must have a leading axis of {runs} runs, got shape {v.shape}")
    return np.isfinite(v.reshape(runs, int(np.prod(v.shape[1:])))).all(axis=1)


def diverged_runs(*defined: Sequence[float] | np.ndarray) -> np.ndarray:
    """``[R]`` booleans: the runs in which one of the ``defined`` quantities is not finite.

    Each argument is ``[R, ...]``, a quantity that every run has (a robot error, a position error
    over time): a NaN or ±inf there means the run diverged. Quantities that are NaN by design
    when there is nothing to score do not belong here.
    """
    if not defined:
        raise ValueError("diverged_runs needs at least one per-run quantity")
    runs = np.shape(defined[0])[0] if np.ndim(defined[0]) else -1
    ok = np.ones(max(runs, 0), bool)
    for values in defined:
        ok &= _per_run_finite(values, runs)
    return ~ok


def mean_ci(values: Sequence[float] | np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    """``(mean, lo, hi)``: the mean of ``values`` and its Student-t ``level`` interval.

    Every run counts: a non-finite run makes all three NaN (:func:`summarize` leaves such runs
    out and counts them). No run gives ``(nan, nan, nan)``; a single one ``lo = hi = mean``.
    """
    v = np.asarray(values, np.float64).ravel()
    if v.size == 0 or not np.all(np.isfinite(v)):
        return math.nan, math.nan, math.nan
    m = float(v.mean())
    if v.size < 2:
        return m, m, m
    half = _t_quantile(0.5 + level / 2, v.size - 1) * float(v.std(ddof=1)) / math.sqrt(v.size)
    return m, m - half, m + half


class Summary(NamedTuple):
    """One quantity over the runs.

    Attributes:
        mean, lo, hi: :func:`mean_ci` of the runs that have a value (NaN when none).
        runs: all runs.
        unscored: runs with nothing to score (NaN) that did not diverge: left out of ``mean``, ``lo``, ``hi``.
        diverged: runs that diverged (:func:`diverged_runs`): left out of ``mean``, ``lo``, ``hi``.
    """

    mean: float
    lo: float
    hi: float
    runs: int
    unscored: int
    diverged: int = 0

    @property
    def scored(self) -> int:
        """Runs with a value."""
        return self.runs - self.unscored - self.diverged


def _diverged_mask(diverged: Sequence[bool] | np.ndarray | None, runs: int) -> np.ndarray:
    if diverged is None:
        return np.zeros(runs, bool)
    mask = np.asarray(diverged)
    if mask.dtype != bool or mask.shape != (runs,):
        raise ValueError(f"diverged must be {runs} booleans (one per run), got {mask.dtype} of shape {mask.shape}")
    return mask


def summarize(
    values: Sequence[float] | np.ndarray,
    level: float = 0.95,
    diverged: Sequence[bool] | np.ndarray | None = None,
) -> Summary:
    """The mean and interval of the runs that have a value, with the runs left out counted.

    Args:
        values: ``[R]`` one value per run (NaN: nothing to score).
        level: the interval's confidence level.
        diverged: ``[R]`` booleans, the runs that diverged (:func:`diverged_runs`), left out
            and counted as ``diverged`` whatever their value here; ``None``: no run diverged.
            The other non-finite runs are counted as ``unscored``.
    """
    v = np.asarray(values, np.float64).ravel()
    gone = _diverged_mask(diverged, v.size)
    kept = v[~gone]
    ok = np.isfinite(kept)
    m, lo, hi = mean_ci(kept[ok], level)
    return Summary(m, lo, hi, int(v.size), int(np.sum(~ok)), int(np.sum(gone)))


def column_summary(values: Sequence[float] | np.ndarray, diverged: Sequence[bool] | np.ndarray | None = None) -> dict:
    """The JSON of one quantity over the runs: ``{"mean", "ci95": [lo, hi]}`` (95 % interval; :func:`summarize`).

    With runs that have nothing to score the dict also holds ``"unscored_runs"``, their
    number, and with runs that diverged ``"diverged_runs"`` (each key only when nonzero).
    """
    s = summarize(values, diverged=diverged)
    out = {"mean": s.mean, "ci95": [s.lo, s.hi]}
    if s.unscored:
        out["unscored_runs"] = s.unscored
    if s.diverged:
        out["diverged_runs"] = s.diverged
    return out


def finite_mean(values: Sequence[float] | np.ndarray) -> tuple[float, int]:
    """``(mean of the finite runs, number of non-finite runs)``; the mean is NaN when no run is finite."""
    v = np.asarray(values, np.float64)
    ok = np.isfinite(v)
    if ok.all():
        return (float(np.mean(v)) if v.size else math.nan), 0
    return (float(np.mean(v[ok])) if ok.any() else math.nan), int(np.sum(~ok))


def finite_median(values: Sequence[float] | np.ndarray) -> tuple[float, int]:
    """``(median of the finite runs, number of non-finite runs)``; the median is NaN when no run is finite."""
    v = np.asarray(values, np.float64).ravel()
    ok = np.isfinite(v)
    return (float(np.median(v[ok])) if ok.any() else math.nan), int(np.sum(~ok))


def mean_ci_columns(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`mean_ci` (95 %) of every column of ``values [R, n]`` at once: ``(mean, lo, hi)``, each ``[n]``.

    Every run counts (a NaN run makes its column NaN): for quantities every
    run has, such as a position error over time (leave the diverged runs out
    first, with :func:`diverged_runs`, and report how many). No run (``R = 0``)
    gives NaN columns.
    """
    v = np.asarray(values, np.float64)
    r = v.shape[0]
    if r == 0:
        nan = np.full(v.shape[1:], np.nan)
        return nan, nan.copy(), nan.copy()
    m = v.mean(axis=0)
    if r < 2:
        return m, m.copy(), m.copy()
    half = _t975(r - 1) * v.std(axis=0, ddof=1) / math.sqrt(r)
    return m, m - half, m + half
