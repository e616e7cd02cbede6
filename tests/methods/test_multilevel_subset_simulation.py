"""Multilevel subset simulation against exact finest-level failure probabilities of two level
families, its correction at the level change, its cost against single-level subset
simulation at the finest level, and its determinism through the executor.

Both families are in two standard normals u1, u2; the scene key ``level`` (0 coarse, 1
finest) sets the model, and the finest level is exactly g = 3.5 - u1, P = Phi(-3.5):

- ``nested``: the coarse level g = 3 - u1 fails on a half-plane that holds the finest's
  (biased: P = Phi(-3), six times the finest's);
- ``narrow``: the coarse level g = 3 - u1 + 3 u2^2 fails on a thin parabola around the
  finest's design point, most of the finest failure domain outside it. The chains at the
  level change start from the seeds in both domains (|u2| < 0.5) and must forget that
  start: this is the case docs/rare_events_across_levels.md reports the burn-in for.

The statistical tests drive the method as the executor does (plan, extend until None,
analyze) on runs evaluated in one vectorized call; the determinism tests run studies.
"""

from __future__ import annotations

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
from uqflow.layout import (CHAIN, CHAIN_STEP, EQUIVALENT_FINEST_COST, EQUIVALENT_FINEST_RUNS,
                           FAILURE_COV, FAILURE_COV_CORRELATED, FAILURE_COV_UNCORRELATED,
                           FAILURE_FAMILIES, FAILURE_INTERVAL, FAILURE_PROBABILITY,
                           FIDELITY_COST, FIDELITY_RUNS,
                           FINEST_COST_RATIO, INPUTS, LEVEL, MULTILEVEL_TOTAL_COST, SEED_KEY,
                           STATUS, STATUS_FAILED, STATUS_OK, SUBSET_CORRECTION,
                           SUBSET_CORRECTION_COV, SUBSET_FIDELITY, SUBSET_THRESHOLD,
                           SUBSET_LEVEL, SUBSET_PROBABILITY, WARNINGS)
from uqflow.levels import LevelsSpec, resolve_levels
from uqflow.limit_states import LimitStates
from uqflow.methods import get_method
from uqflow.methods.form import STAGE, STANDARD_NORMAL
from uqflow.methods.multilevel_subset_simulation import (STAGE_CHAIN, STAGE_CHECK,
                                                         STAGE_DRAW, STAGE_UPDATE,
                                                         MultilevelSubsetSimulation, Subset,
                                                         influence_genealogy)
from uqflow.methods.subset_simulation import SubsetLevel, SubsetSimulation, lognormal_interval
from uqflow.realization import empty_runs
from uqflow.report import open_result, summary_table, write_figures
from uqflow.store import read_runs, write_result
from uqflow.study import load_study

from reliability_helpers import run_quietly as run

EXACT = float(sps.norm.sf(3.5))     # the finest level of both families


def nested(u, level):
    return np.where(level == 0, 3.0 - u[:, 0], 3.5 - u[:, 0])


def narrow(u, level):
    return np.where(level == 0, 3.0 - u[:, 0] + 3.0 * u[:, 1] ** 2, 3.5 - u[:, 0])


def _narrow_solver(u1=0.0, u2=0.0, level=1.0):
    return float(narrow(np.array([[u1, u2]]), np.array([round(level)]))[0])


NarrowSolver = uqflow.solver_from_function(_narrow_solver, outputs="g", units="1",
                                           name="mlsus-narrow-test")
uqflow.register_solver("mlsus-narrow-test")(NarrowSolver)
LIMIT_STATE = [{"name": "fails", "output": "g", "below": 0.0}]


def space():
    return InputSpace([RandomInput.from_spec({"name": n, "distribution": "normal",
                                              "mean": 0.0, "std": 1.0}) for n in ("u1", "u2")])


def configured(method_class=MultilevelSubsetSimulation, levels=(0.0, 1.0), **options):
    method = method_class(**options)
    template = NarrowSolver.from_scene({}).outputs()
    method.check_limit_states(LimitStates.from_tables(LIMIT_STATE, template))
    if method_class is MultilevelSubsetSimulation:
        # one level (a study's [levels] needs two): the method is then subset simulation
        # with its own draws, what its c.o.v. is compared with
        spec = LevelsSpec(key="level", values=list(levels)) if len(levels) > 1 else \
            LevelsSpec.model_construct(key="level", values=list(levels))
        method.check_levels(resolve_levels(spec, {}, NarrowSolver, ["g"], "scene"))
    return method


