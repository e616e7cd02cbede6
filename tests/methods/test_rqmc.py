"""Randomized quasi-Monte Carlo: R independent scramblings of Sobol' / Halton, the standard
error from the spread of their means, t intervals with R - 1 degrees of freedom, stopping only
at whole balanced replicate prefixes, and the quickstart's reported error (issue 8, point 3).

A fallback to independent points must fail these checks: the conformance test asks for an
RQMC standard error far below the i.i.d. one, and ``test_a_random_fallback_fails_...`` runs
the same check on a design whose sampler was swapped for plain random points.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from scipy import stats as sps

import uqflow.methods.monte_carlo as monte_carlo
from uqflow import report
from uqflow.methods.monte_carlo import convergence_figure
from uqflow.errors import StudyError
from uqflow.execute import run_study
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods.monte_carlo import MonteCarlo
from uqflow.sampling import unit_hypercube
from uqflow.study import load_study

from mc_cases import ishigami_space, run_mc

ROOT = Path(__file__).resolve().parents[2]
ISHIGAMI = {"model": "ishigami", "a": 7.0, "b": 0.1}
EXACT_MEAN = 3.5        # a / 2 (tests/data/uq_test_values.toml)


def stat(stats, name, out="y"):
    return float(stats[out].sel(statistic=name))


def check_rqmc_conformance(stats, factor):
    """The mean within 4 RQMC standard errors of 3.5, and that error at least ``factor``
    times below the i.i.d. formula's s / sqrt(n) on the same points."""
    se = stat(stats, "stderr")
    iid = stat(stats, "std") / math.sqrt(stats.attrs["samples_ok"])
    assert abs(stat(stats, "mean") - EXACT_MEAN) < 4 * se
    assert factor * se <= iid, f"RQMC stderr {se:.3g} is not {factor}x below i.i.d. {iid:.3g}"


# Factors: with independent points the ratio i.i.d./replicate-spread error is
# sqrt(7 / chi2_7) (R = 8): >= 4 has probability 3e-4, >= 10 under 1e-6. Scrambled Sobol' on
# Ishigami gives a median 48 over seeds (1st percentile 19), Halton 10 (1st percentile 6.3).
FACTORS = {"sobol": 10, "halton": 4}


@pytest.mark.parametrize("rule", ["sobol", "halton"])
def test_ishigami_rqmc_conformance(rule):
    _, design, runs, stats = run_mc(ISHIGAMI, ishigami_space(), seed=2024, samples=4096,
                                    rule=rule)
    check_rqmc_conformance(stats, FACTORS[rule])
    r = 8
    assert stats.attrs["stderr_kind"] == "rqmc" and stats.attrs["replicates"] == r
    assert stats.attrs["degrees_of_freedom"] == r - 1
    assert f"{r} independently scrambled {rule} replicates" in stats.attrs["stderr_note"]
    # The statistics carry what a reader needs to recompute the error.
    y = runs["y"].values
    by_replicate = y.reshape(-1, r)                  # row j*R + r is point j of replicate r
    np.testing.assert_array_equal(stats["y_replicate_means"].values,
                                  [np.mean(by_replicate[:, k]) for k in range(r)])
    means = stats["y_replicate_means"].values
    assert stat(stats, "mean") == np.mean(means)
    # sqrt(var / R) against std / sqrt(R): three correctly rounded operations, <= 2 eps apart
    assert stat(stats, "stderr") == pytest.approx(np.std(means, ddof=1) / math.sqrt(r),
                                                  rel=4 * np.finfo(float).eps)
    t = sps.t.ppf(0.975, r - 1)
    assert stat(stats, "ci_low") == stat(stats, "mean") - t * stat(stats, "stderr")
    assert stat(stats, "ci_high") == stat(stats, "mean") + t * stat(stats, "stderr")
    # Variance and std stay the pooled sample estimates of the output's spread.
    assert stat(stats, "variance") == np.var(y, ddof=1)


def test_a_random_fallback_fails_the_conformance_check(monkeypatch):
    """The same check on a design whose quasi-random sampler silently returns random points."""
    def random_points(rule, replicates, per_replicate, dimension, seed):
        return unit_hypercube("random", replicates * per_replicate, dimension, seed)

    monkeypatch.setattr(monte_carlo, "replicated_unit_hypercube", random_points)
    _, _, _, stats = run_mc(ISHIGAMI, ishigami_space(), seed=2024, samples=4096, rule="sobol")
    with pytest.raises(AssertionError, match="is not 10x below"):
        check_rqmc_conformance(stats, FACTORS["sobol"])


