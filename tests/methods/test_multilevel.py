"""Multilevel and multifidelity Monte Carlo: the formulas on their own, then conformance on a
model with an exact answer and a known level structure (explicit Euler for y' = -k y, whose
level means, variances and costs are integrals we evaluate by quadrature), over 20 seeds."""

import math

import numpy as np
import pytest
import xarray as xr
from scipy import integrate

from solvers.analytic import AnalyticSolver
from uqflow.inputs import InputSpace, RandomInput
from uqflow.levels import LevelsSpec, resolve_levels
from uqflow.methods.multifidelity import Multifidelity
from uqflow.methods.multilevel import Multilevel
from uqflow.methods.multilevel_estimators import (giles_counts, level_rate, mfmc_best,
                                                  mfmc_estimate, mfmc_ratios,
                                                  mlmc_level_terms, optimal_mlmc_cost)
from uqflow.realization import STATUS_OK, empty_runs

LOW, HIGH = 0.5, 1.5          # k ~ U(LOW, HIGH), T = 1
SEEDS = range(20)


# --- the model, exactly --------------------------------------------------------------------

def euler(k, steps):
    return (1.0 - k / steps) ** steps


def expect(g):
    """E[g(k)] for k ~ U(LOW, HIGH), by adaptive quadrature (error ~1e-14 for these smooth g)."""
    # quad's own targets: a polynomial-like integrand on [0.5, 1.5] of size <= 1 meets them in
    # a few Gauss-Kronrod panels; the tests compare against these values at 1e-3 or looser
    return integrate.quad(g, LOW, HIGH, epsabs=1e-15, epsrel=1e-13)[0] / (HIGH - LOW)


def exact_mean(steps=None):
    if steps is None:
        return (math.exp(-LOW) - math.exp(-HIGH)) / (HIGH - LOW)
    return expect(lambda k: euler(k, steps))


def correction_variances(steps):
    V = [expect(lambda k: euler(k, steps[0]) ** 2) - exact_mean(steps[0]) ** 2]
    for fine, coarse in zip(steps[1:], steps[:-1]):
        d = (lambda k, f=fine, c=coarse: euler(k, f) - euler(k, c))
        V.append(expect(lambda k: d(k) ** 2) - expect(d) ** 2)
    return np.array(V)


# --- driving a method the way the executor does, with the model vectorised ----------------

def space():
    return InputSpace([RandomInput.from_spec({"name": "k", "distribution": "uniform",
                                              "lower": LOW, "upper": HIGH})])


def with_levels(method, steps):
    levels = resolve_levels(LevelsSpec(key="steps", values=list(steps)),
                            {"model": "euler_decay"}, AnalyticSolver, ["y"], "scene")
    method.check_levels(levels)
    return method


def evaluate(design, steps):
    template = xr.Dataset({"y": ((), np.nan)})
    runs = empty_runs(design, template)
    k = design["inputs"].values[:, 0]
    n = np.asarray(steps)[design["level"].values]
    runs["y"].values[:] = euler(k, n)
    runs["status"].values[:] = STATUS_OK
    runs["wall_time"].values[:] = 0.0
    if "sensitivity_realization" in runs.coords:     # the surrogate's run: the model's own
        for j, row in enumerate(runs["sensitivity_realization"].values):
            solver = AnalyticSolver.from_scene({"model": "euler_decay", "steps": int(n[row])})
            got = solver.run_with_sensitivities({"k": float(k[row])}, ["k"], ["y"])
            runs["y__gradient"].values[j] = got["y__gradient"].values
            runs["y__hessian"].values[j] = got["y__hessian"].values
    return runs


