"""Estimates of a probability from sampled events: intervals, coefficient of variation, β.

A Monte Carlo estimate of a failure probability is a count: k failures among n realizations
that ran. For independent draws k is binomial, and two intervals for p follow from that alone:

* Clopper–Pearson ("exact"): the p whose binomial tail probabilities of k are α/2, from the
  beta quantiles B(α/2; k, n − k + 1) and B(1 − α/2; k + 1, n − k). Its coverage is at least
  the confidence level for every p and n (it is conservative), which makes it the default.
* Wilson (score): the p for which |k/n − p| ≤ z sqrt(p(1 − p)/n); shorter, its coverage
  oscillates around the level (Brown, Cai & DasGupta 2001), not always above it.

Randomized quasi-Monte Carlo points are not independent, so neither applies: its estimate is
the mean of R independent replicates' fractions, its interval a Student t with R − 1 degrees
of freedom over their spread (``replicate_interval``).

Where an interval cannot be given (no realization ran, replicates that all saw the same
fraction) its bounds are NaN and ``reason`` says why.

The exceedance curve (``exceedance_curve``) is the same estimate at many thresholds at once:
the fraction of values at or beyond each level, with the interval of each fraction (a
pointwise band: each level's interval has its coverage, the curve as a whole less).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special
from scipy import stats as sps

CLOPPER_PEARSON, WILSON, REPLICATE_T = "clopper-pearson", "wilson", "replicate-t"
#: the comparisons of an exceedance curve: the fraction of values >= a level (a limit state
#: "exceeds", whose failure is y >= threshold) or <= it ("below": y <= threshold)
AT_OR_ABOVE, AT_OR_BELOW = ">=", "<="
#: the most levels an exceedance curve keeps (the threshold comes on top)
MAX_CURVE_LEVELS = 200


@dataclass(frozen=True)
class ProbabilityInterval:
    """An interval [low, high] of a probability at ``confidence``, by ``method``; the bounds
    are NaN where none can be given, and ``reason`` then says why."""

    low: float
    high: float
    method: str
    confidence: float
    reason: str = ""


def _check_count(k, n, confidence) -> tuple[int, int]:
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")
    if int(k) != k or int(n) != n:
        raise ValueError(f"k and n must be whole counts, got k = {k!r}, n = {n!r}")
    k, n = int(k), int(n)
    if not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n, got k = {k}, n = {n}")
    return k, n


def _no_runs(method, confidence) -> ProbabilityInterval:
    return ProbabilityInterval(math.nan, math.nan, method, confidence,
                               "no realization ran: n = 0 gives no estimate")


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> ProbabilityInterval:
    """The exact (Clopper–Pearson) interval of a binomial p from k successes in n trials.

    At k = 0 the lower bound is 0 and the upper 1 − (α/2)^(1/n); at k = n the lower bound is
    (α/2)^(1/n) and the upper 1 (the beta quantiles in closed form)."""
    k, n = _check_count(k, n, confidence)
    if n == 0:
        return _no_runs(CLOPPER_PEARSON, confidence)
    tail = (1 - confidence) / 2
    low = 0.0 if k == 0 else float(sps.beta.ppf(tail, k, n - k + 1))
    high = 1.0 if k == n else float(sps.beta.ppf(1 - tail, k + 1, n - k))
    return ProbabilityInterval(low, high, CLOPPER_PEARSON, confidence)


def wilson(k: int, n: int, confidence: float = 0.95) -> ProbabilityInterval:
    """The Wilson score interval of a binomial p from k successes in n trials: the roots of
    (k/n − p)² = z² p (1 − p) / n, with z the normal quantile of 1 − α/2."""
    k, n = _check_count(k, n, confidence)
    if n == 0:
        return _no_runs(WILSON, confidence)
    z2 = sps.norm.ppf(0.5 + confidence / 2) ** 2
    centre = (k + z2 / 2) / (n + z2)
    half = math.sqrt(z2) / (n + z2) * math.sqrt(k * (n - k) / n + z2 / 4)
    # At k = 0 (k = n) the lower (upper) root is 0 (1) exactly; the formula leaves rounding.
    low = 0.0 if k == 0 else max(centre - half, 0.0)
    high = 1.0 if k == n else min(centre + half, 1.0)
    return ProbabilityInterval(low, high, WILSON, confidence)


def replicate_interval(estimates, confidence: float = 0.95) -> tuple[float, float,
                                                                     ProbabilityInterval]:
    """Mean, standard error and Student t interval (R − 1 degrees of freedom, clipped to
    [0, 1]) of a probability from R independent replicate estimates (randomized QMC).

    NaN estimates (replicates without a realization that ran) are left out. Below two
    replicates, or when every replicate gave the same fraction (all 0 for a rare event), the
    spread says nothing about the error: the interval is NaN with the reason."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")
    values = np.asarray(estimates, dtype=float).ravel()
    values = values[np.isfinite(values)]
    count = values.size
    if count == 0:
        return math.nan, math.nan, _no_runs(REPLICATE_T, confidence)
    mean = float(values.mean())
    if count < 2:
        return mean, math.nan, ProbabilityInterval(
            math.nan, math.nan, REPLICATE_T, confidence,
            "one replicate ran: its spread cannot be estimated")
    if np.all(values == values[0]):
        # Exactly equal fractions (typically no failure in any replicate): a zero spread is
        # no error estimate.
        return float(values[0]), 0.0, ProbabilityInterval(
            math.nan, math.nan, REPLICATE_T, confidence,
            f"every replicate gave the fraction {values[0]:.6g}: their spread is zero and "
            f"bounds nothing (run more samples)")
    stderr = float(values.std(ddof=1) / math.sqrt(count))
    half = float(sps.t.ppf(0.5 + confidence / 2, count - 1)) * stderr
    return mean, stderr, ProbabilityInterval(max(mean - half, 0.0), min(mean + half, 1.0),
                                             REPLICATE_T, confidence)


