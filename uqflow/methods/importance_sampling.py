"""Importance sampling of a failure probability in the standard normal space of the inputs.

p_f = P[g(U) <= 0] with U standard normal (the inputs through their Gaussian copula,
``uqflow.methods.form.to_inputs``) is estimated from N draws u_i of a biasing density q:

    p_hat = (1/N) sum 1[g(u_i) <= 0] phi(u_i) / q(u_i),

unbiased for any q that is positive wherever phi is (every density here is a mixture of
Gaussians with positive weights, so it is). Its standard error is the sample standard deviation
of the terms y_i = 1[g <= 0] phi/q over sqrt(N); the interval is the normal one,
p_hat +- z s.e. (clipped to [0, 1]), valid when the terms' distribution is not too
heavy-tailed, which the effective sample size (Kish) of the failing terms,
(sum y_i)^2 / sum y_i^2, measures.

The pieces here are reusable (multifidelity importance sampling builds on them):
``GaussianMixture`` (sampling and log density), ``defensive_mixture`` (Hesterberg 1995: a
Gaussian at a centre mixed with the standard normal itself, which bounds every weight
phi/q by 1/w), ``cross_entropy_fit`` (the weighted maximum-likelihood Gaussian of the
cross-entropy method, Rubinstein 1999) and ``importance_estimate``. docs/importance_sampling.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

#: the least eigenvalue ``cross_entropy_fit`` leaves in a fitted covariance (standard normal
#: units squared): a standard deviation of 0.1 in some direction. A weighted fit of fewer
#: points than dimensions (or of points on a line) is singular; a biasing density narrower
#: than this in a direction puts no draw where the failure domain may still extend, and its
#: weights phi/q grow without bound off its axis.
COVARIANCE_FLOOR = 1e-2
LOG_2PI = math.log(2.0 * math.pi)


def standard_normal_log_pdf(u: np.ndarray) -> np.ndarray:
    """log phi(u) of the independent standard normal density, per row of ``u`` (n, d)."""
    u = np.atleast_2d(np.asarray(u, dtype=float))
    return -0.5 * np.einsum("ij,ij->i", u, u) - 0.5 * u.shape[1] * LOG_2PI


@dataclass(frozen=True, eq=False)
class GaussianMixture:
    """sum_j weights_j N(means_j, covariances_j) in d dimensions.

    ``weights`` (k,) non-negative with a positive sum (normalized here), ``means`` (k, d),
    ``covariances`` (k, d, d) symmetric positive definite (refused otherwise)."""

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray

    def __post_init__(self):
        weights = np.asarray(self.weights, dtype=float).ravel()
        means = np.asarray(self.means, dtype=float)
        means = means.reshape(weights.size, -1) if means.size else means.reshape(
            weights.size, 0)
        d = means.shape[1]
        covariances = np.asarray(self.covariances, dtype=float).reshape(weights.size, d, d)
        if weights.size == 0:
            raise ValueError("a Gaussian mixture needs at least one component")
        if not (np.all(np.isfinite(weights)) and np.all(np.isfinite(means))
                and np.all(np.isfinite(covariances))):
            raise ValueError("a Gaussian mixture's weights, means and covariances must be "
                             "finite")
        if np.any(weights < 0) or weights.sum() <= 0:
            raise ValueError(f"mixture weights must be >= 0 with a positive sum, got "
                             f"{weights.tolist()}")
        if not np.allclose(covariances, np.swapaxes(covariances, 1, 2), rtol=1e-12,
                           atol=0.0):
            raise ValueError("mixture covariances must be symmetric")
        try:
            lower = np.linalg.cholesky(covariances)
        except np.linalg.LinAlgError:
            raise ValueError("mixture covariances must be positive definite") from None
        object.__setattr__(self, "weights", weights / weights.sum())
        object.__setattr__(self, "means", means)
        object.__setattr__(self, "covariances", covariances)
        object.__setattr__(self, "_lower", lower)
        # the inverse factors once (a product per call is cheaper than a solve; scipy's
        # triangular solve costs milliseconds even for 3 x 3)
        object.__setattr__(self, "_inverse_lower", np.linalg.inv(lower))
        object.__setattr__(self, "_log_norm", -np.log(np.diagonal(lower, axis1=1, axis2=2))
                           .sum(axis=1) - 0.5 * d * LOG_2PI)

    @property
    def dimension(self) -> int:
        return self.means.shape[1]

    @property
    def components(self) -> int:
        return self.weights.size

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` draws (n, d): a component by its weight (one uniform each), then
        mean + L z with z standard normal; the same ``rng`` state gives the same draws."""
        n = int(n)
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        cumulative = np.cumsum(self.weights)
        which = np.minimum(np.searchsorted(cumulative, rng.random(n) * cumulative[-1],
                                           side="right"), self.components - 1)
        z = rng.standard_normal((n, self.dimension))
        return self.means[which] + np.einsum("nij,nj->ni", self._lower[which], z)

    def log_pdf(self, u: np.ndarray) -> np.ndarray:
        """log q(u) per row of ``u`` (n, d), by log-sum-exp over the components."""
        u = np.atleast_2d(np.asarray(u, dtype=float))
        if u.shape[1] != self.dimension:
            raise ValueError(f"points of dimension {u.shape[1]} for a mixture of dimension "
                             f"{self.dimension}")
        terms = np.empty((self.components, u.shape[0]))
        for j in range(self.components):
            y = (u - self.means[j]) @ self._inverse_lower[j].T
            terms[j] = -0.5 * np.einsum("ij,ij->i", y, y) + self._log_norm[j]
        with np.errstate(divide="ignore"):
            terms += np.log(self.weights)[:, None]
        if self.components == 1:
            return terms[0]
        top = np.max(terms, axis=0)
        return top + np.log(np.sum(np.exp(terms - top), axis=0))


