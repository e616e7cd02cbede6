"""taylor-local: one run at the means with the solver's exact local derivatives, checked
against closed forms on the analytic models (for which "local" is exact)."""

import subprocess
import sys
import warnings

import numpy as np
import pytest

from solvers.analytic import AnalyticSolver
from uqflow.errors import AccuracyWarning, StudyError
from uqflow.execute import run_study
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import get_method
from uqflow.methods.taylor_local import CURVATURE_RATIO_WARNING
from uqflow.realization import evaluate_design
from uqflow.study import load_study

EPS = np.finfo(float).eps

C = np.array([1.0, -2.0])
Q = np.array([[1.5, 0.7], [-0.3, 2.0]])
MU = np.array([0.8, -1.3])
SIGMA = np.array([0.25, 0.4])


def _space(kind="normal", mean=MU, std=SIGMA, rho=0.0, names=None):
    names = names or [f"x{k + 1}" for k in range(len(mean))]
    inputs = [RandomInput.from_spec({"name": names[k], "distribution": kind,
                                     "mean": float(m), "std": float(s)})
              for k, (m, s) in enumerate(zip(mean, std))]
    n = len(inputs)
    corr = np.full((n, n), rho) + (1 - rho) * np.eye(n)
    return InputSpace(inputs, corr)


def _statistics(scene, space, **options):
    method = get_method("taylor-local")(**options)
    solver = AnalyticSolver.from_scene(scene)
    method.check_solver(solver, ["y"], space.names)
    design = method.plan(space, None, np.random.SeedSequence(0))
    runs = evaluate_design(solver, design, ["y"])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", AccuracyWarning)
        stats = method.analyze(design, runs)
    return stats, [str(w.message) for w in caught]


QUADRATIC = {"model": "quadratic", "coefficients": C.tolist(), "quadratic": Q.tolist()}


@pytest.mark.parametrize("rho", [0.0, 0.5, -0.9])
def test_quadratic_mean_is_exact_and_variance_is_j_sigma_j(rho):
    stats, _ = _statistics(QUADRATIC, _space(rho=rho))
    cov = np.outer(SIGMA, SIGMA) * np.array([[1, rho], [rho, 1]])
    # E[c.x + x'Qx] = c.mu + mu'Q mu + tr(Q Cov) for any distribution with these moments
    f0 = C @ MU + MU @ Q @ MU
    mean = f0 + np.trace(Q @ cov)
    jacobian = C + (Q + Q.T) @ MU
    var = jacobian @ cov @ jacobian
    y = stats["y"]
    # each estimate is a sum of < 10 products; rounding is a few ulps of the largest term
    terms = abs(f0) + np.abs(Q * cov).sum()
    assert abs(float(y.sel(statistic="mean")) - mean) <= 16 * EPS * terms
    assert abs(float(y.sel(statistic="variance")) - var) <= \
        16 * EPS * (np.abs(jacobian) @ np.abs(cov) @ np.abs(jacobian))
    assert float(y.sel(statistic="nominal")) == pytest.approx(f0, abs=16 * EPS * abs(f0))
    np.testing.assert_array_equal(stats["y_hessian"].values, Q + Q.T)


@pytest.mark.parametrize("rho", [0.0, 0.5, -0.9])
def test_second_order_variance_of_a_gaussian_quadratic_is_exact(rho):
    stats, _ = _statistics(QUADRATIC, _space(rho=rho), variance="second-order")
    cov = np.outer(SIGMA, SIGMA) * np.array([[1, rho], [rho, 1]])
    symmetric = 0.5 * (Q + Q.T)
    jacobian = C + 2 * symmetric @ MU
    # Var(c.x + x'Qx), x ~ N(mu, Cov): J'Cov J + 2 tr((Qs Cov)^2) (a textbook identity)
    exact = jacobian @ cov @ jacobian + 2 * np.trace(symmetric @ cov @ symmetric @ cov)
    # sums of < 20 terms each at most |J| Cov |J| + 2 tr(|Qs| Cov |Qs| Cov) in size
    scale = np.abs(jacobian) @ np.abs(cov) @ np.abs(jacobian) + \
        2 * np.trace(np.abs(symmetric) @ np.abs(cov) @ np.abs(symmetric) @ np.abs(cov))
    assert abs(float(stats["y"].sel(statistic="variance")) - exact) <= 32 * EPS * scale


