"""Polynomial chaos by regression: the Hermite basis, least squares with its closed-form
leave-one-out error, and orthogonal matching pursuit where the basis outgrows the runs.

Everything here works on the independent standard normal variables z behind the inputs
(``uqflow.methods.pce`` maps them); the equations are in docs/pce.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import chaospy
import numpy as np
from scipy.linalg import solve_triangular

#: Least squares is used while runs >= OVERSAMPLING x basis terms (Hosder et al. 2007: a
#: ratio of 2 keeps the hat matrix's leverages h_ii at about P/n = 1/2 on average, so the
#: leave-one-out division by 1 - h_ii stays well conditioned); below it, sparse regression.
OVERSAMPLING = 2
#: OMP stops once this many added terms in a row have not lowered the leave-one-out error.
OMP_PATIENCE = 10
#: Aggregate LOO errors below this are round-off, not truncation: an exact fit leaves
#: relative residuals of about cond(Ψ)·eps, and cond(Ψ) stays below ~1e5 for the designs
#: here, so (1e5 · 2.2e-16)² ≈ 5e-22 < 1e-20. Orders that fit to round-off tie, and the
#: lowest of them is kept.
ROUND_OFF_LOO = 1e-20


def basis_size(order: int, dimension: int) -> int:
    """Terms of a total-degree basis: C(order + dimension, dimension)."""
    return math.comb(order + dimension, dimension)


def multi_indices(order: int, dimension: int) -> np.ndarray:
    """(P, dimension) degrees of every term of total degree <= ``order``, graded (the
    constant first, then degree 1, ...), in chaospy's ordering."""
    if dimension == 0:          # every input constant: the constant term alone
        return np.zeros((1, 0), dtype=np.int64)
    return np.asarray(chaospy.glexindex(start=0, stop=order + 1, dimensions=dimension,
                                        graded=True, cross_truncation=1.0), dtype=np.int64)