def standard_normal(dimension: int) -> GaussianMixture:
    """phi itself, as a one-component mixture."""
    return GaussianMixture(np.ones(1), np.zeros((1, dimension)),
                           np.eye(dimension)[None])


def defensive_mixture(centre, defensive_weight: float = 0.1,
                      scale: float = 1.0) -> GaussianMixture:
    """(1 - w) N(centre, scale^2 I) + w N(0, I): importance sampling at ``centre`` (the
    design point) that keeps a share w of the standard normal, so phi/q <= 1/w everywhere
    (Hesterberg 1995); w = 0 is the plain shifted density, w = 1 plain Monte Carlo."""
    centre = np.asarray(centre, dtype=float).ravel()
    w = float(defensive_weight)
    if not 0.0 <= w <= 1.0:
        raise ValueError(f"defensive_weight must lie in [0, 1], got {defensive_weight!r}")
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale!r}")
    if not np.all(np.isfinite(centre)):
        raise ValueError("the centre of a defensive mixture must be finite")
    d = centre.size
    eye = np.eye(d)
    parts = [(1.0 - w, centre, scale**2 * eye), (w, np.zeros(d), eye)]
    parts = [p for p in parts if p[0] > 0]
    return GaussianMixture(np.array([p[0] for p in parts]), np.array([p[1] for p in parts]),
                           np.array([p[2] for p in parts]))


def cross_entropy_fit(u, log_weights, floor: float = COVARIANCE_FLOOR) -> GaussianMixture:
    """The single Gaussian maximizing sum_i w_i log N(u_i; m, C) (weights w_i =
    exp(log_weights_i), normalized): m = sum w_i u_i, C = sum w_i (u_i - m)(u_i - m)^T, with
    C's eigenvalues raised to at least ``floor``. The cross-entropy method's update, with the
    likelihood ratios phi/q of the elite points as weights."""
    u = np.atleast_2d(np.asarray(u, dtype=float))
    log_weights = np.asarray(log_weights, dtype=float).ravel()
    if u.shape[0] == 0 or u.shape[0] != log_weights.size:
        raise ValueError(f"need one log weight per point and at least one point, got "
                         f"{u.shape[0]} points and {log_weights.size} weights")
    if not (np.all(np.isfinite(u)) and np.all(log_weights < np.inf)
            and np.any(np.isfinite(log_weights))):
        raise ValueError("the points must be finite and some weight positive and finite")
    w = np.exp(log_weights - np.max(log_weights))
    w /= w.sum()
    mean = w @ u
    centred = u - mean
    covariance = (centred * w[:, None]).T @ centred
    covariance = 0.5 * (covariance + covariance.T)
    values, vectors = np.linalg.eigh(covariance)
    covariance = (vectors * np.maximum(values, floor)) @ vectors.T
    return GaussianMixture(np.ones(1), mean[None], 0.5 * (covariance + covariance.T)[None])


@dataclass(frozen=True)
class ImportanceEstimate:
    """An importance-sampling estimate of a probability from ``n`` weighted draws: the
    estimate, its standard error, the normal interval [low, high] at the confidence asked
    (clipped to [0, 1]), the coefficient of variation stderr / probability, and the effective
    sample size (sum y)^2 / sum y^2 of the terms y_i = 1[failed] phi/q. ``reason`` says why
    an interval is NaN."""

    probability: float
    stderr: float
    low: float
    high: float
    cov: float
    effective_sample_size: float
    n: int
    reason: str = ""


def importance_estimate(failed, log_ratio, confidence: float = 0.95) -> ImportanceEstimate:
    """The estimate of P[failure] from draws of q: ``failed`` (n,) the event at each draw,
    ``log_ratio`` (n,) log phi(u_i) - log q(u_i). Draws whose solver run failed must be left
    out by the caller (they are neither failures nor safe)."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")
    failed = np.asarray(failed, dtype=bool).ravel()
    log_ratio = np.asarray(log_ratio, dtype=float).ravel()
    if failed.size != log_ratio.size:
        raise ValueError(f"{failed.size} events and {log_ratio.size} log ratios")
    n = failed.size
    if n == 0:
        return ImportanceEstimate(math.nan, math.nan, math.nan, math.nan, math.nan, 0.0, 0,
                                  "no draw ran: n = 0 gives no estimate")
    if not np.all(np.isfinite(log_ratio[failed])):
        raise ValueError("a failing draw has a log ratio that is not finite")
    if not failed.any():
        return ImportanceEstimate(0.0, 0.0, math.nan, math.nan, math.inf, 0.0, n,
                                  f"no failure among {n} draws: the weighted terms are all "
                                  f"zero and their spread bounds nothing")
    # scaled by the largest term so that exp cannot overflow; the scale cancels in the ratios
    top = float(np.max(log_ratio[failed]))
    scaled = np.where(failed, np.exp(np.where(failed, log_ratio, top) - top), 0.0)
    mean_scaled = float(scaled.mean())
    probability = math.exp(top) * mean_scaled
    spread = float(scaled.std(ddof=1)) if n > 1 else math.nan
    stderr = math.exp(top) * spread / math.sqrt(n)
    z = float(special.ndtri(0.5 + confidence / 2))
    ess = float(scaled.sum() ** 2 / np.sum(scaled**2))
    reason = "" if n > 1 else "one draw: its spread cannot be estimated"
    return ImportanceEstimate(probability, stderr, max(probability - z * stderr, 0.0),
                              min(probability + z * stderr, 1.0), stderr / probability,
                              ess, n, reason)
