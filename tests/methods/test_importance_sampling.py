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
import warnings

import numpy as np
import pytest
import xarray as xr
from scipy import stats as sps

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.execute import run_study
from uqflow.function_solver import solver_from_function
from uqflow.layout import (BIASING_MEAN, BIASING_WEIGHT, CE_THRESHOLD, EFFECTIVE_SAMPLE_SIZE, FAILURE_COV, FAILURE_INTERVAL,
                           FAILURE_LEFT_OUT, FAILURE_PROBABILITY, FAILURE_RUNS, FAILURE_STDERR,
                           FAILURES, INPUTS, LOG_LIKELIHOOD_RATIO, RELIABILITY_INDEX, ROUND,
                           STATUS, STATUS_FAILED)
from uqflow.methods import get_method
from uqflow.methods.form import (DESIGN_POINT, FORM_INDEX, IMPORTANCE, STAGE, STAGE_CHECK,
                                 STAGE_SEARCH)
from uqflow.methods.importance_sampling import (COVARIANCE_FLOOR, DEGENERATE_SHARE,
                                                STAGE_SAMPLING, CrossEntropy,
                                                GaussianMixture, ImportanceEstimate,
                                                ImportanceSampling, cross_entropy_fit,
                                                cross_entropy_step, defensive_mixture,
                                                full_covariance_pays,
                                                importance_estimate, standard_normal_log_pdf)
from uqflow.report import open_result, summary_table
from uqflow.solver import register_solver
from uqflow.study import load_study

from reliability_helpers import (assert_rounds_replay, four_branch_exact, four_branch_margin,
                                 run_warned, study_file)

# 4 standard errors: a normal deviate beyond them 1 time in 16,000
SE4 = 4.0


def test_four_branch_reference_is_the_literature_value():
    # Waarts (2000) and Au & Beck (2001) give 4.46e-3 (k = 6) and 2.22e-3 (k = 7), rounded
    assert four_branch_exact(6.0) == pytest.approx(4.46e-3, abs=0.005e-3)
    assert four_branch_exact(7.0) == pytest.approx(2.22e-3, abs=0.005e-3)
    # the value docs/importance_sampling.md quotes (the integral is good to ~1e-13)
    assert four_branch_exact(6.0) == pytest.approx(4.457e-3, abs=0.0005e-3)


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
    # (atol=0: allclose's default 1e-8 would be the real tolerance)
    assert np.allclose(standard_normal_log_pdf(u),
                       # bound: a sum of 3 squares and a log, a few eps: 1e-12 relative
                       sps.multivariate_normal(np.zeros(3)).logpdf(u), rtol=1e-12, atol=0)


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
    # phi / q <= 1 / w, up to the rounding of two log densities (a few eps of their size,
    # |u|^2 / 2 < 100 here: 1e-13 each)
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
    # size of a few thousand); without the ratios it would be phi's own N(0, I). C's
    # eigenvalues (0.65, 0.85) are above the floor.
    m, c = np.array([1.0, -0.5]), np.array([[0.8, 0.1], [0.1, 0.7]])
    u = np.random.default_rng(8).normal(size=(20_000, 2))
    log_w = sps.multivariate_normal(m, c).logpdf(u) - standard_normal_log_pdf(u)
    fitted = cross_entropy_fit(u, log_w)
    assert np.allclose(fitted.means[0], m, atol=0.05)
    assert np.allclose(fitted.covariances[0], c, atol=0.05)


def test_cross_entropy_fit_floors_a_singular_covariance():
    u = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])  # on a line: rank one
    fitted = cross_entropy_fit(u, np.zeros(3))
    values = np.linalg.eigvalsh(fitted.covariances[0])
    # the floor is set exactly; V diag V^T and eigvalsh each err by about n eps |C| (LAPACK's
    # backward error: 2 x 2.2e-16 x 4/3 = 6e-16) absolute: 1e-14 is 16 of them
    assert values[0] == pytest.approx(COVARIANCE_FLOOR, rel=0, abs=1e-14)
    # bound: LAPACK's n eps |C| = 6e-16 absolute (above): 1e-14
    assert values[1] == pytest.approx(4.0 / 3.0, rel=0, abs=1e-14)
    assert np.linalg.eigvalsh(cross_entropy_fit(u, np.zeros(3), floor=1e-3).covariances[0])[
        0] == pytest.approx(1e-3, rel=0, abs=1e-14)  # the floor given; rounding as above
    one = cross_entropy_fit(u[:1], np.zeros(1))  # a single elite: the floor in every direction
    # V floor V^T of a zero fit: a few eps of the floor, off the diagonal too
    assert np.allclose(one.covariances[0], COVARIANCE_FLOOR * np.eye(2), rtol=0,
                       atol=8 * np.finfo(float).eps * COVARIANCE_FLOOR)
    with pytest.raises(ValueError, match="one log weight per point"):
        cross_entropy_fit(u, np.zeros(2))


