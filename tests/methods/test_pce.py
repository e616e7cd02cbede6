"""The pce method: exact polynomials, Ishigami, the LOO error, sparse regression, warnings."""

import math

import chaospy
import numpy as np
import pytest
from pydantic import ValidationError

from solvers.analytic import AnalyticSolver
from uqflow.errors import StudyError
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import get_method
from uqflow.methods.pce_fit import (hermite_matrix, least_squares, multi_indices,
                                    orthogonal_matching_pursuit)
from uqflow.realization import evaluate_design

EPS = np.finfo(float).eps


def normal(name, mean=0.0, std=1.0):
    return RandomInput.from_spec({"name": name, "distribution": "normal", "mean": mean,
                                  "std": std})


def uniform(name, lower, upper):
    return RandomInput.from_spec({"name": name, "distribution": "uniform", "lower": lower,
                                  "upper": upper})


def study(scene, space, seed=0, **options):
    """Plan, run in-process and analyze: (design, runs, statistics)."""
    method = get_method("pce")(**options)
    design = method.plan(space, None, np.random.SeedSequence(seed))
    runs = evaluate_design(AnalyticSolver.from_scene(scene), design)
    return design, runs, method.analyze(design, runs)


def condition(design, order):
    """cond(Ψ) of the design's order-``order`` regression matrix: the round-off bound of an
    exact fit is cond(Ψ) · eps relative to the coefficients."""
    z = design["standard_normal"].values
    return np.linalg.cond(hermite_matrix(z, multi_indices(order, z.shape[1])))


def test_registered_with_defaults():
    opts = get_method("pce")().options
    assert (opts.order, opts.max_order, opts.samples, opts.rule, opts.regression,
            opts.basis, opts.loo_warning) == ("loo", 5, None, "sobol", "auto", "hermite", 1e-2)


@pytest.mark.numerics
def test_hermite_products_equal_chaospy_expansion():
    """The fast products are chaospy's d-variate orthonormal expansion, term for term."""
    rng = np.random.default_rng(1)
    z = rng.standard_normal((7, 2))
    joint = chaospy.J(chaospy.Normal(0, 1), chaospy.Normal(0, 1))
    expansion = chaospy.generate_expansion(4, joint, normed=True)
    full = np.asarray(expansion(*z.T)).T                            # (n, P)
    # Each chaospy polynomial is identified by its leading (highest-degree) exponent.
    leading = [tuple(poly.exponents[np.argmax(np.where(np.asarray(poly.coefficients) != 0,
                                                       poly.exponents.astype(int).sum(axis=1), -1))])
               for poly in expansion]
    ours = hermite_matrix(z, multi_indices(4, 2))
    column = {tuple(alpha): k for k, alpha in enumerate(multi_indices(4, 2))}
    reordered = ours[:, [column[a] for a in leading]]
    # Both evaluate degree-4 polynomials of |z| < 4 whose terms reach ~1e2: rounding of
    # 1e2 · a few eps.
    np.testing.assert_allclose(reordered, full, rtol=0, atol=1e3 * EPS)  # 1e2 terms x eps


def test_quadratic_in_gaussian_inputs_is_exact_at_order_two_and_three():
    c, q = np.array([1.0, -2.0, 0.5]), np.array([[0.3, 0.1, 0.0], [0.1, 0.0, -0.2],
                                                 [0.0, -0.2, 0.4]])
    m, s = np.array([0.5, -1.0, 2.0]), np.array([0.7, 1.3, 0.4])
    space = InputSpace([normal(f"x{i + 1}", m[i], s[i]) for i in range(3)])
    scene = {"model": "quadratic", "coefficients": c.tolist(), "offset": 1.5,
             "quadratic": q.tolist()}
    cov = np.diag(s**2)
    exact_mean = 1.5 + c @ m + m @ q @ m + np.trace(q @ cov)
    b = c + 2 * q @ m
    exact_var = b @ cov @ b + 2 * np.trace(q @ cov @ q @ cov)
    for order in (2, 3):
        design, _, stats = study(scene, space, order=order)
        kappa = condition(design, order)
        # Zero truncation error: least squares by QR is exact to cond(Ψ) · eps relative to
        # the coefficients, whose size is that of the std; x 10 for the sums over terms.
        bound = 10 * kappa * EPS
        assert stats["y"].sel(statistic="mean") == pytest.approx(
            exact_mean, abs=bound * math.sqrt(exact_var))  # bound = 10 cond(Psi) eps
        assert stats["y"].sel(statistic="variance") == pytest.approx(
            exact_var, rel=2 * bound)  # variance: 2 x the coefficients' relative error
        assert int(stats["y_order"]) == order
        assert float(stats["y_loo_error"]) < bound**2 * 1e2  # round-off residuals only
        assert stats.attrs["warnings"] == ""


