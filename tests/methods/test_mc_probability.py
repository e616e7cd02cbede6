"""Monte Carlo for probabilities (issue 18, point 2): the intervals of uqflow.probability against
their closed forms and their coverage, and P[failure] per limit state from monte-carlo with
each rule, realizations that did not run ok left out, and the target_cov stopping rule.

The analytic model is y = x1 + x2 + x3 with xi ~ N(0, 1), so y ~ N(0, 3) and
P[y > t] = Phi(-t / sqrt(3)) exactly; t = 2.85 gives p ~ 0.0497.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr
from scipy import stats as sps

from uqflow.errors import StudyError
from uqflow.inputs import InputSpace, RandomInput
from uqflow.limit_states import LimitStates
from uqflow.methods.monte_carlo import MonteCarlo, failure_lines
from uqflow.probability import (binomial_cov, clopper_pearson, reliability_index,
                                replicate_interval, wilson)
from uqflow.realization import evaluate_design
from solvers.analytic import AnalyticSolver

from mc_cases import uniform

EPS = np.finfo(float).eps
THRESHOLD = 2.85
EXACT_P = float(sps.norm.sf(THRESHOLD / math.sqrt(3)))
LINEAR3 = {"model": "linear", "coefficients": [1.0, 1.0, 1.0]}


class ExceedanceStates:
    """A stand-in following the LimitStates interface of uqflow.limit_states, for what a
    study's limit states cannot express (an input beyond a threshold): limit state
    ``name`` fails where ``variable`` (an output, or column ``column`` of the inputs) exceeds
    its threshold; margins NaN where the realization did not run ok, unless ``honest`` is
    False (then a margin from the inputs is finite for every realization, to show that the
    method masks non-ok runs itself)."""

    def __init__(self, states, honest=True):
        self.states = states          # name -> (variable, column or None, threshold)
        self.names = list(states)
        self.honest = honest

    def margins(self, runs):
        columns = []
        for variable, column, threshold in self.states.values():
            y = runs[variable].values if column is None else runs[variable].values[:, column]
            columns.append(threshold - y)
        g = np.stack(columns, axis=1).astype(float)
        if self.honest:
            g[runs["status"].values != "ok"] = np.nan
        return xr.DataArray(g, dims=("realization", "limit_state"),
                            coords={"limit_state": self.names})

    def failures(self, runs):
        return self.margins(runs) <= 0


def normal(name):
    return RandomInput.from_spec({"name": name, "distribution": "normal", "mean": 0.0,
                                  "std": 1.0})


def linear_space():
    return InputSpace([normal(f"x{i}") for i in (1, 2, 3)])


def run_with_states(scene, space, states, seed=0, **options):
    method = MonteCarlo(**options)
    method.check_limit_states(states)
    design = method.plan(space, None, np.random.SeedSequence(seed))
    runs = evaluate_design(AnalyticSolver.from_scene(scene), design)
    return method, design, runs, method.analyze(design, runs)


def y_exceeds(threshold=THRESHOLD, name="y_high"):
    """The study's [[limit_states]] { name, output = "y", exceeds = threshold }."""
    return LimitStates.from_tables([{"name": name, "output": "y", "exceeds": threshold}],
                                   AnalyticSolver.from_scene(LINEAR3).outputs(), "test")


# ----------------------------------------------------------------------------- intervals

@pytest.mark.parametrize("n", [1, 7, 1000, 10**6])
def test_clopper_pearson_closed_forms_at_zero_and_all(n):
    """k = 0: [0, 1 - (alpha/2)^(1/n)]; k = n: [(alpha/2)^(1/n), 1]."""
    alpha = 0.05
    # -expm1(log(a)/n) is the closed form without the cancellation of 1 - x near x = 1
    upper = -math.expm1(math.log(alpha / 2) / n)
    none, every = clopper_pearson(0, n, 0.95), clopper_pearson(n, n, 0.95)
    assert none.low == 0.0 and every.high == 1.0
    # scipy's incomplete-beta inverse is accurate to ~1e-15 relative (Boost's ibeta_inv);
    # 1e-12 leaves three decades for libm differences in the few operations around it
    # (abs=0: approx's default 1e-12 would be 3e-7 of the upper bound 3.7e-6 at n = 10^6)
    assert none.high == pytest.approx(upper, rel=1e-12, abs=0)
    # bound: ibeta_inv ~1e-15 relative plus a few libm roundings: 1e-12
    assert every.low == pytest.approx((alpha / 2) ** (1 / n), rel=1e-12, abs=0)
    assert not none.reason and not every.reason


