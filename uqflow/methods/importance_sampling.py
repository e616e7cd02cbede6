"""Importance sampling of a failure probability in the standard normal space of the inputs.

p_f = P[g(U) <= 0] with U standard normal (the inputs through their Gaussian copula,
``uqflow.methods.form.to_inputs``) is estimated from N draws u_i of a biasing density q:

    p_hat = (1/N) sum 1[g(u_i) <= 0] phi(u_i) / q(u_i),

unbiased for any q that is positive wherever phi is (every density here is a mixture of
Gaussians with positive weights or, for cross-entropy in many dimensions, a von
Mises-Fisher-Nakagami density, positive for every u != 0, so it is). Its standard error is
the sample standard deviation of the terms y_i = 1[g <= 0] phi/q over sqrt(N); the interval
is the normal one,
p_hat +- z s.e. (clipped to [0, 1]), valid when the terms' distribution is not too
heavy-tailed, which the effective sample size (Kish) of the failing terms,
(sum y_i)^2 / sum y_i^2, measures.

The pieces here are reusable (multifidelity importance sampling builds on them):
``GaussianMixture`` (sampling and log density), ``defensive_mixture`` (Hesterberg 1995: a
Gaussian at a centre mixed with the standard normal itself, which bounds every weight
phi/q by 1/w), ``cross_entropy_fit`` (the weighted maximum-likelihood Gaussian of the
cross-entropy method, Rubinstein 1999), ``fit_gaussian_mixture`` (its weighted-EM mixture),
the improved cross-entropy rule's ``smoothing_sharpness`` and ``stopping_cov`` (Papaioannou,
Geyer & Straub 2019) and ``importance_estimate``. docs/importance_sampling.md.
"""

from __future__ import annotations

import functools
import hashlib
import math
import warnings as pywarnings
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np
import xarray as xr
from pydantic import Field, model_validator
from scipy import optimize, special

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.layout import (BIASING_COMPONENT, BIASING_DENSITY, BIASING_MEAN, BIASING_WEIGHT,
                           BOUND, BOUND_HIGH, BOUND_LOW, CE_ELITES, CE_ROUND,
                           CE_THRESHOLD, CONFIDENCE, DENSITY_RUNS, EFFECTIVE_SAMPLE_SIZE,
                           FAILURE_COV, FAILURE_INTERVAL, FAILURE_LEFT_OUT, FAILURE_NOTE,
                           FAILURE_PROBABILITY, FAILURE_RUNS, FAILURE_STDERR, FAILURES,
                           INPUT_CORRELATION, INPUT_STD, INPUTS, INTERVAL_METHOD, LIMIT_STATE,
                           LOG_LIKELIHOOD_RATIO, METHOD, PARAMETER, PARAMETER_UNITS, REALIZATION,
                           RELIABILITY_INDEX, ROUND, SAMPLING_RUNS, SOLVER_RUNS, STATISTIC,
                           STATISTIC_MEAN, STATUS, STATUS_PENDING, THRESHOLD_REACHED, UNITS,
                           ok_mask, output_names)
from uqflow.layout import (CE_FAMILY, CE_RULE, CE_SMOOTHING, CE_STOP_COV, NAKAGAMI_M,
                           NAKAGAMI_OMEGA, VMF_DIRECTION, VMF_KAPPA)
from uqflow.methods.base import (MAX_REALIZATIONS, MethodOptions, PropagationMethod,
                                 finish_statistics, make_design, register_method)
from uqflow.methods.form import (CHECK_DISTANCE, CHECK_POINT, DESIGN_POINT, DESIGN_POINT_U,
                                 FORM_INDEX, FORM_PROBABILITY, IMPORTANCE, OTHER_REGION_SHARE,
                                 OUTSIDE_HALF_SPACE, PROBE_CONE, STAGE, STAGE_CHECK,
                                 STAGE_SEARCH, STANDARD_NORMAL, Form, cholesky_of,
                                 importance_factors, moving_axes, system_kind, to_inputs)
from uqflow.methods.von_mises_fisher_nakagami import (VonMisesFisherNakagami,
                                                      fit_von_mises_fisher_nakagami,
                                                      normalized_weights)
from uqflow.probability import normal_interval, reliability_index
from uqflow.report import MethodReport, Sensitivity, number

#: the least eigenvalue ``cross_entropy_fit`` leaves in a fitted covariance (standard normal
#: units squared). The weights phi/q of a Gaussian q have a finite second moment under q only
#: if every eigenvalue of its covariance exceeds 1/2 (along an eigenvector of eigenvalue l,
#: phi^2/q grows like exp((1/(2l) - 1) x^2)); a narrower q gives an estimate of infinite
#: variance whose standard error means nothing, and self-normalized fits that shrink round by
#: round (a linear limit state at beta = 4.75 in 10 dims collapsed to a 0.01 variance and an
#: estimate 1e-8 times too small). 0.6 keeps a margin above 1/2: the second moment's factor
#: (2 - 1/l)^-1/2 per direction is at most sqrt(3).
COVARIANCE_FLOOR = 0.6
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
        # components with a diagonal factor (the identity of mean-shift fits and of the
        # defensive share) scale elementwise: the same numbers as the product with the factor
        # (its zeros add exact zeros), without a BLAS call that threads badly on a busy machine
        diagonal = np.diagonal(lower, axis1=1, axis2=2)
        object.__setattr__(self, "_diagonal", [
            np.diagonal(lower[j]).copy() if np.array_equal(lower[j], np.diag(diagonal[j]))
            else None for j in range(weights.size)])
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
        out = np.empty_like(z)
        for j in range(self.components):  # per component: no (n, d, d) stack of factors
            rows = which == j
            scale = self._diagonal[j]
            out[rows] = self.means[j] + (z[rows] * scale if scale is not None
                                         else z[rows] @ self._lower[j].T)
        return out

    def log_pdf(self, u: np.ndarray) -> np.ndarray:
        """log q(u) per row of ``u`` (n, d), by log-sum-exp over the components."""
        u = np.atleast_2d(np.asarray(u, dtype=float))
        if u.shape[1] != self.dimension:
            raise ValueError(f"points of dimension {u.shape[1]} for a mixture of dimension "
                             f"{self.dimension}")
        terms = np.empty((self.components, u.shape[0]))
        for j in range(self.components):
            y = (u - self.means[j]) * np.diagonal(self._inverse_lower[j]) \
                if self._diagonal[j] is not None else \
                (u - self.means[j]) @ self._inverse_lower[j].T
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
    return design_point_mixture(centre[None], [1.0], defensive_weight, scale)


def design_point_mixture(centres, shares, defensive_weight: float = 0.1,
                         scale: float = 1.0) -> GaussianMixture:
    """(1 - w) sum_k s_k N(c_k, scale^2 I) + w N(0, I): the defensive mixture with a
    Gaussian at each design point c_k (rows of ``centres``), the k-th taking the share s_k
    (normalized) of the non-defensive draws; still phi/q <= 1/w everywhere."""
    centres = np.atleast_2d(np.asarray(centres, dtype=float))
    shares = np.asarray(shares, dtype=float).ravel()
    w = float(defensive_weight)
    if not 0.0 <= w <= 1.0:
        raise ValueError(f"defensive_weight must lie in [0, 1], got {defensive_weight!r}")
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale!r}")
    if not np.all(np.isfinite(centres)):
        raise ValueError("the centre of a defensive mixture must be finite")
    if shares.size != centres.shape[0] or np.any(shares < 0) or not shares.sum() > 0:
        raise ValueError(f"need one non-negative share per centre with a positive sum, got "
                         f"{shares.tolist()} for {centres.shape[0]} centre(s)")
    d = centres.shape[1]
    eye = np.eye(d)
    parts = [((1.0 - w) * share / shares.sum(), c, scale**2 * eye)
             for c, share in zip(centres, shares)] + [(w, np.zeros(d), eye)]
    parts = [p for p in parts if p[0] > 0]
    return GaussianMixture(np.array([p[0] for p in parts]), np.array([p[1] for p in parts]),
                           np.array([p[2] for p in parts]))


def region_shares(betas) -> np.ndarray:
    """Each design point's share of the draws: its first-order probability Phi(-beta_k) over
    their sum (the optimal density's mass near each, for linear limit states)."""
    log_p = special.log_ndtr(-np.asarray(betas, dtype=float))
    shares = np.exp(log_p - np.max(log_p))
    return shares / shares.sum()