# ----------------------------------------------------------------------------- the estimator

def test_estimate_without_weights_is_the_plain_fraction():
    failed = np.zeros(50, dtype=bool)
    failed[:7] = True
    estimate = importance_estimate(failed, np.zeros(50), 0.95)
    assert isinstance(estimate, ImportanceEstimate)
    p = 7 / 50
    # a mean of 50 zeros and ones (weights exp(0) = 1 exactly, C99 Annex F): one rounding of
    # the division (abs=0 here and below: approx's default 1e-12 is 1e-11 of these values)
    assert estimate.probability == pytest.approx(p, rel=1e-15, abs=0)
    # the sample standard deviation of 0/1 terms: sqrt(k (n - k) / (n (n - 1)))
    # 1e-14: a few roundings of a square root and a division
    assert estimate.stderr == pytest.approx(math.sqrt(7 * 43 / (50 * 49)) / math.sqrt(50),
        # bound: one square root of exact integers' ratio, a few eps: 1e-14
                                            rel=1e-14, abs=0)
    # (sum w)^2 / sum w^2 = 49 / 7 of exact sums: one rounding
    assert estimate.effective_sample_size == pytest.approx(7.0, rel=1e-14, abs=0)
    z = sps.norm.ppf(0.975)
    # the same few roundings on both sides (p - z s.e., s.e. / p): 1e-14 relative
    assert estimate.low == pytest.approx(p - z * estimate.stderr, rel=1e-14, abs=0)
    # bound: one division, a few eps: 1e-14
    assert estimate.cov == pytest.approx(estimate.stderr / p, rel=1e-14, abs=0)
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


def ideal_ess_share(beta):
    """ESS / failing draws of N(beta alpha, I) on g = beta - alpha.u, in the limit of many
    draws: E_q[y]^2 / (E_q[y^2] P_q[g <= 0]) = Phi(-beta)^2 / (e^(beta^2) Phi(-2 beta) / 2)."""
    return math.exp(2 * sps.norm.logsf(beta) - beta**2 - sps.norm.logsf(2 * beta) + math.log(2))


def test_effective_sample_size_of_a_linear_limit_state_at_its_design_point():
    # the closed form the page and DEGENERATE_SHARE quote: 0.31 at 4.75, above 0.1 up to 15
    assert ideal_ess_share(4.75) == pytest.approx(0.313, abs=0.0005)
    assert ideal_ess_share(15.0) > 0.1 > ideal_ess_share(16.0)
    assert ideal_ess_share(40.0) * 40.0 == pytest.approx(2 * math.sqrt(2 / math.pi), rel=0.01)
    # and the estimator's ESS from 20,000 draws (about 10,000 failing, a share estimated
    # within a few per cent)
    failed, log_ratio = linear_draws(np.random.default_rng(9), 20_000, 4.75, weight=0.0)
    estimate = importance_estimate(failed, log_ratio)
    share = estimate.effective_sample_size / failed.sum()
    assert share == pytest.approx(ideal_ess_share(4.75), rel=0.1)
    assert share > DEGENERATE_SHARE


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


def test_cross_entropy_rounds_reach_a_linear_limit_state_in_ten_dimensions():
    # the CE iteration of the method (cross_entropy_step) on g = 4.75 - a.u in 10 standard
    # normals, 1,000 draws a round: the threshold reaches 0 in a few rounds and the final
    # estimate is within 4 of its standard errors of Phi(-4.75). With the covariance floor
    # at 0.01 instead of 0.6 the fits collapse along a (an estimate of infinite variance) and
    # this fails.
    d, beta = 10, 4.75
    a = np.ones(d) / math.sqrt(d)
    rng = np.random.default_rng(4)
    density = GaussianMixture([1.0], np.zeros((1, d)), np.eye(d)[None])
    thresholds = []
    for _ in range(10):
        u = density.sample(rng, 1000)
        log_ratio = standard_normal_log_pdf(u) - density.log_pdf(u)
        threshold, elites, density = cross_entropy_step(u, beta - u @ a, log_ratio, 0.1,
                                                        covariance="full")
        thresholds.append(threshold)
        if threshold == 0:
            break
    assert thresholds[-1] == 0 and len(thresholds) <= 6 and elites >= 100
    u = density.sample(rng, 1000)
    estimate = importance_estimate(beta - u @ a <= 0,
                                   standard_normal_log_pdf(u) - density.log_pdf(u))
    assert abs(estimate.probability - sps.norm.sf(beta)) <= SE4 * estimate.stderr
    assert estimate.cov < 0.2