def hermite_matrix(z: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Ψ (n, P): the orthonormal Hermite products Π_k He_{α_k}(z_k)/sqrt(α_k!) at the points
    ``z`` (n, d).

    The same polynomials as ``chaospy.generate_expansion(order, J(Normal(0, 1), ...),
    normed=True)``, evaluated as products of chaospy's 1-D orthonormal Hermite polynomials:
    evaluating the d-variate expansion term by term costs seconds for a thousand terms, the
    products milliseconds (tests/methods/test_pce.py checks that both agree).
    """
    return product_matrix(z, indices, [chaospy.Normal(0, 1)] * z.shape[1])


def product_matrix(points: np.ndarray, indices: np.ndarray, marginals: list) -> np.ndarray:
    """Ψ (n, P): products over k of the 1-D polynomials orthonormal under ``marginals[k]``
    (chaospy's three-term recurrence), of degree α_k, at ``points`` (n, d)."""
    n, d = points.shape
    top = int(indices.max()) if indices.size else 0
    psi = np.ones((n, indices.shape[0]))
    for k in range(d):
        one_d = chaospy.generate_expansion(top, marginals[k], normed=True)
        values = np.asarray(one_d(points[:, k]), dtype=float).reshape(top + 1, n)
        psi *= values[indices[:, k]].T
    return psi


@dataclass
class Fit:
    """A regression on the columns ``active`` of a basis.

    ``coefficients`` (len(active), m); ``loo_mse`` (m,) the mean squared leave-one-out
    residual per output point; ``variance`` (m,) the outputs' sample variance.
    """

    active: np.ndarray
    coefficients: np.ndarray
    residual: np.ndarray
    loo_mse: np.ndarray
    variance: np.ndarray

    @property
    def loo_error(self) -> np.ndarray:
        """Relative leave-one-out error per output point: mean e_i² / sample variance (0 at a
        point the runs leave constant)."""
        flat = self.variance == 0
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = self.loo_mse / np.where(flat, 1.0, self.variance)
        return np.where(flat, 0.0, rel)

    @property
    def aggregate_loo(self) -> float:
        """The variance-weighted mean of the relative errors, Σ mse / Σ variance: the error of
        the whole output relative to its total variance (0 if the output is constant)."""
        total = float(np.sum(self.variance))
        return float(np.sum(self.loo_mse)) / total if total > 0 else 0.0


def output_variance(y: np.ndarray) -> np.ndarray:
    """Sample variance per column, exactly 0 where a column is constant to rounding.

    A column that varies only in its last bits (an output no input acts on) would otherwise
    give a leave-one-out error of order 1 relative to a variance of order eps².
    """
    var = y.var(axis=0, ddof=1) if y.shape[0] > 1 else np.zeros(y.shape[1])
    scale = np.max(np.abs(y), axis=0) if y.size else np.zeros(y.shape[1])
    return np.where(np.sqrt(var) <= 64 * np.finfo(float).eps * scale, 0.0, var)


def least_squares(psi: np.ndarray, y: np.ndarray, active: np.ndarray | None = None) -> Fit:
    """Least squares of ``y`` (n, m) on the columns ``active`` of ``psi`` (n, P), with the
    leave-one-out residuals in closed form: e_i = r_i / (1 - h_ii), h_ii = ||Q_i||² (thin QR
    of the regression matrix, Q's rows)."""
    if active is None:
        active = np.arange(psi.shape[1])
    a = psi[:, active]
    q, r = np.linalg.qr(a)
    coef = solve_triangular(r, q.T @ y)
    residual = y - a @ coef
    leverage = np.sum(q * q, axis=1)
    # A point the fit interpolates (h_ii = 1) has no leave-one-out prediction: infinite error.
    with np.errstate(divide="ignore", invalid="ignore"):
        loo = residual / (1.0 - leverage)[:, None]
    loo[1.0 - leverage <= 1e-12] = np.inf
    return Fit(np.asarray(active), coef, residual, np.mean(loo * loo, axis=0),
               output_variance(y))


def orthogonal_matching_pursuit(psi: np.ndarray, y: np.ndarray) -> Fit:
    """Sparse regression: terms added greedily, the number of terms chosen by leave-one-out.

    Starts from the constant term; each step adds the column whose correlation with the
    current residuals, summed in square over the output points (one common set of terms
    for an output's time/probe points: simultaneous OMP), is largest, and refits by least
    squares on the active columns. Stops at n / OVERSAMPLING terms, when no column is left
    that correlates with the residual, or OMP_PATIENCE steps after the best leave-one-out
    error, or once a fit is exact to round-off; returns the fit with the smallest aggregate
    leave-one-out error.
    """
    n, p = psi.shape
    norms = np.linalg.norm(psi, axis=0)
    most = max(1, min(p, n // OVERSAMPLING))
    active = [0]
    fit = least_squares(psi, y, np.array(active))
    best, since_best = fit, 0
    # A fit at round-off (ROUND_OFF_LOO) is exact: a further term can only win a rounding
    # tie, which another BLAS kernel decides the other way, so the fewest terms are kept.
    while len(active) < most and since_best < OMP_PATIENCE \
            and best.aggregate_loo > ROUND_OFF_LOO:
        score = np.sum((psi.T @ fit.residual) ** 2, axis=1) / norms**2
        score[active] = -1.0
        j = int(np.argmax(score))
        if score[j] <= 0:
            break
        active.append(j)
        fit = least_squares(psi, y, np.array(active))
        if fit.aggregate_loo < best.aggregate_loo:
            best, since_best = fit, 0
        else:
            since_best += 1
    return best


def fit_order(psi: np.ndarray, y: np.ndarray, regression: str) -> Fit | None:
    """The fit on the basis columns ``psi`` (n, P): least squares if the runs are at least
    OVERSAMPLING times the basis size (or ``regression`` is "least-squares"), else OMP (None
    when least squares is demanded and the runs are too few)."""
    enough = psi.shape[0] >= OVERSAMPLING * psi.shape[1]
    if regression == "omp" or (regression == "auto" and not enough):
        return orthogonal_matching_pursuit(psi, y)
    if not enough:
        return None
    return least_squares(psi, y)


@dataclass
class Expansion:
    """The chosen expansion of one output: its order, multi-indices (terms, d) of the kept
    terms, coefficients (terms, m), per-point relative LOO error and the aggregate LOO error
    of every order tried (NaN: not tried)."""

    order: int
    indices: np.ndarray
    coefficients: np.ndarray
    loo_error: np.ndarray
    loo_by_order: np.ndarray
    sparse: bool

    @property
    def mean(self) -> np.ndarray:
        return self.coefficients[0]

    @property
    def variance(self) -> np.ndarray:
        return np.sum(self.coefficients[1:] ** 2, axis=0)

    def sobol(self) -> tuple[np.ndarray, np.ndarray]:
        """First-order and total indices (d, m) of the standard variables: the share of the
        variance in the terms that hold z_i alone, and in every term that holds z_i."""
        c2 = self.coefficients[1:] ** 2
        alpha = self.indices[1:] > 0
        alone = alpha & (alpha.sum(axis=1, keepdims=True) == 1)
        var = self.variance
        with np.errstate(divide="ignore", invalid="ignore"):
            first = (alone.T.astype(float) @ c2) / var
            total = (alpha.T.astype(float) @ c2) / var
        flat = var == 0
        return np.where(flat, np.nan, first), np.where(flat, np.nan, total)


def select_expansion(z: np.ndarray, y: np.ndarray, orders: list[int], regression: str,
                     marginals: list) -> Expansion | None:
    """Fit every order in ``orders`` and keep the one with the smallest aggregate LOO error,
    the lowest order among those at round-off (ROUND_OFF_LOO). None if none could be fitted."""
    top = max(orders)
    loo_by_order = np.full(top, np.nan)
    # One evaluation of the highest order's basis serves every order: the order-p basis is
    # its columns of total degree <= p (the constant term stays first).
    every = multi_indices(top, z.shape[1])
    psi = product_matrix(z, every, marginals)
    degree = every.sum(axis=1)
    fits = {}
    for order in orders:
        fit = fit_order(psi[:, degree <= order], y, regression)
        if fit is not None:
            fits[order] = fit
            loo_by_order[order - 1] = fit.aggregate_loo
    if not fits:
        return None
    least = max(min(f.aggregate_loo for f in fits.values()), ROUND_OFF_LOO)
    order = min(o for o, f in fits.items() if f.aggregate_loo <= least)
    fit = fits[order]
    indices = every[degree <= order]
    # Keep the constant term first: the mean and variance read it by position.
    sort = np.argsort(fit.active, kind="stable")
    sparse = len(fit.active) < indices.shape[0]
    return Expansion(order, indices[fit.active[sort]], fit.coefficients[sort],
                     fit.loo_error, loo_by_order, sparse)
