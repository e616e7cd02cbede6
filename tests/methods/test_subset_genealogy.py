"""Subset simulation's c.o.v. from the genealogy of its failures: the level-0 family of every
state, the estimator's exact agreement with Au & Beck's where theirs is exact, and what it
adds where the levels are correlated through the seeds."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from uqflow.errors import AccuracyWarning
from uqflow.inputs import InputSpace, RandomInput
from uqflow.layout import (EXCEEDANCE_INTERVAL, EXCEEDANCE_PROBABILITY, FAILURE_COV,
                           FAILURE_COV_UNCORRELATED, FAILURE_FAMILIES, FAILURE_INTERVAL, FAILURE_PROBABILITY, SUBSET_LEVEL)
from uqflow.methods.subset_simulation import (SubsetLevel, SubsetSimulation,
                                              family_roots, genealogical_cov,
                                              lognormal_interval, running_genealogy)
from uqflow.testing import run_in_memory


def normal_space(n: int) -> InputSpace:
    return InputSpace([RandomInput.from_spec({"name": f"x{i}", "distribution": "normal",
                                              "mean": 0.0, "std": 1.0}) for i in range(n)])


def run(beta: float, n: int, samples: int, seed: int = 0):
    """Subset simulation of y = a . x > beta, |a| = 1, in n standard normals."""
    a = np.ones(n) / math.sqrt(n)
    method = SubsetSimulation(samples_per_level=samples)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        runs, stats = run_in_memory(method, normal_space(n),
                                    [{"name": "high", "output": "y", "exceeds": beta}],
                                    lambda x: {"y": x @ a}, seed, outputs={"y": "m"})
    return method, runs, stats


def value(stats, name) -> float:
    return float(np.asarray(stats[name].values).ravel()[0])


def test_families_follow_each_chain_to_its_seed_and_the_seed_to_level_0():
    # level 0: rows 0..5; level 1: chains seeded by rows 4 and 1, proposals 6, 7 (accepted)
    # and a rejection (the chain stays at 1); level 2: chains seeded by rows 7 and 1
    levels = [SubsetLevel(0, np.arange(6)[None, :], np.zeros((1, 6))),
              SubsetLevel(1, np.array([[4, 6, 7], [1, 1, 8]]), np.zeros((2, 3))),
              SubsetLevel(2, np.array([[7, 9, -1], [1, 10, -1]]), np.zeros((2, 3)))]
    roots = family_roots(levels, 11)
    np.testing.assert_array_equal(roots[0], np.arange(6)[None, :])
    np.testing.assert_array_equal(roots[1], [[4, 4, 4], [1, 1, 1]])
    np.testing.assert_array_equal(roots[2], [[4, 4, -1], [1, 1, -1]])


def test_at_level_0_it_is_the_binomial_cov():
    # F failures each its own family among N: 1/F - 1/N = (1 - p) / (N p), a few roundings
    n, failures = 1000, 37
    genealogy = genealogical_cov(np.arange(0, 2 * failures, 2), n)
    p = failures / n
    # a sum of 37 equal squares less 1/N (cancellation 1/(1 - p) ~ 1.04): ~40 eps = 1e-14
    assert genealogy.cov_raw == pytest.approx(math.sqrt((1 - p) / (n * p)), rel=1e-13, abs=0)
    # 1 over the same sum: ~40 eps
    assert genealogy.families == pytest.approx(failures, rel=1e-13, abs=0)


def test_with_one_intermediate_level_it_is_au_and_becks_exactly():
    # two levels: sum_c (F_c/F)^2 - 1/N expands into (1 - p0)/(N p0) + (1 - p1)/(N p1)
    # (1 + gamma_1) term by term (docs/subset_simulation.md); 1e-12 bounds the roundings of
    # sums of a few hundred products (N eps ~ 1e-13). Families per state, or 1/(N + 1) in
    # place of 1/N, break it.
    method, runs, stats = run(beta=1.645, n=3, samples=200, seed=4)
    assert stats.sizes[SUBSET_LEVEL] == 2
    genealogy = method.genealogy(method.replay(runs).levels, runs.sizes["realization"])
    # two sums of N = 200 terms, differently ordered: N eps ~ 4e-14, 1e-12 with room
    assert genealogy.cov_raw == pytest.approx(value(stats, FAILURE_COV_UNCORRELATED),
                                              # bound: two N = 200 sums, N eps ~ 4e-14: 1e-12
                                              rel=1e-12, abs=0)
    k = value(stats, FAILURE_FAMILIES)
    # the reported c.o.v. carries the few-families correction k / (k - 1) of the variance:
    # the same product up to a few roundings (1e-13)
    assert value(stats, FAILURE_COV) == pytest.approx(
        # bound: the same product up to a few roundings: 1e-13
        genealogy.cov_raw * math.sqrt(k / (k - 1)), rel=1e-13, abs=0)


def test_levels_correlated_through_their_seeds_raise_the_cov_above_au_and_becks():
    # five levels at p_f = 3e-5: the failures descend from a few level-0 samples, and the
    # spread of their families' shares is larger than the levels' independent fractions
    # imply (over the seeds tried, 1.05 to 1.4 times Au & Beck's)
    method, runs, stats = run(beta=4.0, n=2, samples=200, seed=1)
    assert stats.sizes[SUBSET_LEVEL] >= 4
    assert value(stats, FAILURE_COV) > value(stats, FAILURE_COV_UNCORRELATED)
    assert 1 < value(stats, FAILURE_FAMILIES) < 20


def test_one_family_leaves_the_cov_unknown():
    genealogy = genealogical_cov(np.array([3, 3, 3, 3]), 100)
    assert genealogy.families == 1.0
    assert genealogy.cov == math.inf and genealogy.degrees_of_freedom == 0.0
    assert np.all(np.isnan(lognormal_interval(1e-3, genealogy.cov, 0.95,
                                              genealogy.degrees_of_freedom)))
    assert genealogical_cov(np.zeros(0, dtype=np.int64), 100).cov == math.inf


def test_the_interval_takes_student_t_with_families_minus_one_degrees_of_freedom():
    low, high = lognormal_interval(1e-4, 0.3, 0.95, degrees_of_freedom=4.0)
    s = math.sqrt(math.log1p(0.09))
    # t_{0.975, 4} = 2.7764451051977987 (scipy's t.ppf, about 1e-15 relative); the same
    # arithmetic as the closed form up to a few roundings
    assert math.log(high / low) == pytest.approx(2 * 2.7764451051977987 * s, rel=1e-12)
    # bound: sqrt of a product of two exps, a few eps: 1e-14
    assert math.sqrt(low * high) == pytest.approx(1e-4, rel=1e-14)
    normal = lognormal_interval(1e-4, 0.3, 0.95)
    assert normal[0] > low and normal[1] < high
    assert np.all(lognormal_interval(1e-4, 0.3, 0.95, degrees_of_freedom=0.5) ==
                  np.array([0.0, 1.0]))


def test_the_reported_interval_is_the_t_interval_of_the_genealogical_cov():
    _, _, stats = run(beta=2.5, n=2, samples=200, seed=3)
    p, cov, k = (value(stats, name) for name in (FAILURE_PROBABILITY, FAILURE_COV,
                                                 FAILURE_FAMILIES))
    expected = lognormal_interval(p, cov, 0.95, degrees_of_freedom=k - 1)
    # the same function of the same stored numbers
    np.testing.assert_array_equal(np.asarray(stats[FAILURE_INTERVAL].values)[0], expected)


def test_the_running_genealogy_of_every_prefix_is_the_genealogy_of_that_prefix():
    roots = np.random.default_rng(7).integers(0, 12, size=300)
    running = running_genealogy(roots, 500)
    for i in (1, 2, 17, 150, 300):
        alone = genealogical_cov(roots[:i], 500)
        # sums of at most 300 squares of integers (exact) divided differently: a few eps
        assert running.families[i - 1] == pytest.approx(alone.families, rel=1e-14, abs=0)
        # bound: exact integer sums divided differently, a few eps: 1e-13
        assert running.cov_raw[i - 1] == pytest.approx(alone.cov_raw, rel=1e-13, abs=0)
    assert running.cov[0] == math.inf     # one state: one family, its spread unknown


def test_the_exceedance_band_at_p_f_is_p_fs_interval():
    _, _, stats = run(beta=2.5, n=2, samples=200, seed=3)
    p_f = value(stats, FAILURE_PROBABILITY)
    curve = np.asarray(stats[EXCEEDANCE_PROBABILITY].values)[0]
    band = np.asarray(stats[EXCEEDANCE_INTERVAL].values)[0]
    at = np.flatnonzero(curve == p_f)       # the last level's F-th sample: the same product
    assert at.size >= 1
    # the same c.o.v. summed in another order (a few eps), through exp(z s) with z s < 4:
    # 1e-13 relative
    np.testing.assert_allclose(band[at[0]], np.asarray(stats[FAILURE_INTERVAL].values)[0],
                               # bound: the c.o.v. summed in another order, through exp(z s): 1e-13
                               rtol=1e-13, atol=0)