def test_loo_chooses_the_polynomial_degree():
    """x³ of a normal x: orders 1 and 2 leave a truncation error, 3..6 fit to round-off, and
    the lowest exact order is kept."""
    space = InputSpace([normal("x", 1.0, 0.3)])
    design, _, stats = study({"model": "power", "p": 3.0}, space, max_order=6)
    loo = stats["y_loo_by_order"].values
    assert int(stats["y_order"]) == 3
    assert loo[0] > 1e-2 and loo[1] > 1e-4           # x³ is not linear, nor quadratic
    # An exact fit leaves residuals of rounding only, ~ cond(Psi) eps |y|: its relative LOO
    # error is ~ (cond eps)^2, below 1e-20 (the code's ROUND_OFF_LOO) while cond < 4e5
    # (Hermite bases of order <= 6 in one normal variable: cond ~ 1e2-1e3 on 64 points)
    assert np.all(loo[2:] < 1e-20)
    exact_mean = 1.0 + 3 * 0.3**2
    exact_var = 9 * 0.3**2 + 36 * 0.3**4 + 15 * 0.3**6
    bound = 10 * condition(design, 3) * EPS            # 10 cond(Psi) eps, as above
    assert stats["y"].sel(statistic="mean") == pytest.approx(exact_mean, rel=bound)
    assert stats["y"].sel(statistic="variance") == pytest.approx(exact_var, rel=2 * bound)
    # Orders 3..6 differ only in round-off, which may favour any of them on a given design
    # (without the ROUND_OFF_LOO tie rule seeds 3 and 6 pick 4 and 6): every seed keeps 3.
    for seed in range(1, 8):
        assert int(study({"model": "power", "p": 3.0}, space, seed=seed,
                         max_order=6)[2]["y_order"]) == 3


def least_squares_error(a, b, coef, backward):
    """First-order bounds (Wedin; Higham, Accuracy and Stability, Thm 20.1) on the solution of
    min ‖b − a x‖ computed by a method that is backward stable with the 2-norm backward error
    ``backward`` (Householder QR, SVD): (‖Δx‖, ‖Δ(b − a x̂)‖) per column of b, the residual
    recomputed from the original data. Δx = a⁺(Δb − Δa x) + (aᵀa)⁻¹Δaᵀr: the κ² term is the
    residual's; the residual itself moves by (I − H)(Δb − Δa x) − a⁺ᵀΔaᵀr, κ·eps, no κ²."""
    s = np.linalg.svd(a, compute_uv=False)
    norm_a, norm_pinv = s[0], 1.0 / s[-1]
    norm_b, norm_x = np.linalg.norm(b, axis=0), np.linalg.norm(coef, axis=0)
    norm_r = np.linalg.norm(b - a @ coef, axis=0)
    dx = backward * (norm_pinv * (norm_b + norm_a * norm_x) + norm_pinv**2 * norm_a * norm_r)
    dr = backward * (2 * norm_b + 2 * norm_a * norm_x + norm_a * norm_pinv * norm_r)
    return dx, dr


def mean_square_error(e, de, n):
    """|Δ mean(e²)| for |Δe_i| ≤ de_i, the n-term mean rounded to n eps."""
    return np.mean(2 * np.abs(e) * de + de**2, axis=0) + n * EPS * np.mean(e**2, axis=0)


