"""The arithmetic of multilevel and multifidelity Monte Carlo, on plain arrays.

Kept apart from the methods (which lay out designs and runs) so each formula can be checked
on its own. Arrays of outputs are (samples, points): a study's output of any shape is
flattened to points.

Multilevel (Giles 2008, 2015): P_0, ..., P_L the quantity at levels 0 (coarsest) to L; the
corrections Y_0 = P_0, Y_l = P_l - P_{l-1} are sampled independently, each on N_l coupled
samples (the same inputs at both levels), so

    mean  = sum_l mean(Y_l),                var(mean) = sum_l V_l / N_l,
    Var[P_L] ~ sum_l (s^2(P_l) - s^2(P_{l-1}))  (unbiased sample variances on the pairs),

and the cost-optimal counts for a variance theta * eps^2 are (Lagrange multiplier)

    N_l = ceil( sqrt(V_l / C_l) * sum_k sqrt(V_k C_k) / (theta eps^2) ).

Multifidelity (Peherstorfer, Willcox & Gunzburger 2016, SIAM J. Sci. Comput. 38(5)): models
f_1 (high fidelity) ... f_k, nested sample counts m_1 <= ... <= m_k on the same sample
sequence, and

    s = mean(f_1 over m_1) + sum_{i>=2} alpha_i (mean(f_i over m_i) - mean(f_i over m_{i-1})),
    Var[s] = s_1^2/m_1 + sum_{i>=2} (1/m_{i-1} - 1/m_i)(alpha_i^2 s_i^2 - 2 alpha_i rho_i s_1 s_i),

alpha_i = rho_i s_1 / s_i; with ratios r_i = m_i / m_1 from the correlations rho_i and costs
w_i, Var[s] = s_1^2 / m_1 * (1 - sum_{i>=2} (1/r_{i-1} - 1/r_i) rho_i^2).
"""

from __future__ import annotations

import contextlib
import itertools
import math
import warnings

import numpy as np


@contextlib.contextmanager
def nan_moments_quietly():
    """Moments of a level or model without (enough) successful runs are NaN without numpy's
    RuntimeWarnings: the methods say what that costs in their own warnings."""
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def giles_counts(V: np.ndarray, C: np.ndarray, variance_target: np.ndarray,
                 most: int = 2**62) -> np.ndarray:
    """Optimal N_l, shape (levels,), for the variances ``V`` (levels, points), the costs per
    sample ``C`` (levels,) and the estimator variance wanted at each point
    (``variance_target``, (points,)): the largest over the points (each point is met), at
    most ``most`` (capped before rounding: a count too large for an integer stays ``most``)."""
    V = np.maximum(np.asarray(V, dtype=float), 0.0)
    C = np.asarray(C, dtype=float)
    target = np.asarray(variance_target, dtype=float)
    live = (V.sum(axis=0) > 0) & (target > 0) & np.isfinite(V).all(axis=0)
    if not live.any():
        return np.zeros(V.shape[0], dtype=np.int64)
    V, target = V[:, live], target[live]
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        total = np.sqrt(V * C[:, None]).sum(axis=0)                 # (points,)
        N = np.sqrt(V / C[:, None]) * total / target                # (levels, points)
    N = np.where(V > 0, N, 0.0)      # a level without variance needs no samples (not 0 * inf)
    return np.ceil(np.minimum(N.max(axis=1), most)).astype(np.int64)


def optimal_mlmc_cost(V: np.ndarray, C: np.ndarray, variance_target: float) -> float:
    """The cost of the optimal real-valued allocation for one point: (sum sqrt(V C))^2 / target."""
    return float(np.sum(np.sqrt(np.asarray(V) * np.asarray(C))) ** 2 / variance_target)


def level_rate(values: np.ndarray, decreasing: bool = True) -> float:
    """Rate per level of |values| over the correction levels l >= 1 (least squares on
    log2): alpha or beta with ``decreasing`` (|values| ~ 2^(-rate l)), gamma without. NaN
    when fewer than two usable levels."""
    values = np.abs(np.asarray(values, dtype=float))
    levels = np.arange(values.size)
    use = (levels >= 1) & (values > 0) & np.isfinite(values)
    if use.sum() < 2:
        return math.nan
    slope = np.polyfit(levels[use], np.log2(values[use]), 1)[0]
    return float(-slope if decreasing else slope)


def mlmc_bias(level_means: np.ndarray, alpha: float) -> np.ndarray:
    """Estimated bias of the finest level, per point, from the last two corrections' means
    (``level_means``, (levels, points)): the geometric tail E_L / (2^alpha - 1), taking the
    larger of E_L and E_{L-1} / 2^alpha so a correction that happens to be near 0 does not
    hide it. alpha NaN or <= 0 (not fitted, or not converging) is taken as 1: first order."""
    a = alpha if np.isfinite(alpha) and alpha > 0 else 1.0
    E = np.abs(np.asarray(level_means, dtype=float))
    last = E[-1]
    if E.shape[0] >= 3:
        last = np.maximum(last, E[-2] / 2.0**a)
    return last / (2.0**a - 1.0)


def mlmc_level_terms(fine: np.ndarray, coarse: np.ndarray | None) -> dict:
    """One correction level's contributions from its paired samples (n, points): the mean and
    variance of Y = fine - coarse, the difference of the sample variances and its variance."""
    n = fine.shape[0]
    y = fine if coarse is None else fine - coarse
    mean = y.mean(axis=0) if n else np.full(fine.shape[1:], np.nan)
    V = y.var(axis=0, ddof=1) if n > 1 else np.full(fine.shape[1:], np.nan)
    if n > 1:
        d = (fine - fine.mean(axis=0)) ** 2 * n / (n - 1)
        if coarse is not None:
            d = d - (coarse - coarse.mean(axis=0)) ** 2 * n / (n - 1)
        var_term = d.mean(axis=0)
        # first-order (delta-method) variance of the difference of the sample variances
        var_term_var = d.var(axis=0, ddof=1) / n
    else:
        var_term = var_term_var = np.full(fine.shape[1:], np.nan)
    return {"n": n, "mean": mean, "V": V, "var_term": var_term, "var_term_var": var_term_var}