def evaluate(design, problem, level=None):
    runs = empty_runs(design, NarrowSolver.from_scene({}).outputs())
    levels = design[LEVEL].values if level is None else np.full(design.sizes["realization"],
                                                                 level)
    g = problem(design[INPUTS].values, levels)
    runs["g"].values[:] = g
    runs[STATUS].values[:] = np.where(np.isfinite(g), STATUS_OK, STATUS_FAILED)
    runs["wall_time"].values[:] = 0.0
    return runs


def drive(method, problem, seed, level=None):
    """plan, extend until None, analyze, as the executor does (``level``: run every row at
    that level, for single-level subset simulation)."""
    design = method.plan(space(), None, np.random.SeedSequence(seed))
    runs = evaluate(design, problem, level)
    glue = dict(dim="realization", data_vars="minimal", coords="minimal", compat="override",
                join="override")
    while (more := method.extend(design, runs)) is not None:
        n = design.sizes["realization"]
        more = more.assign_coords(realization=np.arange(n, n + more.sizes["realization"]))
        runs = xr.concat([runs, evaluate(more, problem, level)], **glue)
        design = xr.concat([design, more], **glue)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        return method.analyze(design, runs), runs


def value(stats, name):
    return float(np.asarray(stats[name].values).ravel()[0])


def log_errors(estimates, covs):
    """The mean of ln(p / exact) over repetitions and its standard error from the reported
    c.o.v.s (each estimate lognormal with s^2 = ln(1 + cov^2))."""
    s2 = np.log1p(np.asarray(covs) ** 2)
    return float(np.mean(np.log(np.asarray(estimates) / EXACT))), \
        float(math.sqrt(np.sum(s2)) / len(s2))


# --------------------------------------------------------------- the estimate

def test_nested_levels_the_coarse_subsets_then_one_finest_with_no_correction():
    stats, runs = drive(configured(burn_in=0, samples_per_level=500, costs=[1.0, 10.0]),
                        nested, 3)
    fidelity = stats[SUBSET_FIDELITY].values
    # the coarse level to its failure domain (p = Phi(-3): three subsets at p0 = 0.1), then
    # the finest, whose domain lies inside: every sample of it is in the coarse one
    assert list(fidelity) == [0] * (len(fidelity) - 1) + [1] and len(fidelity) >= 4
    assert list(stats[SUBSET_CORRECTION].values) == [1.0] * len(fidelity)
    p, cov = value(stats, FAILURE_PROBABILITY), value(stats, FAILURE_COV)
    # 4 of its lognormal spreads: fails 1 in 16,000 runs if the c.o.v. is right
    assert abs(math.log(p / EXACT)) <= 4 * math.sqrt(math.log1p(cov**2))
    # the biased coarse level alone would say Phi(-3) = 6 EXACT: the finest subset moved it
    coarse = float(np.prod(stats[SUBSET_PROBABILITY].values[:-1]))
    assert abs(math.log(coarse / sps.norm.sf(3.0))) <= 4 * math.sqrt(math.log1p(cov**2))
    # the update re-ran the last coarse subset's distinct samples at the finest level, with
    # their seed keys; the chains' proposals have their own rows as keys
    stage = runs[STAGE].values
    update = stage == STAGE_UPDATE
    keys = runs[SEED_KEY].values
    assert update.sum() > 0 and np.all(runs[LEVEL].values[update] == 1)
    np.testing.assert_array_equal(runs[STANDARD_NORMAL].values[update],
                                  runs[STANDARD_NORMAL].values[keys[update]])
    chain = np.flatnonzero(stage == STAGE_CHAIN)
    np.testing.assert_array_equal(keys[chain], chain)