def drive(method, steps, seed):
    design = method.plan(space(), None, np.random.SeedSequence(seed))
    runs = evaluate(design, steps)
    while (more := method.extend(design, runs)) is not None:
        n = design.sizes["realization"]
        more = more.assign_coords(realization=np.arange(n, n + more.sizes["realization"]))
        glue = dict(dim="realization", data_vars="minimal", coords="minimal",
                    compat="override", join="override")
        runs = xr.concat([runs, evaluate(more, steps).drop_dims("sensitivity_run",
                                                                errors="ignore")], **glue)
        design = xr.concat([design, more], **glue)
    return method.analyze(design, runs)


# --- the formulas --------------------------------------------------------------------------

def test_giles_counts_are_the_lagrange_optimum_and_skip_constant_points():
    V = np.array([[4.0, 0.0], [1.0, 0.0], [0.25, 0.0]])
    C = np.array([1.0, 4.0, 16.0])
    total = 2.0 + 2.0 + 2.0
    expected = np.ceil(np.sqrt(V[:, 0] / C) * total / 0.01)
    assert giles_counts(V, C, np.array([0.01, 0.01])).tolist() == expected.tolist()
    assert giles_counts(np.zeros((3, 2)), C, np.ones(2)).tolist() == [0, 0, 0]
    # that allocation's variance sum V/N meets the target and its cost is the optimum's:
    # three terms of a few IEEE roundings each (sqrt, /, *, +): ~10 eps, whatever the libm
    N = np.sqrt(V[:, 0] / C) * total / 0.01
    assert np.sum(V[:, 0] / N) == pytest.approx(0.01, rel=1e-14)
    # the same products summed in another order: ~10 eps
    assert np.dot(N, C) == pytest.approx(optimal_mlmc_cost(V[:, 0], C, 0.01), rel=1e-14)


def test_level_rates_of_geometric_sequences_are_exact():
    l = np.arange(5)
    # log2 of exact powers of two and a least-squares line through them: rounding only
    assert level_rate(3.0 * 2.0 ** (-1.5 * l)) == pytest.approx(1.5, rel=1e-12)
    assert level_rate(2.0 ** (2.0 * l), decreasing=False) == pytest.approx(2.0, rel=1e-12)
    assert math.isnan(level_rate(np.array([1.0, 0.5])))          # one correction level
    assert math.isnan(level_rate(np.array([1.0, 0.0, 0.0])))     # nothing to fit


def test_the_multilevel_variance_is_unbiased():
    # Var[P_1] from two levels: E over many replications of s^2(P_0) + (s^2(P_1) - s^2(P_0))
    rng = np.random.default_rng(0)
    reps, n0, n1 = 4000, 20, 6
    estimates = []
    for _ in range(reps):
        k0 = rng.uniform(LOW, HIGH, (n0, 1))
        k1 = rng.uniform(LOW, HIGH, (n1, 1))
        t0 = mlmc_level_terms(euler(k0, 2), None)
        t1 = mlmc_level_terms(euler(k1, 8), euler(k1, 2))
        estimates.append(t0["var_term"][0] + t1["var_term"][0])
    truth = expect(lambda k: euler(k, 8) ** 2) - exact_mean(8) ** 2
    se = np.std(estimates, ddof=1) / math.sqrt(reps)
    assert abs(np.mean(estimates) - truth) < 4 * se


def test_two_model_mfmc_ratio_and_variance_match_the_closed_form():
    rho, w = 0.9, np.array([10.0, 1.0])
    r, factor = mfmc_ratios(np.array([1.0, rho]), w)
    # the same few operations as the closed form, in another order: a few eps
    assert r[1] == pytest.approx(math.sqrt(10 * rho**2 / (1 - rho**2)), rel=1e-14)
    assert factor == pytest.approx(1 - (1 - 1 / r[1]) * rho**2, rel=1e-14)
    # a cheap model that is worse correlated than it is cheap does not pay
    assert mfmc_ratios(np.array([1.0, 0.1]), np.array([1.0, 0.99])) is None
    chosen, _, m1, cost = mfmc_best(1.0, np.array([1.0, 0.1]), np.array([1.0, 0.99]), 0.01)
    assert chosen == [0] and m1 == pytest.approx(100.0) and cost == pytest.approx(100.0)


