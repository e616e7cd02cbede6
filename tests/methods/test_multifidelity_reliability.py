"""Multifidelity importance sampling against exact failure probabilities of level families.

Two families of limit states in two standard normal inputs u1, u2, whose scene key
``resolution`` sets a fidelity: h = 1 / resolution - 1 vanishes at the finest level
(resolution 1), so the finest P[failure] is exact while the coarse level (resolution 0.5,
h = 1) is biased.

- ``biased``: g = beta - u1 + c h (u2^2 - 1): the finest is linear, P = Phi(-beta); the coarse
  level fails earlier and on a parabola (its P by quadrature, three times the finest's).
- ``missed``: g = min(beta - u1, beta2 + u1 + s h): the finest fails on two half-planes,
  P = Phi(-beta) + Phi(-beta2); the coarse level has the first only (the second moved out
  to u1 < -beta2 - s, where phi is 1e-30): a biasing density built on the coarse level
  misses the second region, and only the defensive component samples it.

The statistical tests drive the method the way the executor does (plan, extend until None,
analyze) on runs evaluated in one vectorised call, so 10^4 runs take milliseconds; the
studies at the end go through ``run_study`` like any study.
"""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
import xarray as xr
from scipy import integrate
from scipy import stats as sps

import uqflow
from uqflow.errors import AccuracyWarning, StudyError
from uqflow.inputs import InputSpace, RandomInput
from uqflow.layout import (CONTROL_COARSE_DRAWS, CONTROL_COEFFICIENT, CONTROL_CORRELATION,
                           CONTROL_LEFT_OUT, CONTROL_OPTIMAL_RATIO, CONTROL_PAIRS,
                           CONTROL_THRESHOLD,
                           PLAIN_PROBABILITY, PLAIN_STDERR, WARNINGS, FAILURE_RUNS,
                           EQUIVALENT_FINEST_COST, EQUIVALENT_FINEST_RUNS,
                           FAILURE_COV, FAILURE_PROBABILITY,
                           FAILURE_STDERR, FIDELITY_COST, FIDELITY_RUNS, FINEST_COST_RATIO,
                           FINEST_SEARCH_INDEX, FINEST_SEARCH_ROUNDS, FINEST_SEARCH_SHIFT,
                           GUIDE_PROBABILITY, GUIDE_TOTAL_COST, INPUTS, LEVEL, ROUND,
                           STATUS, STATUS_FAILED, STATUS_OK, BIASING_MEAN)
from uqflow.levels import LevelsSpec, resolve_levels
from uqflow.limit_states import LimitStates
from uqflow.methods import get_method
from uqflow.methods.form import STAGE, STANDARD_NORMAL
from uqflow.methods.importance_sampling import standard_normal_log_pdf
from uqflow.methods.multifidelity_reliability import (STAGE_CONTROL, STAGE_ESTIMATE,
                                                      STAGE_FINEST_SEARCH,
                                                      MultifidelityImportanceSampling,
                                                      control_variate_estimate,
                                                      with_defensive)
from uqflow.realization import empty_runs
from uqflow.report import open_result, summary_table, write_figures
from uqflow.store import read_runs, write_result
from uqflow.study import load_study

from reliability_helpers import comparable, run_quietly as run

BETA, BIAS = 3.5, 0.5           # biased: the finest P = Phi(-3.5) = 2.33e-4
BETA2, SHIFT = 2.0, 10.0        # missed: the second region Phi(-2) = 0.0228
LEVELS = (0.5, 1.0)             # resolution: h = 1 at the coarse level, 0 at the finest


def biased(u, h):
    return BETA - u[:, 0] + BIAS * h * (u[:, 1] ** 2 - 1.0)


def missed(u, h):
    return np.minimum(BETA - u[:, 0], BETA2 + u[:, 0] + SHIFT * h)


def _resolution(value):
    return 1.0 / value - 1.0


def _biased_solver(u1=0.0, u2=0.0, resolution=1.0):
    return float(biased(np.array([[u1, u2]]), _resolution(resolution))[0])


BiasedSolver = uqflow.solver_from_function(_biased_solver, outputs="g", units="1",
                                           name="mfis-biased-test")
uqflow.register_solver("mfis-biased-test")(BiasedSolver)

LIMIT_STATE = [{"name": "fails", "output": "g", "below": 0.0}]


def coarse_biased_probability():
    """P[g <= 0] at h = 1: P[u1 >= beta - c + c u2^2] = E[Phi(-(beta - c + c u2^2))]."""
    def integrand(v):
        return sps.norm.sf(BETA - BIAS + BIAS * v * v) * sps.norm.pdf(v)
    # a smooth integrand decaying like a Gaussian: quad's 1e-12 relative is far inside the
    # 10 % the test asks of the bias
    return integrate.quad(integrand, -np.inf, np.inf, epsabs=0, epsrel=1e-12)[0]


# --------------------------------------------------------------- the method, driven directly

def space(dim=2):
    return InputSpace([RandomInput.from_spec({"name": f"u{i + 1}", "distribution": "normal",
                                              "mean": 0.0, "std": 1.0}) for i in range(dim)])


def configured(levels=LEVELS, **options) -> MultifidelityImportanceSampling:
    method = MultifidelityImportanceSampling(**options)
    template = BiasedSolver.from_scene({}).outputs()
    method.check_limit_states(LimitStates.from_tables(LIMIT_STATE, template))
    method.check_levels(resolve_levels(LevelsSpec(key="resolution", values=list(levels)),
                                       {}, BiasedSolver, ["g"], "scene"))
    return method


def evaluate(design, problem, levels=LEVELS):
    runs = empty_runs(design, BiasedSolver.from_scene({}).outputs())
    h = _resolution(np.asarray(levels)[design[LEVEL].values])
    g = problem(design[INPUTS].values, h)
    runs["g"].values[:] = g
    # a problem marks a run that fails (a solver error) with NaN
    runs[STATUS].values[:] = np.where(np.isfinite(g), STATUS_OK, STATUS_FAILED)
    runs["wall_time"].values[:] = 0.0
    return runs


def drive(method, problem, seed, levels=LEVELS, dim=2):
    design = method.plan(space(dim), None, np.random.SeedSequence(seed))
    runs = evaluate(design, problem, levels)
    glue = dict(dim="realization", data_vars="minimal", coords="minimal", compat="override",
                join="override")
    while (more := method.extend(design, runs)) is not None:
        n = design.sizes["realization"]
        more = more.assign_coords(realization=np.arange(n, n + more.sizes["realization"]))
        runs = xr.concat([runs, evaluate(more, problem, levels)], **glue)
        design = xr.concat([design, more], **glue)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        return method.analyze(design, runs), runs