def cross_entropy_estimate(margin, d, n, rng, rho=0.1, max_rounds=10, covariance="auto"):
    """The cross-entropy method as the study runs it, in numpy: rounds of n draws until the
    threshold reaches 0, then n draws of the last Gaussian for the estimate."""
    density = GaussianMixture([1.0], np.zeros((1, d)), np.eye(d)[None])
    for _ in range(max_rounds):
        u = density.sample(rng, n)
        log_ratio = standard_normal_log_pdf(u) - density.log_pdf(u)
        threshold, _, density = cross_entropy_step(u, margin(u), log_ratio, rho,
                                                   covariance=covariance)
        if threshold == 0:
            break
    u = density.sample(rng, n)
    return importance_estimate(margin(u) <= 0, standard_normal_log_pdf(u) - density.log_pdf(u))


def test_cross_entropy_reported_cov_matches_its_spread_over_repetitions():
    # 40 repetitions of the whole method on the linear limit state at beta = 4.75 in 10
    # dimensions (500 draws a round): the mean reported c.o.v. against the spread of the
    # estimates. The spread's relative sampling error over 40 repetitions is about
    # 1/sqrt(78) = 11 %: a factor 1.5 either way is more than 3 of them.
    d, beta, reps = 10, 4.75, 40
    a = np.ones(d) / math.sqrt(d)
    rng = np.random.default_rng(31)
    estimates = [cross_entropy_estimate(lambda u: beta - u @ a, d, 500, rng)
                 for _ in range(reps)]
    values = np.array([e.probability for e in estimates])
    spread = values.std(ddof=1) / values.mean()
    reported = np.mean([e.cov for e in estimates])
    assert spread / 1.5 < reported < 1.5 * spread
    # and the repetitions' mean is Phi(-beta) within 4 of its standard errors
    exact = sps.norm.sf(beta)
    assert abs(values.mean() - exact) <= SE4 * values.std(ddof=1) / math.sqrt(reps)


def test_cross_entropy_in_100_dimensions_fits_the_mean_only():
    # g = 4.75 - a.u in 100 standard normals, 1,000 draws a round, rho = 0.3, 4 rounds and
    # the final draws (5,000 calls, the benchmark's budget): covariance "auto" fits the
    # identity (300 elites against the 5,050 parameters of a full covariance) and each of
    # two seeds' estimates is Phi(-4.75) within 4 of its standard errors (1 in 16,000 each
    # if normal). The full covariance of the same rounds (what "auto" replaced) is off by
    # orders of magnitude: it fails this.
    d, beta = 100, 4.75
    a = np.ones(d) / math.sqrt(d)
    exact = sps.norm.sf(beta)
    for seed in (1, 2):
        estimate = cross_entropy_estimate(lambda u: beta - u @ a, d, 1000,
                                          np.random.default_rng(seed), rho=0.3, max_rounds=4)
        assert abs(estimate.probability - exact) <= SE4 * estimate.stderr
        assert estimate.cov < 0.5
    full = cross_entropy_estimate(lambda u: beta - u @ a, d, 1000, np.random.default_rng(1),
                                  rho=0.3, max_rounds=4, covariance="full")
    assert full.probability < 0.01 * exact
    # the rule: full from 10 x d(d + 1)/2 elites on
    assert full_covariance_pays(30, 2) and not full_covariance_pays(29.9, 2)
    assert not full_covariance_pays(100, 10) and full_covariance_pays(550, 10)


def test_cross_entropy_fit_diagonal_and_identity():
    rng = np.random.default_rng(2)
    u, log_w = rng.normal(size=(40, 3)) * [2.0, 1.0, 0.1], rng.normal(size=40)
    w = np.exp(log_w) / np.exp(log_w).sum()
    mean = w @ u
    identity = cross_entropy_fit(u, log_w, covariance="identity")
    diagonal = cross_entropy_fit(u, log_w, covariance="diagonal")
    # sums of 40 terms of order 1: rounding of order 40 eps
    assert np.allclose(identity.means[0], mean, rtol=0, atol=1e-12)
    assert np.array_equal(identity.covariances[0], np.eye(3))
    spread = np.maximum(w @ (u - mean) ** 2, COVARIANCE_FLOOR)
    # weighted sums of 40 squares of order 4: rounding of order 40 x 4 eps
    assert np.allclose(diagonal.covariances[0], np.diag(spread), rtol=0, atol=1e-12)
    assert diagonal.covariances[0][2, 2] == COVARIANCE_FLOOR  # 0.01 floored
    with pytest.raises(ValueError, match="covariance must be one of"):
        cross_entropy_fit(u, log_w, covariance="auto")


# ============================================================================= the methods

def study(tmp_path, scene, inputs, limit_states, method, solver="analytic", seed=1,
          name="is", execution=None):
    """A study of ``solver`` with normal ``inputs`` [(name, mean, std)]."""
    return load_study(study_file(tmp_path, name, inputs=inputs, limit_states=limit_states,
                                 method=method, solver=solver, scene=scene, seed=seed,
                                 execution=execution))