def test_the_mfmc_estimator_variance_matches_its_spread():
    # Var[s] = s_1^2/m_1 (1 - sum (1/r_{i-1} - 1/r_i) rho_i^2) against 3000 replications: the
    # sample variance of 3000 values has relative s.e. sqrt(2/2999) = 2.6 %, so 4 s.e. = 10 %.
    rng = np.random.default_rng(1)
    counts = [10, 40, 400]
    est = []
    for _ in range(3000):
        k = rng.uniform(LOW, HIGH, (400, 1))
        values = [euler(k[:10], 64), euler(k[:40], 8), euler(k, 2)]
        est.append(mfmc_estimate(values, counts)["mean"][0])
    sigma = math.sqrt(expect(lambda k: euler(k, 64) ** 2) - exact_mean(64) ** 2)
    f = [lambda k: euler(k, 64), lambda k: euler(k, 8), lambda k: euler(k, 2)]
    rho = [1.0]
    for g in f[1:]:
        cov = expect(lambda k: f[0](k) * g(k)) - exact_mean(64) * expect(g)
        rho.append(cov / (sigma * math.sqrt(expect(lambda k: g(k) ** 2) - expect(g) ** 2)))
    predicted = sigma**2 / 10 * (1 - (1 / 1 - 10 / 40) * rho[1] ** 2
                                 - (10 / 40 - 10 / 400) * rho[2] ** 2)
    assert np.var(est, ddof=1) == pytest.approx(predicted, rel=0.10)
    assert abs(np.mean(est) - exact_mean(64)) < 4 * math.sqrt(predicted / 3000)


# --- conformance ---------------------------------------------------------------------------

def assert_conformant(results, eps, truth, finest_mean, optimum):
    """Over the seeds: RMSE against ``truth`` within 1.5 eps, the mean within 4 standard
    errors of ``finest_mean`` (what the estimator is unbiased for), every seed's cost within
    a factor 3 of ``optimum``. Returns the means."""
    means = np.array([r["y"].sel(statistic="mean").item() for r in results])
    assert math.sqrt(np.mean((means - truth) ** 2)) <= 1.5 * eps
    se = np.std(means, ddof=1) / math.sqrt(len(means))
    assert abs(means.mean() - finest_mean) < 4 * se
    spent = np.array([r.attrs["total_cost"] for r in results])
    assert np.all(spent <= 3 * optimum) and np.all(spent >= optimum / 3)
    return means


MLMC_STEPS = [4, 8, 16, 32, 64, 128]
MLMC_EPS = 0.005


def test_multilevel_reaches_the_rmse_at_near_optimal_cost_without_bias():
    costs = [float(s) for s in MLMC_STEPS]
    results = [drive(with_levels(Multilevel(target_rmse=MLMC_EPS, costs=costs, pilot=10),
                                 MLMC_STEPS), MLMC_STEPS, seed) for seed in SEEDS]
    # the real-valued optimum with the exact V_l: (sum sqrt(V_l C_l))^2 / (theta eps^2)
    C = np.array(costs) + np.concatenate([[0.0], costs[:-1]])
    optimum = optimal_mlmc_cost(correction_variances(MLMC_STEPS), C, 0.5 * MLMC_EPS**2)
    # RMSE against E[e^-k], bias included: MLMC controls both (theta = 1/2 each)
    means = assert_conformant(results, MLMC_EPS, exact_mean(), exact_mean(MLMC_STEPS[-1]),
                              optimum)
    # the reported stderr is the spread over seeds (20 values: ratio within 0.6..1.5)
    reported = np.median([r["y"].sel(statistic="stderr").item() for r in results])
    assert 0.6 < np.std(means, ddof=1) / reported < 1.5
    # the fitted rates: alpha = 1 (Euler's first order), beta = 2, gamma = 1 (stated costs)
    alpha, beta = np.median([r["y_rates"].values for r in results], axis=0)
    assert abs(alpha - 1) < 0.3 and abs(beta - 2) < 0.4
    # log2 of the stated costs 4 .. 128 is exact; polyfit's least squares on 5 points rounds
    # at ~10 eps (its lstsq is LAPACK's, conditioned ~10 here)
    assert results[0].attrs["gamma"] == pytest.approx(1.0, rel=1e-12)