def estimate(stats):
    return (float(stats[FAILURE_PROBABILITY].values[0]),
            float(stats[FAILURE_STDERR].values[0]))


# --------------------------------------------------------------- the problems themselves

def test_the_finest_level_is_exact_and_the_coarse_level_biased():
    u = np.random.default_rng(0).standard_normal((1000, 2))
    # h = 0 leaves beta - u1 itself: the finest P is Phi(-beta) with no approximation
    assert np.array_equal(biased(u, np.zeros(1000)), BETA - u[:, 0])
    assert np.array_equal(missed(u, np.zeros(1000)), np.minimum(BETA - u[:, 0],
                                                                 BETA2 + u[:, 0]))
    assert coarse_biased_probability() > 2.5 * sps.norm.sf(BETA)
    # the coarse missed level has no second region: phi(u1 < -12) = 1.8e-33
    assert sps.norm.cdf(-BETA2 - SHIFT) < 1e-30
    assert _biased_solver(1.0, 2.0, resolution=0.5) == BETA - 1.0 + BIAS * 3.0


# --------------------------------------------------------------- unbiased at the finest level

@pytest.mark.parametrize("search", ["cross-entropy", "form"])
def test_the_finest_probability_is_unbiased_where_the_coarse_level_is_biased(search):
    stats, runs = drive(configured(search=search, costs=[1.0, 10.0]), biased, seed=3)
    p, stderr = estimate(stats)
    exact = sps.norm.sf(BETA)
    # 4 standard errors: a correct estimator fails 1 in 16,000 seeds (normal tail)
    assert abs(p - exact) <= 4 * stderr
    # 1000 draws near the design point: c.o.v. about 0.07 (plain MC would need 2e5 runs)
    assert float(stats[FAILURE_COV].values[0]) < 0.1
    # stage 1 on the coarse level only (FORM's refinement, its own stage, on the finest),
    # stage 2 on the finest only
    level, stage = runs[LEVEL].values, runs[STAGE].values
    assert set(level[stage == STAGE_ESTIMATE]) == {1}
    assert set(level[(stage != STAGE_ESTIMATE) & (stage != STAGE_FINEST_SEARCH)]) == {0}
    assert set(level[stage == STAGE_FINEST_SEARCH]) == ({1} if search == "form" else set())
    assert int((stage == STAGE_ESTIMATE).sum()) == 1000
    # the coarse level's own estimate is its own, biased one: FORM's Phi(-beta_coarse) (the
    # coarse design point is (beta - c, 0): beta_coarse = 3) or the cross-entropy estimate of
    # the coarse P (within 30 %: its last round's 500 draws, c.o.v. about 0.1)
    guide = float(stats[GUIDE_PROBABILITY].values[0])
    if search == "form":
        # the search converges to |g| <= 1e-3 |g(0)|: beta within ~3e-3, Phi(-beta) 1 %
        assert guide == pytest.approx(sps.norm.sf(BETA - BIAS), rel=0.01)
    else:
        assert guide == pytest.approx(coarse_biased_probability(), rel=0.3)


@pytest.mark.parametrize("search_levels", ["coarsest", "all"])
def test_with_three_levels_the_rounds_climb_the_levels_before_the_finest(search_levels):
    # resolutions 0.25, 0.5, 1: h = 3, 1, 0, coarse design points at u1 = 2, 3 and the
    # finest's at 3.5; with "all" the rounds reach level 0's failures, then level 1's
    levels = (0.25, 0.5, 1.0)
    # the quantile rule: its last round at a level fits the failures themselves, which the
    # next level's first round draws from
    stats, runs = drive(configured(levels, search_levels=search_levels, rule="quantile",
                                   costs=[1.0, 2.0, 10.0]), biased, seed=7, levels=levels)
    p, stderr = estimate(stats)
    assert abs(p - sps.norm.sf(BETA)) <= 4 * stderr    # 4 standard errors: 1 in 16,000
    stage, level = runs[STAGE].values, runs[LEVEL].values
    assert set(level[stage == STAGE_ESTIMATE]) == {2}
    used = {"coarsest": {0}, "all": {0, 1}}[search_levels]
    assert set(level[stage != STAGE_ESTIMATE]) == used
    if search_levels == "all":
        # level 1's rounds start from level 0's failures: their first round is its last
        # (the tenth of its draws nearest failure already fail there), and the guide is the
        # middle level's own P, the biased family at h = 1 (within 30 %: 500 draws)
        rounds_at_1 = np.unique(runs[ROUND].values[(level == 1)])
        assert rounds_at_1.size == 1
        guide = float(stats[GUIDE_PROBABILITY].values[0])
        assert guide == pytest.approx(coarse_biased_probability(), rel=0.3)
    assert list(stats[FIDELITY_RUNS].values)[2] == 1000


def test_forgetting_the_likelihood_ratio_would_be_far_off():
    # the same finest-level draws, counted as plain Monte Carlo: the fraction of failures
    # under q is near 0.5, three orders above the answer the weights give back
    stats, runs = drive(configured(search="form", costs=[1.0, 10.0]), biased, seed=3)
    rows = runs[STAGE].values == STAGE_ESTIMATE
    fraction = float(np.mean(runs["g"].values[rows] <= 0))
    p, stderr = estimate(stats)
    assert fraction > 100 * p and abs(fraction - sps.norm.sf(BETA)) > 1000 * stderr


@pytest.mark.parametrize("search", ["cross-entropy", "form"])
def test_the_defensive_component_keeps_a_region_the_coarse_level_misses(search):
    method = configured(search=search, samples=10_000, costs=[1.0, 10.0])
    stats, runs = drive(method, missed, seed=11)
    p, stderr = estimate(stats)
    exact = sps.norm.sf(BETA) + sps.norm.sf(BETA2)
    # 4 standard errors (1 in 16,000 seeds); the missed region is sampled only by the
    # defensive share, 0.1 x 10,000 x 0.0228 = 23 expected draws
    assert abs(p - exact) <= 4 * stderr
    assert stderr < 0.3 * exact
    # the same draws weighted as if q had no defensive component (its weight 1e-12):
    # the missed region has no draw of the Gaussian part and the estimate is the found
    # region's alone, many of its own standard errors below the answer
    guide = method.guide(runs)
    focused = with_defensive(_without_last(guide.density), 1e-12)
    rows = runs[STAGE].values == STAGE_ESTIMATE
    u = runs[STANDARD_NORMAL].values[rows]
    failed = runs["g"].values[rows] <= 0
    near_coarse = u[:, 0] > 0
    weights = np.exp(standard_normal_log_pdf(u) - focused.log_pdf(u))
    terms = np.where(failed & near_coarse, weights, 0.0)
    alone, alone_se = terms.mean(), terms.std(ddof=1) / math.sqrt(terms.size)
    assert exact - alone > 20 * alone_se


