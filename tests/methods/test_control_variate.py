"""Control-variate Monte Carlo (``monte-carlo`` with ``control``): exactness on quadratics,
the reported variance reduction against the empirical one, unbiasedness over seeds, failures,
the design and option checks. Closed-form models of ``solvers/analytic`` only."""

import textwrap
import warnings

import numpy as np
import pytest
from scipy import stats as sps

from solvers.analytic import AnalyticSolver
from uqflow.errors import AccuracyWarning, StudyError
from uqflow.execute import run_study
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods.monte_carlo import MonteCarlo
from uqflow.methods.taylor import NOISE
from uqflow.realization import evaluate_design
from uqflow.report import ResultView, summary_table
from uqflow.store import open_result
from uqflow.study import load_study


C = np.array([1.0, -2.0])
MU = np.array([0.8, -1.3])
SIGMA = np.array([0.25, 0.4])
DIAGONAL_Q = np.array([[1.5, 0.0], [0.0, 2.0]])
FULL_Q = np.array([[1.5, 0.7], [-0.3, 2.0]])


def _normal_space(rho=0.0, mean=MU, std=SIGMA):
    """Normal inputs x1, x2, ... (one input: x, the name of the one-input models)."""
    names = ["x"] if len(mean) == 1 else [f"x{k + 1}" for k in range(len(mean))]
    inputs = [RandomInput.from_spec({"name": names[k], "distribution": "normal",
                                     "mean": float(m), "std": float(s)})
              for k, (m, s) in enumerate(zip(mean, std))]
    n = len(inputs)
    return InputSpace(inputs, np.full((n, n), rho) + (1 - rho) * np.eye(n))


def _run(scene, space, seed=0, **options):
    """Plan, run in process and analyse: (design, runs, statistics, warnings)."""
    method = MonteCarlo(**options)
    solver = AnalyticSolver.from_scene(scene)
    method.check_solver(solver, ["y"], space.names)
    design = method.plan(space, None, np.random.SeedSequence(seed))
    runs = evaluate_design(solver, design, ["y"])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", AccuracyWarning)
        stats = method.analyze(design, runs)
    return design, runs, stats, [str(w.message) for w in caught]


def _stat(stats, label, out="y"):
    return float(stats[out].sel(statistic=label))


# ------------------------------------------------------------------ exact on a quadratic

@pytest.mark.parametrize("control, q, rho", [("taylor", DIAGONAL_Q, 0.0),
                                             ("taylor-local", DIAGONAL_Q, 0.0),
                                             ("taylor-local", FULL_Q, 0.6)])
@pytest.mark.parametrize("rule", ["random", "sobol"])
def test_a_quadratic_with_gaussian_inputs_is_reproduced_to_rounding(control, q, rho, rule):
    scene = {"model": "quadratic", "coefficients": C.tolist(), "quadratic": q.tolist(),
             "offset": 3.0}
    space = _normal_space(rho)
    _, runs, stats, _ = _run(scene, space, rule=rule, samples=256, control=control)
    cov = np.outer(SIGMA, SIGMA) * np.array([[1, rho], [rho, 1]])
    mean = 3.0 + C @ MU + MU @ q @ MU + np.trace(q @ cov)
    grad, hess = C + (q + q.T) @ MU, q + q.T
    variance = grad @ cov @ grad + 0.5 * np.trace(hess @ cov @ hess @ cov)
    f_scale = float(np.max(np.abs(runs["y"].values)))
    # The surrogate differs from f by rounding only. Local derivatives are exact, so the
    # residual f - g is a few dozen ulps of the largest value (NOISE F). Central differences
    # at h = 0.1 s err by up to the stencil's rounding floor 4 NOISE F / h^2 in the curvature,
    # i.e. 4 NOISE F / 0.1^2 over the inputs' spread s^2 (taylor.Stencil.rounding_floor).
    residual = NOISE * f_scale if control == "taylor-local" else 4 * NOISE * f_scale / 0.1**2
    assert abs(_stat(stats, "mean") - mean) <= residual
    assert _stat(stats, "stderr") <= residual
    # Var error ~ 2 std(f) std(f - g) (the covariance of the residual with f), plus the same
    # from the surrogate's variance formula
    assert abs(_stat(stats, "variance") - variance) <= 4 * np.sqrt(variance) * residual
    # 1 - rho ~ (std(f - g) / std f)^2 / 2 <= std(f - g) / std f
    assert 1 - float(stats["y_correlation"]) <= residual / np.sqrt(variance)
    plain_error = abs(float(stats["y_plain"].sel(plain_statistic="mean")) - mean)
    assert plain_error > 100 * residual  # the plain estimate from the same samples is not