def test_subsets_per_level_moves_up_early():
    stats, _ = drive(configured(burn_in=0, samples_per_level=500, subsets_per_level=[1],
                                costs=[1.0, 10.0]), nested, 3)
    # one coarse subset (u1 beyond about 1.3, which holds every finer event), then the
    # finest level's subsets to its failure domain
    fidelity = list(stats[SUBSET_FIDELITY].values)
    assert fidelity[0] == 0 and set(fidelity[1:]) == {1} and len(fidelity) >= 4
    assert list(stats[SUBSET_CORRECTION].values) == [1.0] * len(fidelity)
    p, cov = value(stats, FAILURE_PROBABILITY), value(stats, FAILURE_COV)
    # 4 of its lognormal spreads: fails 1 in 16,000 runs if the c.o.v. is right
    assert abs(math.log(p / EXACT)) <= 4 * math.sqrt(math.log1p(cov**2))


def test_three_nested_levels_climb_one_after_the_other():
    # g = 2.5 - u1, 3 - u1, 3.5 - u1: each level's failure domain inside the one below
    def three(u, level):
        return np.array([2.5, 3.0, 3.5])[level] - u[:, 0]

    stats, runs = drive(configured(levels=(0.0, 1.0, 2.0), burn_in=0, samples_per_level=500,
                                   costs=[1.0, 3.0, 9.0]), three, 4)
    fidelity = list(stats[SUBSET_FIDELITY].values)
    assert fidelity == sorted(fidelity) and fidelity[-2:] == [1, 2] and fidelity[0] == 0
    assert list(stats[SUBSET_CORRECTION].values) == [1.0] * len(fidelity)
    stage, level, subset = runs[STAGE].values, runs[LEVEL].values, runs[SUBSET_LEVEL].values
    # the change 1 -> 2 re-runs the samples at level 2 (update) and, in the same round, the
    # samples of the change 0 -> 1's subset at level 0 (check)
    last = len(fidelity) - 1
    assert set(level[(stage == STAGE_UPDATE) & (subset == last)]) == {2}
    assert set(level[(stage == STAGE_CHECK) & (subset == last)]) == {0}
    assert list(stats[FIDELITY_RUNS].values) == [int((level == lv).sum()) for lv in range(3)]
    p, cov = value(stats, FAILURE_PROBABILITY), value(stats, FAILURE_COV)
    # 4 of its lognormal spreads: fails 1 in 16,000 runs if the c.o.v. is right
    assert abs(math.log(p / EXACT)) <= 4 * math.sqrt(math.log1p(cov**2))


def test_max_levels_reached_says_it_did_not_converge():
    stats, _ = drive(configured(burn_in=0, samples_per_level=100, max_levels=2,
                                costs=[1.0, 10.0]), nested, 2)
    # P = Phi(-3) at the coarse level takes three subsets at p0 = 0.1: two stop short
    assert stats.attrs["converged"] == 0 and stats.sizes[SUBSET_LEVEL] == 2
    assert "max_levels = 2 subsets reached at level 0" in stats.attrs["stop_reason"]
    assert "did not reach the finest level's failure domain" in stats.attrs[WARNINGS]
    # the last fraction is of the coarse failures among its samples
    assert stats[SUBSET_PROBABILITY].values[-1] < 0.1


def test_failed_runs_are_left_out_and_counted_by_stage():
    # the coarse solver fails wherever u2 < -1.5, the finest wherever u2 > 1.5: regions
    # independent of the failure events (u1 only), so leaving them out changes no
    # fraction's expectation; a point that ran ok at one level may fail at the other

    def failing(u, level):
        broken = np.where(level == 0, u[:, 1] < -1.5, u[:, 1] > 1.5)
        return np.where(broken, np.nan, nested(u, level))

    stats, runs = drive(configured(burn_in=0, samples_per_level=500, costs=[1.0, 10.0]),
                        failing, 3)
    failed = runs[STATUS].values == STATUS_FAILED
    stage = runs[STAGE].values
    text = stats.attrs[WARNINGS]
    for kind, words in ((STAGE_DRAW, "first-subset draws did not run ok"),
                        (STAGE_CHAIN, "chain proposals did not run ok"),
                        (STAGE_UPDATE, "update runs (samples re-run at the next level)"),
                        (STAGE_CHECK, "check runs (samples re-run at the previous level)")):
        assert f"{int((failed & (stage == kind)).sum())} {words}" in text
        assert (failed & (stage == kind)).sum() > 0
    p, cov = value(stats, FAILURE_PROBABILITY), value(stats, FAILURE_COV)
    # 4 of its lognormal spreads: fails 1 in 16,000 runs if the c.o.v. is right
    assert abs(math.log(p / EXACT)) <= 4 * math.sqrt(math.log1p(cov**2))