def _without_last(density):
    """The biasing density without its defensive (last) component."""
    from uqflow.methods.importance_sampling import GaussianMixture
    return GaussianMixture(density.weights[:-1], density.means[:-1],
                           density.covariances[:-1])


def test_the_reported_standard_error_matches_the_spread_over_seeds():
    # 40 seeds of stage 2 at 300 finest runs each, on one stage 1 (FORM's is the same for
    # every seed: the spread is stage 2's, which the standard error describes)
    method = configured(search="form", samples=300, costs=[1.0, 10.0])
    runs = drive(method, biased, seed=0)[1]
    stage1 = runs.isel(realization=np.flatnonzero(runs[STAGE].values != STAGE_ESTIMATE))
    guide = method.guide(stage1)
    found = []
    for seed in range(40):
        method.plan(space(), None, np.random.SeedSequence(seed))
        got = method.estimate(evaluate(method.extend(stage1, stage1), biased), guide)
        found.append((got.probability, got.stderr))
    found = np.array(found)
    p, stderr = found[:, 0], found[:, 1]
    exact = sps.norm.sf(BETA)
    # the spread of 40 estimates has a relative standard error ~ 1/sqrt(80) = 0.11: the
    # ratio within 0.6 .. 1.5 is about 4 of those either side
    ratio = p.std(ddof=1) / np.sqrt(np.mean(stderr**2))
    assert 0.6 < ratio < 1.5
    # the mean of 40 unbiased estimates within 4 of its standard errors of the answer
    assert abs(p.mean() - exact) <= 4 * p.std(ddof=1) / math.sqrt(40)
    # 95 % intervals: 40 x 0.95 = 38 expected to cover; 33 or fewer has binomial
    # probability 0.5 % for a correct interval
    low, high = p - 1.96 * stderr, p + 1.96 * stderr
    assert int(np.sum((low <= exact) & (exact <= high))) >= 34


def test_a_search_cut_short_says_so_and_stays_unbiased():
    # one cross-entropy round cannot reach the coarse failure region (its tenth-quantile of g
    # is near 1.7): the density is that round's fit, the result says so, and the defensive
    # share keeps the estimate unbiased
    method = configured(max_search_rounds=1, samples=4000, costs=[1.0, 10.0])
    design = method.plan(space(), None, np.random.SeedSequence(5))
    stats, runs = drive(method, biased, seed=5)
    assert stats.attrs["guide_reached"] == 0 and stats.attrs["guide_search_rounds"] == 1
    assert "did not reach the failure region of level 0 in max_search_rounds = 1" in \
        stats.attrs["warnings"]
    p, stderr = estimate(stats)
    assert abs(p - sps.norm.sf(BETA)) <= 4 * stderr    # 4 standard errors: 1 in 16,000
    assert design.sizes["realization"] == 500


def test_finest_runs_that_failed_are_left_out_and_counted():
    method = configured(search="form", costs=[1.0, 10.0])
    stats, runs = drive(method, biased, seed=3)
    broken = runs.copy(deep=True)
    rows = np.flatnonzero(broken[STAGE].values == STAGE_ESTIMATE)[:25]
    broken[STATUS].values[rows] = "failed"
    broken["g"].values[rows] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        again = method.analyze(broken, broken)
    assert int(again["failure_probability_left_out"].values[0]) == 25
    assert int(again["failure_probability_runs"].values[0]) == 975
    assert "25 finest-level runs did not run ok and are left out" in again.attrs["warnings"]
    assert again.attrs["failed_runs"] == 25
    # the others make the estimate: the same as the draws without those 25
    kept = runs.isel(realization=np.setdiff1d(np.arange(runs.sizes["realization"]), rows))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        alone = method.analyze(kept, kept)
    assert estimate(again) == estimate(alone)


def test_the_outputs_moments_are_weighted_back_to_the_inputs_distribution():
    # g = 3.5 - u1 at the finest level: mean 3.5, std 1 under the inputs' distribution,
    # although the draws sit near u1 = 3.5 where g is near 0
    stats, runs = drive(configured(search="form", costs=[1.0, 10.0]), biased, seed=3)
    mean, std, stderr = (float(stats["g"].sel(statistic=s)) for s in ("mean", "std", "stderr"))
    rows = runs[STAGE].values == STAGE_ESTIMATE
    assert abs(float(np.mean(runs["g"].values[rows]))) < 1.0       # unweighted: far off
    # 4 standard errors (delta method): 1 in 16,000 seeds
    assert abs(mean - BETA) <= 4 * stderr and stderr < 0.2
    # the std of a weighted sample of ~100 effective draws: within 30 % of 1
    assert std == pytest.approx(1.0, rel=0.3)


def relative_variance(beta, along, across):
    """Relative variance per draw of 1[beta - u1 <= 0] phi / q*, q* = N(mu, I), mu = (along,
    across): docs/rare_events_across_levels.md's exp(|mu|^2) Phi(-(beta + a.mu)) / P^2 - 1."""
    return math.exp(along**2 + across**2) * sps.norm.sf(beta + along) / \
        sps.norm.sf(beta) ** 2 - 1.0