@pytest.mark.numerics
def test_second_order_variance_of_independent_uniform_inputs_matches_taylor():
    space = _space(kind="uniform")
    local, _ = _statistics(QUADRATIC, space, variance="second-order")
    taylor = get_method("taylor")(variance="second-order")
    solver = AnalyticSolver.from_scene(QUADRATIC)
    design = taylor.plan(space, None, np.random.SeedSequence(0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        reference = taylor.analyze(design, evaluate_design(solver, design, ["y"]))
    # taylor's differences are exact for a quadratic up to rounding amplified by 1/h^2 with
    # h = 0.1 std: ~ 1e3 ulps of |f| relative to the variance's terms (~1e-13 here)
    np.testing.assert_allclose(local["y"].values, reference["y"].values, rtol=1e-10)


def test_correlated_non_normal_second_order_variance_is_refused():
    method = get_method("taylor-local")(variance="second-order")
    with pytest.raises(StudyError, match="correlated non-normal") as info:
        method.check(_space(kind="uniform", rho=0.5), None)
    assert info.value.key == "method.variance"


def _ishigami_moments(mu, sigma, a=7.0, b=0.1):
    """Exact mean and variance of Ishigami's Y for independent normal inputs."""
    (m1, m2, m3), (s1, s2, s3) = mu, sigma
    e_sin1 = np.sin(m1) * np.exp(-s1**2 / 2)
    e_sin1_sq = 0.5 * (1 - np.cos(2 * m1) * np.exp(-2 * s1**2))
    e_sin2_sq = 0.5 * (1 - np.cos(2 * m2) * np.exp(-2 * s2**2))
    e_sin2_4 = 3 / 8 - 0.5 * np.cos(2 * m2) * np.exp(-2 * s2**2) \
        + np.cos(4 * m2) * np.exp(-8 * s2**2) / 8
    e_x4 = m3**4 + 6 * m3**2 * s3**2 + 3 * s3**4
    e_x8 = m3**8 + 28 * m3**6 * s3**2 + 210 * m3**4 * s3**4 + 420 * m3**2 * s3**6 \
        + 105 * s3**8
    mean = e_sin1 * (1 + b * e_x4) + a * e_sin2_sq
    second = e_sin1_sq * (1 + 2 * b * e_x4 + b**2 * e_x8) \
        + 2 * a * e_sin1 * (1 + b * e_x4) * e_sin2_sq + a**2 * e_sin2_4
    return mean, second - mean**2


def test_ishigami_moments_converge_at_the_expansion_order():
    mu = np.array([0.6, 0.4, 1.3])
    errors = []
    for cv in (0.04, 0.02, 0.01):
        sigma = cv * mu
        stats, _ = _statistics({"model": "ishigami"}, _space(mean=mu, std=sigma))
        mean, var = _ishigami_moments(mu, sigma)
        y = stats["y"]
        errors.append((float(y.sel(statistic="mean")) - mean,
                       float(y.sel(statistic="variance")) - var))
    errors = np.array(errors)
    # For normal inputs the odd terms vanish: the mean errs by O(s^4), the first-order
    # variance by O(s^4); halving s divides both by 16, up to the next term's relative
    # O(s^2) share (s <= 0.05 here, derivatives of order 1-10: a few per cent at most).
    # (An error of order s^2, e.g. a mean without its curvature term, would give 4.)
    np.testing.assert_allclose(errors[:-1] / errors[1:], 16.0, rtol=0.1)


def test_vanishing_cv_gives_the_nominal_value_and_no_nan():
    mu = np.array([0.6, 0.4, 1.3])
    f0 = np.sin(0.6) + 7.0 * np.sin(0.4) ** 2 + 0.1 * 1.3**4 * np.sin(0.6)
    for std in (np.zeros(3), 1e-12 * mu):
        stats, caught = _statistics({"model": "ishigami"}, _space(mean=mu, std=std))
        values = stats["y"].values
        assert np.all(np.isfinite(values)) and np.isfinite(stats["y_curvature_ratio"].values)
        # the curvature term is ~ H s^2 <= 1e-22: the mean is f(mu) to a few ulps
        assert values[0] == pytest.approx(f0, rel=4 * EPS)
        # first-order variance sum_k (df/dx_k s_k)^2 of Ishigami (a = 7, b = 0.1) at mu:
        # a few roundings of each term, all of one sign
        x1, x2, x3 = mu
        gradient = np.array([np.cos(x1) * (1 + 0.1 * x3**4), 7.0 * np.sin(2 * x2),
                             0.4 * x3**3 * np.sin(x1)])
        assert values[1] == pytest.approx(float(np.sum((gradient * std) ** 2)), rel=16 * EPS,
                                          abs=0.0)
        assert caught == []


def test_curvature_warning_fires_where_the_first_order_variance_misses_the_quadratic():
    # y = x^2 at mu = 1, std s: ratio q = s^2 / (2 s) = s / 2; exact Var / first-order
    # Var = 1 + 2 q^2 (the criterion's justification)
    scene = {"model": "quadratic", "coefficients": [0.0], "quadratic": [[1.0]]}
    for s, fires in ((0.5, False), (0.7, True)):
        space = _space(mean=[1.0], std=[s])
        first, caught = _statistics(scene, space, cv_warning=10.0)
        second, _ = _statistics(scene, space, variance="second-order", cv_warning=10.0)
        q = float(first["y_curvature_ratio"])
        assert q == pytest.approx(s / 2, rel=4 * EPS)  # two roundings
        ratio = float(second["y"].sel(statistic="variance") / first["y"].sel(
            statistic="variance"))
        assert ratio == pytest.approx(1 + 2 * q**2, rel=16 * EPS)  # a handful of roundings
        assert (q > CURVATURE_RATIO_WARNING) == fires
        assert any("curvature term of the mean" in m for m in caught) == fires
        assert ("curvature term" in first.attrs["warnings"]) == fires


def test_statistics_layout():
    space = _space(mean=[1.5, 0.15], std=[0.1, 0.01], names=["alpha", "beta"])
    stats, _ = _statistics({"model": "exponential_decay", "t": {"num": 5}}, space)
    assert list(stats["statistic"].values) == ["mean", "variance", "std", "nominal"]
    assert stats["y"].dims == ("statistic", "t")
    assert stats["y_gradient"].dims == ("parameter", "t")
    assert stats["y_hessian"].dims == ("parameter", "parameter_j", "t")
    assert stats["y_curvature_ratio"].dims == ("t",)
    assert stats.attrs["solver_runs"] == 1 and stats.attrs["failed_runs"] == 0
    assert stats.attrs["method"] == "taylor-local"
    assert "frozen state" in stats.attrs["assumption"]
    t = stats["t"].values
    # dy/dalpha = e^(-beta t): one exp and a product, 2 ulps
    np.testing.assert_allclose(stats["y_gradient"].sel(parameter="alpha").values,
                               np.exp(-0.15 * t), rtol=2 * EPS)


# --------------------------------------------------------------- study files and failures

STUDY = """\
name = "{name}"
solver = "{solver}"
scene = {scene}
{inputs}
[method]
kind = "taylor-local"

[execution]
workers = 0
max_failure_fraction = 1.0

[output]
path = "{name}.nc"
figures = false
"""


def _study(tmp_path, scene, inputs, solver="analytic", name="s"):
    path = tmp_path / f"{name}.toml"
    path.write_text(STUDY.format(name=name, solver=solver, scene=scene, inputs=inputs))
    return path


def _normal(name, mean=0.5, std=0.05):
    return f'\n[[inputs]]\nname = "{name}"\ndistribution = "normal"\nmean = {mean}\n' \
           f'std = {std}\n'


def test_a_model_without_local_derivatives_is_a_study_error_naming_taylor(tmp_path):
    path = _study(tmp_path, '{ model = "sobol_g", a = [0.0, 1.0] }', _normal("x1"))
    with pytest.raises(StudyError) as info:
        load_study(path)
    assert info.value.key == "method.kind"
    assert 'use kind = "taylor"' in str(info.value)
    assert str(info.value).startswith(f"{path}: method.kind: solver 'analytic/sobol_g' has no")


def test_the_gamut_bar_has_no_local_derivatives(tmp_path):
    from uqflow.solver import get_solver
    scene = '{ material = "M1", local_bonds = 20, grid = "uniform", loading = "monotonic" }'
    nominal = get_solver("gamut_bar").from_scene(
        {"material": "M1", "local_bonds": 20, "grid": "uniform", "loading": "monotonic"}
    ).nominal()
    name, value = next(iter(nominal.items()))
    path = _study(tmp_path, scene, _normal(name, value, abs(value) * 0.05 or 1.0),
                  solver="gamut_bar")
    with pytest.raises(StudyError, match='has no local sensitivities.*use kind = "taylor"'):
        load_study(path)


class _PartlyDifferentiable:
    """Duck-typed solver: derivatives of 'stress' in 'A' only, none of 'plastic_strain'."""

    def local_sensitivities(self):
        return {"stress": ("A",)}

    name = "mpm-like"

    def describe(self):
        return "mpm-like: 120x70 cells, materials steel, tnt, water"


def test_an_output_or_input_without_a_derivative_names_taylor():
    method = get_method("taylor-local")()
    with pytest.raises(StudyError, match=r"output 'plastic_strain' has no local derivative in "
                                         r"solver 'mpm-like' .*use kind = \"taylor\"") as info:
        method.check_solver(_PartlyDifferentiable(), ["stress", "plastic_strain"], ["A"])
    assert info.value.key == "outputs"
    with pytest.raises(StudyError, match=r"'stress' has no local derivative with respect to "
                                         r"input 'n' .*use kind = \"taylor\""):
        method.check_solver(_PartlyDifferentiable(), ["stress"], ["A", "n"])
    method.check_solver(_PartlyDifferentiable(), ["stress"], ["A"])  # fine


def test_validate_exits_2_with_the_one_line_error(tmp_path):
    path = _study(tmp_path, '{ model = "sobol_g", a = [0.0, 1.0] }', _normal("x1"))
    done = subprocess.run([sys.executable, "-m", "uqflow.cli", "validate", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "method.kind" in lines[0] and 'kind = "taylor"' in lines[0]


def test_a_study_runs_once_and_a_non_finite_hessian_fails_the_realization(tmp_path):
    ok = run_study(load_study(_study(tmp_path, '{ model = "power", p = 1.5 }',
                                     _normal("x", 2.0, 0.1), name="ok")), show_progress=False)
    assert ok.runs.sizes["realization"] == 1 and ok.statistics.attrs["solver_runs"] == 1
    # d2(x^1.5)/dx2 = 0.75 x^-0.5 is infinite at the mean x = 0: that run fails, the study
    # finishes (max_failure_fraction = 1) with NaN estimates and says why
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        bad = run_study(load_study(_study(tmp_path, '{ model = "power", p = 1.5 }',
                                          _normal("x", 0.0, 0.1), name="bad")),
                        show_progress=False)
    assert bad.runs["status"].values.tolist() == ["failed"]
    assert np.isnan(bad.statistics["y"].values).all()
    assert any("non-finite derivative 'y__hessian'" in w for w in bad.warnings)


# --------------------------------------------------------------- the models' own derivatives

DIFFERENTIABLE = [
    ({"model": "ishigami"}, {"x1": 0.6, "x2": 0.4, "x3": 1.3}),
    (QUADRATIC, {"x1": 0.8, "x2": -1.3}),
    ({"model": "power", "p": 2.5}, {"x": 1.7}),
    ({"model": "exponential_decay", "t": {"start": 0.0, "stop": 2.0, "num": 3}},
     {"alpha": 1.5, "beta": 0.4}),
    ({"model": "faulty"}, {"x": 0.3}),
]


@pytest.mark.parametrize("scene, point", DIFFERENTIABLE, ids=lambda v: str(v)[:30])
def test_model_derivatives_match_central_differences(scene, point):
    """Each model's gradient against central differences of its values, its Hessian against
    central differences of its gradient: the closed forms the method tests rely on."""
    solver = AnalyticSolver.from_scene(scene)
    names = list(point)
    assert set(solver.local_sensitivities()["y"]) == set(names)

    def evaluate(p):
        ds = solver.run_with_sensitivities(p, wrt=names, outputs=["y"])
        return ds["y"].values, ds["y__gradient"].values, ds["y__hessian"].values

    _, gradient, hessian = evaluate(point)
    h = 1e-5
    for k, name in enumerate(names):
        plus, minus = (evaluate({**point, name: point[name] + s * h}) for s in (1, -1))
        # truncation h^2 |f'''| / 6 (third and fourth derivatives < 60 here) plus
        # rounding eps |f| / h (|f| < 10): below 1e-9 + 2e-10
        np.testing.assert_allclose(gradient[..., k], (plus[0] - minus[0]) / (2 * h),
                                   rtol=0, atol=2e-9)
        # the same bound one derivative up: h^2 |f''''| / 6 + eps |f'| / h < 2e-9
        np.testing.assert_allclose(hessian[..., k, :], (plus[1] - minus[1]) / (2 * h),
                                   rtol=0, atol=2e-9)
    np.testing.assert_array_equal(hessian, np.swapaxes(hessian, -1, -2))


def test_which_analytic_models_have_local_derivatives():
    """docs/study-files.md: every analytic model but sobol_g and random_E_bar."""
    from solvers.analytic import MODELS
    having = {name for name in MODELS
              if AnalyticSolver.from_scene({"model": name}).local_sensitivities()}
    assert having == set(MODELS) - {"sobol_g", "random_E_bar"}


def _thin_plate_study(tmp_path, outputs):
    """The shipped JC thin-plate study (5 JC inputs, the small MPM scene) with taylor-local."""
    from pathlib import Path
    studies = Path(__file__).resolve().parents[2] / "studies"
    text = (studies / "smpm_jc_thin_plate.toml").read_text()
    head, _ = text.split("[method]", 1)
    head = head.replace('scene = "scenes/', f'scene = "{studies}/scenes/')
    head = "\n".join(f"outputs = {outputs}" if line.startswith("outputs =") else line
                     for line in head.splitlines())
    path = tmp_path / "thin.toml"
    path.write_text(head + '\n[method]\nkind = "taylor-local"\n\n[execution]\nworkers = 0\n'
                    '\n[output]\npath = "thin.nc"\n')
    return path


def test_the_mpm_outputs_with_and_without_local_derivatives(tmp_path):
    study = load_study(_thin_plate_study(tmp_path, '["flow_stress", "S11", "S22"]'))
    assert study.method.name == "taylor-local" and len(study.space.names) == 5
    with pytest.raises(StudyError) as info:
        load_study(_thin_plate_study(tmp_path, '["flow_stress", "plastic_strain"]'))
    assert info.value.key == "outputs"
    assert "output 'plastic_strain' has no local derivative in solver 'mpm'" in str(info.value)
    assert 'use kind = "taylor"' in str(info.value)