@pytest.mark.numerics
def test_loo_closed_form_equals_brute_force():
    rng = np.random.default_rng(3)
    z = rng.standard_normal((24, 2))
    psi = hermite_matrix(z, multi_indices(3, 2))
    y = np.column_stack([np.sin(z[:, 0]) + z[:, 1] ** 2, np.exp(0.3 * z[:, 1])])
    fit = least_squares(psi, y)
    n, p = psi.shape
    # Householder QR (closed form) and SVD (lstsq) are backward stable: Higham's γ̃_{np}
    # columnwise (c = 2), √p to the 2-norm, on any LAPACK/BLAS kernel, any summation order
    backward = n * p**1.5 * EPS
    # the products y − ψc, any order, FMA or not: (p + 1) eps (|y| + |ψ||c|) per entry
    brute, brute_error = np.empty_like(y), np.empty_like(y)
    for i in range(n):
        keep = np.arange(n) != i
        coef = np.linalg.lstsq(psi[keep], y[keep], rcond=None)[0]
        brute[i] = y[i] - psi[i] @ coef
        # a prediction at the left-out row: ‖ψ_i‖‖Δc‖, which holds the κ²‖r‖ term
        d_coef, _ = least_squares_error(psi[keep], y[keep], coef, backward)
        brute_error[i] = (np.linalg.norm(psi[i]) * d_coef
                          + (p + 1) * EPS * (np.abs(y[i]) + np.abs(psi[i]) @ np.abs(coef)))
    # closed form e_i = r_i/(1 − h_ii): the residual moves by dr (κ·eps‖y‖, no κ²); h_ii
    # = ‖Q_i‖² by ‖H(ψ + Δψ) − H(ψ)‖ ≤ κ·backward, Q's loss of orthonormality 2·backward and
    # its p-term sum; both divided by 1 − h_ii (0.0037 at the worst row here: a factor 270)
    kappa = np.linalg.cond(psi)
    _, d_res = least_squares_error(psi, y, fit.coefficients, backward)
    d_res = d_res + (p + 1) * EPS * (np.abs(y) + np.abs(psi) @ np.abs(fit.coefficients))
    q, _ = np.linalg.qr(psi)
    free = (1.0 - np.sum(q * q, axis=1))[:, None]
    d_leverage = (kappa + 3) * backward + p * EPS
    loo = fit.residual / free
    loo_error = d_res / free + np.abs(loo) * (d_leverage / free + EPS)
    bound = mean_square_error(loo, loo_error, n) + mean_square_error(brute, brute_error, n)
    # Two backward-stable solutions of the same problem, each within its first-order
    # perturbation bound above (3.6e-8 and 5.9e-8 relative here, the data's ‖y‖/‖r‖ ≈ 600 and
    # 1/(1 − h_ii) ≈ 270 included); what is compared is their difference.
    assert (np.abs(fit.loo_mse - np.mean(brute**2, axis=0)) <= bound).all()


@pytest.mark.numerics
def test_sparse_regression_recovers_a_sparse_polynomial_with_fewer_runs_than_terms():
    """y = 1.5 + 2 x1 - x2 + 0.3 x3 x4 in six normal inputs: the order-3 basis has 84 terms,
    the design 40 runs; OMP keeps the 4 Hermite terms that represent y and no others."""
    space = InputSpace([normal(f"x{i + 1}") for i in range(6)])
    q = np.zeros((6, 6))
    q[2, 3] = 0.3
    scene = {"model": "quadratic", "coefficients": [2.0, -1.0, 0, 0, 0, 0], "offset": 1.5,
             "quadratic": q.tolist()}
    design, _, stats = study(scene, space, order=3, samples=40)
    assert int(stats["y_terms"]) == 4                 # constant, x1, x2, x3 x4
    kept = {tuple(r) for r in stats["y_multi_index"].values}
    assert kept == {(0,) * 6, (1, 0, 0, 0, 0, 0), (0, 1, 0, 0, 0, 0), (0, 0, 1, 1, 0, 0)}
    bound = 1e3 * EPS   # the kept 4 columns of 40 normal rows: cond ~ 10, x 10 for the sums
    assert stats["y"].sel(statistic="mean") == pytest.approx(1.5, abs=bound)
    assert stats["y"].sel(statistic="variance") == pytest.approx(4 + 1 + 0.09, rel=bound)