# ------------------------------------------------------------- reduction, reported vs seen

def test_reported_reduction_matches_the_spread_over_seeds():
    # y = x^3, x ~ N(1, 0.2): the quadratic surrogate leaves the cubic term d^3 out
    space = _normal_space(mean=[1.0], std=[0.2])
    scene = {"model": "power", "p": 3.0}
    seeds = 50
    cv_means, plain_means, reported = [], [], []
    for seed in range(seeds):
        _, _, stats, _ = _run(scene, space, seed=seed, samples=128, control="taylor-local")
        cv_means.append(_stat(stats, "mean"))
        plain_means.append(float(stats["y_plain"].sel(plain_statistic="mean")))
        reported.append(float(stats["y_variance_reduction"]))
    seen = np.var(plain_means, ddof=1) / np.var(cv_means, ddof=1)
    expected = float(np.mean(reported))
    assert expected > 10  # a case where the control matters
    # A ratio of two sample variances over 50 seeds: within the 0.1 % and 99.9 % quantiles
    # of F(49, 49) (the two spreads are taken as independent normal-sample variances)
    low, high = sps.f.ppf([0.001, 0.999], seeds - 1, seeds - 1)
    assert (round(low, 2), round(high, 2)) == (0.41, 2.46)  # as docs/control_variates.md says
    assert low <= seen / expected <= high


def test_rho_reduction_and_equivalent_count_are_consistent():
    space = _normal_space(mean=[1.0], std=[0.2])
    _, _, stats, _ = _run({"model": "power", "p": 3.0}, space, samples=200,
                          control="taylor-local")
    rho = float(stats["y_correlation"])
    n = stats.attrs["samples_ok"]
    assert 0.9 < rho < 1
    # 1/(1 - rho^2) and n/(1 - rho^2) in floating point: a few ulps each
    assert float(stats["y_variance_reduction"]) == pytest.approx(1 / (1 - rho**2), rel=8 * 2**-52)
    assert float(stats["y_equivalent_samples"]) == pytest.approx(n / (1 - rho**2),
                                                                 rel=8 * 2**-52)
    plain_var = float(stats["y_plain"].sel(plain_statistic="variance"))
    # the i.i.d. control-variate stderr sqrt((1 - rho^2) s^2 / n), a few ulps
    assert _stat(stats, "stderr") == pytest.approx(np.sqrt((1 - rho**2) * plain_var / n),
                                                   rel=8 * 2**-52)
    assert stats.attrs["degrees_of_freedom"] == n - 2
    assert stats.attrs["control"] == "taylor-local" and stats.attrs["control_runs"] == 1
    assert stats.attrs["control_used"] == 1
    assert "control variate" in stats.attrs["stderr_note"]
    assert stats.attrs["solver_runs"] == 201
    assert set(stats["y_surrogate"].surrogate_statistic.values) == {"mean", "variance"}


def test_rqmc_stderr_is_the_spread_of_the_replicate_estimates():
    space = _normal_space(mean=[1.0], std=[0.2])
    _, _, stats, _ = _run({"model": "power", "p": 3.0}, space, samples=256, rule="sobol",
                          control="taylor")
    per_replicate = stats["y_replicate_means"].values
    assert per_replicate.shape == (8,)
    # the mean of 8 replicate estimates and their spread / sqrt(8): a few ulps
    assert _stat(stats, "mean") == pytest.approx(per_replicate.mean(), rel=8 * 2**-52)
    # the spread of 8 numbers that agree to ~1/660 of their size: each deviation from the
    # mean loses |mean|/spread of its digits, so ~8 roundings times that, in any summation order
    spread = per_replicate.std(ddof=1)
    assert _stat(stats, "stderr") == pytest.approx(
        spread / np.sqrt(8), rel=16 * 2**-52 * abs(per_replicate.mean()) / spread)
    assert stats.attrs["degrees_of_freedom"] == 7 and stats.attrs["control_runs"] == 3