def test_the_docs_relative_variance_of_a_shifted_biasing_density_is_exact():
    # the second moment as the product of its two one-dimensional integrals, by quadrature
    def moment(lower, shift):
        def integrand(v):       # phi(v)^2 / phi(v - shift), in logs (both underflow far out)
            return math.exp(2 * sps.norm.logpdf(v) - sps.norm.logpdf(v - shift))
        # quadrature to its 1e-10 relative error estimate (smooth, decaying)
        return integrate.quad(integrand, lower, np.inf, epsabs=0, epsrel=1e-10)[0]
    for along, across in ((3.5, 0.0), (3.0, 0.8), (3.25 * math.cos(math.radians(15)),
                                                     3.25 * math.sin(math.radians(15)))):
        direct = moment(BETA, along) * moment(-np.inf, across) / sps.norm.sf(BETA) ** 2 - 1
        # quad's 1e-10 relative on two smooth Gaussian integrals, the ratio amplifying it by
        # (1 + R) / R < 1.3 here: 1e-8 is far outside both
        assert relative_variance(BETA, along, across) == pytest.approx(direct, rel=1e-8)
    # the figures the docs quote: at the finest design point, and at the 100-input
    # benchmark's coarse one (3.25 along a direction turned 15 degrees)
    assert round(relative_variance(BETA, BETA, 0.0), 2) == 3.94
    turn = math.radians(15.0)
    assert round(relative_variance(BETA, 3.25 * math.cos(turn), 3.25 * math.sin(turn)), 1) \
        == 10.3
    # with the defensive share, centred at the finest design point (the refinement's centre):
    # q/phi = (1 - w) exp(beta t - beta^2 / 2) + w depends on t = a.u alone, so the second
    # moment is the one-dimensional integral of phi(t) / (q/phi) over t > beta
    def defensive(w):
        def integrand(t):
            return math.exp(sps.norm.logpdf(t) - np.logaddexp(
                math.log1p(-w) + BETA * t - BETA**2 / 2, math.log(w)))
        # quadrature to its 1e-10 relative error estimate (smooth, decaying like phi): the
        # rounded figure below is 4 orders of magnitude coarser
        return integrate.quad(integrand, BETA, np.inf, epsabs=0, epsrel=1e-10)[0] / \
            sps.norm.sf(BETA) ** 2 - 1
    # w -> 0 gives back the shifted Gaussian's 3.94 (w = 1e-9 changes it by ~1e-9 relative)
    assert defensive(1e-9) == pytest.approx(relative_variance(BETA, BETA, 0.0), rel=1e-6)
    assert round(defensive(0.1), 2) == 4.49
    # the docs' finest runs x c.o.v.^2 at a budget of N finest runs: N R_w / (N - d - 1) for
    # the refined multifidelity estimate (d = 100: its refinement's 101 runs; d = 2: 3), and
    # N R / (N - c_FORM) for FORM + importance sampling at the finest design point, c_FORM the
    # benchmark's OpenTURNS FORM cost (609 in 100 inputs, 100 in two)
    exact = relative_variance(BETA, BETA, 0.0)
    assert [round(1101 * defensive(w) / 1000, 2) for w in (0.02, 0.1, 0.3)] == \
        [4.45, 4.94, 6.67]
    assert round(2101 * defensive(0.1) / 2000, 2) == 4.72
    assert (round(1101 * exact / (1101 - 609), 2), round(2101 * exact / (2101 - 609), 2)) == \
        (8.82, 5.55)
    assert (round(1003 * defensive(0.1) / 1000, 2), round(1100 * exact / 1000, 2)) == \
        (4.50, 4.34)
    # where the two meet: N R_w / (N - 101) = N R / (N - 609)
    meet = (609 * defensive(0.1) - 101 * exact) / (defensive(0.1) - exact)
    assert round(meet, -2) == 4300


def test_the_equivalent_finest_level_cost_is_plain_monte_carlo_at_the_same_cov():
    stats, runs = drive(configured(search="form", costs=[1.0, 10.0]), biased, seed=3)
    p, cov = float(stats[FAILURE_PROBABILITY].values[0]), float(stats[FAILURE_COV].values[0])
    runs_needed = (1 - p) / (cov**2 * p)
    # the same three roundings (eps/2 = 1.1e-16 each) in perhaps another order, condition
    # number 1 in p and 2 in the c.o.v.: <= 1e-15, and a few-ulp change of p or the c.o.v.
    # moves it by a few ulp more (checked with np.nextafter); 1e-12 leaves 1000 times that
    assert float(stats[EQUIVALENT_FINEST_RUNS].values[0]) == pytest.approx(runs_needed,
                                                                            rel=1e-12)
    per_level = stats[FIDELITY_RUNS].values
    spent = per_level[0] * 1.0 + per_level[1] * 10.0
    # integers times integral costs, far below 2**53: exact in float64, in any order
    assert stats.attrs[GUIDE_TOTAL_COST] == spent
    # one or two more roundings (a product, a quotient, condition number 1) on top of the
    # above's 1e-15
    assert float(stats[EQUIVALENT_FINEST_COST].values[0]) == pytest.approx(
        10.0 * runs_needed, rel=1e-12)
    # the same, one quotient more
    assert float(stats[FINEST_COST_RATIO].values[0]) == pytest.approx(
        10.0 * runs_needed / spent, rel=1e-12)
    # Phi(-3.5) at c.o.v. 0.07 is ~9e5 finest runs; the study ran 1000 of them
    assert float(stats[FINEST_COST_RATIO].values[0]) > 50
    assert list(stats[FIDELITY_COST].values) == [1.0, 10.0]


@pytest.mark.parametrize("search", ["cross-entropy", "form"])
def test_draws_depend_on_the_seed_and_the_runs_alone(search):
    first = drive(configured(search=search, costs=[1.0, 10.0]), biased, seed=3)[1]
    again = drive(configured(search=search, costs=[1.0, 10.0]), biased, seed=3)[1]
    other = drive(configured(search=search, costs=[1.0, 10.0]), biased, seed=4)[1]
    np.testing.assert_array_equal(first[INPUTS].values, again[INPUTS].values)
    estimate_rows = first[STAGE].values == STAGE_ESTIMATE
    assert not np.array_equal(first[INPUTS].values[estimate_rows][:10],
                              other[INPUTS].values[other[STAGE].values == STAGE_ESTIMATE][:10])
    if search == "form":    # the refinement's round ran, between FORM's and the estimate
        assert (first[STAGE].values == STAGE_FINEST_SEARCH).sum() == 3
    # every prefix of finished rounds gives back, bit for bit, the round that ran next
    method = configured(search=search, costs=[1.0, 10.0])
    method.plan(space(), None, np.random.SeedSequence(3))
    rounds = first[ROUND].values
    for r in range(int(rounds.max())):
        prefix = first.isel(realization=np.flatnonzero(rounds <= r))
        more = method.extend(prefix, prefix)
        np.testing.assert_array_equal(more[INPUTS].values, first[INPUTS].values[rounds == r + 1])
    assert method.extend(first, first) is None


def test_target_cov_adds_batches_until_it_is_met():
    stats, runs = drive(configured(search="form", samples=100, target_cov=0.1,
                                   max_samples=5000, costs=[1.0, 10.0]), biased, seed=3)
    stage = runs[STAGE].values
    batches = np.unique(runs[ROUND].values[stage == STAGE_ESTIMATE])
    assert float(stats[FAILURE_COV].values[0]) <= 0.1 and batches.size >= 2
    # one batch fewer did not meet it
    last = runs[ROUND].values != batches[-1]
    method = configured(search="form", samples=100, target_cov=0.1, max_samples=5000,
                        costs=[1.0, 10.0])
    prefix = runs.isel(realization=np.flatnonzero(last))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        assert float(method.analyze(prefix, prefix)[FAILURE_COV].values[0]) > 0.1


