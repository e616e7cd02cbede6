"""The improved cross-entropy method (smoothed targets; Papaioannou, Geyer & Straub 2019) and
its two families: a mixture of Gaussians in low dimensions, the von Mises-Fisher-Nakagami
density (vMFN) in many.

The method runs in memory (``uqflow.testing.run_in_memory``: driven through its contract as
the executor drives it) on g with exact P[failure]; its pieces (the vMFN density, its fit, the
smoothing parameter's root) are checked against independent computations. Statistical
tolerances are a number of standard errors with the seed fixed, so every test is
deterministic.
"""

from __future__ import annotations

import json
import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import integrate, special
from scipy import stats as sps

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.inputs import InputSpace, RandomInput
from uqflow.layout import (BIASING_MEAN, CE_FAMILY, CE_SMOOTHING, CE_STOP_COV, FAILURE_COV,
                           FAILURE_PROBABILITY, FAILURE_STDERR, INPUTS, LOG_LIKELIHOOD_RATIO,
                           ROUND, SOLVER_RUNS, THRESHOLD_REACHED, VMF_DIRECTION, VMF_KAPPA)
from uqflow.methods.importance_sampling import (CrossEntropy, smoothing_sharpness,
                                                standard_normal_log_pdf, stopping_cov)
from uqflow.methods.von_mises_fisher_nakagami import (VonMisesFisherNakagami,
                                                      fit_von_mises_fisher_nakagami,
                                                      log_sphere_area)
from uqflow.study import load_study
from uqflow.testing import run_in_memory

# 4 standard errors: a normal deviate beyond them 1 time in 16,000
SE4 = 4.0
BELOW_ZERO = [{"name": "g", "output": "g", "below": 0.0}]


def standard_space(d: int) -> InputSpace:
    return InputSpace([RandomInput.from_spec({"name": f"x{k}", "distribution": "normal",
                                              "mean": 0.0, "std": 1.0}) for k in range(d)],
                      np.eye(d))


def in_memory(options: dict, d: int, margin, seed: int):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        return run_in_memory(CrossEntropy(**options), standard_space(d), BELOW_ZERO,
                             lambda x: {"g": margin(x)}, seed)


def first(stats, name):
    return float(stats[name].values.ravel()[0])


# ----------------------------------------------------------------------------- the method

def test_a_linear_limit_state_in_100_dimensions_at_beta_4_75():
    # g = 4.75 - a.u in 100 standard normals, p = Phi(-4.75) = 1.017e-6: 500 draws a round,
    # family "auto" fits the vMFN density; the estimate is within 4 of its standard errors
    # of p (1 in 16,000 if normal) with a c.o.v. below 0.3 (about 0.2 at this size). With
    # family = "gaussian" (4 mean-shift Gaussians, "auto" covariance) the same rounds give
    # 4e-7 +- 1e-7 and this fails; so does dropping the sphere's area from the likelihood
    # ratio (p 1e-27).
    d, beta = 100, 4.75
    a = np.ones(d) / math.sqrt(d)
    exact = sps.norm.sf(beta)
    _, stats = in_memory({"samples": 500}, d, lambda x: beta - x @ a, seed=3)
    p, stderr = first(stats, FAILURE_PROBABILITY), first(stats, FAILURE_STDERR)
    assert abs(p - exact) <= SE4 * stderr and first(stats, FAILURE_COV) < 0.3
    assert stats.attrs[CE_FAMILY] == "vmfn" and stats.attrs[THRESHOLD_REACHED] == 1
    # the smoothing parameters shrink round by round; the last round met the stop
    smoothing, stops = stats[CE_SMOOTHING].values, stats[CE_STOP_COV].values
    assert np.all(np.diff(smoothing[:-1]) < 0) and np.isnan(smoothing[-1])
    assert stops[-1] <= 1.5 < stops[-2]
    # the vMF part points along a (its direction's error ~ sqrt(d / n_e) ~ 0.5 rad at most)
    direction = stats[VMF_DIRECTION].values
    assert direction @ a > 0.85 and stats.attrs[VMF_KAPPA] > 0
    assert stats.attrs[SOLVER_RUNS] == 500 * (smoothing.size + 1)