def narrow_repetitions(repetitions=6, **options):
    options = {"samples_per_level": 500, "costs": [1.0, 10.0], **options}
    return [drive(configured(**options), narrow, seed)[0] for seed in range(repetitions)]


def narrow_correction():
    """P[coarse failure | finest failure] on the narrow family, what its level change's
    correction estimates (the finest subset is the finest failure domain there, the last
    coarse one the coarse failure domain): P[u1 >= max(3.5, 3 + 3 u2^2)] / Phi(-3.5)."""
    knot = 1.0 / math.sqrt(6.0)     # where the parabola crosses u1 = 3.5

    def integrand(v):
        return sps.norm.pdf(v) * sps.norm.sf(max(3.5, 3.0 + 3.0 * v * v))
    # smooth pieces decaying like a Gaussian: quad's 1e-12 relative is far inside the
    # corrections' 3 % standard error below
    return sum(integrate.quad(integrand, a, b, epsabs=0, epsrel=1e-12)[0]
               for a, b in ((-np.inf, -knot), (-knot, knot), (knot, np.inf))) / EXACT


def corrections(repetitions):
    """The mean of the level change's correction over repetitions over the exact one, and
    its standard error from the reported c.o.v.s."""
    c = np.array([s[SUBSET_CORRECTION].values[-1] for s in repetitions])
    cov = np.array([s[SUBSET_CORRECTION_COV].values[-1] for s in repetitions])
    exact = narrow_correction()
    return float(c.mean() / exact), float(np.sqrt(np.sum((c * cov) ** 2)) / c.size / exact)


@pytest.mark.slow
def test_narrow_coarse_level_unbiased_with_the_burn_in_and_not_without():
    burnt = narrow_repetitions()                 # the default burn-in, 40 steps
    for s in burnt:
        # a level change straight into the finest failure domain, whose samples lie mostly
        # outside the coarse parabola: the correction is far from 1
        assert s[SUBSET_FIDELITY].values[-1] == 1 and s[SUBSET_THRESHOLD].values[-1] == 0
        assert s[SUBSET_FIDELITY].values[-2] == 0 and s[SUBSET_THRESHOLD].values[-2] == 0
    # the correction itself against its exact value, within 3 standard errors of the mean
    # of 6 (fails 1 in 370 if the reported c.o.v.s are right; the seeds are fixed)
    ratio, stderr = corrections(burnt)
    assert abs(ratio - 1) <= 3 * stderr
    p = [value(s, FAILURE_PROBABILITY) for s in burnt]
    cov = [value(s, FAILURE_COV) for s in burnt]
    mean, stderr = log_errors(p, cov)
    # and p_f: 3 standard errors of the mean of 6 lognormal estimates, as above
    assert abs(mean) <= 3 * stderr
    # the same estimates without the correction in their denominator are far low
    dropped = [value(s, FAILURE_PROBABILITY) * s[SUBSET_CORRECTION].values.prod()
               for s in burnt]
    assert log_errors(dropped, cov)[0] < -3 * stderr
    # chains that do not forget their start (no burn-in) overestimate the correction, and
    # p_f falls low (so far that 3 repetitions show it)
    fresh = narrow_repetitions(3, burn_in=0)
    ratio0, stderr0 = corrections(fresh)
    assert ratio0 - 1 > 3 * stderr0
    mean0, stderr0 = log_errors([value(s, FAILURE_PROBABILITY) for s in fresh],
                                [value(s, FAILURE_COV) for s in fresh])
    assert mean0 < -3 * stderr0


# --------------------------------------------------------------- the c.o.v.