@pytest.mark.parametrize("k, n", [(1, 10), (3, 50), (50, 1000), (999, 1000)])
def test_clopper_pearson_bounds_have_tails_alpha_over_two(k, n):
    """The defining property: P[X >= k | low] = alpha/2 = P[X <= k | high], X ~ Bin(n, p);
    and scipy's own exact interval."""
    ci = clopper_pearson(k, n, 0.95)
    # the bounds' relative error (~1e-15) times d ln(tail) / d ln(p) <= n = 1000
    assert sps.binom.sf(k - 1, n, ci.low) == pytest.approx(0.025, rel=1e-9)
    assert sps.binom.cdf(k, n, ci.high) == pytest.approx(0.025, rel=1e-9)
    ref = sps.binomtest(k, n).proportion_ci(0.95, method="exact")
    # scipy finds its bounds by brentq on the binomial tails, which stops within its xtol
    # 2e-12 + rtol 4 eps |p| of the root (ours, beta quantiles, are within a few ulp):
    # abs=2e-12 is that stop, not approx's default 1e-12 (3e-13 relative apart at k = 1)
    assert (ci.low, ci.high) == pytest.approx((ref.low, ref.high), rel=1e-14, abs=2e-12)


@pytest.mark.parametrize("k, n", [(0, 5), (1, 10), (3, 50), (50, 1000), (1000, 1000)])
def test_wilson_bounds_are_the_score_roots(k, n):
    """(k/n - p)^2 = z^2 p (1 - p) / n at both bounds; scipy's Wilson interval agrees."""
    ci = wilson(k, n, 0.95)
    z2 = sps.norm.ppf(0.975) ** 2
    for p in (ci.low, ci.high):
        lhs, rhs = (k / n - p) ** 2, z2 * p * (1 - p) / n
        # a quadratic's roots: residual ~ eps times the terms' size (z^2/n scale)
        assert lhs == pytest.approx(rhs, abs=64 * EPS * (1 + z2 / n))
    ref = sps.binomtest(k, n).proportion_ci(0.95, method="wilson")
    # two roundings of the same closed form
    assert (ci.low, ci.high) == pytest.approx((ref.low, ref.high), rel=1e-13, abs=1e-15)
    assert (ci.low == 0.0) == (k == 0) and (ci.high == 1.0) == (k == n)


@pytest.mark.parametrize("interval", [clopper_pearson, wilson])
def test_no_runs_gives_nan_with_a_reason_and_bad_counts_are_refused(interval):
    empty = interval(0, 0, 0.95)
    assert math.isnan(empty.low) and math.isnan(empty.high) and "n = 0" in empty.reason
    for k, n, level in ((3, 2, 0.95), (-1, 5, 0.95), (1.5, 5, 0.95), (1, 5, 1.0)):
        with pytest.raises(ValueError):
            interval(k, n, level)


def exact_coverage(interval, n, p, level):
    """P[p in interval(K, n)] for K ~ Bin(n, p), by summing the binomial pmf."""
    pmf = sps.binom.pmf(np.arange(n + 1), n, p)
    covers = np.array([interval(k, n, level).low <= p <= interval(k, n, level).high
                       for k in range(n + 1)])
    return float(pmf[covers].sum()), covers


@pytest.mark.parametrize("n, p", [(10, 0.5), (50, 0.3), (100, 0.01), (200, 0.05),
                                  (1000, 0.05)])
def test_clopper_pearson_covers_at_least_its_level(n, p):
    """A theorem for the exact interval, for every n and p (the summation of <= 1001 pmf
    terms errs by ~1e-13, far below the margin the test needs)."""
    coverage, _ = exact_coverage(clopper_pearson, n, p, 0.95)
    assert coverage >= 0.95


@pytest.mark.parametrize("interval", [clopper_pearson, wilson])
def test_coverage_over_binomial_draws_is_within_its_binomial_band(interval):
    """4000 draws of K ~ Bin(1000, 0.05): the fraction of intervals covering p is
    Binomial(M, c)/M around the interval's exact coverage c; 4 of its standard deviations
    (sqrt(c (1 - c) / M) ~ 0.0034) miss with probability 6e-5. c itself is within the band
    of the nominal 95 % at this M (Clopper-Pearson at or above it, by the theorem)."""
    n, p, level, draws = 1000, 0.05, 0.95, 4000
    coverage, covers = exact_coverage(interval, n, p, level)
    k = np.random.default_rng(18).binomial(n, p, size=draws)
    seen = covers[k].mean()
    assert abs(seen - coverage) <= 4 * math.sqrt(coverage * (1 - coverage) / draws)
    nominal_band = 4 * math.sqrt(level * (1 - level) / draws)
    assert abs(coverage - level) <= nominal_band
    assert abs(seen - level) <= 2 * nominal_band
    if interval is clopper_pearson:
        assert coverage >= level


