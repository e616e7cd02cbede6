"""Importance sampling and the cross-entropy method against exact failure probabilities.

The reusable pieces (GaussianMixture, defensive_mixture, cross_entropy_fit,
importance_estimate) are checked in numpy alone, where repetitions are cheap: against closed
forms, and statistically against P[failure] known exactly (a linear limit state in standard
normals, p = Phi(-beta); the four-branch series system, p from a one-dimensional integral).
Statistical tolerances are a number of standard errors, with the seed fixed so every test is
deterministic.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate
from scipy import stats as sps

from uqflow.methods.importance_sampling import (COVARIANCE_FLOOR, GaussianMixture,
                                                ImportanceEstimate, cross_entropy_fit,
                                                defensive_mixture, importance_estimate,
                                                standard_normal_log_pdf)

# 4 standard errors: a normal deviate beyond them 1 time in 16,000
SE4 = 4.0


def four_branch_margin(u, k=6.0):
    """The four-branch series system (Waarts 2000; Au & Beck): the smallest of
    3 + (u1 - u2)^2/10 -+ (u1 + u2)/sqrt 2 and +-(u1 - u2) + k/sqrt 2."""
    u1, u2 = u[:, 0], u[:, 1]
    s, d = (u1 + u2) / math.sqrt(2), u1 - u2
    return np.minimum.reduce([3 + d**2 / 10 - s, 3 + d**2 / 10 + s,
                              d + k / math.sqrt(2), -d + k / math.sqrt(2)])


def four_branch_exact(k=6.0):
    """In a = (u1 + u2)/sqrt 2, b = (u1 - u2)/sqrt 2 (independent standard normals) the
    safe set is |a| < 3 + b^2/5, |b| < k/2: P[safe] is a one-dimensional integral."""
    safe = integrate.quad(lambda b: sps.norm.pdf(b) * (1 - 2 * sps.norm.sf(3 + b * b / 5)),
                          -k / 2, k / 2, epsabs=0, epsrel=1e-13)[0]
    return 1.0 - safe


def test_four_branch_reference_is_the_literature_value():
    # Waarts (2000) and Au & Beck (2001) give 4.46e-3 (k = 6) and 2.22e-3 (k = 7), rounded
    assert four_branch_exact(6.0) == pytest.approx(4.46e-3, abs=0.005e-3)
    assert four_branch_exact(7.0) == pytest.approx(2.22e-3, abs=0.005e-3)


# ----------------------------------------------------------------------------- the mixture

def two_components():
    return GaussianMixture([0.3, 0.7], [[1.0, -2.0, 0.5], [0.0, 0.0, 0.0]],
                           [[[2.0, 0.3, 0.0], [0.3, 1.0, -0.2], [0.0, -0.2, 0.5]],
                            np.eye(3) * 0.25])


def test_log_pdf_is_the_weighted_sum_of_normal_densities():
    mixture = two_components()
    u = np.random.default_rng(3).normal(size=(50, 3)) * 2
    expected = np.log(0.3 * sps.multivariate_normal(mixture.means[0],
                                                    mixture.covariances[0]).pdf(u)
                      + 0.7 * sps.multivariate_normal(mixture.means[1],
                                                      mixture.covariances[1]).pdf(u))
    # both sides are sums of a few terms of order 10 rounded to eps: 1e-12 relative covers
    # them with the condition number (< 10) of the covariances
    assert np.allclose(mixture.log_pdf(u), expected, rtol=1e-12, atol=1e-12)
    assert np.allclose(standard_normal_log_pdf(u),
                       sps.multivariate_normal(np.zeros(3)).logpdf(u), rtol=1e-12)


def test_sample_has_the_mixtures_moments_and_repeats_under_its_seed():
    mixture = two_components()
    n = 20_000
    u = mixture.sample(np.random.default_rng(11), n)
    assert u.shape == (n, 3)
    assert np.array_equal(u, mixture.sample(np.random.default_rng(11), n))
    mean = mixture.weights @ mixture.means
    spread = sum(w * (c + np.outer(m - mean, m - mean)) for w, m, c in
                 zip(mixture.weights, mixture.means, mixture.covariances))
    # the sample mean is within 4 standard errors sqrt(diag(Cov) / n) of the mixture's mean
    assert np.all(np.abs(u.mean(axis=0) - mean) < SE4 * np.sqrt(np.diag(spread) / n))


def test_a_mixture_refuses_what_is_no_density():
    with pytest.raises(ValueError, match="positive definite"):
        GaussianMixture([1.0], [[0.0, 0.0]], [[[1.0, 2.0], [2.0, 1.0]]])
    with pytest.raises(ValueError, match="weights must be >= 0"):
        GaussianMixture([-0.5, 1.5], [[0.0], [1.0]], [[[1.0]], [[1.0]]])
    with pytest.raises(ValueError, match="dimension"):
        GaussianMixture([1.0], [[0.0]], [[[1.0]]]).log_pdf(np.zeros((2, 2)))


def test_defensive_mixture_bounds_every_weight_by_one_over_w():
    centre = np.array([2.0, -1.0, 0.5])
    mixture = defensive_mixture(centre, 0.1, 1.5)
    assert np.allclose(mixture.weights, [0.9, 0.1]) and np.array_equal(mixture.means[0], centre)
    assert np.array_equal(mixture.covariances[0], 2.25 * np.eye(3))
    assert np.array_equal(mixture.covariances[1], np.eye(3))
    u = np.random.default_rng(5).normal(size=(1000, 3)) * 3
    log_ratio = standard_normal_log_pdf(u) - mixture.log_pdf(u)
    # phi / q <= 1 / w, up to the rounding of two log densities (~1e-15 each)
    assert np.max(log_ratio) <= -math.log(0.1) + 1e-12
    assert defensive_mixture(centre, 0.0).components == 1
    with pytest.raises(ValueError, match="defensive_weight"):
        defensive_mixture(centre, 1.5)
    with pytest.raises(ValueError, match="scale"):
        defensive_mixture(centre, 0.1, 0.0)


# ----------------------------------------------------------------------------- the CE fit

def test_cross_entropy_fit_is_the_weighted_mean_and_covariance():
    rng = np.random.default_rng(2)
    u, log_w = rng.normal(size=(40, 2)), rng.normal(size=40)
    fitted = cross_entropy_fit(u, log_w)
    w = np.exp(log_w) / np.exp(log_w).sum()
    mean = w @ u
    cov = sum(wi * np.outer(ui - mean, ui - mean) for wi, ui in zip(w, u))
    # sums of 40 terms of order 1: rounding of order 40 eps
    assert np.allclose(fitted.means[0], mean, rtol=0, atol=1e-12)
    assert np.allclose(fitted.covariances[0], cov, rtol=0, atol=1e-12)


def test_cross_entropy_fit_recovers_a_target_through_its_likelihood_ratios():
    # draws of phi weighted by N(m, C)/phi: the self-normalized fit is N(m, C) up to the
    # sampling error (a few hundredths with 20,000 draws, whose weights have an effective
    # size of a few thousand); without the ratios it would be phi's own N(0, I)
    m, c = np.array([1.5, -0.5]), np.array([[0.5, 0.2], [0.2, 0.8]])
    u = np.random.default_rng(8).normal(size=(20_000, 2))
    log_w = sps.multivariate_normal(m, c).logpdf(u) - standard_normal_log_pdf(u)
    fitted = cross_entropy_fit(u, log_w)
    assert np.allclose(fitted.means[0], m, atol=0.05)
    assert np.allclose(fitted.covariances[0], c, atol=0.05)


def test_cross_entropy_fit_floors_a_singular_covariance():
    u = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])  # on a line: rank one
    fitted = cross_entropy_fit(u, np.zeros(3))
    values = np.linalg.eigvalsh(fitted.covariances[0])
    # the floor is set exactly, the other eigenvalue (4/3) keeps eps-level rounding
    assert values[0] == pytest.approx(COVARIANCE_FLOOR, rel=1e-12)
    assert values[1] == pytest.approx(4.0 / 3.0, rel=1e-12)
    one = cross_entropy_fit(u[:1], np.zeros(1))  # a single elite: the floor in every direction
    assert np.allclose(one.covariances[0], COVARIANCE_FLOOR * np.eye(2), rtol=1e-12)
    with pytest.raises(ValueError, match="one log weight per point"):
        cross_entropy_fit(u, np.zeros(2))


# ----------------------------------------------------------------------------- the estimator

def test_estimate_without_weights_is_the_plain_fraction():
    failed = np.zeros(50, dtype=bool)
    failed[:7] = True
    estimate = importance_estimate(failed, np.zeros(50), 0.95)
    assert isinstance(estimate, ImportanceEstimate)
    p = 7 / 50
    # a mean of 50 zeros and ones: one rounding of the division
    assert estimate.probability == pytest.approx(p, rel=1e-15)
    # the sample standard deviation of 0/1 terms: sqrt(k (n - k) / (n (n - 1)))
    # 1e-14: a few roundings of a square root and a division
    assert estimate.stderr == pytest.approx(math.sqrt(7 * 43 / (50 * 49)) / math.sqrt(50),
                                            rel=1e-14)
    assert estimate.effective_sample_size == pytest.approx(7.0, rel=1e-14)
    z = sps.norm.ppf(0.975)
    # the same few roundings on both sides (p - z s.e., s.e. / p): 1e-14 relative
    assert estimate.low == pytest.approx(p - z * estimate.stderr, rel=1e-14)
    assert estimate.cov == pytest.approx(estimate.stderr / p, rel=1e-14)
    none = importance_estimate(np.zeros(5, bool), np.zeros(5), 0.95)
    assert none.probability == 0 and math.isinf(none.cov) and math.isnan(none.high)
    assert "no failure" in none.reason
    empty = importance_estimate(np.zeros(0, bool), np.zeros(0), 0.95)
    assert math.isnan(empty.probability) and empty.n == 0


def linear_draws(rng, n, beta, d=2, weight=0.1, drop_ratio=False):
    """IS draws for g = beta - alpha . u with the defensive mixture at the design point."""
    alpha = np.ones(d) / math.sqrt(d)
    mixture = defensive_mixture(beta * alpha, weight)
    u = mixture.sample(rng, n)
    failed = beta - u @ alpha <= 0
    log_ratio = np.zeros(n) if drop_ratio else standard_normal_log_pdf(u) - mixture.log_pdf(u)
    return failed, log_ratio


@pytest.mark.parametrize("drop_ratio", [False, True])
def test_estimate_of_a_linear_limit_state_is_exact_within_its_standard_error(drop_ratio):
    beta = 3.5
    failed, log_ratio = linear_draws(np.random.default_rng(21), 2000, beta,
                                     drop_ratio=drop_ratio)
    estimate = importance_estimate(failed, log_ratio)
    exact = sps.norm.sf(beta)
    within = abs(estimate.probability - exact) <= SE4 * estimate.stderr
    # the perturbed estimator (weights phi/q dropped) counts the biased draws' failures
    assert within != drop_ratio
    if not drop_ratio:
        assert estimate.cov < 0.05


def test_interval_coverage_and_reported_cov_match_repetitions():
    beta, reps, n = 3.0, 400, 500
    rng = np.random.default_rng(1234)
    exact = sps.norm.sf(beta)
    estimates = [importance_estimate(*linear_draws(rng, n, beta, d=3)) for _ in range(reps)]
    covered = sum(e.low <= exact <= e.high for e in estimates)
    # coverage of the 95 % intervals: binomial(400, 0.95), sd 4.4: within 4 of its sd
    assert abs(covered - 0.95 * reps) <= SE4 * math.sqrt(reps * 0.95 * 0.05)
    values = np.array([e.probability for e in estimates])
    spread_cov = values.std(ddof=1) / values.mean()
    reported = np.mean([e.cov for e in estimates])
    # the spread's relative sampling error over 400 near-normal repetitions is
    # 1/sqrt(2 x 399) = 3.5 %: 15 % is more than 4 of them
    assert reported == pytest.approx(spread_cov, rel=0.15)


def test_defensive_mixture_at_one_branch_of_four_stays_unbiased():
    # FORM's design point of the first branch (a = 3, b = 0): the three other branches are
    # reached only by the defensive share, whose weights phi/q near 1/w = 10 make the terms
    # heavy-tailed; the estimate is still unbiased. 200 repetitions of 2,000 draws, pooled:
    # their mean within 4 of its standard errors of the exact value.
    centre = np.array([3.0, 3.0]) / math.sqrt(2)
    mixture = defensive_mixture(centre, 0.1)
    exact, reps, n = four_branch_exact(6.0), 200, 2000
    u = mixture.sample(np.random.default_rng(77), reps * n)
    failed = four_branch_margin(u) <= 0
    log_ratio = standard_normal_log_pdf(u) - mixture.log_pdf(u)
    pooled = importance_estimate(failed, log_ratio)
    assert abs(pooled.probability - exact) <= SE4 * pooled.stderr
    # per repetition the weights degenerate (ESS below 10 % of the failing draws) in most:
    # a draw of the defensive share in another branch outweighs hundreds near the centre
    terms = np.where(failed, np.exp(log_ratio), 0.0).reshape(reps, n)
    ess = terms.sum(axis=1) ** 2 / np.sum(terms**2, axis=1)
    assert np.mean(ess < 0.1 * failed.reshape(reps, n).sum(axis=1)) > 0.5
    # while the draws of the first branch alone (the defensive share's hits elsewhere
    # dropped) underestimate p_f: the other branches are most of it
    first = failed & (u @ np.ones(2) / math.sqrt(2) > 0) & (np.abs(u[:, 0] - u[:, 1]) <
                                                           6 / math.sqrt(2))
    assert importance_estimate(first, log_ratio).high < exact