def hand_built_subsets():
    """Three subsets over six level-0 draws (rows 0-5): subset 1 on level 0 from chains
    seeded by rows 1 and 4 (row 4's chain stays once), then a change to level 1 whose
    fraction is taken on subset 1's chains' states re-run there (one update failed: NaN),
    seeded by rows 7 and 4 twice (the seeds' random draw may repeat a row that repeats),
    and whose own two chains, seeded at random by rows 12 and 7, throw one step away before
    the correction's samples (one check failed)."""
    nan = math.nan
    s0 = Subset(0, 0, np.arange(6)[None, :], np.array([[5.0, 0.5, 3.0, 4.0, 0.2, 6.0]]),
                threshold=1.0, chain_rows=np.array([[1, 6, 7], [4, 4, 8]]))
    s1 = Subset(1, 0, s0.chain_rows, np.array([[0.9, 0.5, -0.1], [0.2, 0.2, 0.8]]),
                threshold=0.3, chain_rows=np.array([[7, 9, 10], [4, 11, 11], [4, 4, 12]]))
    s2 = Subset(2, 1, s1.chain_rows, np.array([[-1.0, -0.2, nan], [2.0, -0.5, -0.5],
                                               [3.0, 3.0, -2.0]]),
                changed=True, threshold=0.0, chain_rows=np.array([[12, 15, 16, 17],
                                                                  [7, 7, 18, 19]]), burn=1,
                check_g=np.array([[0.1, 0.5, nan], [0.2, 0.25, 0.9]]))
    for s in (s0, s1, s2):
        with np.errstate(invalid="ignore"):
            s.hits = s.g <= s.threshold
        s.probability = float(s.hits.sum() / np.isfinite(s.g).sum())
    return [s0, s1, s2]


def test_families_are_traced_through_seeds_level_changes_and_burn_in():
    # roots: subset 1's samples of families 1 and 4 (3 each, hits 1 and 2); subset 2's of
    # 1 (rows 7, 9, 10: 2 ran ok, 2 hits) and 4 (6 ok, 3 hits); the correction's kept
    # states of 4 (row 12's chain: 2 judged, 1 inside 0.3) and 1 (row 7's: 3, 2 inside).
    # psi_1 = (1/2 - 1/6) + (1/3 - 1/2) + (2/5 - 2/8) - (2/3 - 3/5) = 1/4,
    # psi_4 = (1/2 - 1/6) + (2/3 - 1/2) + (3/5 - 6/8) - (1/3 - 2/5) = 5/12,
    # psi_0,2,3,5 = -1/6: sum psi^2 = 25/72
    genealogy = MultilevelSubsetSimulation.subset_genealogy(hand_built_subsets(), 30)
    # bound: sums of a dozen fractions of order 1 (bincounts, divisions, one correctly
    # rounded sqrt; no libm or BLAS call), a few eps each in any order: 1e-13
    assert genealogy.cov_raw == pytest.approx(math.sqrt(25 / 72), rel=1e-13, abs=0)
    # the last fraction's hits: families 1 and 4 with shares 2/5 and 3/5
    # bound: 1 over a sum of two squares, a few eps in any order: 1e-13
    assert genealogy.families == pytest.approx(1 / 0.52, rel=1e-13, abs=0)


def test_on_one_level_it_is_subset_simulations_genealogical_cov():
    # no level change: each subset's seeds are the previous one's hits, psi_r telescopes to
    # F_r / F - 1 / N and sum psi_r^2 is subset simulation's sum (F_r / F)^2 - 1 / N
    method = configured(levels=(0.0,), burn_in=0, samples_per_level=200, costs=[1.0])
    stats, runs = drive(method, nested, 2)
    subsets = method.replay(runs).subsets
    assert len(subsets) >= 3 and stats.attrs["converged"] == 1
    levels = [SubsetLevel(s.index, s.points, s.g) for s in subsets]
    single = SubsetSimulation.genealogy(levels, runs.sizes["realization"])
    # two sums of N = 200 terms of order 1/N, differently grouped, against a difference of
    # order 1/F; arithmetic only (no libm, no BLAS), so any CPU rounds the same way up to order
    # bound: N eps / (F cov^2) ~ 1e-13 in any summation order; 1e-12 with room
    assert value(stats, FAILURE_COV) == pytest.approx(single.cov, rel=1e-12, abs=0)
    assert value(stats, FAILURE_FAMILIES) == single.families
    # three levels correlated through their seeds: not Au & Beck's sum
    assert abs(value(stats, FAILURE_COV) / value(stats, FAILURE_COV_UNCORRELATED) - 1) > 0.01