def four_branch(u, k=7.0):
    """The four-branch series system: the smallest of 3 + (u1 - u2)^2/10 -+ (u1 + u2)/sqrt 2
    and +-(u1 - u2) + k/sqrt 2."""
    u1, u2 = u[:, 0], u[:, 1]
    s, d = (u1 + u2) / math.sqrt(2), u1 - u2
    return np.minimum.reduce([3 + d**2 / 10 - s, 3 + d**2 / 10 + s,
                              d + k / math.sqrt(2), -d + k / math.sqrt(2)])


def four_branch_exact(k=7.0):
    """P[failure] from the one-dimensional integral of P[safe] in b = (u1 - u2)/sqrt 2."""
    safe = integrate.quad(lambda b: sps.norm.pdf(b) * (1 - 2 * sps.norm.sf(3 + b * b / 5)),
                          # quadrature of a smooth integrand, to its 1e-13 relative error estimate
                          -k / 2, k / 2, epsabs=0, epsrel=1e-13)[0]
    return 1.0 - safe


def test_the_four_branch_system_gets_a_gaussian_on_each_branch():
    # k = 7 (p = 2.2228e-3), 300 draws a round: the mixture of 4 Gaussians puts one on each
    # branch (their design points along +-(1, 1)/sqrt 2 at 3 and +-(1, -1)/sqrt 2 at 3.5),
    # and the estimate is within 4 of its standard errors of p with a c.o.v. below 0.15
    # (about 0.08 at this size). One Gaussian (components = 1) spreads over the branches and
    # fails the first assertion.
    exact = four_branch_exact()
    assert exact == pytest.approx(2.2228e-3, abs=0.00005e-3)  # the value docs quote
    _, stats = in_memory({"samples": 300}, 2, four_branch, seed=1)
    p, stderr = first(stats, FAILURE_PROBABILITY), first(stats, FAILURE_STDERR)
    means = stats[BIASING_MEAN].values
    for branch in ([1, 1], [-1, -1], [1, -1], [-1, 1]):
        assert np.max(means @ (np.array(branch) / math.sqrt(2))) > 2.0, branch
    assert abs(p - exact) <= SE4 * stderr and first(stats, FAILURE_COV) < 0.15
    assert stats.attrs[CE_FAMILY] == "gaussian"


# ----------------------------------------------------------------------------- the pieces

def test_the_vmfn_density_integrates_to_one_and_its_ratio_is_phi_over_q():
    # in 2 dimensions, q's integral over the plane in polar coordinates: the periodic
    # trapezoid rule in the angle (spectrally accurate for the smooth vMF) and Simpson's in
    # the radius on [0, 15] (h = 0.0075: error of order h^4 times the 4th derivative, ~1e-8;
    # Nakagami(2, 5) holds e^-90 beyond 15): the Jacobian r^-(d-1) is q's own
    density = VonMisesFisherNakagami([0.6, 0.8], 3.0, 2.0, 5.0)
    radius = np.linspace(0.0, 15.0, 2001)[1:]
    angle = np.linspace(0.0, 2 * math.pi, 256, endpoint=False)
    rr, tt = np.meshgrid(radius, angle, indexing="ij")
    points = np.stack([(rr * np.cos(tt)).ravel(), (rr * np.sin(tt)).ravel()], axis=1)
    ring = np.exp(density.log_pdf(points)).reshape(rr.shape).mean(axis=1) * 2 * math.pi
    mass = integrate.simpson(np.append(0.0, radius * ring), x=np.append(0.0, radius))
    # the quadrature's error ~1e-8 (above), with a factor 10 of room
    assert mass == pytest.approx(1.0, abs=1e-7)
    # the ratio (chi_d over the sphere's area, the r^(d-1) cancelled) against phi's
    # Gaussian formula over q's log density: terms of size up to ~300 in 100 dimensions
    # (gammaln, log r^99, kappa x.mu), each rounded to a few eps relative: 1e-10 absolute
    rng = np.random.default_rng(0)
    for d, kappa in ((3, 2.0), (100, 40.0)):
        density = VonMisesFisherNakagami(rng.normal(size=d), kappa, d / 2 + 3, d + 20.0)
        u = density.sample(rng, 50)
        # terms up to ~300 each rounded to a few eps: ~1e-13 absolute, 1e-10 leaves room
        assert np.allclose(density.log_likelihood_ratio(u),
                           standard_normal_log_pdf(u) - density.log_pdf(u), rtol=0,
                           # bound: ~300-sized terms each a few eps, ~1e-13 absolute (above)
                           atol=1e-10)
    # |S^2| = 4 pi: a log, a gammaln and a sum, each correctly rounded (a few eps)
    assert log_sphere_area(3) == pytest.approx(math.log(4 * math.pi), rel=1e-15)


