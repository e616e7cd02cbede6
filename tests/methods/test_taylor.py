"""The Taylor method against exact moments of analytic models.

Finite differences are exact for polynomials up to degree two, so on the linear and quadratic
models every estimate must agree with the closed form to rounding (1e-8 relative); elsewhere
the tolerances are the truncation errors derived in each test.
"""

import math
import warnings

import numpy as np
import pytest
from pydantic import ValidationError

from solvers.analytic.models import AnalyticSolver
from uqflow.errors import AccuracyWarning, StudyError
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import get_method
from uqflow.methods.taylor import Taylor
from uqflow.realization import evaluate_design

SEED = np.random.SeedSequence(0)


def normals(means, stds, correlation=None):
    inputs = [RandomInput.from_spec({"name": f"x{i + 1}", "distribution": "normal",
                                     "mean": m, "std": s})
              for i, (m, s) in enumerate(zip(means, stds))]
    return InputSpace(inputs, correlation)


def propagate(scene, space, **options):
    """Plan, run and analyze; returns (statistics, design, runs, AccuracyWarning messages)."""
    method = Taylor(**options)
    design = method.plan(space, None, SEED)
    runs = evaluate_design(AnalyticSolver.from_scene(scene), design)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        stats = method.analyze(design, runs)
    raised = [str(w.message) for w in caught if issubclass(w.category, AccuracyWarning)]
    return stats, design, runs, raised


def stat(stats, name, out="y"):
    return stats[out].sel(statistic=name).values


def rel(a, b):
    return np.max(np.abs(np.asarray(a) - b) / np.abs(b))


CORR = np.array([[1.0, 0.6, -0.3],
                 [0.6, 1.0, 0.25],
                 [-0.3, 0.25, 1.0]])
MEANS, STDS = np.array([1.0, -2.5, 4.0]), np.array([0.1, 0.3, 0.5])


def test_registered_under_taylor():
    assert get_method("taylor") is Taylor


def test_linear_correlated_normals_exact():
    c = np.array([2.0, -1.5, 0.75])
    stats, *_ = propagate({"model": "linear", "coefficients": c.tolist(), "offset": 3.0},
                          normals(MEANS, STDS, CORR))
    cov = np.outer(STDS, STDS) * CORR
    assert rel(stat(stats, "mean"), 3.0 + c @ MEANS) < 1e-8
    assert rel(stat(stats, "variance"), c @ cov @ c) < 1e-8
    assert rel(stats["y_gradient"].values, c) < 1e-8


def test_quadratic_second_order_mean_exact_with_correlation():
    c = np.array([1.0, 0.5, -2.0])
    q = np.array([[0.8, 0.3, -0.4], [0.3, -1.2, 0.5], [-0.4, 0.5, 0.6]])
    stats, design, *_ = propagate({"model": "quadratic", "coefficients": c.tolist(),
                                   "offset": -1.0, "quadratic": q.tolist()},
                                  normals(MEANS, STDS, CORR))
    cov = np.outer(STDS, STDS) * CORR
    exact = -1.0 + c @ MEANS + MEANS @ q @ MEANS + np.trace(q @ cov)
    assert rel(stat(stats, "mean"), exact) < 1e-8
    assert rel(stats["y_hessian"].values, 2 * q) < 1e-8
    # first-order variance: the linearisation's gradient c + 2 Q m
    g = c + 2 * q @ MEANS
    assert rel(stat(stats, "variance"), g @ cov @ g) < 1e-8
    assert design.sizes["realization"] == 1 + 4 * 3 + 4 * 3  # every pair is correlated


def test_quadratic_second_order_variance_exact_for_independent_normals():
    c = np.array([1.0, 0.5, -2.0])
    q = np.array([[0.8, 0.3, -0.4], [0.3, -1.2, 0.5], [-0.4, 0.5, 0.6]])
    scene = {"model": "quadratic", "coefficients": c.tolist(), "quadratic": q.tolist()}
    stats, *_ = propagate(scene, normals(MEANS, STDS), variance="second-order")
    s = np.diag(STDS**2)
    g = c + 2 * q @ MEANS
    exact = g @ s @ g + 2 * np.trace(q @ s @ q @ s)
    assert rel(stat(stats, "variance"), exact) < 1e-8
    assert rel(stat(stats, "mean"), c @ MEANS + MEANS @ q @ MEANS + np.trace(q @ s)) < 1e-8
    first, *_ = propagate(scene, normals(MEANS, STDS))
    assert rel(stat(first, "variance"), exact) > 1e-3  # the curvature term matters here