def mfmc_ratios(rho: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Ratios r_i = m_i / m_1 for models in the given order (model 0 the high fidelity,
    ``rho`` their correlations with it, ``w`` their costs), or None if the ordering and cost
    conditions of PWG 2016 (Thm. 3.4) fail. Also the variance factor
    1 - sum (1/r_{i-1} - 1/r_i) rho_i^2 (Var[s] = s_1^2/m_1 times it)."""
    rho2 = np.append(np.asarray(rho, dtype=float) ** 2, 0.0)
    rho2[0] = 1.0
    w = np.asarray(w, dtype=float)
    k = w.size
    if np.any(np.diff(rho2[:k]) >= 0):
        return None
    for i in range(1, k):
        if not w[i - 1] * (rho2[i] - rho2[i + 1]) > w[i] * (rho2[i - 1] - rho2[i]):
            return None
    if k == 1:
        return np.ones(1), 1.0
    with np.errstate(divide="ignore"):
        # a free model (w = 0: a surrogate evaluated at will) gets r = inf: its exact mean
        r = np.sqrt(w[0] * (rho2[:k] - rho2[1:k + 1]) / (w * (1.0 - rho2[1])))
    factor = 1.0 - float(np.sum((1.0 / r[:-1] - 1.0 / r[1:]) * rho2[1:k]))
    return r, factor


def mfmc_best(sigma: float, rho: np.ndarray, w: np.ndarray,
              variance_target: float) -> tuple[list[int], np.ndarray, float, float] | None:
    """The cheapest MFMC for ``variance_target`` over every subset of the low-fidelity models
    that keeps the model order: (chosen models, their ratios r, m_1, cost m_1 sum w_i r_i),
    real-valued; None if no subset qualifies (not even model 0 alone, which always does)."""
    k = len(w)
    best, best_cost = None, math.inf
    for size in range(k):
        for subset in itertools.combinations(range(1, k), size):
            chosen = [0, *subset]
            got = mfmc_ratios(np.asarray(rho)[chosen], np.asarray(w)[chosen])
            if got is None:
                continue
            r, factor = got
            m1 = sigma**2 * factor / variance_target
            wc = np.asarray(w, dtype=float)[chosen]
            cost = m1 * float(np.sum(wc[wc > 0] * r[wc > 0]))
            if cost < best_cost:
                best, best_cost = (chosen, r, m1, cost), cost
    return best


def mfmc_allocation(sigma: float, rho: np.ndarray, w: np.ndarray,
                    variance_target: float, most: int = 2**62) -> np.ndarray:
    """Whole sample counts per model (0 for a model left out) of ``mfmc_best``, each at most
    ``most`` (capped before rounding: a count too large for an integer stays ``most``)."""
    chosen, r, m1, _ = mfmc_best(sigma, rho, w, variance_target)
    counts = np.zeros(len(w), dtype=np.int64)
    finite = np.isfinite(r)          # a free model is never run
    with np.errstate(over="ignore", invalid="ignore"):
        wanted = np.minimum(np.maximum(m1 * r[finite], 1.0), most)
    counts[np.asarray(chosen)[finite]] = np.ceil(np.nan_to_num(wanted, nan=most)).astype(
        np.int64)
    return counts


def mfmc_estimate(values: list[np.ndarray], counts: list[int],
                  exact_mean: np.ndarray | None = None) -> dict:
    """The MFMC mean and its variance per point from ``values[i]`` (n_i, points), model i's
    outputs on samples 0..n_i-1, and the nested counts ``counts`` (m_1 <= m_2 <= ...; a model
    whose count does not exceed the previous one's adds nothing and is skipped). alpha_i and
    the moments are estimated on the m_1 samples every model shares.

    With ``exact_mean`` the last model is a free surrogate whose mean is known (infinitely
    many samples): its count is ``math.inf`` and its term alpha (E[g] - mean of g over the
    previous model's samples); ``values[-1]`` must then cover those samples."""
    m1 = counts[0]
    f1 = values[0][:m1]
    with nan_moments_quietly():  # fewer than two shared samples
        s1 = f1.std(axis=0, ddof=1)
        estimate = f1.mean(axis=0)
    variance = s1**2 / m1
    prev = m1
    alphas = []
    for y, m in zip(values[1:], counts[1:]):
        if m == math.inf and exact_mean is None:
            raise ValueError("a model with infinitely many samples needs its exact mean")
        if m <= prev:
            alphas.append(np.zeros_like(estimate))
            continue
        shared = y[:m1]
        cov = ((f1 - f1.mean(axis=0)) * (shared - shared.mean(axis=0))).sum(axis=0) / (m1 - 1)
        si = shared.std(axis=0, ddof=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            alpha = np.where(si > 0, cov / si**2, 0.0)
            rho = np.where((si > 0) & (s1 > 0), cov / (s1 * si), 0.0)
        upper = exact_mean if m == math.inf else y[:m].mean(axis=0)
        estimate = estimate + alpha * (upper - y[:prev].mean(axis=0))
        variance = variance + (1.0 / prev - 1.0 / m) * (alpha**2 * si**2
                                                       - 2 * alpha * rho * s1 * si)
        alphas.append(alpha)
        prev = m
    return {"mean": estimate, "variance": np.maximum(variance, 0.0), "alpha": alphas,
            "sigma": s1}