# ------------------------------------------------------------------------- unbiasedness

def _uniform_power_moment(k, lower, upper):
    """E[x^k] for x ~ U(lower, upper)."""
    return (upper ** (k + 1) - lower ** (k + 1)) / ((k + 1) * (upper - lower))


@pytest.mark.parametrize("rule, control", [("random", "taylor-local"), ("sobol", "taylor")])
def test_mean_and_variance_are_unbiased_over_seeds(rule, control):
    """y = x^3, x ~ U(0.5, 1.5): a cubic the quadratic surrogate misses by d^3, with a uniform
    input (the surrogate's variance from its fourth moment). The average over seeds of each
    estimate lies within 4 standard errors of that average (the spread over seeds /
    sqrt(seeds)) of the exact value: a false alarm 6e-5 of the time."""
    lower, upper = 0.5, 1.5
    mean = _uniform_power_moment(3, lower, upper)
    variance = _uniform_power_moment(6, lower, upper) - mean**2
    space = InputSpace([RandomInput.from_spec({"name": "x", "distribution": "uniform",
                                               "lower": lower, "upper": upper})])
    seeds = 100
    estimates = {"mean": [], "variance": []}
    for seed in range(seeds):
        _, _, stats, _ = _run({"model": "power", "p": 3.0}, space, seed=seed, rule=rule,
                              samples=64, control=control, trace_points=2)
        for label, values in estimates.items():
            values.append(_stat(stats, label))
        assert float(stats["y_correlation"]) > 0.9  # the control is doing the work
    for label, exact in (("mean", mean), ("variance", variance)):
        values = estimates[label]
        error = np.std(values, ddof=1) / np.sqrt(seeds)
        assert abs(np.mean(values) - exact) <= 4 * error, label


# ----------------------------------------------------------------------------- failures

def test_a_failed_control_run_falls_back_to_plain_monte_carlo_with_a_warning():
    # x^1.5 has an infinite second derivative at x = 0, the mean: the control run fails
    space = _normal_space(mean=[0.0], std=[0.1])
    scene = {"model": "power", "p": 1.5}
    _, runs, stats, caught = _run(scene, space, samples=64, control="taylor-local")
    assert runs["status"].values[0] == "failed"
    _, _, plain, _ = _run(scene, space, samples=64)
    for label in ("mean", "variance", "stderr"):
        assert _stat(stats, label) == _stat(plain, label)
    assert any("gave no surrogate" in w and "plain Monte Carlo" in w for w in caught)
    assert "gave no surrogate" in stats.attrs["warnings"]
    assert stats.attrs["control_used"] == 0 and "y_correlation" not in stats


def test_failed_samples_are_dropped_from_the_output_and_the_surrogate_alike():
    # y = x fails above x = 1: the successful samples are a truncated normal whose plain
    # mean is below 0, but y = g on every one of them, so the control-variate mean is the
    # exact E[g] = 0 only if g is averaged over the same (successful) samples
    space = _normal_space(mean=[0.0], std=[1.0])
    _, runs, stats, _ = _run({"model": "faulty", "raise_above": 1.0}, space, samples=200,
                             control="taylor-local")
    failed = int(np.sum(runs["status"].values[1:] == "failed"))
    assert failed > 10
    assert float(stats["y_plain"].sel(plain_statistic="mean")) < -0.1
    # y and g are the same float at every sample; the estimate adds and subtracts means of
    # values below 4 in magnitude: a few ulps of 4
    assert abs(_stat(stats, "mean")) <= 64 * 4 * 2**-52
    assert f"{failed} failed sample(s) dropped from both" in stats.attrs["control_failures"]


# ------------------------------------------------------------------------------- design