def test_the_vmfn_weights_have_mean_one_under_its_own_draws():
    # E_q[phi/q] = 1 for any density q: 4,000 draws of a vMFN in 100 dimensions, the mean of
    # their weights within 4 of its standard errors of 1. A wrong normalization (the sphere's
    # area, chi's or the Jacobian) moves it by orders of magnitude; draws not from q (the
    # radius from another Omega) by tens of standard errors.
    d = 100
    rng = np.random.default_rng(7)
    density = VonMisesFisherNakagami(np.ones(d), 2.0, 45.0, 104.0)
    weights = np.exp(density.log_likelihood_ratio(density.sample(rng, 4000)))
    stderr = weights.std(ddof=1) / math.sqrt(weights.size)
    assert abs(weights.mean() - 1.0) <= SE4 * stderr and stderr < 0.05


def test_the_vmfn_fit_of_standard_normal_draws_is_the_standard_normal():
    # phi is itself a vMFN density: uniform directions (kappa = 0) and a chi_d radius,
    # Nakagami(m = d/2, Omega = d). 200 equal-weight draws in 100 dimensions: Omega = mean r^2
    # is d within 4 standard errors sqrt(2d/200) = 1; m = Omega^2 / Var(r^2) within 40 % of
    # d/2 (4 relative standard errors sqrt(2/200) of the variance); and kappa is the noise of
    # 200 directions taken out: |mean x|^2 has mean 1/200 and standard deviation
    # sqrt(2/d)/200, so the signal left is below 4 of those and kappa below
    # d sqrt(4 sqrt(2/d) / 200) = 5.3, where the fit without the correction gives about
    # d sqrt(1/200) = 7.
    d, n = 100, 200
    u = np.random.default_rng(12).normal(size=(n, d))
    fitted = fit_von_mises_fisher_nakagami(u, np.zeros(n))
    assert abs(fitted.omega - d) <= SE4 * math.sqrt(2 * d / n)
    assert fitted.m == pytest.approx(d / 2, rel=0.4)
    assert fitted.kappa < d * math.sqrt(SE4 * math.sqrt(2 / d) / n)
    # weights count: the same points, one of them heavy, pull the mean direction to it
    log_w = np.zeros(n)
    log_w[0] = 10.0
    heavy = fit_von_mises_fisher_nakagami(u, log_w)
    assert heavy.mean_direction @ u[0] / np.linalg.norm(u[0]) > 0.99


def test_the_smoothing_parameter_makes_the_weights_cov_the_target():
    # s_j = 1/t_j: c.o.v. of Phi(-g t_j) / Phi(-g t_(j-1)) over the draws = 1.5, recomputed
    # here with scipy's normal distribution function (brentq's rtol 1e-12 on t moves the
    # c.o.v. by ~1e-11; 1e-8 leaves room for the cdf's rounding). A ratio without its
    # denominator Phi(-g t_(j-1)) gives another root and fails.
    g = np.random.default_rng(5).normal(2.0, 1.5, size=400)
    for previous in (0.0, 0.7):
        t = smoothing_sharpness(g, previous, 1.5)
        ratio = sps.norm.cdf(-g * t) / sps.norm.cdf(-g * previous)
        # brentq's rtol 1e-12 on t: the c.o.v. within ~1e-11 of its target; 1e-8 for the cdf
        assert t > previous and ratio.std() / ratio.mean() == pytest.approx(1.5, abs=1e-8)
    # the stop: the c.o.v. of 1[g <= 0] / Phi(-g t) over the draws, infinite without failure
    indicator = (g <= 0) / sps.norm.cdf(-g * 0.7)
    assert stopping_cov(g, 0.7) == pytest.approx(indicator.std() / indicator.mean(),
                                                 rel=1e-12)  # a few roundings of a mean
    assert stopping_cov(np.abs(g) + 0.1, 0.7) == math.inf
    # past the stop's statistic no finite t reaches the target: the indicator itself
    assert smoothing_sharpness(np.array([-1.0, -1.0, 2.0, 3.0]), 0.0, 10.0) == math.inf
    assert special.ndtr(0.0) == 0.5  # Phi(-g 0) = 1/2: s_0 = infinity weighs all alike