def test_at_a_level_change_a_correction_that_moves_with_the_fraction_cancels_it():
    # the correction's samples and hits share the last fraction's families exactly: a
    # family that is rich in failures is as rich in the correction's hits, so p_f's ratio
    # does not move with it and the relative variance is the first fraction's alone,
    # 1/A_0 - 1/N_0 (= Au & Beck's delta_0^2); Au & Beck's terms add both ratios' on top
    first = (np.arange(10), np.arange(10) < 4)            # A_0 = 4 of N_0 = 10
    families = np.array([0, 0, 0, 1, 2, 3, 3, 1])         # the later samples' roots
    hits = np.array([True, True, False, True, False, True, False, False])
    genealogy = influence_genealogy([first, (families, hits)], [(families, hits)], 10)
    # bound: a sum of 10 squares of differences of fractions and a correctly rounded sqrt,
    # a few eps in any order, no libm or BLAS call: 1e-13
    assert genealogy.cov_raw == pytest.approx(math.sqrt(1 / 4 - 1 / 10), rel=1e-13, abs=0)
    # the correction's term dropped (a level change read as no change): larger
    alone = influence_genealogy([first, (families, hits)], [], 10)
    assert alone.cov_raw > 1.05 * genealogy.cov_raw


def test_a_level_change_reports_the_genealogical_cov_with_its_t_interval():
    method = configured(burn_in=7, samples_per_level=100, level_probability=0.2,
                        costs=[1.0, 10.0])
    stats, runs = drive(method, narrow, 1)
    assert 1 in stats[SUBSET_FIDELITY].values and stats.attrs["converged"] == 1
    correction = stats[SUBSET_CORRECTION].values
    assert np.any(correction < 1)
    genealogy = method.subset_genealogy(method.replay(runs).subsets,
                                        runs.sizes["realization"])
    p, cov = value(stats, FAILURE_PROBABILITY), value(stats, FAILURE_COV)
    assert cov == genealogy.cov and value(stats, FAILURE_FAMILIES) == genealogy.families
    # the same function of the same stored numbers
    np.testing.assert_array_equal(stats[FAILURE_INTERVAL].values[0], lognormal_interval(
        p, cov, 0.95, degrees_of_freedom=genealogy.families - 1))
    # Au & Beck's terms stored beside: every fraction's and correction's delta
    terms = np.concatenate([stats["subset_cov"].values, stats[SUBSET_CORRECTION_COV].values])
    uncorrelated, correlated = math.sqrt(np.sum(terms**2)), np.sum(terms)
    # bound: a sum of at most a dozen positive squares and a sqrt, a few eps in any order
    # (numpy's SIMD summation included): 1e-13
    assert value(stats, FAILURE_COV_UNCORRELATED) == pytest.approx(uncorrelated, rel=1e-13, abs=0)
    # bound: a sum of at most a dozen positive terms, a few eps in any order: 1e-13
    assert value(stats, FAILURE_COV_CORRELATED) == pytest.approx(correlated, rel=1e-13, abs=0)
    assert abs(cov / value(stats, FAILURE_COV_UNCORRELATED) - 1) > 0.05


def test_one_family_leaves_no_interval():
    subsets = hand_built_subsets()
    last = subsets[-1]
    # every failure of the last fraction in family 4 (row 7's chain's states re-run safe)
    last.g[0] = [1.0, 1.0, math.nan]
    last.hits = last.g <= 0
    genealogy = MultilevelSubsetSimulation.subset_genealogy(subsets, 30)
    assert genealogy.families == 1.0 and genealogy.cov == math.inf
    assert genealogy.degrees_of_freedom == 0.0
    assert np.all(np.isnan(lognormal_interval(1e-4, genealogy.cov, 0.95,
                                              genealogy.degrees_of_freedom)))


# --------------------------------------------------------------- the cost