def test_second_order_variance_refuses_correlated_inputs():
    with pytest.raises(StudyError, match="second-order variance"):
        Taylor(variance="second-order").plan(normals(MEANS, STDS, CORR), None, SEED)


def lognormal_x(mean, cv):
    return InputSpace([RandomInput.from_spec({"name": "x", "distribution": "lognormal",
                                              "mean": mean, "cv": cv})])


def lognormal_moment(mean, cv, r):
    return mean**r * (1 + cv**2) ** (r * (r - 1) / 2)


def mean_error_bound(p, cv, step=0.1):
    """Bound on |Taylor mean / E[X^p] - 1| for X lognormal (mean mu, C.V. v).

    E[X^p] = mu^p (1 + x)^a with x = v^2, a = p(p-1)/2; the order-2 Taylor mean is
    mu^p (1 + a x (1 + d)), d the finite-difference error of the curvature. Lagrange's
    remainder: (1 + x)^a - 1 - a x = a(a-1)/2 (1 + xi)^(a-2) x^2 for some 0 < xi < x. The
    central second difference of x^p at relative step t = step v is off by
    d = (p-2)(p-3)/12 t^2 + O(t^4); 1.1 covers the O(t^4) rest for t <= 0.03.
    """
    a, x = p * (p - 1) / 2, cv**2
    truncation = abs(a * (a - 1)) / 2 * x**2 * max(1.0, (1 + x) ** (a - 2))
    differencing = 1.1 * abs(a) * x * abs((p - 2) * (p - 3)) / 12 * (step * cv) ** 2
    return (truncation + differencing) / (1 + x) ** a + 1e-12


CVS = (0.01, 0.05, 0.15, 0.3)


@pytest.mark.parametrize("p", [3.0, -0.5])
def test_lognormal_power_mean_error_is_taylor_truncation(p):
    errors = []
    for cv in CVS:
        stats, _, _, raised = propagate({"model": "power", "p": p}, lognormal_x(2.0, cv))
        exact = lognormal_moment(2.0, cv, p)
        err = abs(stat(stats, "mean") / exact - 1)
        bound = mean_error_bound(p, cv)
        assert err <= bound, (cv, err, bound)
        assert err >= 0.9 * bound, (cv, err, bound)  # the bound is the error, not slack
        errors.append(err)
        cv_warned = [m for m in raised if "C.V." in m]
        assert len(cv_warned) == (1 if cv > 0.15 else 0), (cv, raised)
        if cv > 0.15:
            assert "'x'" in cv_warned[0] and "0.3" in cv_warned[0] and "4.1" in cv_warned[0]
        assert not [m for m in raised if "step-stable" in m]  # smooth: the check stays quiet
    assert all(b > a for a, b in zip(errors, errors[1:]))  # grows with C.V. (like C.V.^4)


def test_zero_std_input_gets_no_runs_and_no_derivative():
    c = np.array([2.0, -1.5, 0.75])
    corr = np.array([[1.0, 0.4, -0.3], [0.4, 1.0, 0.2], [-0.3, 0.2, 1.0]])
    stds = np.array([0.1, 0.0, 0.5])
    stats, design, *_ = propagate({"model": "linear", "coefficients": c.tolist()},
                                  normals(MEANS, stds, corr), step_check=False)
    assert design.sizes["realization"] == 1 + 2 * 2 + 4  # + the x1-x3 mixed derivative
    assert np.all(design["inputs"].values[:, 1] == MEANS[1])
    assert stats["y_gradient"].sel(parameter="x2").item() == 0.0
    others = c[[0, 2]] @ (np.outer(stds, stds) * corr)[np.ix_([0, 2], [0, 2])] @ c[[0, 2]]
    assert rel(stat(stats, "variance"), others) < 1e-8
    assert rel(stat(stats, "mean"), c @ MEANS) < 1e-8