def test_ishigami_with_the_askey_basis(reference):
    """Legendre polynomials of the uniform inputs: moments and indices within the error the
    LOO estimate bounds (see the comment at the tolerances)."""
    ref = reference["ishigami"]
    space = InputSpace([uniform(f"x{i}", -math.pi, math.pi) for i in (1, 2, 3)])
    design, _, stats = study({"model": "ishigami"}, space, basis="askey", max_order=10)
    eps_loo = float(stats["y_loo_error"])
    n, terms = design.sizes["realization"], int(stats["y_terms"])
    assert eps_loo < 1e-3
    # The truncated remainder (variance fraction ~ eps_loo) aliases onto the fitted
    # coefficients: their error vector has norm² ≈ eps_loo V P / n (least squares on n
    # random-like points); 3 of those for the mean, and for every variance fraction
    # (variance, indices) 3 sqrt(eps_loo P/n) twice (cross term) plus the missing eps_loo.
    delta = 3 * math.sqrt(eps_loo * terms / n)
    assert stats["y"].sel(statistic="mean") == pytest.approx(
        ref["mean"], abs=delta * math.sqrt(ref["variance"]))
    assert stats["y"].sel(statistic="variance") == pytest.approx(
        ref["variance"], rel=2 * delta + eps_loo)
    sobol = stats["y_sobol"]
    rounding = 5e-5                                   # the reference's 4 printed digits
    np.testing.assert_allclose(sobol.sel(sobol_index="S1"), ref["S"],
                               atol=2 * delta + eps_loo + rounding)
    np.testing.assert_allclose(sobol.sel(sobol_index="ST"), ref["ST"],
                               atol=2 * delta + eps_loo + rounding)
    assert stats.attrs["warnings"] == ""


def test_hermite_basis_on_uniform_inputs_warns_and_points_to_askey():
    space = InputSpace([uniform(f"x{i}", -math.pi, math.pi) for i in (1, 2, 3)])
    _, _, stats = study({"model": "ishigami"}, space, max_order=4)
    assert float(stats["y_loo_error"]) > 1e-2
    assert "y: LOO error" in stats.attrs["warnings"]
    assert 'basis = "askey"' in stats.attrs["warnings"]


@pytest.mark.parametrize("basis", ["hermite", "askey"])
def test_warning_fires_on_a_kink_and_not_on_a_smooth_output(basis):
    """|4 x - 2| (Sobol' g with a = 0) has a kink at x = 1/2: no polynomial fits it to 1 %."""
    kinked = InputSpace([uniform("x1", 0.0, 1.0)])
    _, _, stats = study({"model": "sobol_g", "a": [0.0]}, kinked, basis=basis, max_order=6)
    assert float(stats["y_loo_error"]) > 1e-2
    assert "y: LOO error" in stats.attrs["warnings"]
    assert "not smooth" in stats.attrs["warnings"]
    # Smooth in the germs: normal inputs for Hermite, uniform ones for Legendre (uniform
    # inputs are Φ(z), which Hermite polynomials fit only slowly: the test above).
    smooth = InputSpace([normal("alpha", 1.5, 0.2), normal("beta", 0.15, 0.02)]) \
        if basis == "hermite" else InputSpace([uniform("alpha", 1.0, 2.0),
                                               uniform("beta", 0.1, 0.2)])
    _, _, stats = study({"model": "exponential_decay"}, smooth, basis=basis, max_order=6)
    assert stats["y_loo_error"].dims == ("t",)
    assert float(stats["y_loo_error"].max()) < 1e-6
    assert stats.attrs["warnings"] == ""