def test_replicate_interval_is_a_t_interval_over_the_replicates():
    fractions = np.array([0.04, 0.06, 0.05, 0.03, 0.07, 0.05, 0.06, 0.04, np.nan])
    mean, stderr, ci = replicate_interval(fractions, 0.95)
    used = fractions[:8]
    # a sum of 8 terms and a division: 4 eps; the sample deviation (8 squares, a sum, a root,
    # a division) and mean -+ t s.e.: 16 eps (abs=0: approx's default 1e-12 is 2e-11 of these)
    assert mean == pytest.approx(used.mean(), rel=4 * EPS, abs=0)
    assert stderr == pytest.approx(used.std(ddof=1) / math.sqrt(8), rel=16 * EPS, abs=0)
    half = sps.t.ppf(0.975, 7) * stderr
    assert (ci.low, ci.high) == pytest.approx((mean - half, mean + half), rel=16 * EPS, abs=0)
    # clipped to [0, 1]: a wide spread around a small p
    _, _, wide = replicate_interval([0.0, 0.0, 0.0, 0.2], 0.95)
    assert wide.low == 0.0 and 0 < wide.high < 1
    # no spread: no error estimate, a reason instead
    p, stderr, none = replicate_interval([0.0] * 8, 0.95)
    assert p == 0.0 and stderr == 0.0 and math.isnan(none.low) and "spread is zero" in \
        none.reason
    _, _, one = replicate_interval([0.1, np.nan], 0.95)
    assert math.isnan(one.high) and "one replicate" in one.reason


def test_reliability_index_and_cov():
    # ndtri is accurate to a few ulp; dbeta/dp * p / beta = p / (phi(beta) beta) < 1 here
    # (abs=0: approx's default 1e-12 is 2e-13 of beta)
    assert reliability_index(sps.norm.cdf(-4.75)) == pytest.approx(4.75, rel=1e-13, abs=0)
    assert reliability_index(0.5) == 0.0
    assert reliability_index(0.0) == math.inf and reliability_index(1.0) == -math.inf
    assert math.isnan(reliability_index(math.nan))
    np.testing.assert_array_equal(reliability_index(np.array([0.0, 1.0])), [np.inf, -np.inf])
    # (1 - p) / (n p) in 3 roundings, the root halves them and adds one: 4 eps (abs=0)
    assert binomial_cov(0.05, 1000) == pytest.approx(math.sqrt(0.95 / 50), rel=4 * EPS, abs=0)
    assert binomial_cov(0.0, 1000) == math.inf and binomial_cov(1.0, 10) == 0.0
    assert math.isnan(binomial_cov(0.0, 0))


# ----------------------------------------------------------------------------- monte-carlo

@pytest.mark.parametrize("rule", ["random", "lhs", "sobol", "halton"])
def test_failure_probability_per_rule_covers_the_exact_value(rule):
    """P[y > 2.85] ~ 0.0497 from 2048 realizations: the count, the estimate, its interval
    (Clopper-Pearson for random and LHS, the replicate t interval for RQMC) covering
    Phi(-t / sqrt 3), its c.o.v. and beta."""
    n = 2048
    states = ExceedanceStates({"y_high": ("y", None, THRESHOLD),
                               "x1_low": ("inputs", 0, 1.0)})   # P[x1 > 1] = Phi(-1)
    _, _, runs, stats = run_with_states(LINEAR3, linear_space(), states, seed=5, samples=n,
                                        rule=rule)
    y, x1 = runs["y"].values, runs["inputs"].values[:, 0]
    for name, failing, exact in (("y_high", y > THRESHOLD, EXACT_P),
                                 ("x1_low", x1 > 1.0, float(sps.norm.sf(1.0)))):
        at = stats.sel(limit_state=name)
        k = int(failing.sum())
        assert int(at["failures"]) == k and int(at["failure_probability_runs"]) == n
        assert int(at["failure_probability_left_out"]) == 0
        p = float(at["failure_probability"])
        low, high = at["failure_probability_interval"].values
        assert low <= exact <= high, (rule, name, low, exact, high)
        if rule in ("random", "lhs"):
            assert p == k / n
            ci = clopper_pearson(k, n, 0.95)
            assert (low, high) == (ci.low, ci.high)
            assert float(at["failure_probability_cov"]) == binomial_cov(p, n)
            # i.i.d.: within 4 binomial standard errors (LHS: no larger, Owen 1997)
            assert abs(p - exact) <= 4 * math.sqrt(exact * (1 - exact) / n)
        else:
            fractions = failing.reshape(-1, 8).mean(axis=0)   # realization j*8 + r
            mean, stderr, ci = replicate_interval(fractions, 0.95)
            assert p == mean and (low, high) == (ci.low, ci.high)
            assert float(at["failure_probability_cov"]) == stderr / mean
        assert float(at["reliability_index"]) == -sps.norm.ppf(p)
    expected = "clopper-pearson" if rule in ("random", "lhs") else "replicate-t"
    assert stats.attrs["interval_method"] == expected
    assert ("Owen" in stats.attrs["failure_probability_note"]) == (rule == "lhs")
    # the moments of y are those without limit states, bit for bit
    plain = MonteCarlo(samples=n, rule=rule)
    design = plain.plan(linear_space(), None, np.random.SeedSequence(5))
    without = plain.analyze(design, evaluate_design(AnalyticSolver.from_scene(LINEAR3),
                                                    design))
    assert "limit_state" not in without.dims and "failure_probability" not in without
    xr.testing.assert_identical(without["y"], stats["y"])