def test_tiny_and_huge_inputs_keep_relative_accuracy():
    # y = 1e12 x1 + 1e-12 x2 with x1 ~ 1e-12 and x2 ~ 1e12: both terms are O(1)
    c = np.array([1e12, 1e-12])
    corr = np.array([[1.0, 0.3], [0.3, 1.0]])
    stats, *_ = propagate({"model": "quadratic", "coefficients": c.tolist(),
                           "quadratic": [[0.0, 0.0], [0.0, 0.0]]},
                          normals([1e-12, 1e12], [1e-13, 2e11], corr))
    assert rel(stats["y_gradient"].values, c) < 1e-8
    assert rel(stat(stats, "mean"), 2.0) < 1e-8
    assert rel(stat(stats, "variance"), 0.01 + 0.04 + 2 * 0.3 * 0.1 * 0.2) < 1e-8


def test_field_output_exponential_decay():
    alpha, beta, width = 1.5, 0.15, 0.05
    space = InputSpace([
        RandomInput.from_spec({"name": "alpha", "distribution": "normal", "mean": alpha,
                               "std": 0.2}),
        RandomInput.from_spec({"name": "beta", "distribution": "uniform",
                               "lower": beta - width, "upper": beta + width})])
    stats, design, runs, raised = propagate({"model": "exponential_decay"}, space)
    t = runs["t"].values
    assert stats["y"].dims == ("statistic", "t") and np.array_equal(stats["t"].values, t)
    assert stats["y_gradient"].dims == ("parameter", "t")
    sb, h = width / math.sqrt(3), 0.1 * width / math.sqrt(3)
    e = np.exp(-beta * t)
    # Central differences of exp(-beta t): gradient off by sinh(ht)/(ht) - 1 ~ (ht)^2/6,
    # curvature by 2(cosh(ht) - 1)/(ht)^2 - 1 ~ (ht)^2/12.
    fd = (h * t) ** 2
    grad_b = stats["y_gradient"].sel(parameter="beta").values
    assert grad_b[0] == 0.0 and t[0] == 0.0
    assert np.all(np.abs(grad_b[1:] / (-alpha * t[1:] * e[1:]) - 1) <= fd[1:] / 6 * 1.01 + 1e-9)
    assert rel(stats["y_gradient"].sel(parameter="alpha").values, e) < 1e-8
    var1 = e**2 * (0.2**2 + alpha**2 * t**2 * sb**2)  # seed eq. 24 with exact derivatives
    assert np.all(np.abs(stat(stats, "variance") / var1 - 1) <= fd / 3 * 1.01 + 1e-9)
    z = width * t  # E[exp(-t d)] = sinh(z)/z for d ~ U(-w, w); order 2 keeps 1 + z^2/6
    mean2 = alpha * e * (1 + z**2 / 6)
    assert np.all(np.abs(stat(stats, "mean") / mean2 - 1) <= z**2 / 6 * fd / 12 * 1.01 + 1e-9)
    exact = alpha * e * np.where(z > 0, np.sinh(z) / np.where(z > 0, z, 1), 1.0)
    remainder = np.where(z > 0, np.sinh(z) / np.where(z > 0, z, 1), 1.0) - 1 - z**2 / 6
    assert np.all(np.abs(stat(stats, "mean") / exact - 1) <= remainder + z**2 * fd / 60 + 1e-9)
    # beta ~ U(0.1, 0.2) has C.V. 0.19: above the seed's 0.15
    assert any("'beta'" in m and "C.V." in m for m in raised)
    # smooth in both inputs: every derivative is step-stable at every t
    assert float(stats["y_gradient_change"].max()) < 1e-3
    assert float(stats["y_curvature_change"].max()) < 1e-2  # alpha's is rounding noise
    assert not [m for m in raised if "step-stable" in m]