def test_warning_names_the_point_of_a_series():
    """y(t) = alpha e^(-beta t), beta ~ U(0, 1), at order 1: the late times are far from
    linear in beta. The warning names the worst point by its coordinate, and its std's
    share of the output's largest."""
    space = InputSpace([normal("alpha", 1.5, 0.2), uniform("beta", 0.0, 1.0)])
    _, _, stats = study({"model": "exponential_decay"}, space, order=1)
    loo = stats["y_loo_error"]
    at = int(np.argmax(loo.values))
    assert f"t = {float(loo['t'][at]):.4g}" in stats.attrs["warnings"]
    variance = stats["y"].sel(statistic="variance").values
    share = math.sqrt(variance[at] / variance.max())
    assert share < 1
    assert f"where its std is {100 * share:.2g} % of its largest" in stats.attrs["warnings"]


def test_correlated_linear_model_is_exact():
    """y = 2 x1 - x2, x ~ N((1, 3), diag(1, 2)² with ρ = 0.5): mean -1, variance
    4 + 4 - 2·2·1·2·0.5 = 4."""
    space = InputSpace([normal("x1", 1.0, 1.0), normal("x2", 3.0, 2.0)],
                       np.array([[1.0, 0.5], [0.5, 1.0]]))
    design, _, stats = study({"model": "linear", "coefficients": [2.0, -1.0]}, space,
                             order=1)
    bound = 10 * condition(design, 1) * EPS            # 10 cond(Psi) eps, exact fit
    assert stats["y"].sel(statistic="mean") == pytest.approx(-1.0, abs=2 * bound)
    assert stats["y"].sel(statistic="variance") == pytest.approx(4.0, rel=2 * bound)
    assert "correlated inputs" in stats.attrs["warnings"]


@pytest.mark.parametrize("cv", [0.0, 1e-8, 0.3])
def test_coefficient_of_variation_from_zero_to_large(cv):
    """x³ with x normal, mean 1, C.V. v: mean 1 + 3v², variance 9v² + 36v⁴ + 15v⁶."""
    design, _, stats = study({"model": "power", "p": 3.0}, InputSpace([normal("x", 1.0, cv)]),
                             order=3, samples=16)
    exact_mean, exact_var = 1 + 3 * cv**2, 9 * cv**2 + 36 * cv**4 + 15 * cv**6
    kappa = condition(design, 3) if cv else 1.0
    # Exact fit: 10 cond(Psi) eps relative to the outputs' size, which is 1 / (3 v) times
    # their spread at small C.V. (y = 1 + 3 v z + ...: its rounding is eps, its spread 3 v).
    scale = 1 + 1 / (3 * cv) if cv else 1.0
    bound = 10 * kappa * EPS * scale                   # 10 cond(Psi) eps |y| / std(y)
    assert stats["y"].sel(statistic="mean") == pytest.approx(exact_mean, rel=bound)
    assert stats["y"].sel(statistic="variance") == pytest.approx(exact_var, rel=2 * bound,
                                                                 abs=0.0)
    if cv == 0:
        assert float(stats["y"].sel(statistic="variance")) == 0.0
        assert np.all(np.isnan(stats["y_sobol"].values))


def test_failed_realizations_are_dropped_and_said():
    space = InputSpace([normal("x", 0.0, 1.0)])
    design, runs, stats = study({"model": "faulty", "raise_above": 0.5}, space, order=1,
                                samples=32)
    failed = int((runs["status"].values == "failed").sum())
    assert failed > 0
    assert stats.attrs["failed_runs"] == failed
    assert f"{failed} of {design.sizes['realization']} realizations failed" in \
        stats.attrs["warnings"]
    assert "no longer a balanced sobol set" in stats.attrs["warnings"]
    # y = x on the surviving x <= 0.5: the fit is exact there, so the mean is the
    # regression's intercept at z = 0, i.e. exactly 0 to round-off.
    # Exact fit of a line by QR: intercept round-off ~ cond(Psi) eps <= 1e4 eps = 2e-12.
    assert stats["y"].sel(statistic="mean") == pytest.approx(0.0, abs=2e-12)