def ishigami_runs(design):
    """The runs dataset of ``design`` with Ishigami evaluated in one vectorized step (the
    analytic solver's realization-by-realization loop would dominate 200 repetitions)."""
    x1, x2, x3 = design["inputs"].values.T
    y = np.sin(x1) + 7.0 * np.sin(x2) ** 2 + 0.1 * x3**4 * np.sin(x1)
    n = y.size
    return design.assign(y=("realization", y), status=("realization", np.full(n, "ok", object)),
                         message=("realization", np.full(n, "", object)),
                         wall_time=("realization", np.zeros(n)))


@pytest.mark.slow
@pytest.mark.parametrize("rule", ["sobol", "halton"])
def test_t_interval_covers_the_exact_mean(rule):
    """200 independent Ishigami studies of 8 replicates x 16 points: the 95 % interval holds
    3.5 in a fraction whose binomial 4-sigma band, 0.95 +- 4 sqrt(0.95 0.05 / 200) =
    0.95 +- 0.062, it must fall in; and the RQMC error is an honest spread of the means."""
    repetitions, level = 200, 0.95
    space, method = ishigami_space(), MonteCarlo(samples=128, rule=rule)
    covered, means, errors = 0, [], []
    for seed in range(repetitions):
        design = method.plan(space, None, np.random.SeedSequence([77, seed]))
        stats = method.analyze(design, ishigami_runs(design))
        covered += stat(stats, "ci_low") <= EXACT_MEAN <= stat(stats, "ci_high")
        means.append(stat(stats, "mean"))
        errors.append(stat(stats, "stderr"))
    band = 4 * math.sqrt(level * (1 - level) / repetitions)
    assert abs(covered / repetitions - level) <= band, covered
    # The mean of the squared standard errors estimates the estimator's variance (unbiased);
    # their ratio to the observed spread of the means has relative sampling error about
    # sqrt(2 / 199) (spread) and sqrt(2 / (7 * 200)) (errors): 4 of those is 0.45.
    ratio = np.mean(np.square(errors)) / np.var(means, ddof=1)
    assert abs(ratio - 1) < 0.45, ratio


# --------------------------------------------------------------------------------------------
# Stopping only at whole replicate prefixes, and in agreement with analyze
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("rule", ["sobol", "halton"])
def test_stop_points_are_whole_balanced_replicate_prefixes(rule):
    method = MonteCarlo(samples=4096, rule=rule, target_rel_stderr=1e-3, min_samples=40)
    np.testing.assert_array_equal(method.stop_points(4096),
                                  [64, 128, 256, 512, 1024, 2048, 4096])
    method = MonteCarlo(samples=8 * 500, rule="halton", target_rel_stderr=1e-3)
    assert list(method.stop_points(4000)) == [32, 64, 128, 256, 512, 1024, 2048]
    assert len(MonteCarlo(samples=64, rule=rule).stop_points(64)) == 0   # no target


def test_enough_agrees_with_the_standard_error_analyze_reports():
    target = 2e-3
    method, design, runs, _ = run_mc(ISHIGAMI, ishigami_space(), seed=8, samples=4096,
                                     rule="sobol", target_rel_stderr=target)
    answers = []
    for n in method.stop_points(4096):
        prefix = dict(realization=slice(0, int(n)))
        stats = method.analyze(design.isel(prefix), runs.isel(prefix))
        rel = stat(stats, "stderr") / abs(stat(stats, "mean"))
        assert stats.attrs["replicates"] == 8
        answers.append(method.enough(design.isel(prefix), runs.isel(prefix)))
        assert answers[-1] == (rel <= target), n
    # Small prefixes are far from 0.2 %, the full design (~0.03 %) is well below it.
    assert not answers[0] and answers[-1]


def test_enough_judges_only_whole_replicate_prefixes_before_anything_pending():
    method, design, runs, _ = run_mc(ISHIGAMI, ishigami_space(), seed=8, samples=1024,
                                     rule="sobol", target_rel_stderr=2e-2, min_samples=16)
    whole = dict(realization=slice(0, 256))
    expected = method.enough(design.isel(whole), runs.isel(whole))
    partial = runs.copy(deep=True)
    partial["status"].values[261:] = "pending"   # 5 points of a 33rd row: not whole
    partial["y"].values[261:] = np.nan
    partial["status"].values[300] = "ok"         # finished out of order, after a hole
    assert method.enough(design, partial) == expected
    # 256 whole realizations reach 2 % here (1.6 %) while 16 do not (29 %): it matters.
    first = dict(realization=slice(0, 16))
    assert expected and not method.enough(design.isel(first), runs.isel(first))