# --------------------------------------------------------------- FORM's refinement, finest level

#: the rotated family: the finest g = beta - a.u along a = (cos 30, sin 30) degrees, P =
#: Phi(-beta); the coarse level's g = 3 - b.u, b turned 20 degrees from a: its design point
#: 3 b is 1.23 from the finest's 3.5 a
FINEST_DIRECTION = np.array([math.cos(math.radians(30.0)), math.sin(math.radians(30.0))])
COARSE_DIRECTION = np.array([math.cos(math.radians(50.0)), math.sin(math.radians(50.0))])


def rotated(u, h):
    return np.where(h > 0, 3.0 - u @ COARSE_DIRECTION, BETA - u @ FINEST_DIRECTION)


def test_the_refinement_centres_the_biasing_density_at_the_finest_design_point():
    stats, runs = drive(configured(search="form", costs=[1.0, 10.0]), rotated, seed=3)
    centre = stats[BIASING_MEAN].values[0]
    # one HL-RF step from any point of a linear g lands on its design point: the forward
    # differences of a linear g are exact but for rounding, g's values (|g| < 5) rounded at
    # eps = 2.2e-16 over the step 0.01 leave ~1e-13 in the gradient, and beta = 3.5 times
    # that in the centre; 1e-9 is far outside it, and far inside the 1.23 the coarse point is off
    np.testing.assert_allclose(centre, BETA * FINEST_DIRECTION, rtol=0, atol=1e-9)
    assert float(stats[FINEST_SEARCH_INDEX].values[0]) == pytest.approx(BETA, abs=1e-9)
    assert stats.attrs[FINEST_SEARCH_ROUNDS] == 1
    # without the refinement the centre is the coarse design point (FORM's tolerance 1e-3)
    coarse = drive(configured(search="form", costs=[1.0, 10.0], finest_search_rounds=0),
                   rotated, seed=3)[0]
    np.testing.assert_allclose(coarse[BIASING_MEAN].values[0], 3.0 * COARSE_DIRECTION,
                               atol=1e-2)
    assert stats.attrs[FINEST_SEARCH_SHIFT] == pytest.approx(
        float(np.linalg.norm(BETA * FINEST_DIRECTION - 3.0 * COARSE_DIRECTION)), abs=1e-2)
    p, stderr = estimate(stats)
    assert abs(p - sps.norm.sf(BETA)) <= 4 * stderr    # 4 standard errors: 1 in 16,000


def test_the_refinements_stencil_runs_count_in_the_finest_cost():
    stats, runs = drive(configured(search="form", costs=[1.0, 10.0]), rotated, seed=3)
    stage, level = runs[STAGE].values, runs[LEVEL].values
    refining = stage == STAGE_FINEST_SEARCH
    # the coarse design point and its forward-difference stencil: n + 1 = 3 finest runs
    assert refining.sum() == 3 and set(level[refining]) == {1}
    finest = int((level == 1).sum())
    assert finest == 1003 and int(stats[FIDELITY_RUNS].values[1]) == finest
    coarse = int((level == 0).sum())
    # integers times integral costs, far below 2**53: exact in float64
    assert stats.attrs[GUIDE_TOTAL_COST] == coarse * 1.0 + finest * 10.0
    # the equivalent cost over what both stages and the refinement cost: a product and a
    # quotient (condition number 1), no libm or BLAS call: a few roundings of eps/2 on any
    # CPU, far inside 1e-12
    ratio = float(stats[EQUIVALENT_FINEST_COST].values[0]) / (coarse + 10.0 * finest)
    # bound: a product and a quotient of stored floats, a few eps/2 roundings, no libm, BLAS
    # or numpy reduction, the same on any CPU: 1e-12 relative
    assert float(stats[FINEST_COST_RATIO].values[0]) == pytest.approx(ratio, rel=1e-12, abs=0)


def test_a_refinement_whose_finest_run_fails_falls_back_to_the_coarse_design_point():
    plain = drive(configured(search="form", costs=[1.0, 10.0], finest_search_rounds=0),
                  rotated, seed=3)[0]
    coarse_point = plain[BIASING_MEAN].values[0]

    def broken(u, h):   # the finest runs within 0.05 of the coarse design point fail
        g = rotated(u, h)
        near = np.linalg.norm(u - coarse_point, axis=1) < 0.05
        return np.where((h == 0) & near, np.nan, g)

    stats, runs = drive(configured(search="form", costs=[1.0, 10.0]), broken, seed=3)
    # the same centre, bit for bit, as without the refinement
    np.testing.assert_array_equal(stats[BIASING_MEAN].values[0], coarse_point)
    assert np.isnan(float(stats[FINEST_SEARCH_INDEX].values[0]))
    assert "gradient at the coarse design point is not usable" in stats.attrs["warnings"]
    assert "finest-level runs of the design point's refinement did not run ok" in \
        stats.attrs["warnings"]
    p, stderr = estimate(stats)
    assert abs(p - sps.norm.sf(BETA)) <= 4 * stderr    # 4 standard errors: 1 in 16,000


# --------------------------------------------------------------- cross-entropy in many inputs

def wide(u, h):
    """The wide family, benchmarks/reliability_levels.py's linear-100d in d = u.shape[1]
    standard normals: the finest g = beta - a.u along a = (1, ..., 1) / sqrt(d), P =
    Phi(-beta); the coarse level's g = 3.25 - b.u, b turned 15 degrees from a (towards
    (e1 - e2) / sqrt 2)."""
    finest, coarse = wide_directions(u.shape[1])
    return np.where(h > 0, 3.25 - u @ coarse, BETA - u @ finest)


def wide_directions(d):
    finest = np.full(d, 1.0 / math.sqrt(d))
    across = np.r_[1.0, -1.0, np.zeros(d - 2)] / math.sqrt(2.0)
    turn = math.radians(15.0)
    return finest, math.cos(turn) * finest + math.sin(turn) * across