def run(tmp_path, *args, **kwargs):
    return run_warned(study(tmp_path, *args, **kwargs))


def first(stats, name):
    return float(stats[name].values.ravel()[0])


# R - S with R ~ N(4, 1), S ~ N(2, 1): p = Phi(-sqrt 2)
R_MINUS_S = {"model": "linear", "coefficients": [1.0, -1.0]}
RS_INPUTS = [("x1", 4.0, 1.0), ("x2", 2.0, 1.0)]
BELOW_ZERO = [{"name": "negative", "output": "y", "below": 0.0}]
RS_EXACT = 0.0786496035251426


def linear_in(d):
    coefficients = np.ones(d) / math.sqrt(d)
    return {"model": "linear", "coefficients": coefficients.tolist()}, \
        [(f"x{k + 1}", 0.0, 1.0) for k in range(d)]


def four_branch(x1=0.0, x2=0.0):
    u = np.array([[x1, x2]])
    s, d = (x1 + x2) / math.sqrt(2), x1 - x2
    del u
    return {"g1": 3 + d**2 / 10 - s, "g2": 3 + d**2 / 10 + s,
            "g3": d + 6 / math.sqrt(2), "g4": -d + 6 / math.sqrt(2)}


FourBranch = register_solver("four-branch-test")(solver_from_function(
    four_branch, outputs=["g1", "g2", "g3", "g4"], units={f"g{k}": "1" for k in range(1, 5)},
    name="four-branch-test"))
FOUR_BRANCH_STATES = [{"name": f"branch{k}", "output": f"g{k}", "below": 0.0}
                      for k in range(1, 5)] + [
    {"name": "system", "series": [f"branch{k}" for k in range(1, 5)]}]


def test_registered_under_their_names():
    assert get_method("importance-sampling") is ImportanceSampling
    assert get_method("cross-entropy") is CrossEntropy


@pytest.mark.parametrize("kind, options", [
    ("importance-sampling", {"samples": 400}),
    ("cross-entropy", {"samples": 300}),
])
def test_r_minus_s_is_exact_within_its_standard_error(tmp_path, kind, options):
    outcome, raised = run(tmp_path, R_MINUS_S, RS_INPUTS, BELOW_ZERO, {"kind": kind, **options})
    stats = outcome.statistics
    p, stderr = first(stats, FAILURE_PROBABILITY), first(stats, FAILURE_STDERR)
    assert abs(p - RS_EXACT) <= SE4 * stderr and stderr / p < 0.1
    low, high = stats[FAILURE_INTERVAL].values[0]
    assert low <= RS_EXACT <= high and high - low == pytest.approx(
        2 * sps.norm.ppf(0.975) * stderr, rel=1e-9)  # p +- z s.e., a few roundings
    # one division (abs=0: approx's default 1e-12 is 1e-11 of this c.o.v.)
    assert first(stats, FAILURE_COV) == pytest.approx(stderr / p, rel=1e-12, abs=0)
    assert first(stats, RELIABILITY_INDEX) == pytest.approx(-sps.norm.ppf(p), rel=1e-12)
    assert stats.attrs["interval_method"] == "normal" and raised == []
    assert stats.attrs["sampling_runs"] == options["samples"]
    assert stats.attrs["density_runs"] + stats.attrs["sampling_runs"] == \
        stats.attrs["solver_runs"]


def test_importance_sampling_of_a_linear_limit_state_at_beta_4_75_in_ten_dimensions(tmp_path):
    scene, inputs = linear_in(10)
    outcome, raised = run(tmp_path, scene, inputs,
                          [{"name": "high", "output": "y", "exceeds": 4.75}],
                          {"kind": "importance-sampling", "samples": 500})
    stats = outcome.statistics
    p, stderr = first(stats, FAILURE_PROBABILITY), first(stats, FAILURE_STDERR)
    exact = sps.norm.sf(4.75)
    assert exact == pytest.approx(1.017e-6, abs=0.0005e-6)  # the value the docs quote
    assert abs(p - exact) <= SE4 * stderr and stderr / p < 0.15 and raised == []
    # FORM beside it is exact for a linear limit state (finite differences of a linear g:
    # rounding only, eps |g| / step ~ 1e-13)
    assert first(stats, FORM_INDEX) == pytest.approx(4.75, rel=1e-9)
    # (atol=0 here and below: allclose's default 1e-8 would be the real tolerance)
    assert np.allclose(stats[DESIGN_POINT].values[0], 4.75 / math.sqrt(10), rtol=1e-9, atol=0)
    assert first(stats, EFFECTIVE_SAMPLE_SIZE) > 50
    # FORM's importance factors: 1/10 each (alpha = a / |a|); rounding as for the index
    assert np.allclose(stats[IMPORTANCE].values[0], 0.1, rtol=1e-9, atol=0)
    # the report's table of them (the framework draws their bar chart from the same hook)
    assert "importance factor alpha²" in summary_table(open_result(outcome.path))