MF_STEPS = [2, 8, 64]
MF_EPS = 0.0015


def test_multifidelity_reaches_the_rmse_at_near_optimal_cost_without_bias():
    costs = [float(s) for s in MF_STEPS]
    results = [drive(with_levels(Multifidelity(target_rmse=MF_EPS, costs=costs, pilot=16),
                                 MF_STEPS), MF_STEPS, seed) for seed in SEEDS]
    # the optimum with the exact sigma, rho (models: finest first) and costs
    f = [lambda k, s=s: euler(k, s) for s in MF_STEPS[::-1]]
    m = [expect(g) for g in f]
    sd = [math.sqrt(expect(lambda k, g=g: g(k) ** 2) - mi**2) for g, mi in zip(f, m)]
    rho = [(expect(lambda k, g=g: f[0](k) * g(k)) - m[0] * mi) / (sd[0] * si)
           for g, mi, si in zip(f, m, sd)]
    optimum = mfmc_best(sd[0], np.array(rho), np.array(costs[::-1]), MF_EPS**2)[3]
    # MFMC estimates the high-fidelity model's mean; its RMSE is against that
    truth = exact_mean(MF_STEPS[-1])
    assert_conformant(results, MF_EPS, truth, truth, optimum)
    # the plain-MC equivalent: more high-fidelity runs than were made
    assert np.all([r["y_equivalent_runs"].item() > r["model_samples"].values[0]
                   for r in results])


def test_the_bias_estimate_follows_the_exact_bias_and_warns_when_too_coarse():
    steps = [4, 8, 16]
    results = [drive(with_levels(Multilevel(target_rmse=0.002, costs=[4.0, 8.0, 16.0],
                                            pilot=10), steps), steps, seed)
               for seed in range(5)]
    exact_bias = exact_mean(16) - exact_mean()
    estimated = np.median([r["y"].sel(statistic="bias").item() for r in results])
    # the geometric tail E_L / (2^alpha - 1) with alpha ~ 1: first order, so within 2x
    assert 0.5 < estimated / abs(exact_bias) < 2.0
    # |bias| ~ 0.006 against sqrt(1 - theta) eps = 0.0014: every seed says so
    assert all("add a finer level" in r.attrs["warnings"] for r in results)
    fine = drive(with_levels(Multilevel(target_rmse=MLMC_EPS, costs=[float(s) for s in
                                                                     MLMC_STEPS], pilot=10),
                             MLMC_STEPS), MLMC_STEPS, 0)
    assert "add a finer level" not in fine.attrs["warnings"]


def test_the_shipped_euler_studies_state_the_exact_means():
    from pathlib import Path

    folder = Path(__file__).resolve().parents[2] / "studies" / "multilevel"
    mlmc, mfmc = ((folder / f).read_text() for f in ("euler_mlmc.toml", "euler_mfmc.toml"))
    # six decimals as written: the quadrature is exact to ~1e-13
    assert f"E[e^-k] = {exact_mean():.6f}" in mlmc and f"{exact_mean():.6f}" in mfmc
    assert f"is {exact_mean(128):.6f} (128 steps)" in mlmc
    assert f"is {exact_mean(64):.6f} (64 steps)" in mfmc