def test_trace_carries_the_rqmc_band_at_whole_replicate_prefixes():
    _, _, runs, stats = run_mc(ISHIGAMI, ishigami_space(), seed=3, samples=2048, rule="sobol")
    counts = stats["trace_samples"].values
    np.testing.assert_array_equal(counts, 8 * 2 ** np.arange(9))
    y = runs["y"].values
    trace = stats["y_trace"]
    eps = np.finfo(float).eps
    for k, c in enumerate(counts):
        means = y[:c].reshape(-1, 8).mean(axis=0)
        # Each replicate mean is a sum of c/8 terms, here and in the method possibly in
        # another order: within (c/8) eps mean|y| each (Higham's bound for any order).
        e = c / 8 * eps * np.mean(np.abs(y[:c]))
        assert trace.sel(trace_statistic="mean")[k] == pytest.approx(
            means.mean(), rel=8 * eps, abs=2 * e)
        # perturbing 8 values by <= 2e moves their std by <= 2e sqrt(8/7), the error by
        # 2e / sqrt(7); then a few roundings
        assert trace.sel(trace_statistic="stderr")[k] == pytest.approx(
            means.std(ddof=1) / math.sqrt(8), rel=8 * eps, abs=2 * e / math.sqrt(7))
        # the pooled std: numpy's own reduction of the same values
        assert trace.sel(trace_statistic="std")[k] == y[:c].std(ddof=1)
    last = trace.isel(trace_samples=-1)
    assert float(last.sel(trace_statistic="stderr")) == stat(stats, "stderr")
    # The band narrows faster than 1/sqrt(n). Independent points give slope -1/2; each point
    # is a 7-dof estimate (relative spread 27 %), so the fitted slope over 7 counts a factor 2
    # apart has std 0.27 / sqrt(sum (ln c - mean)^2) = 0.27 / 3.67 = 0.074: -0.8 is 4 of them.
    se = trace.sel(trace_statistic="stderr").values
    slope = np.polyfit(np.log(counts[2:]), np.log(se[2:]), 1)[0]
    assert slope < -0.8, slope


def test_a_failed_realization_leaves_its_replicate_with_fewer_points():
    space = InputSpace([RandomInput.from_spec({"name": "x", "distribution": "uniform",
                                               "lower": -2.0, "upper": 2.0})])
    _, _, runs, stats = run_mc({"model": "faulty", "raise_above": 1.9}, space, seed=1,
                               samples=256, rule="sobol")
    ok = runs["status"].values == "ok"
    assert 0 < (~ok).sum() < 20
    y, which = runs["y"].values, np.arange(256) % 8
    expected = [y[ok & (which == r)].mean() for r in range(8)]
    # the same elements in the same order through numpy's mean: exactly equal
    np.testing.assert_array_equal(stats["y_replicate_means"].values, expected)
    assert stats.attrs["degrees_of_freedom"] == 7


# --------------------------------------------------------------------------------------------
# Options: replicates, and sample counts that split into balanced replicates
# --------------------------------------------------------------------------------------------

def write_study(tmp_path, method_lines):
    text = (ROOT / "studies" / "ishigami_mc.toml").read_text()
    head, _ = text.split("[method]")
    path = tmp_path / "study.toml"
    path.write_text(head + "[method]\nkind = \"monte-carlo\"\n" + method_lines
                    + "\n[output]\npath = \"out.nc\"\n")
    return path


@pytest.mark.parametrize("lines, message", [
    ('samples = 1000\nrule = "sobol"', "method.samples: 1000 is not replicates (8) times a "
                                       "power of two, which rule 'sobol' needs for balanced "
                                       "replicates; nearest: 512 or 1024"),
    ('samples = 4\nrule = "sobol"', "nearest: 8 or 16"),
    ('samples = 1001\nrule = "halton"', "method.samples: 1001 is not a multiple of "
                                        "replicates (8), which rule 'halton' needs; "
                                        "nearest: 1000 or 1008"),
    ('samples = 90\nrule = "sobol"\nreplicates = 3', "method.samples: 90 is not replicates "
                                                      "(3) times a power of two"),
    ('samples = 64\nreplicates = 4', "method: 'replicates' applies to rule sobol or halton "
                                     "only"),
    ('samples = 64\nrule = "sobol"\nreplicates = 1', "method.replicates"),
])
def test_bad_replicate_options_are_one_line_errors(tmp_path, lines, message):
    path = write_study(tmp_path, lines)
    with pytest.raises(StudyError) as info:
        load_study(path)
    text = str(info.value)
    assert text.startswith(f"{path}: ") and message in text and "\n" not in text


def test_good_replicate_options():
    assert MonteCarlo(samples=96, rule="sobol", replicates=3).options.replicates == 3
    assert MonteCarlo(samples=24, rule="halton", replicates=3).options.samples == 24
    assert MonteCarlo(samples=1000).options.replicates == 8   # unused default: no error


# --------------------------------------------------------------------------------------------
# The quickstart as a user runs it, and what the report says about it
# --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def quickstart(tmp_path_factory):
    study = load_study(ROOT / "studies" / "ishigami_mc.toml")
    out = tmp_path_factory.mktemp("quickstart") / "quickstart.nc"
    outcome = run_study(dataclasses.replace(study, output_path=out), workers=0,
                        show_progress=False)
    return study, report.open_result(out)