def test_realizations_that_did_not_run_ok_are_not_failures():
    """x ~ U(-2, 2), the solver raises above 1.5: those realizations are left out of every
    limit state, even of one whose margin (from the inputs) the stand-in computes for them."""
    n = 1000
    states = ExceedanceStates({"y_high": ("y", None, 1.0), "x_high": ("inputs", 0, 1.0)},
                              honest=False)
    _, _, runs, stats = run_with_states({"model": "faulty", "raise_above": 1.5},
                                        InputSpace([uniform("x", -2.0, 2.0)]), states,
                                        seed=3, samples=n)
    x = runs["inputs"].values[:, 0]
    broken = x > 1.5
    assert np.array_equal(runs["status"].values == "failed", broken) and broken.any()
    for name in ("y_high", "x_high"):
        at = stats.sel(limit_state=name)
        assert int(at["failures"]) == int(((x > 1.0) & ~broken).sum())
        assert int(at["failure_probability_left_out"]) == int(broken.sum())
        assert int(at["failure_probability_runs"]) == n - int(broken.sum())
        p = float(at["failure_probability"])
        # P[x > 1 | x <= 1.5] = 0.5 / 3.5, within 4 binomial standard errors
        assert abs(p - 1 / 7) <= 4 * math.sqrt(1 / 7 * 6 / 7 / (n - broken.sum()))
    note = stats.attrs["failure_probability_note"]
    assert f"{int(broken.sum())} realization(s) did not run ok and are left out" in note
    lines = failure_lines(stats)
    assert any(f"{int(broken.sum())} not run ok and left out" in line for line in lines)


def test_no_failure_seen():
    """k = 0: p = 0, beta = inf, c.o.v. inf; Clopper-Pearson [0, 1 - 0.025^(1/n)]; the
    replicate interval has no spread to go on and says so."""
    _, _, _, stats = run_with_states(LINEAR3, linear_space(), y_exceeds(50.0), samples=64)
    at = stats.sel(limit_state="y_high")
    assert int(at["failures"]) == 0 and float(at["failure_probability"]) == 0.0
    assert float(at["reliability_index"]) == math.inf
    assert float(at["failure_probability_cov"]) == math.inf
    # closed form against beta.ppf(0.975, 1, 64): see the Clopper-Pearson test's bound (abs=0:
    # the lower bound is 0 exactly, and approx's default 1e-12 is 2e-11 of the upper)
    assert at["failure_probability_interval"].values == pytest.approx(
        # bound: ibeta_inv ~1e-15 relative plus expm1/log roundings: 1e-12
        [0.0, -math.expm1(math.log(0.025) / 64)], rel=1e-12, abs=0)
    _, _, _, rqmc = run_with_states(LINEAR3, linear_space(), y_exceeds(50.0), samples=64,
                                    rule="sobol")
    assert np.isnan(rqmc["failure_probability_interval"].values).all()
    assert float(rqmc["failure_probability_cov"].sel(limit_state="y_high")) == math.inf
    assert "limit state 'y_high': no interval of P[failure]" in rqmc.attrs["warnings"]


def run_until_enough(method, design, runs):
    """What the executor does: ask ``enough`` on each stop point's prefix, stop at the
    first yes (the count run)."""
    for count in method.stop_points(design.sizes["realization"]):
        prefix = dict(realization=slice(0, int(count)))
        if method.enough(design.isel(prefix), runs.isel(prefix)):
            return int(count)
    return design.sizes["realization"]