def test_a_free_surrogate_is_a_control_variate_with_its_exact_mean():
    r, factor = mfmc_ratios(np.array([1.0, 0.9]), np.array([64.0, 0.0]))
    # 1 - (1/1 - 1/inf) 0.81: two roundings
    assert r[1] == math.inf and factor == pytest.approx(1 - 0.81, rel=1e-14)
    rng = np.random.default_rng(2)
    f = rng.normal(size=(50, 1))
    g = 0.8 * f + 0.2 * rng.normal(size=(50, 1))
    got = mfmc_estimate([f, g], [50, math.inf], exact_mean=np.array([0.0]))
    alpha = np.cov(f[:, 0], g[:, 0])[0, 1] / np.var(g[:, 0], ddof=1)
    # the classic control variate, the same few sums: rounding only
    assert got["mean"][0] == pytest.approx(f.mean() - alpha * g.mean(), rel=1e-12)


SURROGATE_STEPS = [8, 64]
SURROGATE_EPS = 1e-4


def test_multifidelity_with_the_taylor_surrogate_reaches_the_rmse_at_near_optimal_cost():
    costs = [float(s) for s in SURROGATE_STEPS]
    results = [drive(with_levels(Multifidelity(target_rmse=SURROGATE_EPS, costs=costs,
                                               pilot=16, surrogate="taylor-local"),
                                 SURROGATE_STEPS), SURROGATE_STEPS, seed) for seed in SEEDS]
    assert all(r.attrs["surrogate"] == "taylor-local" for r in results)
    # the optimum with the exact sigma and correlations: the finest level, the coarse one
    # and the Taylor polynomial of the finest level around k = 1 (free)
    fine = AnalyticSolver.from_scene({"model": "euler_decay", "steps": 64})
    d = fine.run_with_sensitivities({"k": 1.0}, ["k"], ["y"])
    g1, h1 = d["y__gradient"].values[0], d["y__hessian"].values[0, 0]
    f = [lambda k: euler(k, 64), lambda k: euler(k, 8),
         lambda k: euler(1.0, 64) + g1 * (k - 1) + 0.5 * h1 * (k - 1) ** 2]
    m = [expect(g) for g in f]
    sd = [math.sqrt(expect(lambda k, g=g: g(k) ** 2) - mi**2) for g, mi in zip(f, m)]
    rho = [(expect(lambda k, g=g: f[0](k) * g(k)) - m[0] * mi) / (sd[0] * si)
           for g, mi, si in zip(f, m, sd)]
    optimum = mfmc_best(sd[0], np.array(rho), np.array([64.0, 8.0, 0.0]),
                        SURROGATE_EPS**2)[3] + 64.0        # + the surrogate's own run
    truth = exact_mean(SURROGATE_STEPS[-1])
    assert_conformant(results, SURROGATE_EPS, truth, truth, optimum)
    # the surrogate takes the place of the coarse level where it is better correlated
    assert results[0]["y_correlation"].values[-1] == pytest.approx(rho[2], abs=1e-3)


def test_measured_costs_leave_out_numba_compile_time():
    # numba compiles once per process: with five workers, five of every eight pilot runs of a
    # level may carry the compilation, which moves the median of the wall times
    steps = (4, 8, 16)
    method = with_levels(Multilevel(target_rmse=0.01, pilot=8), steps)
    design = method.plan(space(), None, np.random.SeedSequence(3))
    runs = evaluate(design, steps)
    per_run = np.array([1e-3, 2e-3, 4e-3])
    compiling = np.where(np.arange(design.sizes["realization"]) % 8 < 5, 0.5, 0.0)
    runs["wall_time"].values[:] = per_run[design["level"].values] + compiling
    runs["compile_time"] = ("realization", compiling)
    # wall - compile is exact but for the rounding at 0.5: ulp(0.5) = 1.1e-16, 1.1e-13 of 1e-3
    np.testing.assert_allclose(method.run_costs(runs), per_run, rtol=1e-12, atol=0)  # ulp(0.5)/1e-3
    # an older result without compile times: the wall times as they are
    older = runs.drop_vars("compile_time")
    assert method.run_costs(older).tolist() == (per_run + 0.5).tolist()