def normal_interval(p: float, stderr: float, confidence: float = 0.95) -> tuple[float, float]:
    """p ± z stderr, z the normal quantile of ``confidence``, clipped to [0, 1]: the interval
    of an estimate that is a mean of weighted terms (importance sampling, its control
    variate)."""
    z = float(special.ndtri(0.5 + confidence / 2))
    return max(p - z * stderr, 0.0), min(p + z * stderr, 1.0)


def reliability_index(p):
    """β = −Φ⁻¹(p): +inf at p = 0, −inf at p = 1, NaN for NaN (arrays element-wise)."""
    beta = -sps.norm.ppf(np.asarray(p, dtype=float))
    return float(beta) if np.ndim(beta) == 0 else beta


def binomial_cov(p, n):
    """Coefficient of variation of the fraction of n independent draws estimating p:
    sqrt((1 − p) / (n p)); +inf at p = 0 (no failure seen: no relative accuracy), 0 at p = 1,
    NaN for n = 0."""
    p = np.asarray(p, dtype=float)
    n = np.asarray(n, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        cov = np.where(n > 0, np.sqrt((1 - p) / (n * p)), np.nan)
    cov = np.where((n > 0) & (p == 0), np.inf, cov)
    return float(cov) if cov.ndim == 0 else cov


def binomial_interval(k: int, n: int, method: str = CLOPPER_PEARSON,
                      confidence: float = 0.95) -> ProbabilityInterval:
    """The interval ``method`` (CLOPPER_PEARSON or WILSON) of a binomial p from k in n."""
    if method == CLOPPER_PEARSON:
        return clopper_pearson(k, n, confidence)
    if method == WILSON:
        return wilson(k, n, confidence)
    raise ValueError(f"no binomial interval {method!r}: {CLOPPER_PEARSON!r} or {WILSON!r}")


@dataclass(frozen=True)
class ExceedanceCurve:
    """P[Y >= y] (``comparison`` AT_OR_ABOVE) or P[Y <= y] (AT_OR_BELOW) at ``levels``
    (increasing), each with its own interval ``low`` .. ``high`` at ``confidence`` by
    ``method`` (NaN where none can be given); ``runs``: the values it is estimated from."""

    levels: np.ndarray
    probability: np.ndarray
    low: np.ndarray
    high: np.ndarray
    comparison: str
    method: str
    confidence: float
    runs: int


def curve_levels(values, threshold: float, comparison: str,
                 max_levels: int = MAX_CURVE_LEVELS) -> np.ndarray:
    """The levels of an exceedance curve: the distinct finite ``values`` and ``threshold``,
    the values thinned to at most ``max_levels``. Counted from the failure side (the largest
    value for AT_OR_ABOVE), the j-th distinct value is kept for j on a geometric grid from 1
    to their number: every value of the tail, where the curve is small and matters, and
    fewer where it is near 1. The threshold is always a level (at it the curve is the
    failure probability)."""
    distinct = np.unique(np.asarray(values, dtype=float)[np.isfinite(values)])
    if distinct.size > max_levels:
        tail = distinct[::-1] if comparison == AT_OR_ABOVE else distinct
        ranks = _geometric_ranks(distinct.size, max_levels)
        distinct = tail[ranks - 1]
    levels = np.append(distinct, threshold) if np.isfinite(threshold) else distinct
    return np.unique(levels)


def _geometric_ranks(size: int, most: int) -> np.ndarray:
    """Up to ``most`` distinct ranks in 1 .. ``size``, 1 and ``size`` among them, on a
    geometric grid: rounding merges the grid's first points (every rank of the tail is
    kept), so the grid is made finer until the distinct ranks number ``most`` or one more
    point would pass it."""
    def grid(count):
        return np.unique(np.round(np.geomspace(1, size, count)).astype(int))

    best, count = grid(most), most
    while best.size < most:
        count += most - best.size
        finer = grid(count)
        if finer.size > most or finer.size == best.size:
            break
        best = finer
    return best


def exceedance_curve(values, threshold: float, comparison: str,
                     method: str = CLOPPER_PEARSON, confidence: float = 0.95,
                     replicate=None, replicates: int | None = None,
                     max_levels: int = MAX_CURVE_LEVELS) -> ExceedanceCurve:
    """The exceedance curve of ``values`` (NaN: left out) at ``curve_levels``.

    Independent values: at each level the count k of the n values at or beyond it gives k/n
    and the binomial interval ``method`` (the estimate and interval of a failure probability
    with that level as threshold, exactly). Randomized QMC (``replicates`` R, ``replicate``
    the replicate of each value): the mean over the replicates of their fractions and the
    Student t interval over their spread (``replicate_interval``), level by level."""
    if comparison not in (AT_OR_ABOVE, AT_OR_BELOW):
        raise ValueError(f"comparison must be {AT_OR_ABOVE!r} or {AT_OR_BELOW!r}, got "
                         f"{comparison!r}")
    values = np.asarray(values, dtype=float).ravel()
    finite = np.isfinite(values)
    levels = curve_levels(values, threshold, comparison, max_levels)
    y = values[finite]

    def counts_beyond(sample):
        # values at or beyond each level (the failure event at that threshold), by sorting
        ordered = np.sort(sample)
        if comparison == AT_OR_ABOVE:
            return ordered.size - np.searchsorted(ordered, levels, side="left")
        return np.searchsorted(ordered, levels, side="right")

    probability, low, high = (np.full(levels.size, math.nan) for _ in range(3))
    if replicates is None:
        method_used = method
        for j, k in enumerate(counts_beyond(y)):
            interval = binomial_interval(int(k), y.size, method, confidence)
            probability[j] = k / y.size if y.size else math.nan
            low[j], high[j] = interval.low, interval.high
    else:
        method_used = REPLICATE_T
        which = np.asarray(replicate).ravel()[finite]
        fractions = np.full((replicates, levels.size), math.nan)
        for r in range(replicates):
            if np.any(which == r):
                fractions[r] = counts_beyond(y[which == r]) / np.count_nonzero(which == r)
        for j in range(levels.size):
            probability[j], _, interval = replicate_interval(fractions[:, j], confidence)
            low[j], high[j] = interval.low, interval.high
    return ExceedanceCurve(levels, probability, low, high, comparison, method_used,
                           confidence, int(y.size))