@pytest.mark.parametrize("rule", ["random", "sobol"])
def test_target_cov_stops_at_the_first_stop_point_that_reaches_it(rule):
    """target_cov 0.15 at p ~ 0.05: n ~ (1 - p) / (p 0.15^2) ~ 850 for independent points.
    The stop is the first stop point whose prefix has c.o.v. <= target (computed here by
    hand), the same on a second plan from the same seed, and never before min_samples."""
    target, samples = 0.15, 2048
    method, design, runs, _ = run_with_states(LINEAR3, linear_space(), y_exceeds(), seed=11,
                                              samples=samples, rule=rule, target_cov=target)
    stop = run_until_enough(method, design, runs)
    y = runs["y"].values
    failing = y > THRESHOLD

    def cov(count):
        if rule == "random":
            return binomial_cov(failing[:count].mean(), count)
        mean, stderr, ci = replicate_interval(failing[:count].reshape(-1, 8).mean(axis=0))
        return stderr / mean if mean > 0 and not ci.reason else math.inf

    points = [int(c) for c in method.stop_points(samples)]
    expected = next(c for c in points if cov(c) <= target)
    assert stop == expected < samples
    if rule == "random":
        # stopping at n needs p_hat >= 1 / (1 + n 0.15^2): 0.129 at n = 300, 6 binomial
        # standard errors above p; not stopping by 2048 needs p_hat <= 0.0212, 6 below it
        assert 300 < stop < samples
    else:
        # whole balanced prefixes of the 8 replicates, from min_samples on
        assert stop >= 32 and stop % 8 == 0 and (stop // 8) & (stop // 8 - 1) == 0
    again, design2, runs2, _ = run_with_states(LINEAR3, linear_space(), y_exceeds(),
                                               seed=11, samples=samples, rule=rule,
                                               target_cov=target)
    assert run_until_enough(again, design2, runs2) == stop
    # both targets: the stop waits for the later one
    both = MonteCarlo(samples=samples, rule=rule, target_cov=target, target_rel_stderr=1e-9)
    both.check_limit_states(y_exceeds())
    assert run_until_enough(both, design, runs) == samples


def test_target_cov_needs_limit_states():
    method = MonteCarlo(samples=100, target_cov=0.1)
    with pytest.raises(StudyError) as err:
        method.check_limit_states(None)
    assert err.value.key == "method.target_cov"
    with pytest.raises(StudyError):
        MonteCarlo(samples=100, target_cov=0.1).plan(linear_space(), None,
                                                     np.random.SeedSequence(0))
    MonteCarlo(samples=100).check_limit_states(None)      # no target: fine
    assert MonteCarlo.uses_limit_states


def test_report_lines_give_p_interval_cov_and_beta():
    _, _, _, stats = run_with_states(LINEAR3, linear_space(), y_exceeds(), seed=5,
                                     samples=512)
    at = stats.sel(limit_state="y_high")
    lines = failure_lines(stats)
    low, high = at["failure_probability_interval"].values
    assert lines[0] == (
        f"P[failure of y_high] = {float(at['failure_probability']):.6g} (95 % interval "
        f"{low:.6g} .. {high:.6g}), c.o.v. {float(at['failure_probability_cov']):.6g}, "
        f"beta = {float(at['reliability_index']):.6g}; {int(at['failures'])} failures in 512 "
        f"runs")
    assert "Clopper-Pearson" in lines[-1]
    stats_plain = MonteCarlo(samples=8).analyze(*_plain_design())
    assert failure_lines(stats_plain) == []


def _plain_design():
    method = MonteCarlo(samples=8)
    design = method.plan(linear_space(), None, np.random.SeedSequence(0))
    return design, evaluate_design(AnalyticSolver.from_scene(LINEAR3), design)


# ----------------------------------------------------------------------------- a study file

STUDY = """name = "linear-pf"
solver = "analytic"
scene = {{ model = "linear", coefficients = [1.0, 1.0, 1.0] }}
{inputs}
[method]
kind = "monte-carlo"
samples = 2048
rule = "{rule}"
target_cov = 0.2

[execution]
workers = 0

[output]
path = "out/{rule}.nc"
figures = false

[[limit_states]]
name = "y_high"
output = "y"
exceeds = {threshold}
"""


@pytest.mark.parametrize("rule", ["random", "sobol"])
def test_a_study_with_limit_states_stops_on_target_cov_and_reports_p(rule, tmp_path,
                                                                     monkeypatch, capsys):
    """The real [[limit_states]] of a study file, run twice by the command line: the same
    stop, the statistics of the in-process run at that count, and the report's line."""
    from uqflow import cli
    from uqflow.store import open_result

    inputs = "".join(f'\n[[inputs]]\nname = "x{i}"\ndistribution = "normal"\nmean = 0.0\n'
                     f'std = 1.0\n' for i in (1, 2, 3))
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(inputs=inputs, rule=rule, threshold=THRESHOLD),
                    encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    stats = []
    for again in (False, True):
        assert cli.main(["run", str(path), "--quiet", "--no-figures"]
                        + (["--force"] if again else [])) == 0
        with open_result(tmp_path / "out" / f"{rule}.nc") as tree:
            stats.append(tree["statistics"].to_dataset().load())
    first, second = stats
    for name in ("failures", "failure_probability", "failure_probability_interval",
                 "failure_probability_cov", "y", "exceedance_level", "exceedance_probability",
                 "exceedance_probability_interval", "exceedance_quantity"):
        xr.testing.assert_identical(first[name].variable, second[name].variable)
    # the stored curve, read back from the file, passes through P[failure] at the threshold
    at = first.sel(limit_state="y_high")
    j = int(np.flatnonzero(at["exceedance_level"].values == THRESHOLD)[0])
    assert float(at["exceedance_probability"][j]) == float(at["failure_probability"])
    assert str(at["exceedance_comparison"].values) == ">="
    count = first.attrs["solver_runs"]
    assert count < 2048 and float(first["failure_probability_cov"].item()) <= 0.2
    # the stop of the in-process executor stand-in, on the design of the same seed
    from uqflow.study import load_study
    study = load_study(path)
    design = study.method.plan(study.space, None,
                               np.random.SeedSequence(study.spec.execution.seed))
    runs = evaluate_design(AnalyticSolver.from_scene(LINEAR3), design)
    assert run_until_enough(study.method, design, runs) == count
    capsys.readouterr()
    assert cli.main(["report", str(tmp_path / "out" / f"{rule}.nc"), "--no-figures"]) == 0
    text = capsys.readouterr().out
    assert f"P[failure of y_high] = {float(first['failure_probability'].item()):.6g}" in text


@pytest.mark.parametrize("rule", ["random", "halton"])
def test_every_realization_failing_gives_nan_with_the_reason(rule):
    states = ExceedanceStates({"y_high": ("y", None, 0.0)})
    _, _, _, stats = run_with_states({"model": "faulty", "raise_above": -10.0},
                                     InputSpace([uniform("x", -2.0, 2.0)]), states,
                                     samples=16, rule=rule)
    at = stats.sel(limit_state="y_high")
    assert int(at["failures"]) == 0 and int(at["failure_probability_runs"]) == 0
    assert int(at["failure_probability_left_out"]) == 16
    for name in ("failure_probability", "failure_probability_cov", "reliability_index"):
        assert math.isnan(float(at[name])), name
    assert np.isnan(at["failure_probability_interval"].values).all()
    assert "limit state 'y_high': no interval of P[failure]: no realization ran" in \
        stats.attrs["warnings"]


def test_kl_weibull_reports_the_failure_lines_it_inherits():
    """kl-weibull's statistics are Monte Carlo's, P[failure] included: its report hook
    prints the same lines."""
    from types import SimpleNamespace

    from uqflow.methods.kl_weibull import KLWeibull

    _, _, _, stats = run_with_states(LINEAR3, linear_space(), y_exceeds(), seed=5,
                                     samples=256)
    hook = KLWeibull.report(SimpleNamespace(stats=stats))
    assert [n for n in hook.notes if "failure" in n] == failure_lines(stats)
    assert KLWeibull.uses_limit_states
    # and the exceedance curve of each limit state, stored by Monte Carlo's analyze
    assert "failure_exceedance_y_high" in [f.kind for f in hook.figures]


def test_a_control_variates_control_runs_are_not_draws():
    """control = "taylor-local" opens the design with a run at the means: it is no draw from
    the inputs, so it is neither a failure nor counted; with a threshold every draw
    exceeds, P[failure] = 1 exactly over the samples alone."""
    _, design, runs, stats = run_with_states(LINEAR3, linear_space(), y_exceeds(-100.0),
                                             samples=64, control="taylor-local")
    assert runs.sizes["realization"] == 65
    at = stats.sel(limit_state="y_high")
    assert int(at["failures"]) == 64 and int(at["failure_probability_runs"]) == 64
    assert int(at["failure_probability_left_out"]) == 0
    assert float(at["failure_probability"]) == 1.0 and float(at["failure_probability_cov"]) == 0
    assert float(at["reliability_index"]) == -math.inf
    # Clopper-Pearson at k = n: [(alpha/2)^(1/n), 1]; see the closed-form test's bound
    assert at["failure_probability_interval"].values == pytest.approx(
        [0.025 ** (1 / 64), 1.0], rel=1e-12)
    # the exceedance curve is over the 64 draws too: their values and the threshold are its
    # levels, not the control run's y = 0 at the means
    levels = at["exceedance_level"].values
    samples = runs["y"].values[1:]
    np.testing.assert_array_equal(levels[np.isfinite(levels)],
                                  np.unique(np.append(samples, -100.0)))


# ----------------------------------------------------------------------------- exceedance figure

def test_exceedance_log_figure_draws_the_curve_band_threshold_and_p_on_a_log_axis():
    from uqflow.report.framework_figures import exceedance_log_figure

    fig = exceedance_log_figure([1e-3, 2e-3, 3e-3], [0.5, 0.1, 0.0], [0.3, 0.05, 0.0],
                                [0.7, 0.2, 0.01], threshold=2e-3, failure_probability=0.1,
                                failure_interval=(0.05, 0.2), units="m", name="tip",
                                curve_label="fraction of runs", band_label="95 % band")
    ax = fig.axes[0]
    assert ax.get_yscale() == "log" and ax.get_ylabel() == "P[Y > y]"
    assert ax.get_xlabel() == "y: tip [mm]"
    # the floor is a tenth of the smallest positive number drawn (the band's 0.01): one
    # division, and matplotlib's log-axis round trip of a few ulp (abs=0: not the default 1e-12)
    assert ax.get_ylim()[0] == pytest.approx(1e-3, rel=1e-12, abs=0)
    threshold = [line for line in ax.lines if line.get_label().startswith("threshold")]
    assert len(threshold) == 1 and np.allclose(threshold[0].get_xdata(), 2.0)
    marker = [c for c in ax.containers if c.get_label().startswith("p_f = 0.1 (0.05 .. 0.2)")]
    assert len(marker) == 1
    np.testing.assert_allclose(marker[0].lines[0].get_xydata(), [[2.0, 0.1]])
    # the curve leaves out P = 0 (no place on a log axis), the band keeps it at the floor
    curve = next(line for line in ax.lines if line.get_label() == "fraction of runs")
    assert np.isnan(curve.get_ydata()[2]) and curve.get_ydata()[1] == 0.1
    assert exceedance_log_figure([1.0], [0.0], [0.0], [0.0], threshold=1.0,
                                 failure_probability=0.0) is None
    # no failure seen: the upper bound of p_f is marked at the threshold
    fig = exceedance_log_figure([1.0, 2.0], [0.5, 0.0], [0.3, 0.0], [0.7, 0.02],
                                threshold=3.0, failure_probability=0.0,
                                failure_interval=(0.0, 0.02))
    bound = next(line for line in fig.axes[0].lines if line.get_label().startswith(
        "p_f = 0, no failure seen (upper bound 0.02)"))
    np.testing.assert_allclose(bound.get_xydata(), [[3.0, 0.02]])


# ----------------------------------------------------------------------------- exceedance curve

def tied_samples(y, status=None):
    """Samples of a scalar output y with ties (status "ok" unless given), as the runs."""
    n = len(y)
    return xr.Dataset({"y": ("realization", np.asarray(y, dtype=float)),
                       "status": ("realization", np.array(status or ["ok"] * n, dtype=object))},
                      coords={"realization": np.arange(n)})


TIED = [0.0, 1.0, 1.0, 2.0, 3.0, 1.0, 5.0, -1.0, 2.0, 4.0]


@pytest.mark.parametrize("interval", ["clopper-pearson", "wilson"])
def test_exceedance_curve_counts_the_failure_event_at_every_level(interval):
    """At each stored level y the curve is the fraction of runs that fail a limit state with
    threshold y (y >= level for exceeds, <= for below: ties at the level count, as at the
    threshold), and its band that fraction's binomial interval; at the threshold both are
    P[failure] and its interval. A failed run is in no count; a system's curve is over its
    margin."""
    from uqflow.methods.monte_carlo import exceedance_variables, failure_estimates
    from uqflow.probability import binomial_interval

    samples = tied_samples(TIED + [9.0], ["ok"] * len(TIED) + ["failed"])
    states = LimitStates.from_tables(
        [{"name": "high", "output": "y", "exceeds": 1.0},
         {"name": "low", "output": "y", "below": 1.0},
         {"name": "either", "series": ["high", "low"]}], samples, "test")
    curves = exceedance_variables(states, samples, None, 0.9, interval)
    estimates = failure_estimates(states, samples, None, 0.9, interval)
    y = np.array(TIED)
    names = ["high", "low", "either"]
    for j, (name, estimate) in enumerate(zip(names, estimates)):
        levels = curves["exceedance_level"][1][j]
        levels = levels[np.isfinite(levels)]
        p = curves["exceedance_probability"][1][j][:levels.size]
        band = curves["exceedance_probability_interval"][1][j][:levels.size]
        if name == "either":
            quantity = np.minimum(1.0 - y, y - 1.0)   # the series system's margin
            counts = [(quantity <= m).sum() for m in levels]
            threshold, comparison = 0.0, "<="
        else:
            quantity = y
            counts = [(y >= m).sum() if name == "high" else (y <= m).sum() for m in levels]
            threshold, comparison = 1.0, (">=" if name == "high" else "<=")
        np.testing.assert_array_equal(levels, np.unique(np.append(quantity, threshold)))
        np.testing.assert_array_equal(p * len(TIED), counts)
        for k, (low, high) in zip(counts, band):
            bounds = binomial_interval(int(k), len(TIED), interval, 0.9)
            assert (low, high) == (bounds.low, bounds.high)
        at = int(np.flatnonzero(levels == threshold)[0])
        assert p[at] == estimate.probability
        assert tuple(band[at]) == (estimate.interval.low, estimate.interval.high)
        assert curves["exceedance_comparison"][1][j] == comparison
        assert curves["exceedance_threshold"][1][j] == threshold
    # y = 1 three times: "exceeds 1" fails at y >= 1, 8 of the 10 runs that ran ok
    assert estimates[0].failures == 8 and estimates[0].runs == 10


def test_exceedance_curve_of_randomized_qmc_is_the_replicate_mean_at_every_level():
    """Sobol' replicates: at each level the mean of the replicates' fractions and the t
    interval over them, as P[failure] at the threshold."""
    _, _, runs, stats = run_with_states(LINEAR3, linear_space(), y_exceeds(), seed=2,
                                        samples=256, rule="sobol")
    at = stats.sel(limit_state="y_high")
    levels = at["exceedance_level"].values
    keep = np.isfinite(levels)
    y = runs["y"].values
    for level, p, (low, high) in zip(levels[keep], at["exceedance_probability"].values[keep],
                                     at["exceedance_probability_interval"].values[keep]):
        fractions = (y >= level).reshape(-1, 8).mean(axis=0)   # realization j*8 + r
        mean, _, ci = replicate_interval(fractions, 0.95)
        assert p == mean
        np.testing.assert_array_equal([low, high], [ci.low, ci.high])
    assert "replicates" in stats.attrs["exceedance_note"]


def test_exceedance_curve_follows_the_exact_distribution():
    """y = x1 + x2 + x3 ~ N(0, 3): over the stored levels, sup |curve - Phi(-y / sqrt 3)| is
    within the DKW bound sqrt(ln(2 / 1e-6) / (2 n)) (exceeded with probability <= 1e-6)."""
    n = 2048
    _, _, _, stats = run_with_states(LINEAR3, linear_space(), y_exceeds(), seed=9,
                                     samples=n)
    at = stats.sel(limit_state="y_high")
    levels = at["exceedance_level"].values
    keep = np.isfinite(levels)
    exact = sps.norm.sf(levels[keep] / math.sqrt(3))
    dkw = math.sqrt(math.log(2 / 1e-6) / (2 * n))
    assert np.max(np.abs(at["exceedance_probability"].values[keep] - exact)) <= dkw


def test_exceedance_levels_are_thinned_keeping_the_tail_and_the_threshold():
    from uqflow.probability import curve_levels

    values = np.arange(10_000, dtype=float)
    levels = curve_levels(values, 1234.5, ">=")
    # at most 200 values by default (docs/reliability.md), and the threshold
    assert levels.size == 201 and 1234.5 in levels
    assert np.all(np.diff(levels) > 0)
    # the 20 largest values (the tail of P[Y >= y]) are all kept, and the smallest value
    assert set(values[-20:]) <= set(levels) and 0.0 in levels
    below = curve_levels(values, 1234.5, "<=", max_levels=200)
    assert set(values[:20]) <= set(below) and 9999.0 in below


def test_interval_option_wilson_and_its_refusals():
    from uqflow.probability import WILSON

    _, _, _, stats = run_with_states(LINEAR3, linear_space(), y_exceeds(), seed=5,
                                     samples=512, interval="wilson")
    at = stats.sel(limit_state="y_high")
    ci = wilson(int(at["failures"]), 512, 0.95)
    assert tuple(at["failure_probability_interval"].values) == (ci.low, ci.high)
    assert stats.attrs["interval_method"] == WILSON
    assert "Wilson score" in stats.attrs["failure_probability_note"]
    assert "Wilson interval at each level" in stats.attrs["exceedance_note"]
    from uqflow.methods.monte_carlo import exceedance_figure_of
    legend = exceedance_figure_of(stats, "y_high").axes[0].get_legend_handles_labels()[1]
    assert "95 % pointwise band (Wilson)" in legend
    with pytest.raises(ValueError, match=r"'interval' applies to independent points \(rule "
                                         r"random or lhs\); rule 'sobol' is randomized QMC"):
        MonteCarlo(samples=64, rule="sobol", interval="wilson")
    method = MonteCarlo(samples=64, interval="clopper-pearson")
    with pytest.raises(StudyError, match="no \\[\\[limit_states\\]\\]") as info:
        method.check_limit_states(None)
    assert info.value.key == "method.interval"


def test_report_draws_each_limit_states_exceedance_curve():
    from uqflow.report import ResultView

    method, design, runs, stats = run_with_states(
        LINEAR3, linear_space(), LimitStates.from_tables(
            [{"name": "y_high", "output": "y", "exceeds": THRESHOLD},
             {"name": "y_low", "output": "y", "below": -THRESHOLD}],
            AnalyticSolver.from_scene(LINEAR3).outputs(), "test"), seed=1, samples=256)
    tree = xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "pf"}),
                                  "design": design, "runs": runs, "statistics": stats})
    specs = {f.kind: f for f in MonteCarlo.report(ResultView(tree)).figures}
    assert {"failure_exceedance_y_high", "failure_exceedance_y_low"} <= set(specs)
    assert not specs["failure_exceedance_y_low"].per_output   # one figure per limit state
    ax = specs["failure_exceedance_y_low"].draw(ResultView(tree), None).axes[0]
    assert ax.get_yscale() == "log" and ax.get_ylabel() == "P[Y ≤ y]"
    assert any(c.get_label().startswith(
        f"p_f = {float(stats['failure_probability'].sel(limit_state='y_low')):.3g}")
        for c in ax.containers)
