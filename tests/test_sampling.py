"""Unit-hypercube samplers: range, shape, reproducibility, LHS stratification, edge sizes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import qmc

from uqflow.sampling import (QUASI_RANDOM_RULES, RULES, replicate_seed, replicated_unit_hypercube,
                             unit_hypercube)


def _seed(n=7):
    return np.random.SeedSequence(n)


@pytest.mark.parametrize("rule", RULES)
@pytest.mark.parametrize("n, d", [(1, 1), (1, 5), (7, 3), (256, 4), (1000, 2)])
def test_points_in_open_unit_cube_with_right_shape(rule, n, d):
    u = unit_hypercube(rule, n, d, _seed())
    assert u.shape == (n, d) and u.dtype == float
    assert np.all(u > 0) and np.all(u < 1)


@pytest.mark.parametrize("rule", RULES)
def test_same_seed_same_points_other_seed_other_points(rule):
    a = unit_hypercube(rule, 128, 3, np.random.SeedSequence(42))
    b = unit_hypercube(rule, 128, 3, np.random.SeedSequence(42))
    c = unit_hypercube(rule, 128, 3, np.random.SeedSequence(43))
    np.testing.assert_array_equal(a, b)
    assert not np.any(np.all(a == c, axis=1))     # no point in common, not just "not equal"


@pytest.mark.parametrize("rule", RULES)
def test_seed_object_is_not_consumed(rule):
    """The same SeedSequence object used twice gives the same design (no hidden state)."""
    seed = np.random.SeedSequence(5)
    np.testing.assert_array_equal(unit_hypercube(rule, 64, 2, seed),
                                  unit_hypercube(rule, 64, 2, seed))


@pytest.mark.parametrize("rule", RULES)
def test_no_global_random_state(rule):
    """Designs do not depend on, nor change, numpy's global random state."""
    np.random.seed(1)
    before = np.random.get_state()[1].copy()
    a = unit_hypercube(rule, 32, 2, _seed())
    np.testing.assert_array_equal(np.random.get_state()[1], before)
    np.random.seed(2)
    np.testing.assert_array_equal(unit_hypercube(rule, 32, 2, _seed()), a)


@pytest.mark.parametrize("n", [1, 2, 10, 97, 1000])
@pytest.mark.parametrize("d", [1, 4])
def test_lhs_one_point_per_stratum(n, d):
    """Every 1/n stratum of every dimension holds exactly one point."""
    u = unit_hypercube("lhs", n, d, _seed(n))
    for k in range(d):
        strata = np.floor(u[:, k] * n).astype(int)
        np.testing.assert_array_equal(np.sort(strata), np.arange(n))


@pytest.mark.parametrize("rule", ["sobol", "halton"])
def test_low_discrepancy_points_are_evenly_spread(rule):
    """Scrambled Sobol / Halton: L2-star discrepancy well below a random design's expected
    sqrt((2^-d - 3^-d) / n) (Warnock's formula; 0.0093 for n = 1024, d = 3)."""
    n, d = 1024, 3
    expected_random = math.sqrt((2.0**-d - 3.0**-d) / n)
    for seed in range(3):
        u = unit_hypercube(rule, n, d, _seed(seed))
        assert qmc.discrepancy(u, method="L2-star") < 0.3 * expected_random


@pytest.mark.parametrize("rule", RULES)
def test_uniform_moments(rule):
    """Column means and variances of 4096 points: 1/2 and 1/12 within 4 standard errors."""
    n = 4096
    u = unit_hypercube(rule, n, 3, _seed())
    se_mean = math.sqrt(1 / 12 / n)
    se_var = math.sqrt((1 / 80 - 1 / 144) / n)
    assert np.all(np.abs(u.mean(axis=0) - 0.5) < 4 * se_mean)
    assert np.all(np.abs(u.var(axis=0, ddof=1) - 1 / 12) < 4 * se_var)


@pytest.mark.parametrize("rule", RULES)
def test_dimension_zero(rule):
    u = unit_hypercube(rule, 5, 0, _seed())
    assert u.shape == (5, 0)


@pytest.mark.parametrize("rule", RULES)
def test_zero_points(rule):
    assert unit_hypercube(rule, 0, 3, _seed()).shape == (0, 3)


@pytest.mark.parametrize("rule", RULES)
def test_n_one(rule):
    u = unit_hypercube(rule, 1, 3, _seed())
    assert u.shape == (1, 3) and np.all((u > 0) & (u < 1))


def test_unknown_rule_raises_even_in_dimension_zero():
    for d in (0, 2):
        with pytest.raises(ValueError, match="unknown sampling rule 'grid'"):
            unit_hypercube("grid", 4, d, _seed())


def test_negative_sizes_raise():
    with pytest.raises(ValueError):
        unit_hypercube("random", -1, 2, _seed())
    with pytest.raises(ValueError):
        unit_hypercube("random", 2, -1, _seed())


# --------------------------------------------------------------------------------------------
# Replicated (randomized QMC) designs
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("rule", QUASI_RANDOM_RULES)
def test_replicates_are_interleaved_independent_scramblings(rule):
    """Row j R + r is point j of replicate r, and replicate r is the rule's sequence under
    its own child seed (so another replicate count keeps the first replicates' points)."""
    seed, r, m = np.random.SeedSequence(11), 4, 32
    u = replicated_unit_hypercube(rule, r, m, 3, seed)
    assert u.shape == (r * m, 3)
    for k in range(r):
        np.testing.assert_array_equal(u[k::r], unit_hypercube(rule, m, 3,
                                                              replicate_seed(seed, k)))
    assert not np.any(np.all(u[0::r] == u[1::r], axis=1))     # replicates differ everywhere
    np.testing.assert_array_equal(u, replicated_unit_hypercube(rule, r, m, 3, seed))
    assert seed.n_children_spawned == 0                       # the seed is not consumed


def test_every_replicate_prefix_of_a_power_of_two_is_balanced():
    """Sobol' in 1-D projections is a (0, k, 1)-net at every 2^k prefix: the first R 2^k rows
    hold, for every replicate and dimension, one point in each interval of width 2^-k."""
    r, m, d = 8, 256, 3
    u = replicated_unit_hypercube("sobol", r, m, d, np.random.SeedSequence(5))
    for k in range(9):
        prefix = u[:r * 2**k]
        for rep in range(r):
            cells = np.floor(prefix[rep::r] * 2**k).astype(int)
            for dim in range(d):
                np.testing.assert_array_equal(np.sort(cells[:, dim]), np.arange(2**k))


def test_replicated_designs_refuse_independent_rules_and_bad_sizes():
    for rule in ("random", "lhs"):
        with pytest.raises(ValueError, match="quasi-random rules"):
            replicated_unit_hypercube(rule, 4, 8, 2, _seed())
    with pytest.raises(ValueError, match="replicates >= 1"):
        replicated_unit_hypercube("sobol", 0, 8, 2, _seed())
    assert replicated_unit_hypercube("halton", 3, 0, 2, _seed()).shape == (0, 2)