def test_the_cross_entropy_search_fits_the_single_level_methods_family_in_100_inputs():
    # the search that failed here (a Gaussian fitted to the quantile rule's 50 elites of 500
    # draws: this seed's estimate 1e-6 times the answer, 8.8e5 standard errors off) now the
    # single-level method's: family = "auto", the von Mises-Fisher-Nakagami density from 20
    # inputs on, fitted by the improved rule's rounds at the coarse level
    method = configured(coarse_samples=500, samples=1000, costs=[1.0, 10.0])
    stats, runs = drive(method, wide, seed=3, dim=100)
    assert stats.attrs["cross_entropy_family"] == "vmfn"
    assert stats.attrs["cross_entropy_rule"] == "improved"
    # its mean direction near the coarse level's (cos 15 degrees = 0.97 from the finest's)
    assert stats["vmf_mean_direction"].values @ wide_directions(100)[1] > 0.9
    assert set(runs[LEVEL].values[runs[STAGE].values != STAGE_ESTIMATE]) == {0}
    p, stderr = estimate(stats)
    assert abs(p - sps.norm.sf(BETA)) <= 4 * stderr    # 4 standard errors: 1 in 16,000
    # over 10 seeds its reported c.o.v.s average 0.18 and the spread is 0.18 of p
    assert float(stats[FAILURE_COV].values[0]) < 0.3
    assert "degenerated" not in stats.attrs["warnings"]


def test_a_cross_entropy_fit_on_fewer_effective_draws_than_inputs_warns():
    # the quantile rule's tenth of 100 draws: 10 elites for a Gaussian's 20 means
    method = configured(rule="quantile", family="gaussian", coarse_samples=100, samples=200,
                        costs=[1.0, 10.0])
    stats = drive(method, wide, seed=1, dim=20)[0]
    assert "effective draws for 20 inputs" in stats.attrs["warnings"]


def test_weights_carried_by_a_few_draws_warn():
    # the missed family with a defensive share of 0.02: this seed draws one point of the
    # second region (weight about 1/w), which carries the estimate (2.2 times the answer,
    # effective sample size 1.0 of 481 failures): said, not silent
    method = configured(search="form", defensive_weight=0.02, costs=[1.0, 10.0])
    stats = drive(method, missed, seed=2)[0]
    assert float(stats["effective_sample_size"].values[0]) < 2
    assert "the importance weights have degenerated: effective sample size 1.01" in \
        stats.attrs["warnings"]


# --------------------------------------------------------------- the coarse control variate

def same(u, h):
    """Both levels the finest's linear g: the control is the estimate's own terms (rho = 1)."""
    return BETA - u[:, 0]


def coarse_fails_above(u, h):
    """biased, but the coarse level's solver fails (NaN) wherever u2 > 1."""
    return np.where((h > 0) & (u[:, 1] > 1.0), np.nan, biased(u, h))


CONTROL = dict(search="form", samples=400, costs=[1.0, 64.0], control_variate=True,
               coarse_draws_per_finest=5)


def value(stats, name):
    return float(stats[name].values[0])


def test_the_control_variate_estimate_is_unbiased_and_its_variance_the_mfmc_formula():
    stats, runs = drive(configured(**CONTROL), biased, 3)
    p, stderr = estimate(stats)
    assert abs(p - sps.norm.sf(BETA)) <= 4 * stderr   # 4 standard errors: 1 in 16,000
    n, m = value(stats, CONTROL_PAIRS), value(stats, CONTROL_COARSE_DRAWS)
    assert (n, m) == (400, 2000)
    assert (runs[STAGE].values == STAGE_CONTROL).sum() == 2000
    rho = value(stats, CONTROL_CORRELATION)
    # the coarse event matched to the finest first-order index 3.5 (coarse FORM: 3.0, its
    # g's slope 1): t = (3 - 3.5) * 1, which correlates the two levels' terms
    assert value(stats, CONTROL_THRESHOLD) == pytest.approx(-0.5, abs=1e-6)  # HL-RF's tol
    assert rho > 0.3
    # with alpha = cov / var the variance is the plain one times 1 - (1 - N / M) rho^2 (the
    # pairs are all the finest runs): the same sums of N = 400 terms in another grouping
    plain = value(stats, PLAIN_STDERR)
    mfmc = plain**2 * (1 - (1 - n / m) * rho**2)
    # bound: N eps = 9e-14 per sum in any summation order (numpy's SIMD paths), times the
    # factor's condition 1 / (1 - rho^2) < 2 and a few exp roundings of the weights: 1e-11
    assert stderr**2 == pytest.approx(mfmc, rel=1e-11, abs=0)
    assert stderr < plain
    # MFMC's optimal M / N at the stated costs 1 and 64: a square root of a ratio of the
    # stored rho's own functions (sqrt is correctly rounded everywhere), condition < 2
    optimal = math.sqrt(64 * rho**2 / (1 - rho**2))
    # bound: a few eps roundings times condition < 2, sqrt correctly rounded on every libm,
    # no BLAS or numpy reduction: 1e-13
    assert value(stats, CONTROL_OPTIMAL_RATIO) == pytest.approx(optimal, rel=1e-13, abs=0)


def test_the_control_variate_variance_matches_the_formula_by_hand():
    # M = 6 draws of q with likelihood ratios 1/2, 1/4, 2, 1, 1/8, 3/2; the finest fails at
    # the first 3 (N = 3) as marked, the coarse event as marked; by hand, exactly in fractions
    from fractions import Fraction as F
    ratios = [F(1, 2), F(1, 4), F(2), F(1), F(1, 8), F(3, 2)]
    fine, coarse = [True, False, True], [True, True, False, True, False, True]
    yf = [r if f else F(0) for r, f in zip(ratios, fine)]
    yc = [r if c else F(0) for r, c in zip(ratios, coarse)]
    n, m = 3, 6
    mf, mc_n, mc_m = sum(yf) / n, sum(yc[:n]) / n, sum(yc) / m
    var_f = sum((y - mf) ** 2 for y in yf) / (n - 1)
    var_c = sum((y - mc_n) ** 2 for y in yc[:n]) / (n - 1)
    cov = sum((a - mf) * (b - mc_n) for a, b in zip(yf, yc[:n])) / (n - 1)
    alpha = cov / var_c
    p = mf - alpha * (mc_n - mc_m)
    var = var_f / n + (F(1, n) - F(1, m)) * (alpha**2 * var_c - 2 * alpha * cov)
    found = control_variate_estimate(fine, coarse, np.log([float(r) for r in ratios]))
    # exp(log r) is r within a few ulp on any libm; the sums have at most 6 terms of like
    # size and the variance's terms do not cancel by more than a factor 10 here
    # bound: a few ulp times 6 terms, times 10 for the cancellation: 1e-13; 1e-12
    assert found.probability == pytest.approx(float(p), rel=1e-12, abs=0)
    # bound: numpy's exp within a few ulp on any CPU, sums of 6 like terms in any order, a
    # cancellation of at most 10 in the variance: 1e-13; 1e-12
    assert found.stderr**2 == pytest.approx(float(var), rel=1e-12, abs=0)
    # bound: the covariance over the variance, each as the line above (a few ulp of exp, 6
    # terms, cancellation <= 10), in any summation order: 1e-13; 1e-12
    assert found.coefficient == pytest.approx(float(alpha), rel=1e-12, abs=0)
    assert (found.n, found.coarse_draws) == (3, 6)