def test_finest_runs_saved_against_single_level_subset_simulation():
    stats, runs = drive(configured(burn_in=0, samples_per_level=500, costs=[1.0, 10.0]),
                        nested, 5)
    single, _ = drive(configured(SubsetSimulation, samples_per_level=500), nested, 5, level=1)
    level = runs[LEVEL].values
    finest_runs = int(stats[FIDELITY_RUNS].values[1])
    assert list(stats[FIDELITY_RUNS].values) == [int((level == 0).sum()), finest_runs]
    # single-level subset simulation pays N + (m - 1)(1 - p0) N finest runs for its m levels;
    # the multilevel one N (update) + (1 - p0) N (chains) at the finest for one finest subset
    levels = single.sizes[SUBSET_LEVEL]
    assert levels >= 4
    assert finest_runs <= 500 + 450 and 500 + (levels - 1) * 450 >= 2 * finest_runs
    # both at a comparable c.o.v.: the one multilevel answer inside 3 of the single level's
    # lognormal spreads of the exact one
    assert value(stats, FAILURE_COV) <= 1.5 * value(single, FAILURE_COV)
    p, cov = value(stats, FAILURE_PROBABILITY), value(stats, FAILURE_COV)
    equivalent = (1 - p) / (cov**2 * p)
    # rel 1e-12 here and below: the same three to five products and quotients, each rounded
    # once (eps/2 = 1.1e-16), perhaps in another order, condition number at most 2 in p and
    # the c.o.v.: ~1e-15, and a few-ulp change of p or the c.o.v. (np.nextafter) adds a few
    # ulp; 1e-12 leaves a margin of 1000
    assert value(stats, EQUIVALENT_FINEST_RUNS) == pytest.approx(equivalent, rel=1e-12)
    cost = value(stats, EQUIVALENT_FINEST_COST)
    assert cost == pytest.approx(10.0 * equivalent, rel=1e-12)  # a few ulps, as above
    spent = float(np.dot(stats[FIDELITY_RUNS].values, stats[FIDELITY_COST].values))
    assert stats.attrs[MULTILEVEL_TOTAL_COST] == pytest.approx(spent, rel=1e-12)  # ulps
    ratio = 10.0 * equivalent / spent
    assert value(stats, FINEST_COST_RATIO) == pytest.approx(ratio, rel=1e-12)  # a few ulps


def test_burn_in_steps_are_run_and_thrown_away_at_the_level_change_only():
    stats, runs = drive(configured(burn_in=7, samples_per_level=100, level_probability=0.2,
                                   costs=[1.0, 10.0]), narrow, 1)
    stage, level = runs[STAGE].values, runs[LEVEL].values
    steps = runs[CHAIN_STEP].values
    subset = runs[SUBSET_LEVEL].values
    changed = int(np.flatnonzero(stats[SUBSET_FIDELITY].values == 1)[0])
    chain_of = runs[CHAIN].values
    for k in np.unique(subset[stage == STAGE_CHAIN]):
        chain = (stage == STAGE_CHAIN) & (subset == k)
        if k != changed + 1:
            # p0 N = 20 chains of 5 states: 4 steps each
            assert steps[chain].max() == 4 and chain_of[chain].max() == 19
            continue
        # after the level change N // burn_in = 14 chains, each 7 steps thrown away and then
        # ceil(100 / 14) = 8 states kept: 14 steps, 196 finest runs where p0 N chains of
        # 7 + 5 states would be 220 (and 40 steps of burn-in 4 N runs, not about N)
        assert steps[chain].max() == 14 and chain_of[chain].max() == 13
        assert chain.sum() == 14 * 14 and np.all(level[chain] == 1)
    check = stage == STAGE_CHECK
    assert check.sum() > 0 and np.all(level[check] == 0) and \
        np.all(subset[check] == changed + 1)


# --------------------------------------------------------------- determinism

def study_file(tmp_path, name, *, workers=0, method=None):
    """The analytic linear model g = offset - x1 with the offset as the levels' key: 1.0 at
    the coarse level, 1.5 at the finest (P = Phi(-1.5)); tiny counts."""
    method = {"kind": "multilevel-subset-simulation", "samples_per_level": 20,
              "level_probability": 0.25, "burn_in": 3, "costs": [1.0, 4.0], **(method or {})}
    lines = [f'name = "{name}"', 'solver = "analytic"',
             'scene = { model = "linear", offset = 1.5, coefficients = [-1.0, 0.0] }', ""]
    for n in ("x1", "x2"):
        lines += ["[[inputs]]", f'name = "{n}"', 'distribution = "normal"', "mean = 0.0",
                  "std = 1.0", ""]
    lines += ["[levels]", 'key = "offset"', "values = [1.0, 1.5]", "",
              "[[limit_states]]", 'name = "fails"', 'output = "y"', "below = 0.0", "",
              "[method]"]
    lines += [f"{k} = {v!r}".replace("'", '"') for k, v in method.items()]
    lines += ["", "[execution]", f"workers = {workers}", "seed = 4", "batch = 7", "",
              "[output]", f'path = "{name}.nc"', "figures = false", ""]
    path = tmp_path / f"{name}.toml"
    path.write_text("\n".join(lines))
    return path


