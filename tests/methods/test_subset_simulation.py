"""Subset simulation against exact failure probabilities, its error estimate against its
spread, and its determinism through the executor.

Most statistical tests drive the method as the executor does (``plan``, then ``extend``
until it answers None, then ``analyze``) with a vectorized function in place of the solver
(``drive``): the method sees the same design and runs, without the executor's per-realization
overhead (``uqflow.testing.run_in_memory`` drives it the same way, bit for bit, but builds the
executor's layout in every round: 2.3 times the CPU on subset simulation's one round a chain
step, 6 s more on this file). The determinism tests (workers, kill and resume) run real
studies through ``run_study``. Every seed is fixed, so each test is deterministic; a tolerance says which
sampling error bounds it.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import xarray as xr
from scipy import stats as sps

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.inputs import InputSpace, RandomInput
from uqflow.layout import (BOUND, BOUND_HIGH, BOUND_LOW, CHAIN, CHAIN_STEP,
                           EXCEEDANCE_INTERVAL, EXCEEDANCE_LEVEL, EXCEEDANCE_PROBABILITY,
                           FAILED_RUNS, FAILURE_COV, FAILURE_COV_CORRELATED,
                           FAILURE_COV_UNCORRELATED, FAILURE_FAMILIES, FAILURE_INTERVAL, FAILURE_PROBABILITY, INPUT_SUMMARY, INPUTS,
                           MESSAGE, PARAMETER, PARAMETER_J, REALIZATION, RELIABILITY_INDEX,
                           SOLVER_RUNS, STATUS, STATUS_FAILED, STATUS_OK, SUBSET_ACCEPTANCE,
                           SUBSET_FAILED_RUNS, SUBSET_GAMMA, SUBSET_LEVEL, SUBSET_PROBABILITY,
                           SUBSET_SAMPLES, SUBSET_THRESHOLD, UNITS, WALL_TIME, WARNINGS)
from uqflow.limit_states import LimitStates
from uqflow.methods import get_method
from uqflow.methods.form import STANDARD_NORMAL
from uqflow.methods.subset_simulation import (SubsetSimulation, correlation_factor,
                                              lognormal_interval)
from uqflow.report import open_result, summary_table, write_figures
from uqflow.study import load_study

import reliability_helpers as helpers
from reliability_helpers import (comparable, cut_result, four_branch_exact, four_branches,
                                 paraboloid_exact, run_quietly)

# ----------------------------------------------------------------------------- the fast path

_DESIGN_COORDS = (STANDARD_NORMAL, SUBSET_LEVEL, CHAIN, CHAIN_STEP)


def space_of(n: int) -> InputSpace:
    return InputSpace([RandomInput.from_spec({"name": f"x{k + 1}", "distribution": "normal",
                                              "mean": 0.0, "std": 1.0}) for k in range(n)])


def method_for(tables, outputs=("y",), **options) -> SubsetSimulation:
    template = xr.Dataset({o: xr.Variable((), np.nan, {UNITS: "m"}) for o in outputs})
    method = SubsetSimulation(**options)
    method.check_limit_states(LimitStates.from_tables(tables, template))
    return method


def assemble(pieces: list[xr.Dataset], values: list[dict]) -> xr.Dataset:
    """The runs of the designs ``pieces`` whose outputs are ``values`` (NaN: a failed run),
    laid out as the executor lays them out (built from plain arrays: no alignment)."""
    first = pieces[0]

    def stacked(name):
        return np.concatenate([p.variables[name].values for p in pieces])

    outputs = {k: np.concatenate([v[k] for v in values]) for k in values[0]}
    ok = np.all([np.isfinite(v) for v in outputs.values()], axis=0)
    n = ok.size
    data = {INPUTS: ((REALIZATION, PARAMETER), stacked(INPUTS)),
            STATUS: (REALIZATION, np.where(ok, STATUS_OK, STATUS_FAILED).astype(object)),
            MESSAGE: (REALIZATION, np.where(ok, "", "diverged").astype(object)),
            WALL_TIME: (REALIZATION, np.zeros(n), {UNITS: "s"})}
    data.update({k: (REALIZATION, v, {UNITS: "m"}) for k, v in outputs.items()})
    data.update({v: first.variables[v] for v in INPUT_SUMMARY})
    coords = {REALIZATION: np.arange(n), PARAMETER: first[PARAMETER].values,
              PARAMETER_J: first[PARAMETER_J].values}
    coords.update({c: (first.variables[c].dims, stacked(c)) for c in _DESIGN_COORDS})
    return xr.Dataset(data, coords=coords)


def drive(method, n_inputs, function, seed=1):
    """plan, extend until None, analyze, as the executor does; ``function(x)`` gives the
    outputs of the rows x (rows, inputs) as a dict of arrays. ``n_inputs``: that many
    standard normal inputs, or an InputSpace."""
    space = n_inputs if isinstance(n_inputs, InputSpace) else space_of(n_inputs)
    design = method.plan(space, None, np.random.SeedSequence(seed))
    pieces, values = [design], [function(design[INPUTS].values)]
    runs = assemble(pieces, values)
    while (more := method.extend(runs, runs)) is not None:
        pieces.append(more)
        values.append(function(more[INPUTS].values))
        runs = assemble(pieces, values)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        return runs, method.analyze(runs, runs)


def linear(beta, n):
    """y = a . x with |a| = 1 along the diagonal; "y exceeds beta" has p_f = Phi(-beta)."""
    a = np.ones(n) / math.sqrt(n)
    return (lambda x: {"y": x @ a}), [{"name": "high", "output": "y", "exceeds": beta}]


def value(stats, name) -> float:
    return float(np.asarray(stats[name].values).ravel()[0])


def log_error(stats, exact) -> float:
    """|ln(p_f / exact)| in units of the reported lognormal spread sqrt(ln(1 + cov^2))."""
    p, cov = value(stats, FAILURE_PROBABILITY), value(stats, FAILURE_COV)
    return abs(math.log(p / exact)) / math.sqrt(math.log1p(cov**2))


def test_registered_under_subset_simulation():
    assert get_method("subset-simulation") is SubsetSimulation


# ----------------------------------------------------------------------------- exact answers

def test_linear_limit_state_in_ten_dims_within_its_reported_cov():
    beta, n, samples = 3.09, 10, 500
    function, tables = linear(beta, n)
    runs, stats = drive(method_for(tables, samples_per_level=samples), n, function)
    exact = sps.norm.sf(beta)
    levels = stats.sizes[SUBSET_LEVEL]
    # p0 = 0.1: level m - 1 holds Phi(-3.09) / 0.01 = 0.1 failures per sample, so 3 or 4
    assert levels in (3, 4) and stats.attrs["converged"] == 1
    # level 0 runs N, each later level N - p0 N proposals (the seeds are not re-run)
    assert stats.attrs[SOLVER_RUNS] == samples + (levels - 1) * (samples - samples // 10)
    # 3 reported standard deviations of ln p_f: fails 1 in 370 seeds were ln p_f normal
    assert log_error(stats, exact) < 3
    # the chains' correlation is seen: gamma > 0 at every level with chains
    assert np.all(stats[SUBSET_GAMMA].values[1:] > 0)
    assert np.all(np.abs(stats[SUBSET_ACCEPTANCE].values[1:] - 0.44) < 0.15)
    # beta = -Phi^-1(p_f) of the estimate: the same inverse of the same p, a few ulp apart
    # at most under another libm (1e-15 of beta ~ 3)
    assert value(stats, RELIABILITY_INDEX) == pytest.approx(-sps.norm.ppf(
        value(stats, FAILURE_PROBABILITY)), rel=1e-12)
    low, high = stats[FAILURE_INTERVAL].values[0]
    assert low < value(stats, FAILURE_PROBABILITY) < high


def test_a_lognormal_input_correlated_with_a_normal_one_through_the_copula():
    # x1 = exp(mu + sigma z1) with z1 correlated 0.6 with x2 ~ N(0, 1): "x1 exceeds t" has
    # p_f = Phi(-(ln t - mu) / sigma) whatever the correlation; the chains move u, the
    # copula maps it (z = L u), so a wrong map moves p_f
    mu, sigma, threshold = 0.2, 0.3, 4.0
    space = InputSpace([RandomInput.from_spec({"name": "x1", "distribution": "lognormal",
                                               "mu": mu, "sigma": sigma}),
                        RandomInput.from_spec({"name": "x2", "distribution": "normal",
                                               "mean": 0.0, "std": 1.0})],
                       np.array([[1.0, 0.6], [0.6, 1.0]]))
    method = method_for([{"name": "high", "output": "y", "exceeds": threshold}],
                        samples_per_level=500)
    runs, stats = drive(method, space, lambda x: {"y": x[:, 0]}, seed=8)
    exact = sps.norm.sf((math.log(threshold) - mu) / sigma)
    assert 1e-5 < exact < 1e-4 and stats.sizes[SUBSET_LEVEL] >= 4
    assert log_error(stats, exact) < 3  # 3 reported standard deviations
    # the inputs of every row are the copula's image of its point u
    u = runs[STANDARD_NORMAL].values
    z = u @ np.linalg.cholesky(space.correlation).T
    # the same product u L^T (x2 = 0 + 1 z2): a BLAS may sum in another order, a few ulp of
    # |z| < 10, far inside 1e-12
    np.testing.assert_allclose(runs[INPUTS].values[:, 1], z[:, 1], rtol=0, atol=1e-12)


def test_parabolic_limit_state_where_form_is_off():
    beta, kappa, n = 3.0, 0.2, 5
    exact = paraboloid_exact(beta, kappa, n)
    assert sps.norm.sf(beta) / exact > 1.5  # FORM's Phi(-beta) is far off here

    def function(x):
        return {"y": x[:, -1] - kappa / 2 * np.sum(x[:, :-1] ** 2, axis=1)}

    _, stats = drive(method_for([{"name": "high", "output": "y", "exceeds": beta}],
                                samples_per_level=500), n, function, seed=3)
    assert log_error(stats, exact) < 3  # 3 reported standard deviations (above)


FOUR_BRANCHES = [{"name": f"g{i}", "output": f"g{i}", "below": 0.0} for i in (1, 2, 3, 4)] + \
    [{"name": "system", "series": ["g1", "g2", "g3", "g4"]}]


def test_four_branch_series_system():
    # the literature's 4.46e-3 (k = 6) and 2.22e-3 (k = 7), to the integral's digits
    assert four_branch_exact(6) == pytest.approx(4.46e-3, rel=2e-3)
    assert four_branch_exact(7) == pytest.approx(2.22e-3, rel=5e-3)
    method = method_for(FOUR_BRANCHES, outputs=("g1", "g2", "g3", "g4"),
                        limit_state="system", samples_per_level=1000)
    _, stats = drive(method, 2, four_branches(6), seed=5)
    assert log_error(stats, four_branch_exact(6)) < 3  # 3 reported standard deviations


# 1500 a level: six or seven levels, 8250 or 9600 runs of 100 inputs, a few seconds on the
# fast path. At 1000 a level the genealogical c.o.v. and the spread of p_f over seeds are
# about 0.4 to 0.49; at 1500 the spread is under 0.4 (benchmarks/reliability.py, linear_100)
# and a single run's reported c.o.v. says so
@pytest.mark.slow
def test_one_in_a_million_in_100_dims_with_cov_at_most_0_4_in_10_000_calls():
    beta, n = 4.75, 100
    function, tables = linear(beta, n)
    _, stats = drive(method_for(tables, samples_per_level=1500), n, function, seed=2)
    assert stats.attrs[SOLVER_RUNS] <= 10_000
    assert value(stats, FAILURE_COV) <= 0.4
    assert log_error(stats, sps.norm.sf(beta)) < 3  # 3 reported standard deviations


def test_the_exceedance_curve_follows_the_exact_one_down_to_p_f():
    beta, n = 3.09, 10
    function, tables = linear(beta, n)
    _, stats = drive(method_for(tables, samples_per_level=500), n, function, seed=4)
    y = stats[EXCEEDANCE_LEVEL].values[0]
    p = stats[EXCEEDANCE_PROBABILITY].values[0]
    band = stats[EXCEEDANCE_INTERVAL].values[0]
    assert np.all(np.diff(y) >= 0) and np.all(np.diff(p) <= 0)  # P[Y >= y] falls
    # at the threshold the curve is p_f: the last level's failures, counted the same way
    at = np.searchsorted(y, beta)
    assert p[at] == pytest.approx(value(stats, FAILURE_PROBABILITY), rel=0.02)
    # each level's pointwise 95 % band holds the exact Phi(-y) at levels 1 .. 3: 4 points,
    # so a 4.5 standard-deviation band (~99.999 %) bounds them all with room
    for level in (1.0, 2.0, 2.5, 3.0):
        i = np.searchsorted(y, level)
        spread = math.log(band[i, 1] / p[i]) / sps.norm.ppf(0.975)
        assert abs(math.log(sps.norm.sf(y[i]) / p[i])) < 4.5 * spread


# ----------------------------------------------------------------------------- its error

def test_gamma_of_stuck_chains_and_of_independent_states():
    # chains that never move: the lag correlation is 1 at every lag, gamma = L - 1, and the
    # level's variance is that of N / L independent samples
    rng = np.random.default_rng(0)
    stuck = np.repeat(rng.random((200, 1)) < 0.1, 10, axis=1)
    # each rho(k) a ratio of two equal sums (1 up to a few eps), 9 of them weighted and
    # summed: 1e-14 of 9, inside 1e-12
    assert correlation_factor(stuck) == pytest.approx(9.0, rel=1e-12)
    # independent states: gamma is 0 up to the estimate's noise, 2 sum (1 - k/L) rho(k) with
    # each rho(k) ~ N(0, 1 / (N - k C)): sd about 2 sqrt(sum (1-k/L)^2 / N) = 0.08 at N = 5000
    free = rng.random((500, 10)) < 0.1
    assert abs(correlation_factor(free)) < 0.35  # 4 of those standard deviations


@pytest.mark.slow
def test_reported_cov_agrees_with_the_spread_over_repetitions():
    # 30 independent runs at p_f = 1e-3 in 10 dims (3 levels of 200): the spread of ln p_f
    # against the spread the reported c.o.v. implies, sqrt(mean of ln(1 + cov^2)). The sample
    # sd of 30 near-normal values errs by about 1/sqrt(2 x 29) = 13 % (relative), and the
    # genealogical c.o.v. with its few-families correction sits near the spread: [0.75, 1.35]
    # is about 2 of those standard errors below 1 and 2.7 above. Families taken as the last
    # level's chains (the levels' correlation left out) give 1.66 on these seeds, and each
    # state its own family (chains as independent samples) 3.9: both fail.
    beta, n, repetitions = 3.09, 10, 30
    function, tables = linear(beta, n)
    logs, reported = [], []
    for seed in range(repetitions):
        _, stats = drive(method_for(tables, samples_per_level=200), n, function, seed=seed)
        logs.append(math.log(value(stats, FAILURE_PROBABILITY)))
        reported.append(math.log1p(value(stats, FAILURE_COV) ** 2))
    ratio = np.std(logs, ddof=1) / math.sqrt(np.mean(reported))
    assert 0.75 <= ratio <= 1.35, ratio
    # the mean of ln p_f within 3 of its standard errors of ln p, plus the bias of ln of a
    # product estimator (about -cov^2 / 2)
    assert abs(np.mean(logs) - math.log(sps.norm.sf(beta))) < \
        3 * np.std(logs, ddof=1) / math.sqrt(repetitions) + 0.5 * np.mean(reported)


def test_lognormal_interval_has_median_p_and_the_cov():
    low, high = lognormal_interval(1e-4, 0.3, 0.95)
    s = math.sqrt(math.log1p(0.09))
    # closed forms of the same arithmetic: exp(-zs) exp(zs) = 1 within the two exps' ulp (a
    # few each under any libm) and 3 roundings, halved by the root: 1e-14 (abs=0: approx's
    # default 1e-12 is 1e-8 of 1e-4)
    assert math.sqrt(low * high) == pytest.approx(1e-4, rel=1e-14, abs=0)
    assert math.log(high / low) == pytest.approx(2 * 1.959963984540054 * s, rel=1e-12)
    assert np.all(np.isnan(lognormal_interval(0.0, math.inf, 0.95)))


# ----------------------------------------------------------------------------- failed runs

def test_failed_runs_are_counted_apart_and_rejected_proposals():
    # the solver fails wherever x2 > 1.5, a region independent of the failure event
    # (x1 > 3.09): leaving it out changes neither the level-0 fractions nor the chains'
    # conditional law of x1, so p_f stays Phi(-3.09)
    beta = 3.09

    def function(x):
        return {"y": np.where(x[:, 1] > 1.5, np.nan, x[:, 0])}

    runs, stats = drive(method_for([{"name": "high", "output": "y", "exceeds": beta}],
                                   samples_per_level=500), 3, function, seed=6)
    failed = runs[STATUS].values == STATUS_FAILED
    level = runs[SUBSET_LEVEL].values
    counted = stats[SUBSET_FAILED_RUNS].values
    assert counted[0] == int(failed[level == 0].sum()) > 0
    assert stats[SUBSET_SAMPLES].values[0] == 500 - counted[0]
    assert counted[1:].sum() == int(failed[level > 0].sum()) > 0
    # a failed proposal is rejected: every state of every chain ran ok
    assert np.all(stats[SUBSET_SAMPLES].values[1:] == 500)
    assert stats.attrs[FAILED_RUNS] == int(failed.sum())
    # level 0's first probability is p0 N over the samples that ran ok
    assert stats[SUBSET_PROBABILITY].values[0] == pytest.approx(50 / (500 - counted[0]))
    assert log_error(stats, sps.norm.sf(beta)) < 3  # 3 reported standard deviations
    text = stats.attrs[WARNINGS]
    assert "level-0 samples did not run ok: neither failure nor safe" in text
    assert "rejected (its chain stayed)" in text


def test_a_discrete_output_that_ties_at_the_threshold_stops_saying_so():
    # y is 0 or 1 (a "broken" flag): g = 0.5 - y ties at 0.5 for 98 % of the samples, so the
    # p0 quantile cannot split a level; the study stops after level 0 with its plain fraction
    def function(x):
        return {"y": (x[:, 0] > 2.0).astype(float)}

    runs, stats = drive(method_for([{"name": "broken", "output": "y", "exceeds": 0.5}],
                                   samples_per_level=100), 2, function, seed=7)
    assert stats.attrs["converged"] == 0 and "stopped falling" in stats.attrs["stop_reason"]
    assert runs.sizes[REALIZATION] == 100 and stats.sizes[SUBSET_LEVEL] == 1
    failures = int(np.sum(runs["y"].values > 0.5))
    assert value(stats, FAILURE_PROBABILITY) == failures / 100
    assert "did not reach the failure domain" in stats.attrs[WARNINGS]


# ----------------------------------------------------------------------------- studies

def study_file(tmp_path, name, method=None, limit_states=None, workers=0, n=3, beta=2.33):
    """A study of the analytic y = sum x_k / sqrt n in n standard normals, "y exceeds
    beta": p_f = Phi(-beta); 50 samples a level in 10 chains of 5 (p0 = 0.2), so that
    p_f ~ 1e-2 takes three levels in 9 rounds (the executor writes a checkpoint after each
    round: about 0.25 s a round)."""
    return helpers.study_file(
        tmp_path, name, scene={"model": "linear", "coefficients": [1 / math.sqrt(n)] * n},
        inputs=[(0.0, 1.0)] * n,
        limit_states=limit_states or [{"name": "high", "output": "y", "exceeds": beta}],
        method={"kind": "subset-simulation", "samples_per_level": 50,
                "level_probability": 0.2, **(method or {})},
        seed=9, execution={"workers": workers})


def test_a_killed_study_resumes_to_the_uninterrupted_numbers(tmp_path):
    path = study_file(tmp_path, "whole")
    whole = run_quietly(path)
    assert whole.statistics.attrs["converged"] == 1
    assert whole.statistics.sizes[SUBSET_LEVEL] >= 3
    level, step = whole.runs[SUBSET_LEVEL].values, whole.runs[CHAIN_STEP].values
    # killed inside level 1's third round, 4 of its 10 proposals done: the rounds after it
    # cross level 2's threshold and seeds, all replayed from the stored runs
    third = np.flatnonzero((level == 1) & (step == 3))
    keep = third[-1] + 1
    cut = cut_result(whole.path, keep, third[4:], tmp_path / "cut.nc")
    resumed = run_quietly(path, resume=True, output=cut)
    assert resumed.resumed == keep - 6
    (runs_w, stats_w), (runs_c, stats_c) = comparable(whole.path), comparable(cut)
    xr.testing.assert_identical(runs_w.drop_vars(MESSAGE), runs_c.drop_vars(MESSAGE))
    stats_c.attrs.pop("resumed", None)
    xr.testing.assert_identical(stats_w, stats_c)


@pytest.mark.slow
def test_no_worker_and_two_workers_give_identical_results(tmp_path):
    # p_f = 0.05: two levels in 5 rounds (dask starts its cluster once; each round's
    # proposals are spread over both workers)
    paths = [run_quietly(study_file(tmp_path, f"w{w}", workers=w, beta=1.645)).path
             for w in (0, 2)]
    (runs0, stats0), (runs2, stats2) = map(comparable, paths)
    xr.testing.assert_identical(runs0, runs2)
    xr.testing.assert_identical(stats0, stats2)


def test_the_report_gives_p_f_the_levels_and_their_figure(tmp_path):
    outcome = run_quietly(study_file(tmp_path, "report", beta=1.645))  # two levels, 5 rounds
    tree = open_result(outcome.path)
    text = summary_table(tree)
    stats = outcome.statistics
    p = number_text(value(stats, FAILURE_PROBABILITY))
    assert f"subset simulation, limit state 'high' (y > 1.645): p_f = {p}" in text
    assert "lognormal), c.o.v. " in text and "effective level-0 families" in text
    assert "levels uncorrelated" in text and "fully correlated" in text
    assert "level  threshold b" in text
    rows = [line for line in text.splitlines() if line.strip()[:1].isdigit()
            and "  " in line and line.split()[0].isdigit()]
    assert len(rows) >= stats.sizes[SUBSET_LEVEL]
    assert "levels' correlation through the seeds" in text
    written = [p.name for p in write_figures(tree, tmp_path / "figures")]
    assert "subset_levels.png" in written
    # what the report shows is stored: thresholds, probabilities, both c.o.v.s
    for name in (SUBSET_THRESHOLD, SUBSET_PROBABILITY, SUBSET_GAMMA, SUBSET_ACCEPTANCE,
                 FAILURE_COV_CORRELATED, FAILURE_COV_UNCORRELATED, FAILURE_FAMILIES):
        assert name in tree["statistics"].to_dataset()
    assert value(stats, FAILURE_COV_CORRELATED) >= value(stats, FAILURE_COV_UNCORRELATED)
    low = float(stats[FAILURE_INTERVAL].sel({BOUND: BOUND_LOW}).values[0])
    high = float(stats[FAILURE_INTERVAL].sel({BOUND: BOUND_HIGH}).values[0])
    assert low < value(stats, FAILURE_PROBABILITY) < high


def number_text(x) -> str:
    return f"{x:.6g}"


def test_a_series_system_is_accepted_by_name(tmp_path):
    # its margin is the smallest of its members' (LimitStates.margins): nested events
    # g <= b as for one limit state; the numbers are test_four_branch_series_system's
    tables = [{"name": "high", "output": "y", "exceeds": 3.0},
              {"name": "low", "output": "y", "below": -3.0},
              {"name": "either", "series": ["high", "low"]}]
    method = load_study(study_file(tmp_path, "either", {"limit_state": "either"},
                                   tables)).method
    assert method.limit_state == "either"


# ----------------------------------------------------------------------------- refusals

@pytest.mark.parametrize("options, key, words", [
    ({"samples_per_level": 52}, "method.samples_per_level", "do not make whole chains"),
    ({"level_probability": 0.6}, "method.level_probability", "less than or equal to 0.5"),
    ({"max_levels": 0}, "method.max_levels", "greater than or equal to 1"),
    ({"limit_state": "nope"}, "method.limit_state", "not among the study's limit states"),
    ({"samples_per_level": 1000.0}, "method.samples_per_level", "must be an integer"),
])
def test_bad_options_are_one_line_errors_naming_the_key(tmp_path, options, key, words):
    with pytest.raises(StudyError) as error:
        load_study(study_file(tmp_path, "bad", options))
    assert error.value.key == key and words in str(error.value)
    assert "\n" not in str(error.value)


def test_several_limit_states_need_one_named_and_none_is_refused(tmp_path):
    two = [{"name": "high", "output": "y", "exceeds": 3.0},
           {"name": "low", "output": "y", "below": -3.0}]
    with pytest.raises(StudyError) as error:
        load_study(study_file(tmp_path, "two", limit_states=two))
    assert error.value.key == "method.limit_state" and "name it with limit_state" in \
        str(error.value)
    path = study_file(tmp_path, "none")
    text = path.read_text()
    path.write_text(text[:text.index("[[limit_states]]")] + text[text.index("[method]"):])
    with pytest.raises(StudyError) as error:
        load_study(path)
    assert error.value.key == "limit_states" and "\n" not in str(error.value)