def two_points(x1=0.0, x2=0.0):
    w = (x1 + x2) / math.sqrt(2)
    return {"g": min(3 - w, 3.2 + w)}


TwoPoints = register_solver("two-design-points-test")(solver_from_function(
    two_points, outputs=["g"], units={"g": "1"}, name="two-design-points-test"))
#: g = min(3 - w, 3.2 + w), w = (u1 + u2)/sqrt 2: two half-planes, p = Phi(-3) + Phi(-3.2)
TWO_POINTS_EXACT = float(sps.norm.sf(3.0) + sps.norm.sf(3.2))


def test_importance_sampling_puts_a_gaussian_on_each_design_point_the_check_finds(tmp_path):
    outcome, raised = run(tmp_path, {}, [("x1", 0.0, 1.0), ("x2", 0.0, 1.0)],
                          [{"name": "g", "output": "g", "below": 0.0}],
                          {"kind": "importance-sampling", "samples": 2000},
                          solver="two-design-points-test")
    stats = outcome.statistics
    assert TWO_POINTS_EXACT == pytest.approx(2.037e-3, abs=0.0005e-3)  # the docs' value
    p, stderr = first(stats, FAILURE_PROBABILITY), first(stats, FAILURE_STDERR)
    assert abs(p - TWO_POINTS_EXACT) <= SE4 * stderr and raised == []
    # FORM's point (beta 3, exact for a half-plane: finite differences round only, 1e-9), the
    # check's estimate of the other (beta 3.2; g linear between the medians and the probe
    # -u*: 3 x 3/(3 - 0.2) = 3.21), the defensive standard normal
    weights, means = stats[BIASING_WEIGHT].values, stats[BIASING_MEAN].values
    # (atol=0: allclose's default 1e-8 would be the real tolerance)
    assert np.allclose(means[0], 3 / math.sqrt(2), rtol=1e-9, atol=0)
    assert np.allclose(means[1], -(9 / 2.8) / math.sqrt(2), rtol=1e-9, atol=0)
    assert np.array_equal(means[2], [0.0, 0.0]) and weights[2] == pytest.approx(0.1)
    share = sps.norm.sf(9 / 2.8) / (sps.norm.sf(9 / 2.8) + sps.norm.sf(3.0))
    assert weights[1] == pytest.approx(0.9 * share, rel=1e-9)  # one division and product
    assert "1 other(s) its design-point check found" in stats.attrs["biasing_density"]
    # that density (as the method built it) over 100 repetitions of 2,000 draws: every
    # estimate within 4 of its reported standard errors, and the mean reported c.o.v.
    # within a factor 1.3 of the estimates' spread (the spread's relative sampling error
    # over 100 repetitions is 1/sqrt(198) = 7 %: 1.3 is 4 of them). Centred on FORM's point
    # alone (the defensive share finds the other region) the reported c.o.v. is a fraction
    # of the spread, and this fails.
    def repetitions(mixture):
        rng = np.random.default_rng(40)
        found = []
        for _ in range(100):
            u = mixture.sample(rng, 2000)
            w = u.sum(axis=1) / math.sqrt(2)
            found.append(importance_estimate(np.minimum(3 - w, 3.2 + w) <= 0,
                                             standard_normal_log_pdf(u) - mixture.log_pdf(u)))
        values = np.array([e.probability for e in found])
        return found, values.std(ddof=1) / values.mean(), np.mean([e.cov for e in found])

    found, spread, reported = repetitions(GaussianMixture(weights, means, np.array(
        [np.eye(2)] * 3)))
    assert all(abs(e.probability - TWO_POINTS_EXACT) <= SE4 * e.stderr for e in found)
    assert spread / 1.3 < reported < 1.3 * spread
    _, spread, reported = repetitions(defensive_mixture(means[0], 0.1))
    assert reported < 0.5 * spread


def test_cross_entropy_finds_the_four_branch_system_where_form_is_wrong(tmp_path):
    outcome, raised = run(tmp_path, {}, [("x1", 0.0, 1.0), ("x2", 0.0, 1.0)],
                          FOUR_BRANCH_STATES, {"kind": "cross-entropy", "samples": 500,
                                               "limit_state": "system", "rule": "quantile"},
                          solver="four-branch-test")
    stats = outcome.statistics
    exact = four_branch_exact(6.0)
    low, high = stats[FAILURE_INTERVAL].values[0]
    # one Gaussian spread over the four branches: c.o.v. near 0.16 from 500 draws, where plain
    # Monte Carlo's sqrt((1 - p) / (500 p)) is 0.67
    assert low <= exact <= high and first(stats, FAILURE_COV) < 0.25
    thresholds = stats[CE_THRESHOLD].values
    assert thresholds[-1] == 0 and np.all(np.diff(thresholds) < 0)
    assert stats.attrs["threshold_reached"] == 1 and raised == []