def comparable(path):
    tree = open_result(path)
    runs = tree["runs"].to_dataset().drop_vars(["wall_time", "compile_time", "message"],
                                               errors="ignore")
    stats = tree["statistics"].to_dataset()
    for key in ("solver_wall_time", "solver_compile_time", "resumed"):
        stats.attrs.pop(key, None)
    return runs, stats


def test_a_study_changes_level_and_reports_it(tmp_path):
    outcome = run(study_file(tmp_path, "mlsus"))
    runs, stats = outcome.runs, outcome.statistics
    offset = np.array([1.0, 1.5])[runs[LEVEL].values]
    # each row ran at its own level's offset: the model's own float64 sum, bit for bit
    np.testing.assert_array_equal(runs["y"].values, offset - runs[INPUTS].values[:, 0])
    assert stats.attrs["converged"] == 1 and 1 in stats[SUBSET_FIDELITY].values
    text = summary_table(open_result(outcome.path))
    assert "multilevel subset simulation, limit state 'fails': p_f at the finest level" in text
    assert "plain Monte Carlo at the finest level needs" in text
    written = [p.name for p in write_figures(open_result(outcome.path), tmp_path / "figures")]
    assert "multilevel_subsets.png" in written


def test_a_killed_study_resumes_to_the_uninterrupted_numbers(tmp_path):
    path = study_file(tmp_path, "whole")
    whole = run(path)
    stage = whole.runs[STAGE].values
    # killed inside the first burn-in round at the finest level, 2 of its 5 proposals done
    first = np.flatnonzero((stage == STAGE_CHAIN) & (whole.runs[LEVEL].values == 1))[:5]
    keep = first[-1] + 1
    stored, attrs = read_runs(whole.path)
    stored = stored.isel(realization=np.arange(keep))
    pending = first[2:]
    stored[STATUS].values[pending] = "pending"
    stored["y"].values[pending] = np.nan
    stored["wall_time"].values[pending] = np.nan
    attrs.update(complete=0)
    attrs.pop("runs_sha256", None)
    cut = tmp_path / "cut.nc"
    write_result(cut, stored, None, attrs)
    resumed = run(path, resume=True, output=cut)
    assert resumed.resumed == keep - 3
    (runs_w, stats_w), (runs_c, stats_c) = comparable(whole.path), comparable(cut)
    xr.testing.assert_identical(runs_w, runs_c)
    xr.testing.assert_identical(stats_w, stats_c)


@pytest.mark.slow
def test_no_worker_and_two_workers_give_identical_results(tmp_path):
    paths = [run(study_file(tmp_path, f"w{w}", workers=w)).path for w in (0, 2)]
    (runs0, stats0), (runs2, stats2) = map(comparable, paths)
    xr.testing.assert_identical(runs0, runs2)
    xr.testing.assert_identical(stats0, stats2)


# --------------------------------------------------------------- refusals

@pytest.mark.parametrize("method, key, words", [
    ({"costs": [1.0]}, "method.costs", "costs has 1 values for 2 levels"),
    ({"subsets_per_level": [1, 2]}, "method.subsets_per_level",
     "subsets_per_level has 2 values for the 1 levels below the finest"),
    ({"burn_in": -1}, "method.burn_in", "greater than or equal to 0"),
])
def test_refusals_are_one_line_naming_the_key(tmp_path, method, key, words):
    with pytest.raises(StudyError) as error:
        load_study(study_file(tmp_path, "bad", method=method))
    assert error.value.key == key and "\n" not in str(error.value)
    assert words in str(error.value)


def test_registered_under_its_kind():
    assert get_method("multilevel-subset-simulation") is MultilevelSubsetSimulation
