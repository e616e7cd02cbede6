"""Analytic solver: every model against its formula, exact moments by Monte Carlo, the bar
with a random E field, scene validation and the output template."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from solvers.analytic import MODELS, AnalyticSolver
from uqflow.errors import SceneError, SolverError
from uqflow.inputs import InputSpace, RandomInput
from uqflow.realization import evaluate_design
from uqflow.sampling import unit_hypercube
from uqflow.testing import check_solver
from uqflow.solver import Solver, get_solver

EPS = np.finfo(float).eps


def solver(**scene):
    return AnalyticSolver.from_scene(scene)


def y(sol, params, fields=None, out="y"):
    return sol.run(params, fields)[out].values


def test_registered_and_a_solver():
    assert get_solver("analytic") is AnalyticSolver
    assert issubclass(AnalyticSolver, Solver)
    assert set(MODELS) >= {"ishigami", "sobol_g", "linear", "quadratic", "power",
                           "exponential_decay", "random_E_bar", "faulty"}
    assert solver(model="ishigami").describe() == "analytic/ishigami"


# --------------------------------------------------------------------------------------------
# Outputs against the formulas
# --------------------------------------------------------------------------------------------

POINTS3 = [(0.0, 0.0, 0.0), (1.0, -2.0, 3.0), (-math.pi, math.pi / 2, -1.5), (0.3, 0.7, 2.9)]


@pytest.mark.parametrize("x1, x2, x3", POINTS3)
def test_ishigami(x1, x2, x3):
    for a, b in [(7.0, 0.1), (5.0, 0.2)]:
        terms = [math.sin(x1), a * math.sin(x2) ** 2, b * x3**4 * math.sin(x1)]
        scene = {"model": "ishigami"} if a == 7.0 else {"model": "ishigami", "a": a, "b": b}
        # Each term within ~4 roundings (sin <= 1 ulp in any libm, powers, products) on both
        # sides, then a sum that can cancel: 16 eps times the sum of the terms' magnitudes.
        assert y(solver(**scene), {"x1": x1, "x2": x2, "x3": x3}) == \
            pytest.approx(sum(terms), rel=0, abs=16 * EPS * sum(map(abs, terms)))


def test_sobol_g():
    a = np.array([0.0, 1.0, 4.5, 9.0, 99.0, 99.0, 99.0, 99.0])
    sol = solver(model="sobol_g")
    assert sol.nominal() == {f"x{i + 1}": 0.5 for i in range(8)}
    rng = np.random.default_rng(0)
    for x in [np.full(8, 0.5), np.zeros(8), rng.random(8), rng.random(8)]:
        exact = np.prod((np.abs(4 * x - 2) + a) / (1 + a))
        params = {f"x{i + 1}": float(v) for i, v in enumerate(x)}
        # 8 factors of ~5 roundings each (-2, +a, 1+a, /, *) on both sides: 80 eps
        assert y(sol, params) == pytest.approx(exact, rel=80 * EPS)
    sol = solver(model="sobol_g", a=[0, 2])
    # decimal 0.1, 0.9 (1/2 ulp each) through 2 factors of ~5 roundings, both sides: 24 eps
    assert y(sol, {"x1": 0.1, "x2": 0.9}) == pytest.approx(1.6 * (1.6 + 2) / 3, rel=24 * EPS)


def test_linear_and_quadratic():
    sol = solver(model="linear", coefficients=[2.0, -3.0, 0.5], offset=1.0)
    assert sol.nominal() == {"x1": 0.0, "x2": 0.0, "x3": 0.0}
    # small integers and halves: every product and sum is exact in binary
    assert y(sol, {"x1": 1.0, "x2": 2.0, "x3": 4.0}) == 1 + 2 - 6 + 2
    assert y(sol, {}) == 1.0                            # nominal values: all zero
    assert y(sol, {"x2": 1.0}) == pytest.approx(-2.0)   # others stay nominal
    q = [[1.0, 0.5], [0.5, -2.0]]
    sol = solver(model="quadratic", coefficients=[1.0, 1.0], offset=0.5, quadratic=q)
    x = np.array([1.5, -0.5])
    exact = 0.5 + x.sum() + x @ np.array(q) @ x
    assert exact == 2.5                 # dyadic values: exact in binary, whatever the order
    assert y(sol, {"x1": 1.5, "x2": -0.5}) == exact


def test_linear_keeps_relative_accuracy_at_extreme_magnitudes():
    sol = solver(model="linear", coefficients=[1e-12, 1e12])
    # four decimal inputs within 1/2 ulp each, two products and a sum: <= 4 eps of 5
    assert y(sol, {"x1": 3e12, "x2": 2e-12}) == pytest.approx(5.0, rel=4 * EPS)
    sol = solver(model="linear", coefficients=[1.0])
    assert y(sol, {"x1": 1.234567890123e-12}) == 1.234567890123e-12


@pytest.mark.parametrize("p, x, exact", [(2.0, 3.0, 9.0), (2.0, -3.0, 9.0), (0.5, 4.0, 2.0),
                                         (-1.0, 4.0, 0.25), (3.0, -2.0, -8.0),
                                         (1.7, 2.5, 2.5**1.7)])
def test_power(p, x, exact):
    sol = solver(model="power", p=p)
    assert sol.nominal() == {"x": 1.0}
    # pow is within 1 ulp in any libm, on both sides (2.5**1.7): 4 eps
    assert y(sol, {"x": x}) == pytest.approx(exact, rel=4 * EPS)


@pytest.mark.parametrize("p, x", [(0.5, -1.0), (-1.0, 0.0), (2.0, 1e200)])
def test_power_outside_its_domain_is_a_solver_error(p, x):
    with pytest.raises(SolverError):
        solver(model="power", p=p).run({"x": x})


def test_exponential_decay_outputs():
    sol = solver(model="exponential_decay")
    t = np.linspace(0.0, 10.0, 21)
    np.testing.assert_allclose(sol.outputs()["t"].values, t)
    assert sol.nominal() == {"alpha": 1.5, "beta": 0.15}
    # exp within 1 ulp; the rounding of beta t (<= 3 here) enters as |beta t| eps; a product;
    # both sides: 2 (3 + 2) eps = 10 eps
    np.testing.assert_allclose(y(sol, {"alpha": 2.0, "beta": 0.3}), 2.0 * np.exp(-0.3 * t),
                               rtol=10 * EPS)
    np.testing.assert_allclose(y(sol, {}), 1.5 * np.exp(-0.15 * t), rtol=10 * EPS)
    sol = solver(model="exponential_decay", t=[0.5, 2.0, 7.0])
    np.testing.assert_allclose(y(sol, {"alpha": 1.0, "beta": 0.1}),
                               np.exp(-0.1 * np.array([0.5, 2.0, 7.0])), rtol=10 * EPS)
    sol = solver(model="exponential_decay", t={"start": 1.0, "stop": 3.0, "num": 3})
    np.testing.assert_allclose(sol.outputs()["t"].values, [1.0, 2.0, 3.0])


def test_faulty():
    sol = solver(model="faulty", raise_above=1.0, nan_below=-1.0)
    assert y(sol, {"x": 0.5}) == 0.5
    assert math.isnan(y(sol, {"x": -2.0}))
    with pytest.raises(SolverError, match="exceeds"):
        sol.run({"x": 1.5})
    assert y(solver(model="faulty"), {"x": 1e300}) == 1e300   # no limits by default


# --------------------------------------------------------------------------------------------
# Exact moments by Monte Carlo (tests/data/uq_test_values.toml)
# --------------------------------------------------------------------------------------------

def test_exponential_decay_exact_mean_and_second_moment(reference):
    """alpha ~ N(1.5, 0.2), beta ~ U(0.1, 0.2): E[y] = 15 (e^-0.1t - e^-0.2t) / t and
    E[y^2] = 11.45 (e^-0.2t - e^-0.4t) / t, within 4 standard errors at every t."""
    assert "15 (exp(-0.1 t) - exp(-0.2 t)) / t" in reference["exponential_decay"]["note"]
    times = [0.5, 1.0, 2.0, 5.0, 10.0, 20.0]
    sol = solver(model="exponential_decay", t=times)
    space = InputSpace([
        RandomInput.from_spec({"name": "alpha", "distribution": "normal", "mean": 1.5,
                               "std": 0.2}),
        RandomInput.from_spec({"name": "beta", "distribution": "uniform", "lower": 0.1,
                               "upper": 0.2}),
    ])
    n = 8192
    x = space.from_unit_hypercube(unit_hypercube("random", n, 2, np.random.SeedSequence(11)))
    ys = np.array([y(sol, {"alpha": a, "beta": b}) for a, b in x])
    t = np.array(times)
    mean_exact = 15 * (np.exp(-0.1 * t) - np.exp(-0.2 * t)) / t
    second_exact = 11.45 * (np.exp(-0.2 * t) - np.exp(-0.4 * t)) / t
    se_mean = ys.std(axis=0, ddof=1) / math.sqrt(n)
    se_second = (ys**2).std(axis=0, ddof=1) / math.sqrt(n)
    assert np.all(np.abs(ys.mean(axis=0) - mean_exact) < 4 * se_mean)
    assert np.all(np.abs((ys**2).mean(axis=0) - second_exact) < 4 * se_second)
    # and the formula really is the mean: the errors are small in absolute terms too
    np.testing.assert_allclose(ys.mean(axis=0), mean_exact, rtol=0.01)


# --------------------------------------------------------------------------------------------
# Bar with random E
# --------------------------------------------------------------------------------------------

def test_random_E_bar_constant_E():
    F, A, L, E = 2.5e4, 2.0e-4, 0.3, 71.6e9
    sol = solver(model="random_E_bar", force=F, area=A, length=L, points=50)
    assert sol.nominal() == {"bar.E": 200.0e9}
    assert sol.parameter_units() == {"bar.E": "Pa"}
    # a sum of n equal positive terms is within n eps, plus a few products: (n + 4) eps
    assert y(sol, {"bar.E": E}, out="end_displacement") == pytest.approx(F * L / (A * E),
                                                                        rel=(50 + 4) * EPS)
    default = solver(model="random_E_bar")   # F = 1e4 N, A = 1e-4 m^2, L = 0.1 m, E = 200 GPa
    # 100 points by default: (100 + 4) eps, as above
    assert y(default, {}, out="end_displacement") == pytest.approx(1e4 * 0.1 / (1e-4 * 200e9),
                                                                   rel=(100 + 4) * EPS)


def test_random_E_bar_field_is_the_midpoint_integral():
    F, A, L, n = 1.0e4, 1.0e-4, 0.1, 200
    sol = solver(model="random_E_bar", force=F, area=A, length=L, points=n)
    x = sol.field_points("E")
    assert x.shape == (n, 1)
    # (i + 1/2) L / n: three roundings on each side
    np.testing.assert_allclose(x[:, 0], (np.arange(n) + 0.5) * L / n, rtol=6 * EPS)
    rng = np.random.default_rng(3)
    field = 200e9 * np.exp(0.2 * rng.standard_normal(n))
    # two sums of n positive terms (each within n eps) and a few products: 2 (n + 4) eps
    assert y(sol, {}, {"E": field}, out="end_displacement") == \
        pytest.approx(F / A * np.sum((L / n) / field), rel=2 * (n + 4) * EPS)
    # a smooth field: the midpoint rule converges to the exact integral (error ~ 1/n^2)
    E0 = 100e9
    smooth = E0 * (1 + x[:, 0] / L)
    exact = F / A * L / E0 * math.log(2.0)
    got = y(sol, {"bar.E": 1.0}, {"E": smooth}, out="end_displacement")   # field wins
    assert got == pytest.approx(exact, rel=1e-5)
    assert abs(got - exact) / exact < 1 / (12 * n**2) * 2   # midpoint error bound, f''/f <= 2


@pytest.mark.parametrize("bad", [0.0, -1e9, math.nan])
def test_random_E_bar_nonpositive_E_names_the_point(bad):
    sol = solver(model="random_E_bar", points=10)
    field = np.full(10, 100e9)
    field[7] = bad
    with pytest.raises(SolverError, match=r"point 7 \(x = 0\.075 m\)"):
        sol.run({}, {"E": field})
    with pytest.raises(SolverError, match="point 0"):
        sol.run({"bar.E": -5.0})


def test_random_E_bar_field_of_wrong_size():
    with pytest.raises(SolverError, match="10 values"):
        solver(model="random_E_bar", points=20).run({}, {"E": np.full(10, 1e9)})


def test_field_points_of_unknown_field():
    with pytest.raises(SceneError, match="no random field 'nu'"):
        solver(model="random_E_bar").field_points("nu")
    with pytest.raises(SceneError):
        solver(model="ishigami").field_points("E")


# --------------------------------------------------------------------------------------------
# Scene validation
# --------------------------------------------------------------------------------------------

BAD_SCENES = [
    ({}, "scene.model"),
    ({"model": "rosenbrock"}, "scene.model"),
    ({"model": ["ishigami"]}, "scene.model"),
    ({"model": "ishigami", "c": 1.0}, "scene.c"),
    ({"model": "ishigami", "coefficients": [1.0]}, "scene.coefficients"),
    ({"model": "ishigami", "a": "seven"}, "scene.a"),
    ({"model": "ishigami", "b": math.inf}, "scene.b"),
    ({"model": "ishigami", "a": True}, "scene.a"),
    ({"model": "ishigami", "delay": -1.0}, "scene.delay"),
    ({"model": "ishigami", "delay": "slow"}, "scene.delay"),
    ({"model": "sobol_g", "a": []}, "scene.a"),
    ({"model": "sobol_g", "a": [1.0, -1.0]}, "scene.a"),
    ({"model": "sobol_g", "a": 3.0}, "scene.a"),
    ({"model": "linear", "coefficients": ["a", 1.0]}, "scene.coefficients"),
    ({"model": "linear", "coefficients": [[1.0, 2.0], [3.0]]}, "scene.coefficients"),
    ({"model": "linear", "coefficients": [True, 1.0]}, "scene.coefficients"),
    ({"model": "linear", "coefficients": [1.0, math.nan]}, "scene.coefficients"),
    ({"model": "linear", "offset": None}, "scene.offset"),
    ({"model": "quadratic", "coefficients": [1.0, 2.0], "quadratic": [[1.0, 0.0]]},
     "scene.quadratic"),
    ({"model": "quadratic", "coefficients": [1.0, 2.0], "quadratic": [[1.0, 0.0], [0.0]]},
     "scene.quadratic"),
    ({"model": "quadratic", "coefficients": [1.0, 2.0],
      "quadratic": [["x", 0.0], [0.0, 1.0]]}, "scene.quadratic"),
    ({"model": "quadratic", "coefficients": [1.0, 2.0], "quadratic": 1.0}, "scene.quadratic"),
    ({"model": "power", "p": "2"}, "scene.p"),
    ({"model": "exponential_decay", "t": []}, "scene.t"),
    ({"model": "exponential_decay", "t": "0..10"}, "scene.t"),
    ({"model": "exponential_decay", "t": {"start": 0.0, "end": 5.0}}, "scene.t"),
    ({"model": "exponential_decay", "t": {"num": 0}}, "scene.t.num"),
    ({"model": "exponential_decay", "t": {"num": 2.5}}, "scene.t.num"),
    ({"model": "exponential_decay", "t": {"num": True}}, "scene.t.num"),
    ({"model": "exponential_decay", "t": {"start": "zero"}}, "scene.t.start"),
    ({"model": "exponential_decay", "t": {"stop": math.nan}}, "scene.t.stop"),
    ({"model": "random_E_bar", "area": 0.0}, "scene.area"),
    ({"model": "random_E_bar", "length": -0.1}, "scene.length"),
    ({"model": "random_E_bar", "points": 0}, "scene.points"),
    ({"model": "random_E_bar", "points": 10.0}, "scene.points"),
    ({"model": "random_E_bar", "force": "big"}, "scene.force"),
    ({"model": "faulty", "raise_above": "high"}, "scene.raise_above"),
    ({"model": "faulty", "nan_below": [0.0]}, "scene.nan_below"),
]


@pytest.mark.parametrize("scene, key", BAD_SCENES, ids=[f"{k}-{i}" for i, (_, k)
                                                        in enumerate(BAD_SCENES)])
def test_bad_scene_raises_scene_error_naming_the_key(scene, key):
    with pytest.raises(SceneError) as err:
        AnalyticSolver.from_scene(scene)
    assert err.value.key == key
    assert str(err.value).startswith(key + ": ")
    assert "\n" not in str(err.value)


def test_scene_must_be_a_table():
    with pytest.raises(SceneError) as err:
        AnalyticSolver.from_scene(["ishigami"])
    assert err.value.key == "scene"


def test_scene_accepts_numpy_lists():
    sol = AnalyticSolver.from_scene({"model": "linear", "coefficients": np.array([1.0, 2.0])})
    assert y(sol, {"x1": 1.0, "x2": 1.0}) == 3.0


# --------------------------------------------------------------------------------------------
# Output template
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("scene, out, dims, units, shape", [
    ({"model": "ishigami"}, "y", (), "", ()),
    ({"model": "sobol_g"}, "y", (), "", ()),
    ({"model": "linear"}, "y", (), "", ()),
    ({"model": "power"}, "y", (), "", ()),
    ({"model": "faulty"}, "y", (), "", ()),
    ({"model": "exponential_decay"}, "y", ("t",), "", (21,)),
    ({"model": "exponential_decay", "t": [1.0, 2.0]}, "y", ("t",), "", (2,)),
    ({"model": "random_E_bar"}, "end_displacement", (), "m", ()),
])
def test_outputs_template(scene, out, dims, units, shape):
    sol = AnalyticSolver.from_scene(scene)
    tmpl = sol.outputs()
    assert list(tmpl.data_vars) == [out]
    assert tmpl[out].dims == dims and tmpl[out].shape == shape
    assert tmpl[out].attrs["units"] == units
    assert np.all(np.isnan(tmpl[out].values))
    if dims:
        assert tmpl["t"].attrs["units"] == "s"
    # run returns the template's layout, and neither run nor edits touch the template
    result = sol.run({})
    assert result[out].dims == dims and result[out].attrs["units"] == units
    assert np.all(np.isfinite(result[out].values))
    tmpl[out].values[...] = 1.0
    again = sol.outputs()
    assert np.all(np.isnan(again[out].values))
    r1 = sol.run({}).copy(deep=True)
    sol.run(dict.fromkeys(sol.nominal(), 0.123))
    assert r1.identical(sol.run({}))


def test_delay_makes_runs_slow():
    sol = solver(model="linear", delay=0.02)
    start = time.perf_counter()
    sol.run({"x1": 1.0})
    assert time.perf_counter() - start >= 0.02


def test_failures_through_the_realization_runner():
    """SolverError, NaN output and an unexpected exception all make 'failed' realizations."""
    sol = solver(model="faulty", raise_above=1.0, nan_below=-1.0)
    space = InputSpace([RandomInput.from_spec({"name": "x", "distribution": "uniform",
                                               "lower": -2.0, "upper": 2.0})])
    from uqflow.methods.base import make_design
    design = make_design(space, np.array([[-1.5], [0.0], [0.5], [1.5]]))
    runs = evaluate_design(sol, design)
    assert list(runs["status"].values) == ["failed", "ok", "ok", "failed"]
    assert "non-finite output 'y'" in runs["message"].values[0]
    assert "SolverError" in runs["message"].values[3] and "exceeds" in runs["message"].values[3]
    np.testing.assert_array_equal(runs["y"].values[1:3], [0.0, 0.5])
    assert np.isnan(runs["y"].values[0]) and np.isnan(runs["y"].values[3])


@pytest.mark.parametrize("model", sorted(MODELS))
def test_every_output_has_a_label_a_reader_understands(model):
    # the report titles figures and tables with long_name (uqflow.layout.LONG_NAME)
    template = AnalyticSolver.from_scene({"model": model}).outputs()
    for name, var in template.data_vars.items():
        assert var.attrs["long_name"] and var.attrs["long_name"] != name, name


@pytest.mark.parametrize("model", sorted(MODELS))
def test_every_model_passes_the_conformance_kit(model):
    outcome = check_solver(AnalyticSolver, {"model": model},
                           bad_scenes={"scene.model": {"model": "no-such-model"}})
    assert all(v == "ok" for k, v in outcome.items() if k != "local_sensitivities")
    smooth = hasattr(MODELS[model], "derivatives")
    assert (outcome["local_sensitivities"] == "ok") == smooth