@pytest.mark.parametrize("rule", ["random", "lhs", "sobol"])
@pytest.mark.parametrize("control, extra", [("taylor", 5), ("taylor-local", 1)])
def test_the_samples_are_those_of_the_plain_design(rule, control, extra):
    space = _normal_space()
    plain = MonteCarlo(rule=rule, samples=64).plan(space, None, np.random.SeedSequence(3))
    method = MonteCarlo(rule=rule, samples=64, control=control)
    design = method.plan(space, None, np.random.SeedSequence(3))
    assert design.sizes["realization"] == 64 + extra
    assert design.attrs["control_runs"] == extra
    assert list(design["role"].values) == ["control"] * extra + ["sample"] * 64
    np.testing.assert_array_equal(design["inputs"].values[extra:], plain["inputs"].values)
    np.testing.assert_array_equal(design["inputs"].values[0], space.means)
    if control == "taylor-local":
        assert design["with_sensitivities"].values.tolist() == [True] + [False] * 64
    stopping = dict(target_rel_stderr=0.01, min_samples=16)
    shifted = MonteCarlo(rule=rule, samples=64, control=control, **stopping).stop_points(
        64 + extra)
    np.testing.assert_array_equal(
        shifted, MonteCarlo(rule=rule, samples=64, **stopping).stop_points(64) + extra)


def test_a_study_stops_on_the_control_variate_error_and_stores_it(tmp_path):
    # y linear in x: the surrogate is exact, the control-variate stderr is 0 at the first
    # check, so the study stops after min_samples; plain Monte Carlo would need ~1e4
    path = _study(tmp_path, '{ model = "linear", coefficients = [2.0], offset = 1.0 }',
                  'control = "taylor"\ntarget_rel_stderr = 0.001\nmin_samples = 16\n'
                  'samples = 4096')
    result = run_study(load_study(path), show_progress=False)
    stats = result.statistics
    assert stats.attrs["solver_runs"] == 3 + 16
    assert stats.attrs["control"] == "taylor" and stats.attrs["control_runs"] == 3
    # 1 + 2 x at the mean 0.5, from 16 samples of an exact surrogate: a few ulps of 2
    assert _stat(stats, "mean") == pytest.approx(2.0, abs=64 * 2 * 2**-52)
    assert (tmp_path / "s.nc").exists()
    # the report's histogram and faint runs show the samples, not the stencil points
    tree = open_result(tmp_path / "s.nc")
    assert ResultView(tree).sample_values("y").shape == (16,)
    table = summary_table(tree)
    assert "control variate taylor (3 control run(s))" in table
    assert "y: rho 1, the surrogate reproduces it to rounding" in table


def test_the_report_says_what_the_control_bought(tmp_path):
    path = _study(tmp_path, '{ model = "power", p = 3.0 }', 'control = "taylor-local"\n'
                  'samples = 64', inputs='\n[[inputs]]\nname = "x"\ndistribution = "normal"\n'
                                        'mean = 1.0\nstd = 0.1\n')
    run_study(load_study(path), show_progress=False)
    tree = open_result(tmp_path / "s.nc")
    stats = tree["statistics"].to_dataset()
    rho, gain, count = (float(stats[f"y_{v}"]) for v in
                        ("correlation", "variance_reduction", "equivalent_samples"))
    assert f"y: rho {rho:.6g}, reduction {gain:.3g}x, equivalent to {count:.3g} plain " \
           f"samples" in summary_table(tree)


# --------------------------------------------------------------------------- validation

def _study(tmp_path, scene, method_options, inputs=None, name="s"):
    inputs = inputs or ('\n[[inputs]]\nname = "x1"\ndistribution = "normal"\nmean = 0.5\n'
                        'std = 0.05\n')
    text = textwrap.dedent(f"""\
        name = "{name}"
        solver = "analytic"
        scene = {scene}
        """) + inputs + f'\n[method]\nkind = "monte-carlo"\n{method_options}\n\n' \
        f'[execution]\nworkers = 0\nmax_failure_fraction = 1.0\n\n[output]\npath = ' \
        f'"{name}.nc"\nfigures = false\n'
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def test_a_solver_without_local_derivatives_names_control_taylor(tmp_path):
    path = _study(tmp_path, '{ model = "sobol_g", a = [0.0] }', 'control = "taylor-local"')
    with pytest.raises(StudyError) as info:
        load_study(path)
    assert str(info.value).startswith(f"{path}: method.control: solver 'analytic/sobol_g'")
    assert 'use control = "taylor"' in str(info.value)
    load_study(_study(tmp_path, '{ model = "sobol_g", a = [0.0] }', 'control = "taylor"',
                      name="fd"))