def test_defensive_importance_sampling_at_one_branch_warns_of_its_weights(tmp_path):
    # centred at the first branch's design point (FORM's answer for the branch nearest the
    # origin), the draws of the defensive share in the other branches carry the estimate
    centre = {"x1": 3 / math.sqrt(2), "x2": 3 / math.sqrt(2)}
    outcome, raised = run(tmp_path, {}, [("x1", 0.0, 1.0), ("x2", 0.0, 1.0)],
                          FOUR_BRANCH_STATES, {"kind": "importance-sampling", "samples": 1000,
                                               "limit_state": "system",
                                               "design_point": centre},
                          solver="four-branch-test", seed=2)
    stats = outcome.statistics
    assert any("importance weights have degenerated" in w for w in raised)
    assert first(stats, EFFECTIVE_SAMPLE_SIZE) < 0.1 * first(stats, FAILURES)
    assert stats.attrs["density_runs"] == 0  # the design point given: no FORM search
    # the given point, stored as given: a few roundings at most (atol=0: not the default 1e-8)
    assert np.allclose(stats[DESIGN_POINT].values[0], list(centre.values()), rtol=1e-15,
                       atol=0)
    text = summary_table(open_result(outcome.path))
    assert "importance weights have degenerated" in text
    assert "design point: x1 = 2.12132 m, x2 = 2.12132 m" in text


def test_a_failed_run_is_left_out_and_counted_apart(tmp_path):
    # y = x, failing runs above 0.5: draws of the failure domain y < -2 all run, draws past
    # 0.5 (mostly of the defensive share) do not, and are neither failures nor safe
    outcome, raised = run(tmp_path, {"model": "faulty", "raise_above": 0.5}, [("x", 0.0, 1.0)],
                          [{"name": "low", "output": "y", "below": -2.0}],
                          {"kind": "importance-sampling", "samples": 400},
                          execution={"max_failure_fraction": 0.5})
    stats, runs = outcome.statistics, outcome.runs
    sampling = runs[STAGE].values == STAGE_SAMPLING
    failed = sampling & (runs[STATUS].values == STATUS_FAILED)
    assert failed.sum() > 0
    assert int(stats[FAILURE_LEFT_OUT].values[0]) == failed.sum()
    assert int(stats[FAILURE_RUNS].values[0]) == 400 - failed.sum()
    ok = sampling & ~failed
    y = runs["y"].values[ok]
    expected = importance_estimate(y <= -2.0, runs[LOG_LIKELIHOOD_RATIO].values[ok])
    assert first(stats, FAILURE_PROBABILITY) == expected.probability
    assert int(stats[FAILURES].values[0]) == int((y <= -2.0).sum())
    assert any(f"{failed.sum()} of 400 draws of the biasing density did not run ok" in w
               for w in raised)
    assert "left out of the mean" in stats.attrs["failure_probability_note"]


@pytest.mark.parametrize("kind", ["importance-sampling", "cross-entropy"])
def test_every_round_replays_from_the_runs_before_it(tmp_path, kind):
    # a resume asks extend the same question of the same runs: each prefix of finished
    # rounds gives back, bit for bit, the round that ran next; another seed other draws
    options = {"kind": kind, "samples": 200, "batches": 2}
    outcome, _ = run(tmp_path, R_MINUS_S, RS_INPUTS, BELOW_ZERO, options, seed=3, name="a")
    fresh = load_study(tmp_path / "a.toml")
    method = fresh.method
    method.plan(fresh.space, None, np.random.SeedSequence(3))
    runs = outcome.runs
    rounds = runs[ROUND].values
    # the log ratios too (NaN: a search row is no draw)
    assert_rounds_replay(method, runs, (INPUTS, LOG_LIKELIHOOD_RATIO))
    # another seed: the same prefix gives other draws in the first round that draws
    method.plan(fresh.space, None, np.random.SeedSequence(4))
    drawn = int(rounds[~np.isin(runs[STAGE].values, [STAGE_SEARCH, STAGE_CHECK])].min())
    prefix = runs.isel(realization=np.flatnonzero(rounds < drawn))
    other = method.extend(prefix, prefix) if drawn else \
        method.plan(fresh.space, None, np.random.SeedSequence(4))
    assert not np.array_equal(other[INPUTS].values, runs[INPUTS].values[rounds == drawn])


def same_answer(one, other):
    columns = [INPUTS, "y", STATUS]
    xr.testing.assert_identical(one.runs[columns], other.runs[columns])
    xr.testing.assert_identical(one.statistics.drop_attrs(), other.statistics.drop_attrs())