def other_design_points(probes, distance, alpha, beta) -> list[tuple[np.ndarray, float]]:
    """FORM's design-point check read as design points: along each probe's ray, the failure
    point t p/|p| (t from ``distance``) that lies outside FORM's half-space alpha . u >= beta
    by more than OUTSIDE_HALF_SPACE of beta and whose Phi(-t) is OTHER_REGION_SHARE of
    Phi(-beta) or more (form.Form.add_check's rule), nearest first; one per region (a point
    within PROBE_CONE of one already taken is the same region). [(u, t)]."""
    found: list[tuple[np.ndarray, float]] = []
    probes = np.atleast_2d(np.asarray(probes, dtype=float))
    distance = np.asarray(distance, dtype=float)
    for k in np.argsort(distance):
        t = float(distance[k])
        if not np.isfinite(t):
            continue
        point = t * probes[k] / np.linalg.norm(probes[k])
        outside = float(alpha @ point) < (1 - OUTSIDE_HALF_SPACE) * beta
        if not (outside and special.ndtr(-t) >= OTHER_REGION_SHARE * special.ndtr(-beta)):
            continue
        if any(point @ u / (np.linalg.norm(u) * t) >= PROBE_CONE for u, _ in found):
            continue
        found.append((point, t))
    return found


#: the covariance a cross-entropy fit may take: all of it, its diagonal, or the identity (the
#: "mean-shift" cross-entropy method: only the mean is fitted)
COVARIANCES = ("full", "diagonal", "identity")
#: covariance = "auto" fits the full covariance only when a round's elites number at least
#: this many times its d(d + 1)/2 parameters, else the identity. A covariance estimated
#: from n_e effective points differs from its target by E||C_hat - C||_F^2 ~ d(d + 1)/n_e
#: (relative to C); the second moment of the weights phi/q grows by the factor
#: prod_i l_i/sqrt(2 l_i - 1) ~ exp(sum (l_i - 1)^2 / 2) over its relative eigenvalues l_i,
#: about exp(d(d + 1)/(2 n_e)): the estimate's variance is inflated by e^(P/n_e), P the
#: parameter count. At n_e >= 10 P that is at most e^0.1 = 1.1, less than what a full
#: covariance gains over the identity on a smooth limit state; below it the noise wins (10
#: dims, 100 elites: the full fit's c.o.v. 0.13 against the identity's 0.075; 100 dims: an
#: estimate 1e-4 times too small).
AUTO_FULL_FACTOR = 10.0


def full_covariance_pays(elites: float, d: int) -> bool:
    """Whether ``elites`` points fit a full d x d covariance well enough
    (AUTO_FULL_FACTOR times its d(d + 1)/2 parameters)."""
    return elites >= AUTO_FULL_FACTOR * d * (d + 1) / 2


def cross_entropy_fit(u, log_weights, floor: float = COVARIANCE_FLOOR,
                      covariance: str = "full") -> GaussianMixture:
    """The single Gaussian maximizing sum_i w_i log N(u_i; m, C) (weights w_i =
    exp(log_weights_i), normalized): m = sum w_i u_i, C = sum w_i (u_i - m)(u_i - m)^T, with
    C's eigenvalues raised to at least ``floor``. The cross-entropy method's update, with the
    likelihood ratios phi/q of the elite points as weights. ``covariance`` = "diagonal" keeps
    C's diagonal (each floored), "identity" fits the mean only (C = I)."""
    if covariance not in COVARIANCES:
        raise ValueError(f"covariance must be one of {', '.join(COVARIANCES)}, got "
                         f"{covariance!r}")
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
    d = u.shape[1]
    if covariance == "identity":
        return GaussianMixture(np.ones(1), mean[None], np.eye(d)[None])
    centred = u - mean
    if covariance == "diagonal":
        spread = np.maximum(w @ centred**2, floor)
        return GaussianMixture(np.ones(1), mean[None], np.diag(spread)[None])
    fitted = (centred * w[:, None]).T @ centred
    fitted = 0.5 * (fitted + fitted.T)
    values, vectors = np.linalg.eigh(fitted)
    fitted = (vectors * np.maximum(values, floor)) @ vectors.T
    return GaussianMixture(np.ones(1), mean[None], 0.5 * (fitted + fitted.T)[None])


def effective_count(log_weights) -> float:
    """Kish's effective count (sum w)^2 / sum w^2 of weights exp(log_weights)."""
    log_weights = np.asarray(log_weights, dtype=float).ravel()
    w = np.exp(log_weights - np.max(log_weights))
    return float(w.sum() ** 2 / np.sum(w**2))


def cross_entropy_step(u, g, log_ratio, rho: float, floor: float = COVARIANCE_FLOOR,
                       covariance: str = "auto") -> tuple[float, int, GaussianMixture]:
    """One cross-entropy round from its draws ``u`` (n, d) of q_k, their margins ``g`` (NaN
    for a run that did not finish: left out) and log phi/q_k: the threshold (the
    rho-quantile of g, clipped at 0), the count of elite draws (g at or below it) and
    q_k+1, the Gaussian fitted to the elites with their likelihood ratios as weights
    (``covariance`` "auto": full if ``full_covariance_pays`` for the elite count, else the
    identity)."""
    g = np.asarray(g, dtype=float)
    usable = np.flatnonzero(np.isfinite(g))
    if not usable.size:
        raise ValueError("no draw of the round has a margin")
    threshold = max(float(np.quantile(g[usable], rho)), 0.0)
    elite = usable[g[usable] <= threshold]
    u = np.atleast_2d(np.asarray(u, dtype=float))
    elite_ratio = np.asarray(log_ratio, dtype=float)[elite]
    if covariance == "auto":
        covariance = "full" if full_covariance_pays(elite.size, u.shape[1]) else "identity"
    fitted = cross_entropy_fit(u[elite], elite_ratio, floor, covariance)
    return threshold, int(elite.size), fitted


#: EM of a Gaussian mixture stops when the weighted log-likelihood gains less than this
#: (relative) in an iteration, or after EM_ITERATIONS
EM_TOLERANCE, EM_ITERATIONS = 1e-8, 200
#: a component whose weight falls below this share of the whole is dropped (it holds no point)
EM_SMALLEST_SHARE = 1e-6


def fit_gaussian_mixture(u, log_weights, components: int, floor: float = COVARIANCE_FLOOR,
                         covariance: str = "auto") -> GaussianMixture:
    """A mixture of ``components`` Gaussians fitted to the points ``u`` (n, d) with weights
    exp(log_weights) by weighted EM: each point's responsibilities as in plain EM, each
    component's weight, mean and covariance from the responsibilities times the points'
    weights. Starting point, deterministic: the heaviest point, then each next centre the
    point of largest weight x squared distance to the centres so far; each point to its
    nearest centre. Covariances per ``covariance`` ("auto": a component's full covariance
    when its effective count of points (Kish) pays for it, ``full_covariance_pays``, else
    the identity), eigenvalues floored at ``floor``. One component is
    ``cross_entropy_fit``'s Gaussian."""
    u = np.atleast_2d(np.asarray(u, dtype=float))
    w = normalized_weights(log_weights)
    if u.shape[0] != w.size or not np.all(np.isfinite(u)):
        raise ValueError(f"need {u.shape[0]} finite points with a weight each, got "
                         f"{w.size} weights")
    if int(components) < 1:
        raise ValueError(f"components must be >= 1, got {components!r}")
    responsibility = initial_responsibilities(u, w, int(components))
    previous = -math.inf
    for _ in range(EM_ITERATIONS):
        mixture = weighted_m_step(u, w, responsibility, floor, covariance)
        log_joint = component_log_densities(mixture, u) + np.log(mixture.weights)[None]
        top = np.max(log_joint, axis=1, keepdims=True)
        log_mix = top[:, 0] + np.log(np.sum(np.exp(log_joint - top), axis=1))
        responsibility = np.exp(log_joint - log_mix[:, None])
        likelihood = float(w @ log_mix)
        if likelihood - previous <= EM_TOLERANCE * abs(likelihood):
            break
        previous = likelihood
    return mixture


def initial_responsibilities(u, w, components: int) -> np.ndarray:
    centres = [int(np.argmax(w))]
    distance = np.sum((u - u[centres[0]]) ** 2, axis=1)
    for _ in range(1, components):
        score = w * distance
        best = int(np.argmax(score))
        if score[best] <= 0:  # fewer distinct weighted points than components
            break
        centres.append(best)
        distance = np.minimum(distance, np.sum((u - u[best]) ** 2, axis=1))
    nearest = np.argmin(np.stack([np.sum((u - u[c]) ** 2, axis=1) for c in centres]), axis=0)
    return np.eye(len(centres))[nearest]