@pytest.mark.parametrize("options, message", [
    ('control = "pce"', "method.control: Input should be 'none', 'taylor-local' or 'taylor'"),
    ('control_step = 0.5', "method: 'control_step' applies to control = \"taylor\" only"),
    ('control = "taylor-local"\ncontrol_step = 0.5', "applies to control = \"taylor\" only"),
    ('control = "taylor"\ncontrol_step = 0.0', "method.control_step: .*greater than 0"),
])
def test_option_errors_name_the_key(tmp_path, options, message):
    path = _study(tmp_path, '{ model = "linear", coefficients = [2.0] }', options)
    with pytest.raises(StudyError, match=message):
        load_study(path)


def test_a_stencil_step_lost_to_rounding_names_control_step(tmp_path):
    inputs = '\n[[inputs]]\nname = "x1"\ndistribution = "normal"\nmean = 1e20\nstd = 1.0\n'
    path = _study(tmp_path, '{ model = "linear", coefficients = [2.0] }', 'control = "taylor"',
                  inputs=inputs)
    with pytest.raises(StudyError, match="method.control_step: .*a larger control_step"):
        load_study(path)


def test_correlated_non_normal_inputs_are_refused(tmp_path):
    inputs = "".join(f'\n[[inputs]]\nname = "x{k}"\ndistribution = "uniform"\nlower = 0.0\n'
                     f'upper = 1.0\n' for k in (1, 2))
    inputs += '\n[correlation]\ninputs = ["x1", "x2"]\nmatrix = [[1.0, 0.5], [0.5, 1.0]]\n'
    path = _study(tmp_path, '{ model = "linear", coefficients = [2.0, 1.0] }',
                  'control = "taylor"', inputs=inputs)
    with pytest.raises(StudyError, match="method.control: .*correlated non-normal"):
        load_study(path)


# ------------------------------------------------------------------------------ the MPM

def test_on_the_mpm_the_whole_solver_control_sees_what_the_frozen_state_misses():
    """The small thin-plate scene, coarse and short, Johnson-Cook A and B uncertain. The
    flow stress depends on A and B directly: both controls follow it (rho > 0.99 at the
    median point). The pressure depends on them only through the deformation history: its
    local (frozen-state) derivatives are zero, so the taylor-local surrogate is constant and
    the estimate is plain Monte Carlo's, while the whole-solver stencil follows it."""
    import tomllib
    from pathlib import Path

    from uqflow.solver import get_solver

    scene = tomllib.loads((Path(__file__).parents[2] / "studies/scenes/"
                           "mpm_contact_thin_small.toml").read_text())
    scene.update(resolution=0.5, end_time=12e-6, output_interval=1e-6, threads=1)
    solver = get_solver("mpm").from_scene(scene)
    nominal = solver.nominal()
    space = InputSpace([RandomInput.from_spec({"name": n, "distribution": "normal",
                                               "mean": nominal[n], "std": 0.1 * nominal[n]})
                        for n in ("steel.jc.A", "steel.jc.B")])
    outputs = ["flow_stress", "pressure"]
    median_rho = {}
    for control in ("taylor-local", "taylor"):
        method = MonteCarlo(samples=16, control=control)
        method.check_solver(solver, outputs, space.names)
        design = method.plan(space, None, np.random.SeedSequence(0))
        stats = method.analyze(design, evaluate_design(solver, design, outputs))
        assert stats.attrs["control_used"] == 1
        for out in outputs:
            varies = stats[out].sel(statistic="variance").values > 0
            median_rho[control, out] = np.median(stats[f"{out}_correlation"].values[varies])
            if (control, out) == ("taylor-local", "pressure"):
                assert np.all(stats[f"{out}_surrogate"].sel(surrogate_statistic="variance") == 0)
                # fold-size-weighted fold means against the pooled mean: a few ulps
                np.testing.assert_allclose(
                    stats[out].sel(statistic="mean"),
                    stats[f"{out}_plain"].sel(plain_statistic="mean"), rtol=8 * 2**-52)
    assert median_rho["taylor-local", "flow_stress"] > 0.99
    assert median_rho["taylor", "flow_stress"] > 0.99
    assert median_rho["taylor-local", "pressure"] == 0
    assert median_rho["taylor", "pressure"] > 0.9
