"""Monte Carlo conformance: exact moments of the analytic models within a few standard errors,
the convergence trace, early stopping on a target error, quantiles, failures and edge cases.

Designs are run in-process with ``evaluate_design`` (no dask): the method sees exactly what
the executor would hand it.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pydantic
import pytest

from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import get_method
from uqflow.methods.monte_carlo import MonteCarlo

from mc_cases import ishigami_space, run_mc, uniform

RULES = ["random", "lhs", "sobol", "halton"]
N_CONFORMANCE = 4096
EPS = np.finfo(float).eps


def summation_error(y):
    """Bound on the error of any sum of ``y`` divided by its length, whatever the order:
    recursive summation of n terms errs by at most (n - 1) eps sum|y_i| (Higham 2002, 4.3)."""
    return len(y) * EPS * np.mean(np.abs(y))


def normal(name, mean, std, units=""):
    return RandomInput.from_spec({"name": name, "distribution": "normal", "mean": mean,
                                  "std": std, "units": units})


def stat(stats, name, out="y"):
    return stats[out].sel(statistic=name).values


def variance_stderr(y):
    """Standard error of the unbiased variance estimator, from the sample's 4th central moment:
    Var(s^2) = (mu4 - sigma^4 (n - 3) / (n - 1)) / n."""
    n = y.size
    d = y - y.mean()
    m4 = np.mean(d**4)
    s2 = d @ d / (n - 1)
    return math.sqrt((m4 - s2**2 * (n - 3) / (n - 1)) / n)


def test_registered():
    assert get_method("monte-carlo") is MonteCarlo
    assert MonteCarlo.name == "monte-carlo"


# --------------------------------------------------------------------------------------------
# Conformance: Ishigami (a = 7, b = 0.1, Xi ~ U(-pi, pi))
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("rule", RULES)
def test_ishigami_mean_and_variance(rule, reference):
    """Every rule: the pooled variance within 4 of its standard errors, the mean within 4
    standard errors of the rule's kind (i.i.d. for random/LHS, replicate spread for the
    quasi-random rules: tests/methods/test_rqmc.py), the interval mean +- t stderr."""
    ref = reference["ishigami"]
    assert (ref["a"], ref["b"], ref["mean"]) == (7.0, 0.1, 3.5)
    exact_var = ref["variance"]
    # the stored 17-digit value against the closed form: pi^8 and four terms, ~8 roundings
    # on each side: 16 eps
    assert exact_var == pytest.approx(7**2 / 8 + 0.1 * math.pi**4 / 5
                                      + 0.1**2 * math.pi**8 / 18 + 0.5, rel=16 * EPS)
    _, design, runs, stats = run_mc({"model": "ishigami", "a": 7.0, "b": 0.1},
                                    ishigami_space(), seed=2024, samples=N_CONFORMANCE,
                                    rule=rule)
    assert design.attrs["rule"] == rule and stats.attrs["rule"] == rule
    y = runs["y"].values
    assert np.all(runs["status"].values == "ok")
    n = y.size
    mean, var, stderr = stat(stats, "mean"), stat(stats, "variance"), stat(stats, "stderr")
    assert stat(stats, "std") == math.sqrt(var)          # the same correctly rounded sqrt
    assert var == np.var(y, ddof=1)                      # pooled, whatever the rule
    if rule in ("random", "lhs"):
        # sqrt(var / n) against sqrt(var) / sqrt(n): three roundings, <= 2 eps apart
        assert stderr == pytest.approx(math.sqrt(var / n), rel=4 * np.finfo(float).eps)
        assert stats.attrs["stderr_kind"] == ("iid" if rule == "random" else
                                              "iid-conservative")
        assert stats.attrs["degrees_of_freedom"] == n - 1
    else:
        assert stats.attrs["stderr_kind"] == "rqmc"
    assert abs(mean - ref["mean"]) < 4 * stderr
    assert abs(var - exact_var) < 4 * variance_stderr(y)
    # the interval is mean +- t stderr, t with the estimate's degrees of freedom
    from scipy import stats as sps
    t = sps.t.ppf(0.975, stats.attrs["degrees_of_freedom"])
    assert stat(stats, "ci_low") == mean - t * stderr
    assert stat(stats, "ci_high") == mean + t * stderr
    assert stats.attrs["solver_runs"] == n and stats.attrs["failed_runs"] == 0
    assert stats.attrs["samples_ok"] == n and stats.attrs["warnings"] == ""
    assert stats.attrs["method"] == "monte-carlo"


def test_statistics_layout():
    _, design, runs, stats = run_mc({"model": "ishigami"}, ishigami_space(), samples=64,
                                    quantiles=[0.95, 0.05, 0.5, 0.5, 0.25])
    assert list(stats["statistic"].values) == ["mean", "variance", "std", "stderr", "ci_low",
                                               "ci_high", "q5", "q25", "q50", "q95"]
    assert stats["y"].dims == ("statistic",)
    assert stats["y_trace"].dims == ("trace_samples", "trace_statistic")
    assert list(stats["trace_statistic"].values) == ["mean", "std", "stderr"]
    for v in ("input_mean", "input_std", "input_cv", "input_skewness", "input_kurtosis",
              "input_correlation"):
        assert v in stats
    # (a + b) / 2 and (b - a) / sqrt(12) with |a| = |b| = pi: a few roundings of pi
    np.testing.assert_allclose(stats["input_mean"].values, 0.0, atol=4 * EPS * math.pi)
    np.testing.assert_allclose(stats["input_std"].values, 2 * math.pi / math.sqrt(12),
                               rtol=4 * EPS)
    assert stats.attrs["confidence"] == 0.95 and stats.attrs["samples_ok"] == 64


def test_plan_is_reproducible_and_maps_the_inputs():
    space = InputSpace([normal("E", 200e9, 10e9, "Pa"), uniform("nu", 0.25, 0.35)])
    method = MonteCarlo(samples=100, rule="lhs")
    a = method.plan(space, None, np.random.SeedSequence(9))
    b = method.plan(space, None, np.random.SeedSequence(9))
    c = method.plan(space, None, np.random.SeedSequence(10))
    assert a["inputs"].shape == (100, 2)
    assert list(a["parameter"].values) == ["E", "nu"]
    assert list(a["parameter_units"].values) == ["Pa", ""]
    np.testing.assert_array_equal(a["inputs"].values, b["inputs"].values)
    assert not np.array_equal(a["inputs"].values, c["inputs"].values)
    nu = a["inputs"].sel(parameter="nu").values
    assert np.all((nu > 0.25) & (nu < 0.35))
    # LHS: one value of nu in each of the 100 strata
    np.testing.assert_array_equal(np.sort(np.floor((nu - 0.25) / 0.1 * 100)), np.arange(100))


# --------------------------------------------------------------------------------------------
# Convergence trace
# --------------------------------------------------------------------------------------------

def test_trace_ends_at_the_final_estimate_and_matches_prefixes():
    _, _, runs, stats = run_mc({"model": "ishigami"}, ishigami_space(), seed=5, samples=2000,
                               rule="random", trace_points=30)
    y = runs["y"].values
    trace = stats["y_trace"]
    counts = stats["trace_samples"].values
    assert counts[0] == 2 and counts[-1] == 2000 and np.all(np.diff(counts) > 0)
    last = trace.isel(trace_samples=-1)
    # The trace sums centred values cumulatively, the statistics use numpy's own sums: each
    # mean within summation_error of exact (2 of them, plus the centring's own error).
    tol_mean = 2 * summation_error(y) + summation_error(y - y.mean())
    assert last.sel(trace_statistic="mean") == pytest.approx(stat(stats, "mean"), rel=0,
                                                             abs=tol_mean)
    # sums of n squares: relative n eps each; std halves it, and both sides err: 2 n eps
    assert last.sel(trace_statistic="std") == pytest.approx(stat(stats, "std"),
                                                            rel=2 * len(y) * EPS)
    assert last.sel(trace_statistic="stderr") == pytest.approx(stat(stats, "stderr"),
                                                               rel=2 * len(y) * EPS)
    centred = y - y.mean()
    for k, c in enumerate(counts):   # every point is the estimate from the first c samples
        assert trace.sel(trace_statistic="mean")[k] == pytest.approx(
            y[:c].mean(), rel=0, abs=tol_mean)
        # s2 - s1^2 / c cancels when the prefix mean is far from the overall one: the
        # relative error of the sum of squares is amplified by s2 / (c - 1) var_c
        s1, s2 = centred[:c].sum(), np.sum(centred[:c] ** 2)
        amplification = s2 / (s2 - s1**2 / c)
        assert trace.sel(trace_statistic="std")[k] == pytest.approx(
            y[:c].std(ddof=1), rel=4 * len(y) * EPS * amplification)


def test_trace_stderr_falls_like_one_over_sqrt_n():
    _, _, _, stats = run_mc({"model": "ishigami"}, ishigami_space(), seed=6, samples=8192,
                            rule="random")
    counts = stats["trace_samples"].values
    se = stats["y_trace"].sel(trace_statistic="stderr").values
    keep = counts >= 64
    slope = np.polyfit(np.log(counts[keep]), np.log(se[keep]), 1)[0]
    assert slope == pytest.approx(-0.5, abs=0.08)
    # and stderr * sqrt(n) is the (stable) std
    ratio = se[keep] * np.sqrt(counts[keep])
    assert np.all(np.abs(ratio / ratio[-1] - 1) < 0.25)


# --------------------------------------------------------------------------------------------
# Early stopping on target_rel_stderr
# --------------------------------------------------------------------------------------------

def test_enough_once_the_target_is_reached():
    target, min_samples = 0.05, 32
    method, design, runs, _ = run_mc({"model": "ishigami"}, ishigami_space(), seed=8,
                                     samples=1500, rule="random", target_rel_stderr=target,
                                     min_samples=min_samples)
    y = runs["y"].values
    answers = {}
    for k in list(range(2, 64)) + list(range(64, 1501, 7)):
        prefix = dict(realization=slice(0, k))
        answers[k] = method.enough(design.isel(prefix), runs.isel(prefix))
        rel = y[:k].std(ddof=1) / math.sqrt(k) / abs(y[:k].mean())
        assert answers[k] == (k >= min_samples and rel <= target), k
    assert not any(answers[k] for k in range(2, 64))   # early: nowhere near 5 %
    assert answers[max(answers)]                          # ~ 1.06 / sqrt(1500) = 2.7 %
    first = min(k for k, ok in answers.items() if ok)
    assert 300 < first < 700                              # (3.72 / 3.5 / 0.05)^2 = 452


def test_enough_counts_only_finished_realizations():
    """The executor passes the whole runs dataset with unfinished realizations 'pending'."""
    method, design, runs, _ = run_mc({"model": "ishigami"}, ishigami_space(), seed=8,
                                     samples=1500, target_rel_stderr=0.05)
    partial = runs.copy(deep=True)
    partial["status"].values[600:] = "pending"
    partial["y"].values[600:] = np.nan
    prefix = dict(realization=slice(0, 600))
    assert method.enough(design, partial) == method.enough(design.isel(prefix),
                                                           runs.isel(prefix))
    partial["status"].values[:] = "pending"
    assert not method.enough(design, partial)


def test_enough_without_target_or_below_min_samples():
    method, design, runs, _ = run_mc({"model": "linear"}, InputSpace([normal("x1", 5.0, 0.0)]),
                                     samples=40)
    assert not method.enough(design, runs)                  # no target: run the whole design
    method = MonteCarlo(samples=40, target_rel_stderr=0.5, min_samples=41)
    assert not method.enough(design, runs)
    method = MonteCarlo(samples=40, target_rel_stderr=0.5, min_samples=40)
    assert method.enough(design, runs)                      # constant output: stderr 0


def test_enough_with_zero_mean_never_stops():
    method, design, runs, _ = run_mc({"model": "linear"}, InputSpace([normal("x1", 0.0, 1.0)]),
                                     samples=500, target_rel_stderr=0.5, min_samples=10)
    y = runs["y"].values
    assert abs(y.mean()) < 3 / math.sqrt(500)
    # relative error of a mean near zero is large; with an exact 0 it is infinite
    runs = runs.copy(deep=True)
    runs["y"].values[:] = np.concatenate([y[:250], -y[:250]])
    assert not method.enough(design, runs)


# --------------------------------------------------------------------------------------------
# Quantiles, edge sample counts
# --------------------------------------------------------------------------------------------

def test_quantiles_of_a_uniform_output():
    qs = [0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.99]
    n = 4096
    _, _, _, stats = run_mc({"model": "linear", "coefficients": [1.0]},
                            InputSpace([uniform("x1", 2.0, 6.0)]), seed=3, samples=n,
                            rule="random", quantiles=qs)
    for q in qs:
        exact = 2.0 + 4.0 * q
        se = 4.0 * math.sqrt(q * (1 - q) / n)      # density of U(2, 6) is 1/4
        assert abs(stat(stats, f"q{100 * q:g}") - exact) < 4 * se, q


def test_quantile_options_are_validated():
    assert MonteCarlo(quantiles=[0.9, 0.1, 0.1]).options.quantiles == [0.1, 0.9]
    assert MonteCarlo(quantiles=[]).options.quantiles == []
    for bad in ([1.5], [-0.1]):
        with pytest.raises(pydantic.ValidationError):
            MonteCarlo(quantiles=bad)


@pytest.mark.parametrize("options", [{"samples": 0}, {"confidence": 1.0}, {"confidence": 0.0},
                                     {"min_samples": 1}, {"target_rel_stderr": 0.0},
                                     {"trace_points": 1}, {"rule": "grid"}, {"sample": 10}])
def test_bad_options(options):
    with pytest.raises(pydantic.ValidationError):
        MonteCarlo(**options)


def test_one_sample_gives_nan_variance_and_a_warning():
    space = InputSpace([normal("x1", 2.0, 0.5)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")           # no numpy "degrees of freedom" warnings either
        _, design, runs, stats = run_mc({"model": "linear"}, space, samples=1)
    y0 = runs["y"].values[0]
    assert stat(stats, "mean") == y0 and stat(stats, "q50") == y0
    for name in ("variance", "std", "stderr", "ci_low", "ci_high"):
        assert np.isnan(stat(stats, name)), name
    assert "only 1 realization(s) succeeded" in stats.attrs["warnings"]
    assert stats.attrs["samples_ok"] == 1
    trace = stats["y_trace"]
    assert trace.sizes["trace_samples"] == 1
    assert trace.sel(trace_statistic="mean").item() == y0
    assert np.isnan(trace.sel(trace_statistic="std").item())


def test_two_samples():
    """Two samples: the variance is defined ((y1 - y2)^2 / 2); two with one failed is the
    one-sample case."""
    space = InputSpace([uniform("x", -2.0, 2.0)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, _, runs, stats = run_mc({"model": "faulty"}, space, samples=2, seed=1)
    y = runs["y"].values
    # y_i - mean errs by eps |mean| (the mean's rounding), relative to |y0 - y1| / 2: the
    # variance's relative error is ~ 4 eps (1 + |mean| / |y0 - y1|), the std's half that
    cond = 1 + abs(y.mean()) / abs(y[0] - y[1])
    assert stat(stats, "variance") == pytest.approx((y[0] - y[1]) ** 2 / 2, rel=8 * EPS * cond)
    assert stat(stats, "stderr") == pytest.approx(abs(y[0] - y[1]) / 2, rel=8 * EPS * cond)
    assert stats.attrs["warnings"] == ""
    limit = float(min(y))          # the larger sample now raises SolverError
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, _, runs, stats = run_mc({"model": "faulty", "raise_above": limit}, space,
                                   samples=2, seed=1)
    assert list(runs["status"].values).count("failed") == 1
    assert stat(stats, "mean") == limit
    assert np.isnan(stat(stats, "variance")) and np.isnan(stat(stats, "stderr"))
    assert "1 of 2 realizations failed" in stats.attrs["warnings"]
    assert "only 1 realization(s) succeeded" in stats.attrs["warnings"]


# --------------------------------------------------------------------------------------------
# Failures
# --------------------------------------------------------------------------------------------

def test_failed_realizations_are_left_out():
    """x ~ U(-2, 2); the solver raises above 1.5 and returns NaN below -1.5: a quarter of the
    realizations fail; the statistics are those of U(-1.5, 1.5) from the rest."""
    n = 4000
    _, _, runs, stats = run_mc({"model": "faulty", "raise_above": 1.5, "nan_below": -1.5},
                               InputSpace([uniform("x", -2.0, 2.0)]), seed=4, samples=n,
                               rule="random")
    x = runs["inputs"].values[:, 0]
    status = runs["status"].values
    failed = (x > 1.5) | (x < -1.5)
    np.testing.assert_array_equal(status == "failed", failed)
    assert all("SolverError" in m for m in runs["message"].values[x > 1.5])
    assert all("non-finite" in m for m in runs["message"].values[x < -1.5])
    k = int(failed.sum())
    assert abs(k - n / 4) < 4 * math.sqrt(n * 0.25 * 0.75)
    ok = x[~failed]
    assert np.array_equal(runs["y"].values[~failed], ok)   # the model returns x itself
    assert stat(stats, "mean") == ok.mean()                 # so the same numpy reductions
    assert stat(stats, "variance") == ok.var(ddof=1)
    assert abs(stat(stats, "mean")) < 4 * stat(stats, "stderr")
    assert abs(stat(stats, "variance") - 0.75) < 4 * variance_stderr(ok)
    assert stats.attrs["failed_runs"] == k and stats.attrs["solver_runs"] == n
    assert stats.attrs["samples_ok"] == n - k
    assert f"{k} of {n} realizations failed" in stats.attrs["warnings"]
    # cumulative sums of centred values against numpy's: see summation_error
    assert stats["y_trace"].isel(trace_samples=-1).sel(trace_statistic="mean") == \
        pytest.approx(ok.mean(), rel=0, abs=2 * summation_error(ok)
                      + summation_error(ok - ok.mean()))


def test_every_realization_failing_gives_nan_statistics():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, _, runs, stats = run_mc({"model": "faulty", "raise_above": -10.0},
                                   InputSpace([uniform("x", -2.0, 2.0)]), samples=20)
    assert np.all(runs["status"].values == "failed")
    assert np.all(np.isnan(stats["y"].values))
    assert np.all(np.isnan(stats["y_trace"].values))
    assert stats.attrs["failed_runs"] == 20 and stats.attrs["samples_ok"] == 0
    assert "20 of 20 realizations failed" in stats.attrs["warnings"]
    assert "only 0 realization(s)" in stats.attrs["warnings"]


# --------------------------------------------------------------------------------------------
# Zero variance and extreme magnitudes
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("rule", RULES)
def test_zero_std_inputs_give_exactly_zero_variance(rule):
    space = InputSpace([normal("x1", 0.1, 0.0), normal("x2", 0.7, 0.0)])
    _, _, runs, stats = run_mc({"model": "linear", "coefficients": [0.3, 1.1]}, space,
                               samples=256, rule=rule)
    y0 = 0.3 * 0.1 + 1.1 * 0.7
    assert np.all(runs["y"].values == y0)
    assert stat(stats, "mean") == y0          # equal values: their value, not a sum
    for name in ("variance", "std", "stderr"):
        assert stat(stats, name) == 0.0, name
    assert stat(stats, "ci_low") == stat(stats, "ci_high") == stat(stats, "mean")
    assert np.all(stats["y_trace"].sel(trace_statistic=["std", "stderr"]).values == 0.0)
    np.testing.assert_array_equal(stats["input_std"].values, [0.0, 0.0])


@pytest.mark.parametrize("scale", [1e12, 1e-12], ids=["1e12", "1e-12"])
def test_extreme_magnitudes_keep_relative_accuracy(scale):
    """y = x with x ~ N(3 scale, 1e-6 scale): the statistics are the sample's to ~1e-10
    relative, and the exact ones within a few standard errors."""
    n = 2048
    mean, std = 3.0 * scale, 1e-6 * scale
    _, _, runs, stats = run_mc({"model": "linear", "coefficients": [1.0]},
                               InputSpace([normal("x1", mean, std)]), seed=12, samples=n,
                               rule="random")
    y = runs["y"].values
    fmean = math.fsum(y) / n
    fvar = math.fsum((v - fmean) ** 2 for v in y) / (n - 1)
    # fsum is exact: numpy's sum of n same-sign terms is within (n - 1) eps
    assert stat(stats, "mean") == pytest.approx(fmean, rel=n * EPS)
    # Two-pass variance: the mean's error (<= n eps |mean|) shifts every deviation alike and
    # enters only squared, relative to std; the sum of squares is within n eps (both sides).
    var_tol = 2 * n * EPS + (n * EPS * mean / std) ** 2
    assert stat(stats, "variance") == pytest.approx(fvar, rel=var_tol)
    assert abs(stat(stats, "mean") - mean) < 4 * stat(stats, "stderr")
    assert abs(stat(stats, "variance") - std**2) < 4 * variance_stderr(y)
    last = stats["y_trace"].isel(trace_samples=-1)
    # the trace centres on the overall mean: the same argument as the variance's
    assert last.sel(trace_statistic="std") == pytest.approx(math.sqrt(fvar), rel=var_tol)
    mid = stats["trace_samples"].values[10]
    # overall mean (n eps relative) plus a cumulative sum of centred values (negligible)
    assert stats["y_trace"].sel(trace_statistic="mean")[10] == \
        pytest.approx(math.fsum(y[:mid]) / mid, rel=2 * n * EPS)


def test_linear_model_mixing_magnitudes():
    """y = 1e-12 x1 + 1e12 x2, x1 ~ N(3e12, 3e10), x2 ~ N(2e-12, 2e-14): y ~ N(5, 0.0013)."""
    n = 4096
    space = InputSpace([normal("x1", 3e12, 3e10), normal("x2", 2e-12, 2e-14)])
    _, _, runs, stats = run_mc({"model": "linear", "coefficients": [1e-12, 1e12]}, space,
                               seed=13, samples=n, rule="random")
    y = runs["y"].values
    x = runs["inputs"].values
    # two products and a sum of same-sign terms, on both sides: 6 eps
    np.testing.assert_allclose(y, 1e-12 * x[:, 0] + 1e12 * x[:, 1], rtol=6 * EPS)
    exact_var = 0.03**2 + 0.02**2
    assert abs(stat(stats, "mean") - 5.0) < 4 * stat(stats, "stderr")
    assert abs(stat(stats, "variance") - exact_var) < 4 * variance_stderr(y)


# --------------------------------------------------------------------------------------------
# Field-valued output
# --------------------------------------------------------------------------------------------

def test_exponential_decay_field_output(reference):
    """E[y(t)] = 15 (e^-0.1t - e^-0.2t) / t at every t of the output, within 4 stderr."""
    t = np.array([0.5, 1.0, 2.0, 4.0, 8.0])
    space = InputSpace([normal("alpha", 1.5, 0.2), uniform("beta", 0.1, 0.2)])
    _, _, runs, stats = run_mc({"model": "exponential_decay", "t": t.tolist()}, space,
                               seed=14, samples=2048, rule="sobol")
    assert stats["y"].dims == ("statistic", "t")
    np.testing.assert_array_equal(stats["t"].values, t)
    assert stats["y_trace"].dims == ("trace_samples", "trace_statistic", "t")
    exact = 15 * (np.exp(-0.1 * t) - np.exp(-0.2 * t)) / t
    assert np.all(np.abs(stat(stats, "mean") - exact) < 4 * stat(stats, "stderr"))
    second = 11.45 * (np.exp(-0.2 * t) - np.exp(-0.4 * t)) / t
    exact_var = second - exact**2
    y = runs["y"].values
    se_var = np.array([variance_stderr(y[:, k]) for k in range(t.size)])
    assert np.all(np.abs(stat(stats, "variance") - exact_var) < 4 * se_var)
    # the RQMC trace's last point is the same mean of replicate means, computed alike
    last = stats["y_trace"].isel(trace_samples=-1).sel(trace_statistic="mean").values
    np.testing.assert_array_equal(last, stat(stats, "mean"))