def weighted_m_step(u, w, responsibility, floor, covariance) -> GaussianMixture:
    mass = responsibility * w[:, None]
    shares = mass.sum(axis=0)
    keep = shares > EM_SMALLEST_SHARE * shares.sum()
    mass, shares = mass[:, keep], shares[keep]
    d = u.shape[1]
    means = (mass.T @ u) / shares[:, None]
    covariances = np.empty((shares.size, d, d))
    for k in range(shares.size):
        kind = covariance
        if kind == "auto":
            effective = shares[k] ** 2 / np.sum(mass[:, k] ** 2)
            kind = "full" if full_covariance_pays(effective, d) else "identity"
        centred = u - means[k]
        if kind == "identity":
            covariances[k] = np.eye(d)
        elif kind == "diagonal":
            covariances[k] = np.diag(np.maximum(mass[:, k] @ centred**2 / shares[k], floor))
        else:
            fitted = (centred * mass[:, k:k + 1]).T @ centred / shares[k]
            values, vectors = np.linalg.eigh(0.5 * (fitted + fitted.T))
            fitted = (vectors * np.maximum(values, floor)) @ vectors.T
            covariances[k] = 0.5 * (fitted + fitted.T)
    return GaussianMixture(shares, means, covariances)


def component_log_densities(mixture: GaussianMixture, u) -> np.ndarray:
    """log N(u_i; m_k, C_k), (n, k), from the mixture's factors."""
    out = np.empty((u.shape[0], mixture.components))
    for k in range(mixture.components):
        y = (u - mixture.means[k]) @ mixture._inverse_lower[k].T
        out[:, k] = -0.5 * np.einsum("ij,ij->i", y, y) + mixture._log_norm[k]
    return out


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
    ess = float(scaled.sum() ** 2 / np.sum(scaled**2))
    reason = "" if n > 1 else "one draw: its spread cannot be estimated"
    return ImportanceEstimate(probability, stderr, *normal_interval(probability, stderr,
                                                                    confidence),
                              stderr / probability, ess, n, reason)


def log_likelihood_ratio(density, u) -> np.ndarray:
    """log phi(u) - log q(u) of the points ``u`` (n, d) under a Gaussian mixture or a
    von Mises-Fisher-Nakagami density (its own ratio, whose r^(d-1) cancel)."""
    if isinstance(density, VonMisesFisherNakagami):
        return density.log_likelihood_ratio(u)
    return standard_normal_log_pdf(u) - density.log_pdf(u)


# ============================================================================= the methods

#: what a row of the design is besides FORM's search rows: a draw of the biasing density whose
#: terms make the estimate, or a draw of a cross-entropy round (which only adapts the density)
STAGE_SAMPLING, STAGE_CROSS_ENTROPY = "sampling", "cross-entropy"
#: the draws of round r come from SeedSequence(entropy, spawn_key=(*key, SAMPLING_STREAM, r)):
#: a spawn key longer than a realization's own (i,), so no solver seed shares their stream
SAMPLING_STREAM = 18
#: ESS below this share of the failing draws: the weights have degenerated. N(u*, I) at the
#: one design point of a linear limit state keeps ESS / failures at
#: Phi(-beta)^2 / (e^(beta^2) Phi(-2 beta) / 2), about 1.6 / beta (above 0.1 up to
#: beta = 15); far below it a few draws carry the estimate.
DEGENERATE_SHARE = 0.1
#: ESS below this: the normal interval rests on too few effective draws to be trusted
FEW_EFFECTIVE = 10.0
INTERVAL_NORMAL = "normal"


def round_generator(seed: np.random.SeedSequence, round_: int) -> np.random.Generator:
    """The generator of round ``round_``'s draws: a pure function of the study's seed and the
    round number, so the draws are the same after a resume and for any worker count."""
    return np.random.default_rng(np.random.SeedSequence(
        seed.entropy, spawn_key=(*seed.spawn_key, SAMPLING_STREAM, int(round_))))