@pytest.mark.parametrize("scene, bad, label", [
    ({"raise_above": 1.007}, 1, "x+h"),        # SolverError at mean + h
    ({"nan_below": 0.993}, 2, "x-h"),          # NaN output at mean - h
    ({"raise_above": 0.999}, 0, "mean"),       # the centre itself
])
def test_failed_stencil_point_gives_nan_and_a_warning(scene, bad, label):
    x = InputSpace([RandomInput.from_spec({"name": "x", "distribution": "normal",
                                           "mean": 1.0, "std": 0.1})])
    stats, design, runs, raised = propagate({"model": "faulty", **scene}, x)
    assert runs["status"].values[bad] == "failed"
    assert np.isnan(stat(stats, "mean")) and np.isnan(stat(stats, "variance"))
    assert np.isnan(stat(stats, "nominal")) == (bad == 0)
    assert stats.attrs["failed_runs"] >= 1
    assert any(f"realization {bad} (stencil point {label}) failed" in m for m in raised)
    assert f"realization {bad}" in stats.attrs["warnings"]


def test_run_counts():
    space = normals(MEANS, STDS)
    n = 3
    assert Taylor(step_check=False).plan(space, None, SEED).sizes["realization"] == 2 * n + 1
    assert Taylor().plan(space, None, SEED).sizes["realization"] == 4 * n + 1
    # one correlated pair: four more points for its mixed derivative (order 2 only)
    corr = np.eye(3)
    corr[0, 2] = corr[2, 0] = 0.5
    space = normals(MEANS, STDS, corr)
    assert Taylor().plan(space, None, SEED).sizes["realization"] == 4 * n + 1 + 4
    assert Taylor(order=1).plan(space, None, SEED).sizes["realization"] == 4 * n + 1
    # the second-order variance needs every pair
    indep = normals(MEANS, STDS)
    assert Taylor(variance="second-order", step_check=False).plan(
        indep, None, SEED).sizes["realization"] == 2 * n + 1 + 4 * 3


def test_step_check_flags_a_kink_at_the_mean():
    # y = |4 x - 2| (Sobol' G with a = 0) has a kink at x = 0.5: the central "curvature"
    # there is 8/h, so it doubles when the step is halved and the order-2 mean (2.0 here,
    # against the exact 4 * 0.05 * sqrt(2/pi) = 0.16) is meaningless.
    stats, _, _, raised = propagate({"model": "sobol_g", "a": [0.0]},
                                    InputSpace([RandomInput.from_spec(
                                        {"name": "x1", "distribution": "normal", "mean": 0.5,
                                         "std": 0.05})]))
    assert stats["y_curvature_change"].item() == pytest.approx(0.5, rel=1e-6)
    msg = [m for m in raised if "step-stable" in m]
    assert len(msg) == 1 and "curvature" in msg[0] and "'x1'" in msg[0] and "'y'" in msg[0]


def test_options_are_validated():
    with pytest.raises(ValidationError):
        Taylor(order=3)
    with pytest.raises(ValidationError):
        Taylor(step=0.0)
    with pytest.raises(ValidationError):
        Taylor(order=1, mixed_derivatives=True)
    with pytest.raises(ValidationError):
        Taylor(variance="third-order")


def test_step_warning_names_a_labelled_coordinate():
    # Outputs on a string coordinate (e.g. named probes) must not break the warning text.
    space = InputSpace([RandomInput.from_spec(dict(name="x", distribution="normal", mean=0.5,
                                                   std=0.05))])
    method = Taylor(order=2, step_check=True)
    design = method.plan(space, None, np.random.SeedSequence(0))
    x = design["inputs"].values[:, 0]
    kink = np.abs(4 * x - 2)                                 # not smooth at the mean
    runs = design.copy()
    runs["y"] = (("realization", "probe"), np.stack([kink, x], axis=1))
    runs = runs.assign_coords(probe=["H", "I"])
    runs["status"] = ("realization", np.array(["ok"] * x.size, dtype=object))
    runs["wall_time"] = ("realization", np.zeros(x.size))
    with pytest.warns(AccuracyWarning, match="probe = H"):
        stats = method.analyze(design, runs)
    assert "probe = H" in stats.attrs["warnings"]