# ----------------------------------------------------------------------------- study files

def study(tmp_path, d, method, name="ce", execution=None):
    """A study of g = 2.5 - sum(x)/sqrt(d) (the analytic solver's linear model) with d
    standard normal inputs, below 0 failing."""
    scene = {"model": "linear", "coefficients": [-1 / math.sqrt(d)] * d, "offset": 2.5}
    lines = [f'name = "{name}"', 'solver = "analytic"',
             "scene = { " + ", ".join(f"{k} = {json.dumps(v)}" for k, v in scene.items())
             + " }", ""]
    for k in range(d):
        lines += ["[[inputs]]", f'name = "x{k + 1}"', 'distribution = "normal"', "mean = 0.0",
                  "std = 1.0", ""]
    lines += ["[[limit_states]]", 'name = "g"', 'output = "y"', "below = 0.0", "",
              "[method]"] + [f"{k} = {json.dumps(v)}" for k, v in method.items()]
    execution = {"workers": 0, "seed": 4, **(execution or {})}
    lines += ["", "[execution]"] + [f"{k} = {json.dumps(v)}" for k, v in execution.items()]
    lines += ["", "[output]", f'path = "{name}.nc"', "figures = false", ""]
    path = tmp_path / f"{name}.toml"
    path.write_text("\n".join(lines))
    return load_study(path)


@pytest.mark.parametrize("d, options, key, words", [
    (2, {"rho": 0.2}, "method", "'rho' applies to rule = \"quantile\""),
    (2, {"rule": "quantile", "smoothing_cov": 1.0}, "method",
     "'smoothing_cov' applies to rule = \"improved\""),
    (2, {"family": "vmfn", "components": 2}, "method", "'components' applies to the gaussian"),
    (2, {"family": "vmfn", "covariance": "full"}, "method", "'covariance' applies to the"),
    (2, {"smoothing_cov": 0.0}, "method.smoothing_cov", "greater than 0"),
    (2, {"components": 0}, "method.components", "greater than or equal to 1"),
    (2, {"family": "gauss"}, "method.family", "'auto', 'gaussian' or 'vmfn'"),
    (1, {"family": "vmfn"}, "method.family", "needs at least 2 inputs with a spread"),
])
def test_bad_options_are_one_line_errors_naming_the_key(tmp_path, d, options, key, words):
    with pytest.raises(StudyError) as error:
        study(tmp_path, d, {"kind": "cross-entropy", **options})
    assert error.value.key == key and "\n" not in str(error.value)
    assert words in str(error.value)


def test_every_vmfn_round_replays_from_the_runs_before_it():
    # 20 dimensions (family "auto" takes the vMFN): each prefix of finished rounds gives back,
    # bit for bit, the draws and log ratios of the round that ran next (what a resume asks),
    # and another seed other draws
    d = 20
    a = np.ones(d) / math.sqrt(d)
    method = CrossEntropy(samples=100, batches=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        runs, stats = run_in_memory(method, standard_space(d), BELOW_ZERO,
                                    lambda x: {"g": 3.0 - x @ a}, 2)
    assert stats.attrs[CE_FAMILY] == "vmfn"
    rounds = runs[ROUND].values
    assert rounds.max() >= 3  # vMFN rounds, then the two batches
    for r in range(int(rounds.max())):
        prefix = runs.isel(realization=np.flatnonzero(rounds <= r))
        more = method.extend(prefix, prefix)
        for column in (INPUTS, LOG_LIKELIHOOD_RATIO):
            assert np.array_equal(more[column].values, runs[column].values[rounds == r + 1])
    assert method.extend(runs, runs) is None
    method.plan(standard_space(d), None, np.random.SeedSequence(3))
    prefix = runs.isel(realization=np.flatnonzero(rounds == 0))
    assert not np.array_equal(method.extend(prefix, prefix)[INPUTS].values,
                              runs[INPUTS].values[rounds == 1])
    # the report hook's lines: the density, each round's smoothing parameter and stop c.o.v.
    notes = "\n".join(CrossEntropy.report(SimpleNamespace(stats=stats)).notes)
    assert "biasing density: von Mises-Fisher direction (kappa = " in notes
    assert "cross-entropy smoothing s per round: " + ", ".join(
        f"{s:.6g}" for s in stats[CE_SMOOTHING].values[:-1]) + ", stop; stopping c.o.v.: " \
        in notes