@pytest.mark.parametrize("options, match", [
    ({"order": 2.0}, "integer"), ({"order": "2"}, "loo"), ({"order": True}, "boolean"),
    ({"order": 0}, "1..20"), ({"order": 21}, "1..20"), ({"max_order": 21}, "20"),
    ({"order": 2, "max_order": 3}, "max_order"), ({"samples": 0}, "1"),
    ({"rule": "grid"}, "sobol"), ({"regression": "lasso"}, "omp"), ({"loo_warning": 0}, "0"),
    ({"basis": "legendre"}, "askey"), ({"degree": 2}, "degree"),
])
def test_options_are_strict(options, match):
    with pytest.raises(ValidationError, match=match):
        get_method("pce")(**options)


def test_too_few_samples_for_least_squares_names_the_minimum():
    space = InputSpace([normal(f"x{i}") for i in range(3)])
    method = get_method("pce")(order=3, samples=30, regression="least-squares")
    with pytest.raises(StudyError, match=r"method\.samples: .*at least 40 "):
        method.check(space, None)
    get_method("pce")(order=3, samples=40, regression="least-squares").check(space, None)
    get_method("pce")(order=3, samples=30).check(space, None)   # auto: sparse regression
    with pytest.raises(StudyError, match=r"method\.samples: .*at least 8"):
        get_method("pce")(order=1, samples=7).check(space, None)


def test_askey_basis_refuses_correlated_inputs_and_big_bases():
    space = InputSpace([normal("x1"), normal("x2")], np.array([[1.0, 0.2], [0.2, 1.0]]))
    with pytest.raises(StudyError, match=r"method\.basis"):
        get_method("pce")(basis="askey").check(space, None)
    wide = InputSpace([normal(f"x{i}") for i in range(20)])
    with pytest.raises(StudyError, match=r"method\.order: .*basis terms"):
        get_method("pce")(order=6).check(wide, None)


def test_summary_table_shows_order_terms_and_loo_error():
    import xarray as xr

    from uqflow.report import summary_table
    space = InputSpace([normal("x", 1.0, 0.3)])
    _, runs, stats = study({"model": "power", "p": 3.0}, space, max_order=4)
    tree = xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "pce-test"}),
                                  "/runs": runs, "/statistics": stats})
    text = summary_table(tree)
    loo = float(stats["y_loo_error"])
    assert f"order 3, 4 terms, LOO error {loo:.2g}" in text


def test_docs_state_the_code_constants():
    """docs/pce.md states the method's constants and default counts: they are the code's."""
    import re
    from pathlib import Path

    from uqflow.methods import pce, pce_fit
    text = (Path(__file__).resolve().parents[2] / "docs" / "pce.md").read_text()
    stated = {
        "OVERSAMPLING": r"`OVERSAMPLING = (\d+)`", "OMP_PATIENCE": r"10 steps after the best "
        r"LOO error\s+\(`OMP_PATIENCE`\)", "ROUND_OFF_LOO": r"`ROUND_OFF_LOO = ([0-9e.-]+)`",
        "MAX_BASIS_TERMS": r"`MAX_BASIS_TERMS = (\d+)`",
    }
    assert float(re.search(stated["OVERSAMPLING"], text).group(1)) == pce_fit.OVERSAMPLING
    assert re.search(stated["OMP_PATIENCE"], text) and pce_fit.OMP_PATIENCE == 10
    assert float(re.search(stated["ROUND_OFF_LOO"], text).group(1)) == pce_fit.ROUND_OFF_LOO
    assert int(re.search(stated["MAX_BASIS_TERMS"], text).group(1)) == pce.MAX_BASIS_TERMS
    assert "5,000 terms (`MAX_BASIS_TERMS`" in (
        Path(__file__).resolve().parents[2] / "docs" / "study-files.md").read_text()
    # The default design sizes the page quotes: 3 inputs at max_order 5, 10 at order 3.
    assert "# samples = 112 " in text and get_method("pce")()._samples(3) == 112
    assert "d = 10 inputs at order 3 is 286 terms (572 runs by default)" in " ".join(
        text.split())
    assert get_method("pce")(order=3)._samples(10) == 572
    assert "the linear basis needs (2(d + 1))" in " ".join(text.split())