CE_OPTIONS = {"kind": "cross-entropy", "samples": 100, "batches": 2}


def test_identical_after_a_kill_and_resume(tmp_path, monkeypatch):
    whole, _ = run(tmp_path, R_MINUS_S, RS_INPUTS, BELOW_ZERO, CE_OPTIONS, name="whole")
    cut = study(tmp_path, R_MINUS_S, RS_INPUTS, BELOW_ZERO, CE_OPTIONS, name="cut")
    original = CrossEntropy.extend

    def killed_after_two_rounds(self, design, runs):
        if int(runs[ROUND].values.max()) >= 1:
            raise KeyboardInterrupt
        return original(self, design, runs)

    monkeypatch.setattr(CrossEntropy, "extend", killed_after_two_rounds)
    with pytest.raises(KeyboardInterrupt):
        run_study(cut, show_progress=False, force=True)
    monkeypatch.undo()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        resumed = run_study(load_study(tmp_path / "cut.toml"), show_progress=False,
                            resume=True)
    assert resumed.resumed == 200  # the two rounds the kill left in the file
    same_answer(whole, resumed)


@pytest.mark.slow
def test_identical_for_workers_0_and_2(tmp_path):
    # two batches of draws at a given centre: a planned round and one through extend, both
    # on the dask workers (the densities' replay is checked in process above)
    options = {"kind": "importance-sampling", "samples": 100, "batches": 2,
               "design_point": {"x1": 3.0, "x2": 3.0}}
    zero, _ = run(tmp_path, R_MINUS_S, RS_INPUTS, BELOW_ZERO, options, name="w0")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        two = run_study(study(tmp_path, R_MINUS_S, RS_INPUTS, BELOW_ZERO, options,
                              name="w2", execution={"workers": 2}),
                        show_progress=False, force=True)
    same_answer(zero, two)


def test_target_cov_stops_after_the_first_batch_that_reaches_it(tmp_path):
    options = {"kind": "importance-sampling", "samples": 1000, "batches": 10,
               "target_cov": 0.1}
    outcome, _ = run(tmp_path, R_MINUS_S, RS_INPUTS, BELOW_ZERO, options)
    stats, runs = outcome.statistics, outcome.runs
    drawn = stats.attrs["sampling_runs"]
    assert drawn < 1000 and drawn % 100 == 0 and first(stats, FAILURE_COV) <= 0.1
    # one batch fewer had not reached it: the stop is the first that does
    sampling = np.flatnonzero(runs[STAGE].values == STAGE_SAMPLING)[:drawn - 100]
    y = runs["y"].values[sampling]
    earlier = importance_estimate(y <= 0.0, runs[LOG_LIKELIHOOD_RATIO].values[sampling])
    assert earlier.cov > 0.1


@pytest.mark.parametrize("kind, options, key, words", [
    ("importance-sampling", {"samples": 1}, "method.samples", "greater than or equal to 2"),
    ("importance-sampling", {"samples": 4, "batches": 5}, "method",
     "batches = 5 exceeds samples = 4"),
    ("importance-sampling", {"target_cov": 0.1}, "method", "'target_cov' applies to batches > 1"),
    ("importance-sampling", {"defensive_weight": 1.5}, "method.defensive_weight",
     "less than or equal to 1"),
    ("importance-sampling", {"design_point": {"x1": 1.0}}, "method.design_point",
     "x2 missing"),
    ("importance-sampling", {"design_point": {"x1": 1.0, "x2": 1.0, "x9": 0.0}},
     "method.design_point", "'x9' is not an input"),
    ("importance-sampling", {"step": 0.1, "design_point": {"x1": 1.0, "x2": 1.0}}, "method",
     "'step' applies to the FORM search, which a given design_point skips"),
    ("cross-entropy", {"rho": 0.7}, "method.rho", "less than or equal to 0.5"),
    ("cross-entropy", {"samples": 100, "max_rounds": 0}, "method.max_rounds",
     "greater than or equal to 1"),
])
def test_bad_options_are_one_line_errors_naming_the_key(tmp_path, kind, options, key, words):
    with pytest.raises(StudyError) as error:
        study(tmp_path, R_MINUS_S, RS_INPUTS, BELOW_ZERO, {"kind": kind, **options})
    assert error.value.key == key and "\n" not in str(error.value)
    assert words in str(error.value)


def test_importance_sampling_of_a_system_needs_a_design_point(tmp_path):
    with pytest.raises(StudyError) as error:
        study(tmp_path, {}, [("x1", 0.0, 1.0), ("x2", 0.0, 1.0)], FOUR_BRANCH_STATES,
              {"kind": "importance-sampling", "limit_state": "system"},
              solver="four-branch-test")
    assert error.value.key == "method.limit_state" and "\n" not in str(error.value)
    assert "series system" in str(error.value) and "cross-entropy" in str(error.value)