def test_a_coarse_level_equal_to_the_finest_leaves_only_the_var_over_m_term():
    method = configured(**dict(CONTROL, control_event="coarse"))
    stats, runs = drive(method, same, 5)
    p, stderr = estimate(stats)
    # the two levels' terms are the same numbers: cov / sqrt(var var) and cov / var are 1
    # bound: up to N = 400-term sums' rounding in two groupings, 400 eps = 9e-14: 1e-12
    assert value(stats, CONTROL_CORRELATION) == pytest.approx(1.0, rel=1e-12, abs=0)
    # bound: cov / var of the same 400 numbers summed in two groupings (numpy's SIMD or
    # not), 400 eps = 9e-14 each: 1e-12
    assert value(stats, CONTROL_COEFFICIENT) == pytest.approx(1.0, rel=1e-12, abs=0)
    assert value(stats, CONTROL_OPTIMAL_RATIO) == math.inf   # every coarse draw pays
    # alpha = 1: P is the mean of the M coarse terms, var(Y_f) / M its variance
    rows = np.flatnonzero(runs[STAGE].values == STAGE_CONTROL)
    u = runs[STANDARD_NORMAL].values[rows]
    density = method.guide(runs).density
    terms = np.where(runs["g"].values[rows] <= 0,
                     np.exp(standard_normal_log_pdf(u) - density.log_pdf(u)), 0.0)
    # sums of 2000 positive terms (exp of the same log ratios on any libm to a few ulp):
    # each rounding relative eps in any order, at most 2000 eps = 4.4e-13
    # bound: 4.4e-13 plus a few ulp: 1e-11
    assert p == pytest.approx(terms.mean(), rel=1e-11, abs=0)
    # bound: sums of 2000 positive terms in any order (4.4e-13), exp to a few ulp on any
    # libm or numpy SIMD path, one correctly rounded sqrt: 1e-11
    assert stderr == pytest.approx(value(stats, PLAIN_STDERR) / math.sqrt(5), rel=1e-11, abs=0)


def test_coarse_runs_of_the_control_that_fail_are_left_out_and_said():
    stats, runs = drive(configured(**CONTROL), coarse_fails_above, 3)
    control = runs[STAGE].values == STAGE_CONTROL
    failed = control & (runs[STATUS].values == STATUS_FAILED)
    twins = np.flatnonzero(control)[:400]
    left = int((runs[STATUS].values[twins] == STATUS_FAILED).sum())
    assert left > 0
    assert value(stats, CONTROL_LEFT_OUT) == left
    assert value(stats, CONTROL_PAIRS) == 400 - left
    assert value(stats, CONTROL_COARSE_DRAWS) == 2000 - int(failed.sum())
    assert f"{int(failed.sum())} coarse-level runs of the control variate did not run ok" \
        in stats.attrs[WARNINGS]
    p, stderr = estimate(stats)
    assert abs(p - sps.norm.sf(BETA)) <= 4 * stderr   # 4 standard errors: 1 in 16,000
    # the plain estimate keeps the finest runs whose twin failed
    assert value(stats, FAILURE_RUNS) == 400
    assert value(stats, PLAIN_PROBABILITY) != p


# --------------------------------------------------------------- studies through the executor

def toml(value) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (str, bool)):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml(v) for v in value) + "]"
    return repr(value)


def study_file(tmp_path, name, method=None, *, levels=True, workers=0, limit_states=None,
               batch=7):
    """The analytic linear model g = offset - u1 in two standard normals, the offset as the
    levels' key: 3.0 at the coarse level (biased), 3.5 at the finest (P = Phi(-3.5))."""
    method = {"kind": "multifidelity-importance-sampling", "samples": 100,
              "costs": [1.0, 10.0], **(method or {})}
    if method.get("search", "cross-entropy") == "cross-entropy":
        method.setdefault("coarse_samples", 50)
    lines = [f'name = "{name}"', 'solver = "analytic"',
             'scene = { model = "linear", offset = 3.5, coefficients = [-1.0, 0.0] }', ""]
    for n in ("x1", "x2"):
        lines += ["[[inputs]]", f'name = "{n}"', 'distribution = "normal"', "mean = 0.0",
                  "std = 1.0", ""]
    if levels:
        lines += ["[levels]", 'key = "offset"', "values = [3.0, 3.5]", ""]
    for table in limit_states or [{"name": "fails", "output": "y", "below": 0.0}]:
        lines += ["[[limit_states]]"] + [f"{k} = {toml(v)}" for k, v in table.items()] + [""]
    lines += ["[method]"] + [f"{k} = {toml(v)}" for k, v in method.items()]
    lines += ["", "[execution]", f"workers = {workers}", "seed = 8", f"batch = {batch}", "",
              "[output]", f'path = "{name}.nc"', "figures = false", ""]
    path = tmp_path / f"{name}.toml"
    path.write_text("\n".join(lines))
    return path


def test_a_study_runs_each_stage_on_its_level_and_reports_the_saving(tmp_path):
    outcome = run(study_file(tmp_path, "mfis", {"search": "form"}))
    runs, stats = outcome.runs, outcome.statistics
    offset = np.array([3.0, 3.5])[runs[LEVEL].values]
    # each row ran at its own level's offset: the model's own float64 sum, bit for bit
    np.testing.assert_array_equal(runs["y"].values, offset - runs[INPUTS].values[:, 0])
    p, stderr = estimate(stats)
    assert abs(p - sps.norm.sf(3.5)) <= 4 * stderr   # 4 standard errors: 1 in 16,000
    text = summary_table(open_result(outcome.path))
    assert "P[failure of fails] (y < 0) at the finest level = " in text
    assert "plain Monte Carlo at the finest level needs" in text
    assert "stage 1 (form) on the coarsest level: 2 rounds, 10 runs" in text
    # the refinement's 3 finest runs (the coarse design point and its forward stencil) are
    # the finest level's too; the centre moved from the coarse 3.0 to the finest 3.5
    assert "design point refined on the finest level: 1 round(s) of FORM's search from " \
        "the coarse design point, first-order beta there 3.5; the biasing density's centre " \
        "moved 0.5 from" in text
    assert "runs per level (3, 3.5): 10, 103" in text
    written = [p.name for p in write_figures(open_result(outcome.path), tmp_path / "figures")]
    assert "stages.png" in written