def test_quickstart_reports_an_rqmc_error_below_a_fifth_of_the_iid_one(quickstart):
    """Issue 8: 4,096 scrambled Sobol' points on Ishigami; the reported standard error below
    0.0116 (the i.i.d. one is sqrt(13.84 / 4096) = 0.058) and the mean within 4 of them."""
    study, tree = quickstart
    assert study.spec.method.kind == "monte-carlo"
    assert (study.method.options.samples, study.method.options.rule) == (4096, "sobol")
    stats = tree["statistics"].to_dataset()
    se = stat(stats, "stderr")
    assert se < 0.0116
    assert abs(stat(stats, "mean") - EXACT_MEAN) < 4 * se
    assert stats.attrs["stderr_kind"] == "rqmc"


def test_report_states_the_error_estimate(quickstart):
    _, tree = quickstart
    table = report.summary_table(tree)
    assert ("standard error and interval of the mean: randomized QMC: spread of the means of 8 "
            "independently scrambled sobol replicates, Student t with 7 degrees of freedom"
            ) in table
    for rule, words in [("random", "i.i.d. formula s/sqrt(n), Student t with 63 degrees"),
                        ("lhs", "i.i.d. formula, conservative for Latin hypercube (its variance is at most "
                                "N/(N-1) times the i.i.d. one, Owen 1997)")]:
        _, _, runs, stats = run_mc(ISHIGAMI, ishigami_space(), samples=64, rule=rule)
        text = report.summary_table(xr.DataTree.from_dict({"runs": runs,
                                                           "statistics": stats}))
        assert f"standard error and interval of the mean: {words}" in text, rule


def test_convergence_figure_draws_the_rqmc_band(quickstart):
    _, tree = quickstart
    stats = tree["statistics"].to_dataset()
    fig = convergence_figure(report.ResultView(tree), "y")
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "95 % interval, randomized QMC (8 replicates, t with 7 dof)" in labels
    band = ax.collections[0].get_paths()[0].vertices
    t = sps.t.ppf(0.975, 7)
    trace = stats["y_trace"]
    mean = trace.sel(trace_statistic="mean").values
    half = t * trace.sel(trace_statistic="stderr").values
    # the band's edges are mean -+ t stderr at every trace count (the same float ops)
    for c, lo, hi in zip(stats["trace_samples"].values, mean - half, mean + half):
        edge = band[band[:, 0] == c, 1]
        assert lo in edge and hi in edge, c


def test_error_of_the_mean_table_in_the_docs():
    """docs/inputs.md's table for choosing R: t quantile and t c4(R) R^(alpha - 1/2), to the
    digits shown (3 significant: half a unit of the last digit), and the quoted spreads."""
    from scipy.special import gammaln

    text = (ROOT / "docs" / "inputs.md").read_text()
    rows = [line.split("|")[1:-1] for line in text.splitlines()
            if line.startswith("| ") and line.split("|")[1].strip().isdigit()]
    assert [int(r[0]) for r in rows] == [4, 8, 16, 32]
    for cells in rows:
        r = int(cells[0])
        t = sps.t.ppf(0.975, r - 1)
        c4 = math.sqrt(2 / (r - 1)) * math.exp(gammaln(r / 2) - gammaln((r - 1) / 2))
        expected = [t] + [t * c4 * r ** (alpha - 0.5) for alpha in (0.5, 1.0, 1.5)]
        for shown, value in zip(cells[1:], expected):
            digits = shown.strip()
            unit = 10.0 ** (math.floor(math.log10(abs(value))) - 2)   # 3 significant digits
            assert abs(float(digits) - value) <= 0.5 * unit, (r, digits, value)
    assert "41 % at R = 4, 27 % at R = 8" in text
    assert round(100 / math.sqrt(2 * 3)) == 41 and round(100 / math.sqrt(2 * 7)) == 27
    assert "within 16 % of the best possible" in text and round(100 * (2.28 / 1.96 - 1)) == 16
    assert "1.6× the R = 4 width" in text and round(18.3 / 11.7, 1) == 1.6


def test_kl_weibull_stays_independent_draws():
    """kl-weibull samples its scalars and germs at random: i.i.d. errors, 9 % stop ladder."""
    from uqflow.methods.kl_weibull import KLWeibull

    method = KLWeibull(realizations=100, target_rel_stderr=0.1, min_samples=10)
    assert method.options.rule == "random" and not hasattr(method.options, "replicates")
    points = method.stop_points(100)
    assert points[0] == 10 and points[-1] == 100
    # ceil(10 2^(k/8)): each within 2^(1/8) = 1.09 of the last, plus the ceiling's 1
    assert np.all(points[1:] <= points[:-1] * 2 ** (1 / 8) + 1)