def test_cross_entropy_warns_of_a_fit_on_fewer_elites_than_dimensions(tmp_path):
    # 20 draws a round in 10 dimensions, rho = 0.1: each fit rests on 2 elites (the mean
    # only, "auto" takes the identity), whose mean is off by about sqrt(10 / 2) per the
    # warning; and the advice on degenerate weights is cross-entropy's own, not "use
    # cross-entropy"
    scene, inputs = linear_in(10)
    outcome, raised = run(tmp_path, scene, inputs,
                          [{"name": "high", "output": "y", "exceeds": 2.0}],
                          {"kind": "cross-entropy", "samples": 20, "max_rounds": 1,
                           "rule": "quantile"})
    assert any("effective elite draws for 10 dimensions" in w for w in raised)
    assert "identity covariance (mean shift)" in outcome.statistics.attrs["biasing_density"]
    for kind, advice in (("cross-entropy", "use more samples a round"),
                         ("importance-sampling", "use cross-entropy or more samples")):
        method = study(tmp_path, scene, inputs, [{"name": "high", "output": "y",
                                                  "exceeds": 2.0}],
                       {"kind": kind, "samples": 20}, name=kind).method
        words = method.estimate_warnings(ImportanceEstimate(1e-3, 1e-4, 0.0, 2e-3, 0.1, 1.0,
                                                            20), 20, 0, 20)
        assert len(words) == 1 and advice in words[0]


def test_report_lines(tmp_path):
    outcome, _ = run(tmp_path, R_MINUS_S, RS_INPUTS, BELOW_ZERO,
                     {"kind": "cross-entropy", "samples": 100, "rule": "quantile"})
    text = summary_table(open_result(outcome.path))
    stats = outcome.statistics
    assert (f"cross-entropy, limit state 'negative' (y < 0): p_f = "
            f"{first(stats, FAILURE_PROBABILITY):.6g}, 95% normal interval") in text
    # p ~ 0.08 < rho: round 0's threshold is above 0, round 1's reaches it
    thresholds = stats[CE_THRESHOLD].values
    assert thresholds.size == 2 and thresholds[0] > 0 and thresholds[1] == 0
    assert f"cross-entropy thresholds: {thresholds[0]:.6g}, 0\n" in text
    assert "solver runs: 200 building the density, 100 sampling it" in text


def test_a_form_search_that_finds_nothing_leaves_plain_monte_carlo_and_says_so(tmp_path):
    # every run above x = 0.005 fails, the start's neighbour x = 0.01 among them: no gradient
    # at the start, no design point, so the draws come from the defensive mixture centred at
    # the medians (the standard normal); about half of them fail too
    outcome, raised = run(tmp_path, {"model": "faulty", "raise_above": 0.005},
                          [("x", 0.0, 1.0)], [{"name": "low", "output": "y", "below": -2.0}],
                          {"kind": "importance-sampling", "samples": 50},
                          execution={"max_failure_fraction": 0.9})
    stats, runs = outcome.statistics, outcome.runs
    assert any("FORM found no design point" in w for w in raised)
    assert stats.attrs["density_runs"] == 3  # the start and its two neighbours
    sampling = runs[STAGE].values == STAGE_SAMPLING
    # q is phi itself: every log ratio is 0 up to the rounding of two log densities
    assert np.allclose(runs[LOG_LIKELIHOOD_RATIO].values[sampling], 0.0, atol=1e-12)
    assert np.isnan(first(stats, FORM_INDEX))


def test_a_design_point_in_the_inputs_units_maps_back_through_the_copula():
    from uqflow.inputs import InputSpace, RandomInput
    from uqflow.methods.form import to_inputs
    from uqflow.methods.importance_sampling import to_standard_normal
    space = InputSpace([
        RandomInput.from_spec({"name": "a", "distribution": "lognormal", "mean": 2.0,
                               "cv": 0.3}),
        RandomInput.from_spec({"name": "b", "distribution": "normal", "mean": 1.0,
                               "std": 0.5}),
        RandomInput.from_spec({"name": "c", "distribution": "uniform", "lower": 0.0,
                               "upper": 4.0})],
        np.array([[1.0, 0.5, 0.2], [0.5, 1.0, -0.3], [0.2, -0.3, 1.0]]))
    point = {"a": 3.1, "b": 0.2, "c": 3.5}
    u = to_standard_normal(space, point)
    # the round trip x -> u -> x: a few roundings through Phi, its inverse and chaospy's
    # inverse distribution functions, each good to ~1e-12 relative here
    assert np.allclose(to_inputs(space, u)[0], list(point.values()), rtol=1e-9)
    with pytest.raises(StudyError, match="outside the support of input 'c'") as error:
        to_standard_normal(space, {"a": 3.1, "b": 0.2, "c": 5.0})
    assert error.value.key == "method.design_point.c"