def batch_sizes(samples: int, batches: int) -> list[int]:
    """``samples`` split into ``batches`` sizes differing by at most one."""
    return [samples // batches + (1 if b < samples % batches else 0) for b in range(batches)]


def moving_axes_of(runs: xr.Dataset) -> np.ndarray:
    """The axes of u that move an input, from the input summary stored with the runs."""
    stds = np.asarray(runs[INPUT_STD].values, dtype=float)
    return moving_axes(stds, cholesky_of(np.asarray(runs[INPUT_CORRELATION].values,
                                                    dtype=float)))


def to_standard_normal(space, point: dict[str, float]) -> np.ndarray:
    """u of a point in the inputs' units (every input with a spread named): z_k =
    Phi^-1(F_k(x_k)) (a normal input's (x_k - mean) / std exactly), u = L^-1 z."""
    z = np.zeros(len(space))
    for k, inp in enumerate(space.inputs):
        if inp.variance == 0:
            continue
        x = point[inp.name]
        if inp.kind == "normal":
            z[k] = (x - inp.mean) / inp.std
        else:
            p = float(inp.distribution.fwd(x))
            if not 0.0 < p < 1.0:
                raise StudyError(f"{x!r} is outside the support of input '{inp.name}' (its "
                                 f"distribution function there is {p:g})",
                                 key=f"method.design_point.{inp.name}")
            z[k] = float(special.ndtri(p))
    lower = cholesky_of(space.correlation)
    return np.linalg.solve(lower, z) if lower.size else z


class ImportanceSamplingOptions(MethodOptions):
    # the FORM search's options (uqflow.methods.form reads them by these names), declared
    # here so that this method's options do not change with FORM's
    limit_state: str | None = Field(None, description="the study's limit state to analyse "
                                    "(default: its only one)")
    step: float = Field(0.01, gt=0, le=1, description="finite-difference step of the FORM "
                        "gradient, in standard normal units")
    gradient: Literal["central", "forward"] = Field(
        "central", description="central (2n + 1 runs a round) or forward (n + 1 runs) "
                               "differences of the FORM search")
    u_tolerance: float = Field(1e-3, gt=0, description="largest next step |u_{k+1} - u_k| "
                               "at the search's convergence, in standard normal units")
    g_tolerance: float = Field(1e-3, gt=0, description="largest |g| at the search's "
                               "convergence, as a fraction of |g| at the inputs' medians")
    max_iterations: int = Field(30, ge=1, le=10_000, description="most rounds of the FORM "
                                "search (line-search trials included)")
    samples: int = Field(1000, ge=2, le=MAX_REALIZATIONS, description="draws of the biasing "
                         "density that make the estimate")
    batches: int = Field(1, ge=1, le=10_000, description="rounds the draws run in (target_cov "
                         "is checked after each)")
    defensive_weight: float = Field(0.1, ge=0, le=1, description="share w of the standard "
                                    "normal in the biasing density (phi/q <= 1/w)")
    scale: float = Field(1.0, gt=0, le=10, description="standard deviation of the Gaussian "
                         "at the design point, in standard normal units")
    confidence: float = Field(0.95, gt=0, lt=1, description="level of the normal interval "
                              "of P[failure]")
    target_cov: float | None = Field(None, gt=0, description="stop after the batch whose "
                                     "c.o.v. of P[failure] is at most this")
    design_point: dict[str, float] | None = Field(
        None, description="the centre in the inputs' units, {name = value} for every input "
                          "with a spread (skips the FORM search)")
    design_point_check: bool = Field(True, description="after FORM converges, one round of "
                                     "g at -u* and at |u*| along the other axes (FORM's "
                                     "check); each other design point it finds gets a "
                                     "Gaussian of the mixture too")

    @model_validator(mode="after")
    def _batches_fit(self):
        if self.batches > self.samples:
            raise ValueError(f"batches = {self.batches} exceeds samples = {self.samples} "
                             f"(a batch holds at least one draw)")
        return self.only_where("target_cov", self.batches > 1,
                               "batches > 1 (the c.o.v. is checked after each batch)")

    @model_validator(mode="after")
    def _search_options_need_a_search(self):
        for key in ("step", "gradient", "u_tolerance", "g_tolerance", "max_iterations",
                    "design_point_check"):
            self.only_where(key, self.design_point is None,
                            "the FORM search, which a given design_point skips")
        return self


#: the improved cross-entropy method's default target c.o.v. of the weights between
#: successive smoothed targets, and of 1[g <= 0] / Phi(-g/s) at its stop (Papaioannou, Geyer
#: & Straub 2019 recommend 1.5: about N / (1 + 1.5^2), a third of a round's draws, carry
#: each fit)
SMOOTHING_COV = 1.5
#: family = "auto" fits the von Mises-Fisher-Nakagami density from this many moving axes of
#: u on, a mixture of Gaussians below. A mixture's means are d numbers per component, each off
#: by about 1/sqrt(n_e) (n_e the component's effective draws), which inflates the weights'
#: second moment by about e^(d / n_e): with a round's ~N/3 effective draws shared by 4
#: components (N = 1,000) that is e^0.24 at d = 20 and grows past e^1 by d = 100, where
#: the vMFN's shell and cap need no per-axis mean. Below 20 axes the mixture keeps what the
#: vMFN cannot: failure regions in several directions (the four-branch system, two design
#: points).
VMFN_DIMENSION = 20
#: components of the Gaussian family: the improved rule fits this many (four regions of the
#: four-branch system each get one); the quantile rule one (its rho N elites are too few to
#: share)
IMPROVED_COMPONENTS, QUANTILE_COMPONENTS = 4, 1
RULES = ("improved", "quantile")
FAMILIES = ("auto", "gaussian", "vmfn")


class CrossEntropyRoundOptions(MethodOptions):
    """The options of cross-entropy rounds, shared by ``cross-entropy`` and the cross-entropy
    search of ``multifidelity-importance-sampling``."""

    rule: Literal["improved", "quantile"] = Field(
        "improved", description="improved: smoothed intermediate targets Phi(-g/s_j) phi "
                                "(Papaioannou et al. 2019); quantile: the classic "
                                "rho-quantile thresholds and elites (Rubinstein 1999)")
    smoothing_cov: float = Field(SMOOTHING_COV, gt=0, le=10, description="improved rule: "
                                 "target c.o.v. of the weights between successive smoothed "
                                 "targets, and the stop's c.o.v. of 1[g <= 0] / Phi(-g/s)")
    rho: float = Field(0.1, gt=0, le=0.5, description="quantile rule: quantile of g that "
                       "sets each round's intermediate threshold")
    family: Literal["auto", "gaussian", "vmfn"] = Field(
        "auto", description="density fitted: gaussian (a mixture of `components` "
                            "Gaussians), vmfn (von Mises-Fisher direction, Nakagami radius), "
                            "auto: vmfn from 20 moving axes of u on, else gaussian")
    components: int | None = Field(None, ge=1, le=20, description="Gaussians of the "
                                   "gaussian family (default 4 for the improved rule, 1 for "
                                   "the quantile rule)")
    covariance: Literal["auto", "full", "diagonal", "identity"] = Field(
        "auto", description="covariance of each fitted Gaussian: full, its diagonal, or the "
                            "identity (the mean only); auto: full when its (effective) "
                            "points number at least 10 times its d(d + 1)/2 parameters, else "
                            "the identity")


class CrossEntropyOptions(CrossEntropyRoundOptions):
    limit_state: str | None = Field(None, description="the study's limit state or system to "
                                    "analyse (default: its only one)")
    samples: int = Field(1000, ge=10, le=MAX_REALIZATIONS, description="draws of each "
                         "cross-entropy round, and of the final estimate")
    max_rounds: int = Field(10, ge=1, le=100, description="most cross-entropy rounds before "
                            "the final estimate")
    batches: int = Field(1, ge=1, le=10_000, description="rounds the final draws run in "
                         "(target_cov is checked after each)")
    confidence: float = Field(0.95, gt=0, lt=1, description="level of the normal interval "
                              "of P[failure]")
    target_cov: float | None = Field(None, gt=0, description="stop the final draws after the "
                                     "batch whose c.o.v. of P[failure] is at most this")

    @model_validator(mode="after")
    def _batches_fit(self):
        if self.batches > self.samples:
            raise ValueError(f"batches = {self.batches} exceeds samples = {self.samples} "
                             f"(a batch holds at least one draw)")
        return self.only_where("target_cov", self.batches > 1,
                               "batches > 1 (the c.o.v. is checked after each batch)")

    @model_validator(mode="after")
    def _options_of_the_rule_and_family(self):
        self.only_where("rho", self.rule == "quantile", 'rule = "quantile" (the improved '
                        'rule sets its targets by smoothing_cov)')
        self.only_where("smoothing_cov", self.rule == "improved", 'rule = "improved"')
        for key in ("components", "covariance"):
            self.only_where(key, self.family != "vmfn", "the gaussian family (family = "
                            '"vmfn" fits a direction and a radius)')
        return self

    @property
    def mixture_components(self) -> int:
        if self.components is not None:
            return self.components
        return IMPROVED_COMPONENTS if self.rule == "improved" else QUANTILE_COMPONENTS

    def family_for(self, dimension: int) -> str:
        """The family fitted in ``dimension`` moving axes of u."""
        if self.family != "auto":
            return self.family
        return "vmfn" if dimension >= VMFN_DIMENSION else "gaussian"


@dataclass
class CrossEntropyState:
    """The cross-entropy rounds replayed from their runs: the density of the next round (or
    of the final draws), each round's threshold and elite count (quantile rule) or smoothing
    parameter and stopping c.o.v. (improved rule), and how the adaptation ended."""

    density: object
    thresholds: list = field(default_factory=list)
    elites: list = field(default_factory=list)
    #: improved rule: s_j fitted after each round (NaN for the round that met the stop) and
    #: each round's c.o.v. of 1[g <= 0] / Phi(-g/s_(j-1))
    smoothing: list = field(default_factory=list)
    stop_covs: list = field(default_factory=list)
    #: the fit's effective count (Kish, of its weights) and the covariance fitted
    effective: list = field(default_factory=list)
    fitted: list = field(default_factory=list)
    reached: bool = False
    stopped: str = ""

    @property
    def rounds(self) -> int:
        return max(len(self.thresholds), len(self.stop_covs))


@functools.lru_cache(maxsize=8)
def standard_normal_start(dimension: int) -> GaussianMixture:
    """phi, the density of every cross-entropy method's first round (built once per
    dimension: its factorization costs a BLAS call per replay otherwise)."""
    return standard_normal(dimension)


def weights_cov(log_weights) -> float:
    """The c.o.v. (standard deviation over the mean, of the draws themselves: ddof 0) of the
    weights exp(log_weights); infinite when none is positive."""
    log_weights = np.asarray(log_weights, dtype=float)
    top = np.max(log_weights) if log_weights.size else -math.inf
    if not np.isfinite(top):
        return math.inf
    w = np.exp(log_weights - top)
    return float(w.std() / w.mean())


def log_smoothed_indicator(g, sharpness: float) -> np.ndarray:
    """log Phi(-g t), t = 1/s the smoothing's sharpness: 1[g <= 0] at t = infinity."""
    g = np.asarray(g, dtype=float)
    if math.isinf(sharpness):
        return np.where(g <= 0, 0.0, -np.inf)
    return special.log_ndtr(-g * sharpness)


def stopping_cov(g, sharpness: float) -> float:
    """The improved rule's stop: the c.o.v. of 1[g <= 0] / Phi(-g t) (t = 1/s) over the
    round's draws ``g`` (finite): how far the smoothed target is from the optimal density
    phi 1[g <= 0] / p_f where the round's draws lie."""
    g = np.asarray(g, dtype=float)
    return weights_cov(np.where(g <= 0, -log_smoothed_indicator(g, sharpness), -np.inf))


def smoothing_sharpness(g, previous: float, target: float = SMOOTHING_COV) -> float:
    """t_j = 1/s_j >= ``previous`` (t_(j-1); 0 for s_0 = infinity, where Phi(-g t) = 1/2):
    the root of c.o.v.[Phi(-g t) / Phi(-g t_(j-1))] = ``target`` over the round's draws
    ``g`` (finite), by Brent's method. The c.o.v. is 0 at t = t_(j-1) and tends, as t grows,
    to that of 1[g < 0] / Phi(-g t_(j-1)) (the stop's statistic, above the target unless the
    stop was met); infinity when no finite t reaches the target (the indicator itself)."""
    if math.isinf(previous):
        return math.inf
    g = np.asarray(g, dtype=float)
    base = special.log_ndtr(-g * previous)

    def excess(t):
        return weights_cov(special.log_ndtr(-g * t) - base) - target

    spread = float(np.median(np.abs(g)))
    high = max(2.0 * previous, 1.0 / spread if spread > 0 else 1.0)
    while excess(high) < 0:
        high *= 2.0
        if high > 1e300:
            return math.inf
    return float(optimize.brentq(excess, previous, high, xtol=1e-14 * high, rtol=1e-12))


@register_method("importance-sampling")
class ImportanceSampling(Form):
    """Importance sampling at FORM's design point with a defensive mixture."""

    Options: ClassVar = ImportanceSamplingOptions
    extends = True
    curvatures: ClassVar[bool] = False
    #: the estimator's name in the report
    label: ClassVar[str] = "importance sampling"

    # ------------------------------------------------------------------ the limit state
    def systems_allowed(self) -> bool:
        """Whether a series or parallel system may be analysed (no design point needed)."""
        return self.options.design_point is not None

    def check_limit_states(self, limit_states) -> None:
        if limit_states is None or not list(limit_states.names):
            raise StudyError(f"method '{self.name}' needs a limit state: add a "
                             f"[[limit_states]] table", key="limit_states")
        chosen = limit_states.choose(self.options.limit_state, self.name, self.systems_allowed())
        kind = system_kind(limit_states, chosen)
        if kind and not self.systems_allowed():
            raise StudyError(f"'{chosen}' is a {kind} system: the FORM search of "
                             f"{self.name} needs one limit state; give the centre with "
                             f"design_point = {{...}}, or use cross-entropy",
                             key="method.limit_state")
        self.limit_states = limit_states
        self.limit_state = chosen

    def check(self, space, fields):
        super().check(space, fields)
        given = getattr(self.options, "design_point", None)
        if given is not None:
            names = [inp.name for inp in space.inputs]
            unknown = [k for k in given if k not in names]
            if unknown:
                raise StudyError(f"'{unknown[0]}' is not an input of the study "
                                 f"({', '.join(names)})", key="method.design_point")
            missing = [inp.name for inp in space.inputs if inp.variance > 0 and
                       inp.name not in given]
            if missing:
                raise StudyError(f"give the design point's value of every input with a "
                                 f"spread: {', '.join(missing)} missing",
                                 key="method.design_point")
            to_standard_normal(space, given)

    # ------------------------------------------------------------------ designs
    def plan(self, space, fields, seed):
        self.check(space, fields)
        if getattr(self, "limit_states", None) is None:
            raise StudyError(f"method '{self.name}' needs a limit state: add a "
                             f"[[limit_states]] table", key="limit_states")
        self._space, self._seed = space, seed
        self._axes = moving_axes(space.stds, cholesky_of(space.correlation))
        first = self.density_rows(None, 0)
        return first if first is not None else self.sampling_rows(None, 0, 0)

    def rows(self, u, offsets, round_, stage, log_ratio=None) -> xr.Dataset:
        """Form's rows, each with its log likelihood ratio log phi(u) - log q(u) (NaN for a
        row that is no draw of a biasing density)."""
        n = u.shape[0]
        ratio = np.full(n, np.nan) if log_ratio is None else np.asarray(log_ratio, float)
        if isinstance(self.options, ImportanceSamplingOptions):  # as the search's rows
            design = super().rows(u, offsets, round_, stage)
        else:
            design = make_design(self._space, to_inputs(self._space, u), **{
                ROUND: (REALIZATION, np.full(n, round_, dtype=np.int64))}).assign_coords({
                    STANDARD_NORMAL: ((REALIZATION, PARAMETER), u,
                                      {"long_name": "point in standard normal space"}),
                    STAGE: (REALIZATION, np.full(n, stage, dtype=object))})
        return design.assign_coords({
            LOG_LIKELIHOOD_RATIO: (REALIZATION, ratio, {
                "long_name": "log phi(u) - log q(u) of the density the row was drawn from"})})

    def draws(self, density: GaussianMixture, size: int, round_: int, stage: str):
        """``size`` draws of ``density`` (on the moving axes) as rows of round ``round_``."""
        v = density.sample(round_generator(self._seed, round_), size)
        u = np.zeros((size, len(self._space)))
        u[:, self._axes] = v
        log_ratio = standard_normal_log_pdf(v) - density.log_pdf(v)
        return self.rows(u, np.zeros_like(u), round_, stage, log_ratio)

    def sampling_rows(self, runs, batch: int, round_: int) -> xr.Dataset:
        density = self.biasing_density(runs, self._axes, len(self._space))
        size = batch_sizes(self.options.samples, self.options.batches)[batch]
        return self.draws(density, size, round_, STAGE_SAMPLING)

    def density_rows(self, runs, round_: int) -> xr.Dataset | None:
        """The next rows that build the biasing density (None: it is built). Here: the FORM
        search, unless the design point is given."""
        if self.options.design_point is not None:
            return None
        if runs is None:
            return self.search_rows(np.zeros(len(self._space)), round_)
        search = self.replay(runs)
        following = search.next_point()
        if following is not None:
            return self.search_rows(following, round_)
        if self.options.design_point_check and search.converged and \
                not np.any(runs[STAGE].values == STAGE_CHECK):
            probes = self.probe_points(search)
            if probes.size:
                return self.rows(probes, np.zeros_like(probes), round_, STAGE_CHECK)
        return None

    def biasing_density(self, runs, axes: np.ndarray, n: int) -> GaussianMixture:
        """The defensive mixture at the design point(s) (given, or FORM's last accepted point
        and every other design point its check found, each with its share Phi(-beta_k); the
        origin if the search found none), on the moving axes."""
        points = self.design_points(runs, n)
        centres = np.array([u[axes] for u, _ in points])
        return design_point_mixture(centres, region_shares([b for _, b in points]),
                                    self.options.defensive_weight, self.options.scale)

    def design_points(self, runs, n: int) -> list[tuple[np.ndarray, float]]:
        """[(u, beta)] the draws are centred at: the given design point, or FORM's and the
        others its check found (nearest first), or the origin."""
        if self.options.design_point is not None:
            u = to_standard_normal(self._space, self.options.design_point)
            return [(u, float(np.linalg.norm(u)))]
        search = self.replay(runs) if runs is not None else None
        if search is None or search.point is None:
            return [(np.zeros(n), 0.0)]
        alpha = -search.point.gradient / np.linalg.norm(search.point.gradient)
        beta = float(alpha @ search.point.u)
        return [(search.point.u, beta)] + self.checked_points(runs, search, alpha, beta)

    def checked_points(self, runs, search, alpha, beta) -> list[tuple[np.ndarray, float]]:
        """The other design points of FORM's check round (none without one)."""
        if not np.any(runs[STAGE].values == STAGE_CHECK):
            return []
        scratch = xr.Dataset(coords={PARAMETER: runs[PARAMETER].values})
        self.add_check(scratch, runs, search, beta, alpha)
        if CHECK_DISTANCE not in scratch:
            return []
        return other_design_points(scratch[CHECK_POINT].values, scratch[CHECK_DISTANCE].values,
                                   alpha, beta)

    def extend(self, design, runs):
        round_ = int(runs[ROUND].values.max()) + 1
        stage = runs[STAGE].values
        sampling = stage == STAGE_SAMPLING
        if not sampling.any():
            more = self.density_rows(runs, round_)
            return more if more is not None else self.sampling_rows(runs, 0, round_)
        done = np.unique(runs[ROUND].values[sampling]).size
        if done >= self.options.batches:
            return None
        if self.options.target_cov is not None and \
                self.estimate(runs)[0].cov <= self.options.target_cov:
            return None
        return self.sampling_rows(runs, done, round_)

    # ------------------------------------------------------------------ the estimate
    def estimate(self, runs) -> tuple[ImportanceEstimate, int, int]:
        """The estimate from the sampling rows, the failing draws among them, and the draws
        left out (their run did not finish ok, or the limit state has no value)."""
        rows = np.flatnonzero(runs[STAGE].values == STAGE_SAMPLING)
        g = self.margins(runs)[rows]
        usable = np.isfinite(g)
        failed = g[usable] <= 0
        log_ratio = np.asarray(runs[LOG_LIKELIHOOD_RATIO].values, dtype=float)[rows][usable]
        estimate = importance_estimate(failed, log_ratio, self.options.confidence)
        return estimate, int(failed.sum()), int((~usable).sum())

    def analyze(self, design, runs):
        stage = runs[STAGE].values
        sampling = stage == STAGE_SAMPLING
        estimate, failures, left_out = self.estimate(runs)
        warnings = self.estimate_warnings(estimate, failures, left_out, int(sampling.sum()))
        names = [str(p) for p in design[PARAMETER].values]
        data = {
            FAILURE_PROBABILITY: ((LIMIT_STATE,), [estimate.probability], {
                "long_name": f"failure probability ({self.label})", UNITS: "1"}),
            FAILURE_STDERR: ((LIMIT_STATE,), [estimate.stderr], {
                "long_name": "standard error of the failure probability", UNITS: "1"}),
            FAILURE_INTERVAL: ((LIMIT_STATE, BOUND), [[estimate.low, estimate.high]], {
                "long_name": f"normal interval of the failure probability at confidence "
                             f"{self.options.confidence:g}", UNITS: "1"}),
            FAILURE_COV: ((LIMIT_STATE,), [estimate.cov], {
                "long_name": "coefficient of variation of the failure probability's "
                             "estimate", UNITS: "1"}),
            RELIABILITY_INDEX: ((LIMIT_STATE,), [reliability_index(estimate.probability)], {
                "long_name": "reliability index beta = -Phi^-1(p_f)", UNITS: "1"}),
            EFFECTIVE_SAMPLE_SIZE: ((LIMIT_STATE,), [estimate.effective_sample_size], {
                "long_name": "effective sample size (sum y)^2 / sum y^2 of the weighted "
                             "failing draws", UNITS: "1"}),
            FAILURES: ((LIMIT_STATE,), np.array([failures], dtype=np.int64), {
                "long_name": "failing draws of the biasing density"}),
            FAILURE_RUNS: ((LIMIT_STATE,), np.array([estimate.n], dtype=np.int64), {
                "long_name": "draws of the biasing density in the estimate"}),
            FAILURE_LEFT_OUT: ((LIMIT_STATE,), np.array([left_out], dtype=np.int64), {
                "long_name": "draws left out: their run did not finish ok"}),
        }
        stats = xr.Dataset(data, coords={LIMIT_STATE: [self.limit_state],
                                         BOUND: [BOUND_LOW, BOUND_HIGH], PARAMETER: names})
        warnings += self.density_statistics(stats, runs)
        self.add_biasing_components(stats, runs)
        self.add_output_means(stats, runs, sampling)
        for message in warnings:
            pywarnings.warn(message, AccuracyWarning, stacklevel=2)
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        state = self.limit_states[self.limit_state]
        done = np.asarray(runs[STATUS].values != STATUS_PENDING)
        stats.attrs.update({
            LIMIT_STATE: self.limit_state, "limit_state_output": getattr(state, "output", ""),
            "limit_state_event": state.describe(), INTERVAL_METHOD: INTERVAL_NORMAL,
            CONFIDENCE: self.options.confidence,
            FAILURE_NOTE: self.treatment_note(left_out),
            DENSITY_RUNS: int((done & ~sampling).sum()),
            SAMPLING_RUNS: int((done & sampling).sum()),
            BIASING_DENSITY: self.density_words(runs)})
        return stats

    def treatment_note(self, left_out: int) -> str:
        return (f"unbiased importance-sampling estimate mean(1[g <= 0] phi/q) over the draws "
                f"of the biasing density; normal interval p +- z s.e. at confidence "
                f"{self.options.confidence:g}; {left_out} draw(s) whose run did not finish "
                f"ok left out of the mean (neither failure nor safe; this biases p if solver "
                f"errors depend on the inputs)")

    def estimate_warnings(self, estimate, failures, left_out, draws) -> list[str]:
        warnings = []
        if left_out:
            warnings.append(f"{left_out} of {draws} draws of the biasing density did not run "
                            f"ok: left out of the estimate (n = {estimate.n}), which biases "
                            f"it if solver errors depend on the inputs")
        if estimate.reason:
            warnings.append(f"P[failure]: {estimate.reason}")
        if failures:
            ess = estimate.effective_sample_size
            if ess < DEGENERATE_SHARE * failures:
                warnings.append(
                    f"the importance weights have degenerated: effective sample size "
                    f"{ess:.3g} of {failures} failing draws; a few draws carry the estimate, "
                    f"and the biasing density misses part of the failure domain (several "
                    f"design points, or a wrong one): the estimate stays unbiased but its "
                    f"standard error and interval cannot be trusted; {self.weights_advice()}")
            elif ess < FEW_EFFECTIVE:
                warnings.append(f"effective sample size {ess:.3g} < {FEW_EFFECTIVE:g}: the "
                                f"normal interval rests on too few effective draws")
        return warnings

    def weights_advice(self) -> str:
        """What to do about degenerate weights (the other method for this one)."""
        return "use cross-entropy or more samples"

    def add_output_means(self, stats, runs, sampling) -> None:
        """Each output's importance-weighted (self-normalized) mean over the draws that ran
        ok: sum w_i y_i / sum w_i, w = phi/q, consistent for E[y] under the inputs."""
        rows = np.flatnonzero(sampling & ok_mask(runs))
        log_ratio = np.asarray(runs[LOG_LIKELIHOOD_RATIO].values, dtype=float)[rows]
        weights = np.exp(log_ratio - log_ratio.max()) if rows.size else log_ratio
        for out in output_names(runs):
            values = np.asarray(runs[out].values, dtype=float)
            mean = np.tensordot(weights / weights.sum(), values[rows], axes=1) if rows.size \
                else np.full(values.shape[1:], np.nan)
            stats[out] = xr.DataArray(np.asarray(mean)[None], dims=(STATISTIC,
                                                                    *runs[out].dims[1:]),
                                      attrs={"long_name": f"importance-weighted mean of {out}"})
        stats.coords[STATISTIC] = [STATISTIC_MEAN]
        for d in runs.coords:
            if d not in (REALIZATION, PARAMETER) and d in stats.dims:
                stats.coords[d] = runs[d]

    # ------------------------------------------------------------------ FORM beside
    def density_statistics(self, stats, runs) -> list[str]:
        """FORM's index, its p_f and the design point (physical units and u) beside the
        estimate; the search's warnings."""
        n = stats.sizes[PARAMETER]
        warnings = []
        beta, x_star, u_star = math.nan, np.full(n, np.nan), np.full(n, np.nan)
        importance = np.full(n, np.nan)
        given = self.options.design_point is not None
        search_rows = runs[STAGE].values == STAGE_SEARCH
        if given:
            centre = runs[STAGE].values == STAGE_SAMPLING
            x_star = np.array([self.options.design_point.get(p, math.nan)
                               for p in stats[PARAMETER].values])
            sampling_inputs = runs[INPUTS].values[centre]
            if sampling_inputs.size:  # inputs without a spread sit at their only value
                x_star = np.where(np.isnan(x_star), sampling_inputs[0], x_star)
        elif search_rows.any():
            search = self.replay(runs)
            if search.point is not None:
                gradient = search.point.gradient
                alpha = -gradient / np.linalg.norm(gradient)
                beta = float(alpha @ search.point.u)
                u_star = search.point.u
                importance = importance_factors(alpha, cholesky_of(np.asarray(
                    runs[INPUT_CORRELATION].values, dtype=float)))
                x_star = np.asarray(runs[INPUTS].values[self.centre_row(runs, search.point.round)],
                                    dtype=float)
                if not search.converged:
                    warnings.append(f"FORM did not converge ({search.stopped or 'stopped'}): "
                                    f"the sampling is centred at its last accepted point; the "
                                    f"estimate stays unbiased")
                # FORM's check statistics (check_point, check_margin, ...); its words are
                # FORM's advice, and here the other design points have their own Gaussians
                self.add_check(stats, runs, search, beta, alpha)
            else:
                warnings.append(f"FORM found no design point ({search.stopped}): the draws "
                                f"are centred at the inputs' medians (plain Monte Carlo)")
            failed = int((~ok_mask(runs) & search_rows).sum())
            if failed:
                warnings.append(f"{failed} run(s) of the FORM search did not finish ok: "
                                f"treated as trial points the line search rejects")
        stats[FORM_INDEX] = ((LIMIT_STATE,), [beta], {
            "long_name": "FORM reliability index alpha . u*", UNITS: "1"})
        stats[FORM_PROBABILITY] = ((LIMIT_STATE,), [float(special.ndtr(-beta))], {
            "long_name": "FORM failure probability Phi(-beta)", UNITS: "1"})
        stats[DESIGN_POINT] = ((LIMIT_STATE, PARAMETER), [x_star], {
            "long_name": "centre of the biasing density in the inputs' units"})
        stats[DESIGN_POINT_U] = ((LIMIT_STATE, PARAMETER), [u_star], {
            "long_name": "FORM design point u* in standard normal space", UNITS: "1"})
        stats[IMPORTANCE] = ((LIMIT_STATE, PARAMETER), [importance], {
            "long_name": "FORM importance factor gamma^2 (alpha^2 for independent inputs)",
            UNITS: "1"})
        if PARAMETER_UNITS in runs.coords:
            stats.coords[PARAMETER_UNITS] = (PARAMETER, runs[PARAMETER_UNITS].values)
        return warnings

    def density_words(self, runs) -> str:
        tail = f", w = {self.options.defensive_weight:g}, s = {self.options.scale:g}"
        if self.options.design_point is not None:
            return "(1 - w) N(u*, s^2 I) + w N(0, I) at the given design point" + tail
        points = self.design_points(runs, runs.sizes[PARAMETER])
        if len(points) == 1:
            return "(1 - w) N(u*, s^2 I) + w N(0, I) at FORM's design point" + tail
        shares = region_shares([b for _, b in points])
        others = "; ".join(f"u = ({', '.join(f'{v + 0.0:.3g}' for v in u)}), beta about "
                           f"{b:.3g}, share {s:.2g}" for (u, b), s in zip(points[1:],
                                                                         shares[1:]))
        return (f"(1 - w) sum_k s_k N(u_k, s^2 I) + w N(0, I) at FORM's design point (share "
                f"{shares[0]:.2g}) and {len(points) - 1} other(s) its design-point check "
                f"found ({others}); s_k proportional to Phi(-beta_k)" + tail)

    def add_biasing_components(self, stats, runs) -> None:
        """The biasing density's weights and means (standard normal space, the defensive
        standard normal last) the sampling draws came from."""
        if isinstance(self.options, ImportanceSamplingOptions) and \
                self.options.design_point is not None and getattr(self, "_space", None) is None:
            return  # a given point maps to u through the study's space (plan's)
        axes = moving_axes_of(runs)
        n = runs.sizes[PARAMETER]
        density = self.biasing_density(runs, axes, n)
        means = np.zeros((density.components, n))
        means[:, axes] = density.means
        stats[BIASING_WEIGHT] = ((BIASING_COMPONENT,), density.weights, {
            "long_name": "weight of each Gaussian of the biasing density", UNITS: "1"})
        stats[BIASING_MEAN] = ((BIASING_COMPONENT, PARAMETER), means, {
            "long_name": "mean of each Gaussian of the biasing density in standard normal "
                         "space", UNITS: "1"})

    # ------------------------------------------------------------------ report
    @classmethod
    def report(cls, view):
        """p_f, its interval, c.o.v., beta and the ESS; what built the biasing density (FORM's
        index and design point, or the cross-entropy thresholds); the runs of each stage."""
        stats = view.stats
        attrs = stats.attrs
        name = str(attrs.get(LIMIT_STATE, "?"))
        event = f" ({attrs['limit_state_event']})" if attrs.get("limit_state_event") else ""

        def first(var):
            return float(stats[var].values.ravel()[0]) if var in stats else math.nan

        low, high = (stats[FAILURE_INTERVAL].values[0] if FAILURE_INTERVAL in stats
                     else (math.nan, math.nan))
        confidence = float(attrs.get(CONFIDENCE, math.nan))
        kind = str(attrs.get(METHOD, cls.name))
        notes = [f"{kind}, limit state '{name}'{event}: p_f = {number(first(FAILURE_PROBABILITY))}"
                 f", {confidence:.0%} {attrs.get(INTERVAL_METHOD, '')} interval "
                 f"[{number(float(low))}, {number(float(high))}], c.o.v. "
                 f"{number(first(FAILURE_COV))}, beta = {number(first(RELIABILITY_INDEX))}",
                 f"effective sample size {number(first(EFFECTIVE_SAMPLE_SIZE))} of "
                 f"{int(first(FAILURES)) if FAILURES in stats else 0} failing draws among "
                 f"{int(first(FAILURE_RUNS)) if FAILURE_RUNS in stats else 0}; "
                 f"{int(first(FAILURE_LEFT_OUT)) if FAILURE_LEFT_OUT in stats else 0} left out "
                 f"(run not ok)",
                 f"biasing density: {attrs.get(BIASING_DENSITY, '')}",
                 f"solver runs: {int(attrs.get(DENSITY_RUNS, 0))} building the density, "
                 f"{int(attrs.get(SAMPLING_RUNS, 0))} sampling it"]
        if FORM_INDEX in stats and np.isfinite(first(FORM_INDEX)):
            notes.append(f"FORM beside it: beta = {number(first(FORM_INDEX))}, p_f = "
                         f"{number(first(FORM_PROBABILITY))}")
        if DESIGN_POINT in stats and np.any(np.isfinite(stats[DESIGN_POINT].values)):
            units = [str(u) for u in stats[PARAMETER_UNITS].values] \
                if PARAMETER_UNITS in stats.coords else [""] * stats.sizes[PARAMETER]
            notes.append("design point: " + ", ".join(
                f"{p} = {number(v)}{(' ' + u) if u else ''}" for p, v, u in zip(
                    stats[PARAMETER].values, stats[DESIGN_POINT].values[0], units)))
        if CE_THRESHOLD in stats:
            reached = bool(int(attrs.get(THRESHOLD_REACHED, 0)))
            notes.append("cross-entropy thresholds: " + ", ".join(
                number(t) for t in stats[CE_THRESHOLD].values)
                + ("" if reached else " (did NOT reach 0)"))
        runs = int(attrs.get(SOLVER_RUNS, 0))
        output = str(attrs.get("limit_state_output", ""))

        def importance(out):
            if IMPORTANCE not in stats or not np.any(np.isfinite(stats[IMPORTANCE].values)) \
                    or (output and out != output):
                return None
            values = stats[IMPORTANCE].isel({LIMIT_STATE: 0}).expand_dims(
                {"index": ["importance factor alpha²"]}, axis=1)
            return Sensitivity(title=f"FORM importance factors of '{name}' (the design point "
                                     f"{kind} is centred at)", values=values,
                               quantity="share of beta² (sums to 1)")

        return MethodReport(
            description=f"{kind} of limit state '{name}', {runs} run{'' if runs == 1 else 's'}",
            notes=notes, sensitivities=importance)


@register_method("cross-entropy")
class CrossEntropy(ImportanceSampling):
    """Adaptive importance sampling by the cross-entropy method in standard normal space: the
    improved rule's smoothed targets (default) or the classic quantile thresholds, fitting a
    mixture of Gaussians or a von Mises-Fisher-Nakagami density round by round."""

    Options: ClassVar = CrossEntropyOptions
    label: ClassVar[str] = "cross-entropy importance sampling"

    def systems_allowed(self) -> bool:
        return True

    def check(self, space, fields):
        PropagationMethod.check(self, space, fields)
        axes = moving_axes(space.stds, cholesky_of(space.correlation)).size
        if self.options.family == "vmfn" and axes < 2:
            raise StudyError(f'family = "vmfn" needs at least 2 inputs with a spread (a '
                             f"direction on a sphere), the study has {axes}",
                             key="method.family")

    def check_solver(self, solver, outputs, parameter_names) -> None:
        """Any solver: the draws need no derivatives."""

    def density_rows(self, runs, round_: int) -> xr.Dataset | None:
        m = self._axes.size
        state = self.adapt(runs, self._axes) if runs is not None else \
            CrossEntropyState(standard_normal_start(m))
        if state.reached or state.stopped or state.rounds >= self.options.max_rounds:
            return None
        return self.draws(state.density, self.options.samples, round_, STAGE_CROSS_ENTROPY)

    def draws(self, density, size: int, round_: int, stage: str):
        """``size`` draws of ``density`` (either family, on the moving axes) as rows."""
        v = density.sample(round_generator(self._seed, round_), size)
        u = np.zeros((size, len(self._space)))
        u[:, self._axes] = v
        return self.rows(u, np.zeros_like(u), round_, stage, log_likelihood_ratio(density, v))

    def biasing_density(self, runs, axes, n):
        return self.adapt(runs, axes).density

    def fit(self, u, log_weights, family: str):
        """The rule's weighted maximum-likelihood fit in the family."""
        if family == "vmfn":
            return fit_von_mises_fisher_nakagami(u, log_weights)
        return fit_gaussian_mixture(u, log_weights, self.options.mixture_components,
                                    covariance=self.options.covariance)

    def adapt(self, runs, axes) -> CrossEntropyState:
        """The rounds replayed in order (the next round's density a pure function of the
        rounds before it). Quantile rule: round k's threshold is the rho-quantile of its g
        (clipped at 0), its elites the draws at or below it, the fit weighted by their phi/q_k.
        Improved rule: round k stops the adaptation if the c.o.v. of 1[g <= 0] / Phi(-g/s_k)
        is at most smoothing_cov (the final draws come from q_k); else s_(k+1) < s_k makes the
        c.o.v. of Phi(-g/s_(k+1)) / Phi(-g/s_k) smoothing_cov and every draw of the round
        enters the fit with the weight Phi(-g/s_(k+1)) phi/q_k."""
        state = CrossEntropyState(standard_normal_start(axes.size))
        if runs is None:
            return state
        g = self.margins(runs)
        rounds = runs[ROUND].values
        stage = runs[STAGE].values
        log_ratio = np.asarray(runs[LOG_LIKELIHOOD_RATIO].values, dtype=float)
        u = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)
        # the same runs replay to the same state: computed once (plan, extend, analyze and
        # the report's words each ask), keyed on everything the replay reads
        key = hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in (
            axes, g, rounds, stage == STAGE_CROSS_ENTROPY, log_ratio, u))).hexdigest()
        cached = getattr(self, "_adapted", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        state = self.replay_rounds(state, g, rounds, stage, log_ratio, u, axes)
        self._adapted = (key, state)
        return state

    def replay_rounds(self, state, g, rounds, stage, log_ratio, u, axes) -> CrossEntropyState:
        """``adapt``'s rounds, in order."""
        family = self.options.family_for(axes.size)
        sharpness = 0.0
        for r in np.unique(rounds[stage == STAGE_CROSS_ENTROPY]):
            rows = np.flatnonzero((rounds == r) & (stage == STAGE_CROSS_ENTROPY))
            if not np.isfinite(g[rows]).any():
                state.stopped = f"no run of cross-entropy round {state.rounds} ran ok"
                break
            if self.options.rule == "quantile":
                self.quantile_round(state, u[np.ix_(rows, axes)], g[rows], log_ratio[rows],
                                    family)
            else:
                usable = rows[np.isfinite(g[rows])]
                stop = stopping_cov(g[usable], sharpness)
                state.stop_covs.append(stop)
                if stop <= self.options.smoothing_cov:
                    state.smoothing.append(math.nan)
                    state.reached = True
                    break
                sharpness = smoothing_sharpness(g[usable], sharpness,
                                                self.options.smoothing_cov)
                state.smoothing.append(1.0 / sharpness)
                log_weights = log_smoothed_indicator(g[usable], sharpness) + log_ratio[usable]
                if not np.isfinite(log_weights).any():  # s = 0 and no failing draw
                    state.stopped = (f"no draw of cross-entropy round {state.rounds - 1} "
                                     f"carries weight (no failure, and the indicator itself "
                                     f"is the next target)")
                    break
                state.effective.append(effective_count(log_weights))
                state.density = self.fit(u[np.ix_(usable, axes)], log_weights, family)
                state.fitted.append(family)
            if state.reached:
                break
        return state

    def quantile_round(self, state, u, g, log_ratio, family) -> None:
        """One round of the classic rule: its threshold, elites and fit."""
        if family == "gaussian" and self.options.mixture_components == 1:
            threshold, elites, state.density = cross_entropy_step(
                u, g, log_ratio, self.options.rho, covariance=self.options.covariance)
            kind = self.options.covariance if self.options.covariance != "auto" else \
                "full" if full_covariance_pays(elites, u.shape[1]) else "identity"
        else:
            usable = np.isfinite(g)
            threshold = max(float(np.quantile(g[usable], self.options.rho)), 0.0)
            elite = usable & (g <= threshold)
            elites = int(elite.sum())
            state.density = self.fit(u[elite], log_ratio[elite], family)
            kind = family
        elite = np.isfinite(g) & (g <= threshold)
        state.thresholds.append(threshold)
        state.elites.append(elites)
        state.effective.append(effective_count(log_ratio[elite]))
        state.fitted.append(kind)
        state.reached = threshold == 0.0

    def density_statistics(self, stats, runs) -> list[str]:
        axes = moving_axes_of(runs)
        state = self.adapt(runs, axes)
        improved = self.options.rule == "improved"
        warnings = []
        if state.stopped:
            warnings.append(f"cross-entropy stopped: {state.stopped}")
        if not state.reached:
            last = (f", last stopping c.o.v. {state.stop_covs[-1]:.4g} against "
                    f"{self.options.smoothing_cov:g}" if improved and state.stop_covs else
                    f", last threshold {state.thresholds[-1]:.4g}" if state.thresholds
                    else "")
            goal = "its stopping c.o.v. did not fall to smoothing_cov" if improved else \
                "the cross-entropy threshold did not reach 0"
            warnings.append(
                f"{goal} in {state.rounds} round(s) (max_rounds = {self.options.max_rounds}"
                + last + "): the final draws come from the last density; the estimate stays "
                         "unbiased, but its variance may be large and underestimated")
        d = axes.size
        family = self.options.family_for(d)
        if state.effective and state.effective[-1] < d:
            centre = "mean" if family == "gaussian" else "mean direction"
            warnings.append(
                f"the last cross-entropy fit rests on {state.effective[-1]:.3g} effective "
                f"{'draws' if improved else 'elite draws'} for {d} dimensions: its {centre} "
                f"is off by about sqrt(d / n) = {math.sqrt(d / state.effective[-1]):.2g} "
                f"(standard normal units, or radians), which can inflate the weights' "
                f"second moment by about e^(d / n); the estimate stays unbiased but is "
                f"likely below p_f and its c.o.v. underestimated; use more samples a round "
                f"or importance-sampling at FORM's design point")
        stats.coords[CE_ROUND] = np.arange(state.rounds)
        if improved:
            stats[CE_SMOOTHING] = ((CE_ROUND,), np.asarray(state.smoothing, dtype=float), {
                "long_name": "smoothing parameter s of the target Phi(-g/s) phi fitted after "
                             "each round (NaN: the round met the stop)", UNITS: "1"})
            stats[CE_STOP_COV] = ((CE_ROUND,), np.asarray(state.stop_covs, dtype=float), {
                "long_name": "c.o.v. of 1[g <= 0] / Phi(-g/s) over each round's draws",
                UNITS: "1"})
        else:
            stats[CE_THRESHOLD] = ((CE_ROUND,), np.asarray(state.thresholds, dtype=float), {
                "long_name": "intermediate threshold of g of each cross-entropy round"})
            stats[CE_ELITES] = ((CE_ROUND,), np.asarray(state.elites, dtype=np.int64), {
                "long_name": "elite draws (g at or below the threshold) of each round"})
        stats.attrs[THRESHOLD_REACHED] = int(state.reached)
        stats.attrs[CE_RULE] = self.options.rule
        stats.attrs[CE_FAMILY] = family
        failed = int((~ok_mask(runs) & (runs[STAGE].values == STAGE_CROSS_ENTROPY)).sum())
        if failed:
            warnings.append(f"{failed} run(s) of the cross-entropy rounds did not finish ok: "
                            f"left out of their fit")
        return warnings

    def add_biasing_components(self, stats, runs) -> None:
        """A Gaussian mixture's weights and means (as importance-sampling's), or the vMFN's
        mean direction, concentration and Nakagami parameters."""
        axes = moving_axes_of(runs)
        density = self.biasing_density(runs, axes, runs.sizes[PARAMETER])
        if isinstance(density, GaussianMixture):
            return super().add_biasing_components(stats, runs)
        direction = np.zeros(runs.sizes[PARAMETER])
        direction[axes] = density.mean_direction
        stats[VMF_DIRECTION] = ((PARAMETER,), direction, {
            "long_name": "mean direction of the von Mises-Fisher part of the biasing density "
                         "in standard normal space", UNITS: "1"})
        stats.attrs.update({VMF_KAPPA: float(density.kappa), NAKAGAMI_M: float(density.m),
                            NAKAGAMI_OMEGA: float(density.omega)})

    def density_words(self, runs) -> str:
        axes = moving_axes_of(runs)
        state = self.adapt(runs, axes)
        if self.options.rule == "improved":
            how = (f"improved cross-entropy (smoothed targets Phi(-g/s) phi, smoothing_cov = "
                   f"{self.options.smoothing_cov:g})")
        else:
            how = f"cross-entropy (rho = {self.options.rho:g})"
        how += f", {self.options.samples} draws a round"
        density = state.density
        if isinstance(density, VonMisesFisherNakagami):
            return (f"von Mises-Fisher direction (kappa = {density.kappa:.4g}) times a "
                    f"Nakagami radius (m = {density.m:.4g}, Omega = {density.omega:.4g}) in "
                    f"standard normal space, fitted by {how}")
        kinds = [k for k in state.fitted if k in ("full", "diagonal", "identity")]
        if density.components == 1 and kinds:
            words = {"full": "a full covariance", "diagonal": "a diagonal covariance",
                     "identity": "the identity covariance (mean shift)"}[kinds[-1]]
            return (f"one Gaussian with {words} in standard normal space, fitted by {how}, "
                    f"covariance = {self.options.covariance}")
        return (f"a mixture of {density.components} Gaussian(s) in standard normal space "
                f"(covariance = {self.options.covariance}), fitted by {how}")

    def weights_advice(self) -> str:
        return ("use more samples a round, or importance-sampling at FORM's design point if "
                "there is one")

    @classmethod
    def report(cls, view):
        """importance-sampling's lines, and the improved rule's smoothing parameters."""
        out = super().report(view)
        stats = view.stats
        if CE_SMOOTHING in stats:
            reached = bool(int(stats.attrs.get(THRESHOLD_REACHED, 0)))
            out.notes.append(
                "cross-entropy smoothing s per round: " + ", ".join(
                    number(s) if np.isfinite(s) else "stop" for s in stats[CE_SMOOTHING].values)
                + "; stopping c.o.v.: " + ", ".join(number(c) for c in stats[CE_STOP_COV].values)
                + ("" if reached else " (did NOT meet the stop)"))
        return out