def test_measured_costs_are_each_levels_median_run_time_less_compile_time(tmp_path):
    method = {"search": "form", "costs": "measured"}
    outcome = run(study_file(tmp_path, "measured", method))
    runs, stats = outcome.runs, outcome.statistics
    seconds = runs["wall_time"].values - np.nan_to_num(runs["compile_time"].values)
    level = runs[LEVEL].values
    for lv in (0, 1):
        assert float(stats[FIDELITY_COST].values[lv]) == float(np.median(seconds[level == lv]))
    assert stats[FIDELITY_COST].attrs["units"] == "s"
    spent = float(np.dot(stats[FIDELITY_RUNS].values, stats[FIDELITY_COST].values))
    # two products and a sum of positive terms (condition number 1), perhaps fused in the
    # dot: at most 3 roundings of eps/2, 3.3e-16; 1e-14 allows 30 times that
    assert stats.attrs[GUIDE_TOTAL_COST] == pytest.approx(spent, rel=1e-14)


@pytest.mark.parametrize("search", ["cross-entropy", "form"])
def test_a_killed_study_resumes_to_the_uninterrupted_numbers(tmp_path, search):
    # search = form with the coarse control variate: its batch (100 finest rows, then 300
    # coarse ones) is killed after 40 rows
    control = {"control_variate": True, "coarse_draws_per_finest": 3} \
        if search == "form" else {}
    path = study_file(tmp_path, "whole", {"search": search, **control})
    whole = run(path)
    runs_w, stats_w = comparable(whole.path)
    last = int(whole.runs[ROUND].values.max())
    # killed in the first cross-entropy round (FORM: its first round, and the refinement's
    # round at the finest level, one of its 3 runs done), and in the finest-level round
    stage = whole.runs[STAGE].values
    refined = int(whole.runs[ROUND].values[stage == STAGE_FINEST_SEARCH].max()) \
        if search == "form" else None
    kills = ((1, 30), (last + 1, 40)) if search == "cross-entropy" else \
        ((1, 2), (refined + 1, 1), (last + 1, 40))
    for keep, finished in kills:
        stored, attrs = read_runs(whole.path)
        stored = stored.isel(realization=np.flatnonzero(stored[ROUND].values < keep))
        pending = np.flatnonzero(stored[ROUND].values == keep - 1)[finished:]
        stored[STATUS].values[pending] = "pending"
        stored["y"].values[pending] = np.nan
        stored["wall_time"].values[pending] = np.nan
        attrs.update(complete=0)
        attrs.pop("runs_sha256", None)
        write_result(whole.path, stored, None, attrs)
        resumed = run(path, resume=True)
        assert resumed.resumed > 0
        runs_c, stats_c = comparable(whole.path)
        xr.testing.assert_identical(runs_w.drop_vars("message"), runs_c.drop_vars("message"))
        xr.testing.assert_identical(stats_w, stats_c)


@pytest.mark.slow
@pytest.mark.parametrize("small", [{"coarse_samples": 20, "samples": 40},
                                   {"search": "form", "samples": 40, "control_variate": True,
                                    "coarse_draws_per_finest": 3}])
def test_one_and_two_workers_give_identical_results(tmp_path, small):
    # a smaller study (dask's start dominates): cross-entropy rounds of 20, or FORM's
    # search and its refinement at the finest level with the coarse control variate (120
    # coarse draws); 40 finest draws
    paths = [run(study_file(tmp_path, f"w{w}", small, workers=w, batch=9)).path
             for w in (0, 2)]
    (runs0, stats0), (runs2, stats2) = map(comparable, paths)
    xr.testing.assert_identical(runs0, runs2)
    xr.testing.assert_identical(stats0, stats2)


def test_a_function_solver_study_with_resolution_levels(tmp_path):
    text = f"""\
name = "biased"
solver = "mfis-biased-test"
scene = {{}}

[[inputs]]
name = "u1"
distribution = "normal"
mean = 0.0
std = 1.0

[[inputs]]
name = "u2"
distribution = "normal"
mean = 0.0
std = 1.0

[levels]
key = "resolution"
values = {list(LEVELS)}

[[limit_states]]
name = "fails"
output = "g"
below = 0.0

[method]
kind = "multifidelity-importance-sampling"
search = "form"
samples = 300
costs = [1.0, 10.0]

[execution]
workers = 0
seed = 2

[output]
path = "biased.nc"
figures = false
"""
    path = tmp_path / "biased.toml"
    path.write_text(text)
    outcome = run(path)
    p, stderr = estimate(outcome.statistics)
    assert abs(p - sps.norm.sf(BETA)) <= 4 * stderr   # 4 standard errors: 1 in 16,000


# --------------------------------------------------------------- refusals

@pytest.mark.parametrize("change, key, words", [
    (dict(levels=False), "levels", "add a [levels] table"),
    (dict(method={"costs": [1.0]}), "method.costs", "costs has 1 values for 2 levels"),
    (dict(method={"search": "form", "coarse_samples": 100}), "method",
     "'coarse_samples' applies to search = \"cross-entropy\""),
    (dict(method={"search": "form", "coarse_draws_per_finest": 5}), "method",
     "'coarse_draws_per_finest' applies to control_variate = true"),
    (dict(method={"search": "form", "control_variate": True, "coarse_draws_per_finest": 0}),
     "method.coarse_draws_per_finest", "greater than or equal to 1"),
    (dict(method={"search": "form", "control_variate": True, "control_event": "fine"}),
     "method.control_event", "'matched' or 'coarse'"),
    (dict(method={"search": "form", "limit_state": "either"},
          limit_states=[{"name": "low", "output": "y", "below": 0.0},
                        {"name": "high", "output": "y", "exceeds": 9.0},
                        {"name": "either", "series": ["low", "high"]}]),
     "method.limit_state", "series system"),
])
def test_refusals_are_one_line_naming_the_key(tmp_path, change, key, words):
    path = study_file(tmp_path, "bad", **change)
    with pytest.raises(StudyError) as error:
        load_study(path)
    assert error.value.key == key and "\n" not in str(error.value)
    assert words in str(error.value)


def test_a_system_is_taken_by_the_cross_entropy_search(tmp_path):
    systems = [{"name": "low", "output": "y", "below": 0.0},
               {"name": "high", "output": "y", "exceeds": 9.0},
               {"name": "either", "series": ["low", "high"]}]
    study = load_study(study_file(tmp_path, "system", {"limit_state": "either"},
                                  limit_states=systems))
    assert study.method.limit_state == "either"


def test_registered_under_its_kind():
    assert get_method("multifidelity-importance-sampling") is MultifidelityImportanceSampling
