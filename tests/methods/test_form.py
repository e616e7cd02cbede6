"""FORM and SORM against exact failure probabilities of the analytic polynomial model.

The model is y = c0 + c . x + x' Q x with normal inputs, so the limit state "y below 0" (or
"y exceeds t") is a polynomial of degree two in the standard normal space u: central
differences of it are exact up to rounding, and the only errors left are the roundings and,
for SORM, the asymptotic formulas themselves. Studies run through ``run_study`` in process
(workers = 0): the rounds go through ``extend`` as in any study.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import xarray as xr
from scipy import stats as sps

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.execute import run_study
from uqflow.layout import (FAILURE_PROBABILITY, INPUTS, MESSAGE, RELIABILITY_INDEX, ROUND,
                           STATUS, STATUS_FAILED)
from uqflow.methods import get_method
from uqflow.methods.form import (STAGE, STAGE_CHECK, STAGE_CURVATURE, Form, Sorm,
                                 sorm_probabilities)
from uqflow.report import open_result, summary_table, write_figures
from uqflow.study import load_study

from reliability_helpers import (assert_rounds_replay, comparable, cut_result, paraboloid_exact,
                                 run_quietly, run_warned, study_file)

EPS = np.finfo(float).eps


def study(tmp_path, scene, inputs, limit_states, method, correlation=None, seed=1,
          name="form", execution=None):
    """Load a study of the analytic model ``scene`` with normal ``inputs`` [(mean, std)] named
    x1, x2, ... (or [(name, mean, std)], or any distribution as its table)."""
    return load_study(study_file(tmp_path, name, inputs=inputs, limit_states=limit_states,
                                 method=method, scene=scene, correlation=correlation,
                                 seed=seed, execution=execution))


def run(tmp_path, *args, **kwargs):
    return run_warned(study(tmp_path, *args, **kwargs))


BELOW_ZERO = [{"name": "negative", "output": "y", "below": 0.0}]


def paraboloid(beta, kappa, n):
    """g = beta - w + kappa/2 (|v|^2) in n standard normals, w = (x1 + x2)/sqrt 2 the
    direction of the design point and v the other n - 1 orthonormal directions: a paraboloid
    whose axis is not a coordinate axis (SORM's rotation is exercised)."""
    c = np.zeros(n)
    c[:2] = -1 / math.sqrt(2)
    q = np.eye(n) * kappa / 2
    # |v|^2 = |x|^2 - w^2
    q -= kappa / 2 * np.outer(-c, -c)
    return {"model": "quadratic", "offset": beta, "coefficients": c.tolist(),
            "quadratic": q.tolist()}


def test_registered_under_form_and_sorm():
    assert get_method("form") is Form and get_method("sorm") is Sorm


# ----------------------------------------------------------------------------- FORM, linear

MEANS, STDS = [1.0, -2.0, 0.5], [0.2, 0.5, 0.1]
CORR = [[1.0, 0.4, -0.3], [0.4, 1.0, 0.2], [-0.3, 0.2, 1.0]]
C0, C = 0.5, np.array([2.0, -1.0, 3.0])


@pytest.mark.parametrize("gradient", ["central", "forward", "solver"])
def test_form_is_exact_for_a_linear_limit_state_in_correlated_normals(tmp_path, gradient):
    # y = c0 + c.x is normal: beta = (t - E y) / sd y, the design point mu + Sigma c beta / sd
    sigma = np.outer(STDS, STDS) * np.array(CORR)
    mean_y, sd_y = C0 + C @ MEANS, math.sqrt(C @ sigma @ C)
    threshold = mean_y + 2.7 * sd_y
    outcome, raised = run(tmp_path, {"model": "linear", "offset": C0, "coefficients": C},
                          list(zip(MEANS, STDS)),
                          [{"name": "high", "output": "y", "exceeds": threshold}],
                          {"kind": "form", "gradient": gradient}, correlation=CORR)
    stats = outcome.statistics
    assert raised == [] and stats.attrs["converged"] == 1
    beta = (threshold - mean_y) / sd_y
    # g is linear in u, so the differences err by rounding alone: about eps |g| / step per
    # component (|g| <= 10, step 0.01: 1e-13 of |grad g| ~ 1), far inside 1e-9
    assert float(stats[RELIABILITY_INDEX].values[0]) == pytest.approx(beta, rel=1e-9)
    assert float(stats[FAILURE_PROBABILITY].values[0]) == pytest.approx(sps.norm.sf(beta),
                                                                        rel=1e-8)
    design = np.array(MEANS) + sigma @ C * beta / sd_y
    # u* errs by the gradient's rounding (1e-13 relative) times beta ~ 3, scaled by stds < 1
    assert np.allclose(stats["design_point"].values[0], design, rtol=0, atol=1e-9)
    # the importance factors of correlated inputs (Der Kiureghian's gamma^2): (s_k c_k)^2 / sum
    share = (np.array(STDS) * C) ** 2
    # from the gradient's 1e-13 (above), squared and normalized: 1e-9 absolute (rtol=0:
    # allclose's default rtol 1e-5 would be the real tolerance)
    assert np.allclose(stats["importance_factor"].values[0], share / share.sum(), rtol=0,
                       atol=1e-9)
    # the first step lands on the design point; the second round only confirms it
    assert stats.attrs["iterations"] == 2
    # the solver's derivatives (dy/dx = c) come with the one run of a round, through the
    # chain rule grad_u g = L^T diag(std) grad_x g
    per_round = {"central": 2 * 3 + 1, "forward": 3 + 1, "solver": 1}[gradient]
    # the design-point check: -u* and |u*| along the axes not within 30 degrees of u*
    checks = int((outcome.runs[STAGE].values == STAGE_CHECK).sum())
    assert 1 <= checks <= 2 * 3 + 1 and stats.attrs["other_design_points"] == 0
    assert stats.attrs["solver_runs"] == 2 * per_round + checks
    assert outcome.runs["with_sensitivities"].values.sum() == (2 if gradient == "solver"
                                                                else 0) \
        if "with_sensitivities" in outcome.runs else gradient != "solver"


# ----------------------------------------------------------------------------- SORM, curved

def test_sorm_within_a_few_per_cent_of_an_exact_paraboloid_where_form_is_not(tmp_path):
    beta, kappa, n = 3.0, 0.2, 3
    outcome, raised = run(tmp_path, paraboloid(beta, kappa, n), [(0.0, 1.0)] * n, BELOW_ZERO,
                          {"kind": "sorm"})
    stats = outcome.statistics
    exact = paraboloid_exact(beta, kappa, n)
    assert raised == [] and stats.attrs["converged"] == 1
    # g is quadratic in u: the second differences are exact up to rounding, 4 eps |g| / h^2
    # (h = 0.1, |g| < 5: 1e-13) over |grad g| = 1
    assert np.allclose(stats["curvatures"].values, kappa, rtol=0, atol=1e-9)
    assert np.allclose(stats["design_point"].values[0], [beta / math.sqrt(2)] * 2 + [0.0],
                       rtol=0, atol=1e-9)
    breitung, hohenbichler, tvedt = stats["sorm_failure_probability"].values[0]
    # kappa errs by 1e-13 (above), so 1 + beta kappa by 1e-13 relative (abs=0: p ~ 1e-3,
    # where approx's default abs 1e-12 would loosen 1e-9 relative)
    assert breitung == pytest.approx(sps.norm.sf(beta) / (1 + beta * kappa), rel=1e-9, abs=0)
    # the asymptotic formulas are not exact for a paraboloid; their error is second order in
    # kappa beta = 0.6 and 1/beta: within a few per cent for Tvedt and Hohenbichler-Rackwitz
    assert abs(tvedt / exact - 1) < 0.03 and abs(hohenbichler / exact - 1) < 0.03
    assert float(stats[FAILURE_PROBABILITY].values[0]) == tvedt
    assert float(stats[RELIABILITY_INDEX].values[0]) == pytest.approx(-sps.norm.ppf(tvedt))
    # FORM ignores the curvature: 1.68 times the exact p_f
    assert float(stats["form_failure_probability"].values[0]) / exact - 1 > 0.5
    # one curvature round: 2 (n - 1) axis points and 4 per pair of the n - 1 axes
    curvature_rows = int(np.sum(outcome.runs[STAGE].values == STAGE_CURVATURE))
    assert curvature_rows == 2 * (n - 1) + 4 * (n - 1) * (n - 2) // 2


def test_sorm_formulas_against_their_closed_forms():
    # flat: every formula is FORM's Phi(-beta), times factors that are 1 exactly; the two
    # calls of the normal tail a few ulp apart at most (atol=0: allclose's default 1e-8 is
    # 4e-7 of p = 0.023)
    assert np.allclose(sorm_probabilities(2.0, np.zeros(3))[0], sps.norm.sf(2.0), rtol=1e-14,
                       atol=0)
    # the origin in the failure domain: 1 - P[safe] with the safe side's index and curvatures
    got, _ = sorm_probabilities(-2.0, np.array([0.1, -0.2]))
    safe, _ = sorm_probabilities(2.0, np.array([-0.1, 0.2]))
    # the same arithmetic on both sides: only the subtraction 1 - safe rounds (eps / p)
    assert np.allclose(got, 1 - safe, rtol=1e-14, atol=0)
    # Hohenbichler-Rackwitz: psi = phi(beta) / Phi(-beta) in place of beta
    psi = sps.norm.pdf(3.0) / sps.norm.sf(3.0)
    got, why = sorm_probabilities(3.0, np.array([0.2, -0.1]))
    # psi from exp(logpdf - logsf) and from pdf / sf differ by a few ulp of log terms ~ 5:
    # 1e-15 relative, and the product of two square roots adds a few eps (abs=0: approx's
    # default 1e-12 is 1e-9 of this p ~ 1e-3)
    assert got[1] == pytest.approx(sps.norm.sf(3.0) / math.sqrt((1 + 0.2 * psi) *
        # bound: a few eps of log terms ~5 and two square roots, 1e-13 (above)
                                                                (1 - 0.1 * psi)), rel=1e-13,
                                   abs=0)
    assert why == []


def test_sorm_says_when_breitung_is_undefined():
    # kappa beta <= -1: the limit state bends round the origin; Breitung's product is not real
    got, why = sorm_probabilities(3.0, np.array([-0.4, 0.1]))
    assert np.isnan(got[0]) and np.isnan(got[2])
    assert any("Breitung's formula is undefined" in w and "-0.2" in w for w in why)


def test_sorm_warns_of_large_curvatures(tmp_path):
    # kappa beta = -0.9: the formulas disagree far beyond 10 %
    outcome, raised = run(tmp_path, paraboloid(3.0, -0.3, 3), [(0.0, 1.0)] * 3, BELOW_ZERO,
                          {"kind": "sorm"})
    assert any("large curvatures" in w for w in raised)
    assert any("large curvatures" in w for w in outcome.warnings)


# ----------------------------------------------------------------------------- convergence

CURVED = {"model": "quadratic", "offset": 2.0, "coefficients": [-1.0, -1.0],
          "quadratic": [[0.3, 0.0], [0.0, -0.1]]}


def nearest_failure_point():
    """The design point by another optimizer: min |u|^2 subject to g(u) = 0 (SLSQP)."""
    from scipy import optimize

    def g(u):
        return 2.0 - u[0] - u[1] + 0.3 * u[0] ** 2 - 0.1 * u[1] ** 2
    found = optimize.minimize(lambda u: u @ u, [1.0, 1.0], jac=lambda u: 2 * u,
                              constraints={"type": "eq", "fun": g}, method="SLSQP",
                              options={"ftol": 1e-14, "maxiter": 200})
    assert found.success
    return found.x


def test_form_converges_on_a_curved_limit_state_to_the_nearest_failure_point(tmp_path):
    outcome, raised = run(tmp_path, CURVED, [(0.0, 1.0)] * 2, BELOW_ZERO, {"kind": "form"})
    stats = outcome.statistics
    assert raised == [] and stats.attrs["converged"] == 1
    assert stats.attrs["iterations"] > 3  # not a one-step problem
    u_star = nearest_failure_point()
    # stopped at |next step| <= u_tolerance = 1e-3 (the iteration converges linearly with
    # ratio below 1/2 here, so the distance left is below the next step): 2e-3
    assert np.allclose(stats["design_point_standard_normal"].values[0], u_star, atol=2e-3)
    assert float(stats[RELIABILITY_INDEX].values[0]) == pytest.approx(
        np.linalg.norm(u_star), abs=2e-3)
    history = stats["iteration_margin"].values
    assert history[0] == 2.0 and abs(history[-1]) <= 1e-3 * 2.0
    # the convergence diagnostics are the last accepted point's, within the tolerances
    assert stats.attrs["final_relative_margin"] == abs(history[-1]) / 2.0 <= 1e-3
    assert 0 <= stats.attrs["final_step"] <= 1e-3
    # at a converged point u* is parallel to -grad g to the order of the next step / beta
    assert abs(stats.attrs["alignment_error"]) <= 1e-3


def test_form_says_when_it_did_not_converge(tmp_path):
    outcome, raised = run(tmp_path, CURVED, [(0.0, 1.0)] * 2, BELOW_ZERO,
                          {"kind": "sorm", "max_iterations": 4})
    stats = outcome.statistics
    assert stats.attrs["converged"] == 0 and stats.attrs["iterations"] == 4
    assert any("FORM did not converge (max_iterations = 4 rounds reached)" in w
               for w in raised)
    assert any("SORM needs a converged design point" in w for w in outcome.warnings)
    # no curvature round and no design-point check after a search that did not converge
    assert not np.any(outcome.runs[STAGE].values == STAGE_CURVATURE)
    assert not np.any(outcome.runs[STAGE].values == STAGE_CHECK)
    assert np.isnan(float(stats[FAILURE_PROBABILITY].values[0]))
    # the diagnostics say how far from converged: the next step is above u_tolerance
    assert stats.attrs["final_step"] > 1e-3
    text = summary_table(open_result(outcome.path))
    assert f"next step |d| = {stats.attrs['final_step']:.6g} (u_tolerance 0.001)" in text
    text = summary_table(open_result(outcome.path))
    assert "NOT converged: max_iterations = 4 rounds reached" in text


# ----------------------------------------------------------------------------- determinism

def test_deterministic_and_replayable_round_by_round(tmp_path):
    first, _ = run(tmp_path, CURVED, [(0.0, 1.0)] * 2, BELOW_ZERO, {"kind": "sorm"}, seed=1,
                   name="a")
    second, _ = run(tmp_path, CURVED, [(0.0, 1.0)] * 2, BELOW_ZERO, {"kind": "sorm"}, seed=7,
                    name="b")
    xr.testing.assert_identical(first.runs[INPUTS], second.runs[INPUTS])
    xr.testing.assert_identical(first.statistics.drop_attrs(), second.statistics.drop_attrs())
    # a resume asks extend the same question of the same runs: every prefix of finished
    # rounds gives back, bit for bit, the next round that ran
    method = load_study(tmp_path / "a.toml").method
    method.plan(load_study(tmp_path / "a.toml").space, None, np.random.SeedSequence(1))
    assert_rounds_replay(method, first.runs)


# ----------------------------------------------------------------------------- refusals

def test_refuses_several_limit_states_a_system_and_none(tmp_path):
    two = BELOW_ZERO + [{"name": "high", "output": "y", "exceeds": 5.0}]
    line = {"model": "linear", "coefficients": [1.0]}
    with pytest.raises(StudyError) as error:
        study(tmp_path, line, [(0.0, 1.0)], two, {"kind": "form"})
    assert error.value.key == "method.limit_state" and "\n" not in str(error.value)
    assert "name it with limit_state" in str(error.value)
    chosen = study(tmp_path, line, [(0.0, 1.0)], two, {"kind": "form", "limit_state": "high"})
    assert chosen.method.limit_state == "high"
    series = two + [{"name": "either", "series": ["negative", "high"]}]
    with pytest.raises(StudyError) as error:
        study(tmp_path, line, [(0.0, 1.0)], series, {"kind": "form", "limit_state": "either"})
    assert error.value.key == "method.limit_state" and "series system" in str(error.value)
    with pytest.raises(StudyError) as error:
        study(tmp_path, line, [(0.0, 1.0)], [], {"kind": "sorm"})
    assert error.value.key == "limit_states" and "\n" not in str(error.value)


@pytest.mark.parametrize("kind", ["form", "sorm"])
def test_a_failed_start_is_reported_not_raised(tmp_path, kind):
    outcome, _ = run(tmp_path, CURVED, [(0.0, 1.0)] * 2, BELOW_ZERO, {"kind": kind})
    runs = outcome.runs.copy(deep=True)
    runs[STATUS].values[0] = STATUS_FAILED
    runs[MESSAGE].values[0] = "diverged"
    runs["y"].values[0] = np.nan
    method = load_study(tmp_path / "form.toml").method  # a fresh one: analyze needs no plan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        stats = method.analyze(runs, runs)
    assert stats.attrs["converged"] == 0 and stats.attrs["failed_runs"] == 1
    assert np.isnan(float(stats[RELIABILITY_INDEX].values[0]))
    assert "medians is not available" in stats.attrs["stop_reason"]


# ----------------------------------------------------------------------------- report

def test_report_gives_beta_design_point_and_importance_bars(tmp_path):
    outcome, _ = run(tmp_path, paraboloid(3.0, 0.2, 3), [(0.0, 1.0)] * 3, BELOW_ZERO,
                     {"kind": "sorm"})
    tree = open_result(outcome.path)
    text = summary_table(tree)
    assert "SORM, limit state 'negative' (y < 0): beta = " in text
    assert "design point: x1 = 2.12132 m, x2 = 2.12132 m, x3 = 0 m" in text
    assert "importance factor alpha²" in text
    assert "design-point check: g at " in text and "no other design point found" in text
    assert "convergence: |g(u*)| / |g(medians)| = " in text
    written = [p.name for p in write_figures(tree, tmp_path / "figures")]
    assert "y_sensitivities.png" in written and "form_convergence.png" in written


def test_sorm_finds_unequal_curvatures_along_axes_of_their_own(tmp_path):
    # g = beta - w + (k1 v1^2 + k2 v2^2) / 2 with v1, v2 turned by 0.5 rad about w: the
    # curvatures' axes are neither the coordinate axes nor the basis SORM rotates to, so the
    # mixed second differences carry them
    beta, kappas, turn = 2.5, np.array([0.3, -0.15]), 0.5
    w = np.array([1.0, 1.0, 0.0]) / math.sqrt(2)
    a, b = np.array([1.0, -1.0, 0.0]) / math.sqrt(2), np.array([0.0, 0.0, 1.0])
    v1 = math.cos(turn) * a + math.sin(turn) * b
    v2 = -math.sin(turn) * a + math.cos(turn) * b
    q = 0.5 * (kappas[0] * np.outer(v1, v1) + kappas[1] * np.outer(v2, v2))
    scene = {"model": "quadratic", "offset": beta, "coefficients": (-w).tolist(),
             "quadratic": q.tolist()}
    outcome, raised = run(tmp_path, scene, [(0.0, 1.0)] * 3, BELOW_ZERO, {"kind": "sorm"})
    stats = outcome.statistics
    # exact to the rounding of the second differences (4 eps |g| / h^2 ~ 1e-13)
    assert np.allclose(stats["curvatures"].values, np.sort(kappas), rtol=0, atol=1e-9)
    breitung = stats["sorm_failure_probability"].values[0][0]
    # the curvatures' 1e-13 error (above) moves 1 + beta kappa by 1e-13 relative
    assert breitung == pytest.approx(sps.norm.sf(beta) / math.sqrt(np.prod(1 + beta * kappas)),
                                     rel=1e-9)


def test_failed_runs_are_rejected_trials_and_reported(tmp_path):
    # the solver diverges just past the design point x* = 2: every full step's stencil fails,
    # the line search halves it, and the search creeps up to x* without converging
    outcome, raised = run(tmp_path, {"model": "faulty", "raise_above": 2.005},
                          [("x", 0.0, 1.0)], [{"name": "high", "output": "y", "exceeds": 2.0}],
                          {"kind": "form", "max_iterations": 8},
                          execution={"max_failure_fraction": 0.9})
    stats = outcome.statistics
    assert stats.attrs["converged"] == 0 and stats.attrs["failed_runs"] > 0
    steps = stats["iteration_step"].values
    accepted = stats["iteration_accepted"].values
    assert list(accepted[:4]) == [1, 0, 1, 0] and list(steps[:4]) == [1.0, 1.0, 0.5, 1.0]
    assert any("treated as one the line search rejects" in w for w in raised)
    points = stats["iteration_point"].values[:, 0]
    assert np.all(points[accepted == 1] < 2.0)


def test_sorm_of_one_moving_input_is_form(tmp_path):
    # x2 has no spread: u has one moving axis, the limit state is a point, no curvature round
    outcome, raised = run(tmp_path, {"model": "linear", "coefficients": [1.0, 2.0]},
                          [(0.0, 1.0), (3.0, 0.0)],
                          [{"name": "high", "output": "y", "exceeds": 9.0}], {"kind": "sorm"})
    stats = outcome.statistics
    # two search rounds of 3 runs, and the design-point check's one probe (-u*: the only
    # axis is u*'s own)
    assert raised == [] and outcome.runs.sizes["realization"] == 2 * 3 + 1
    # linear: rounding alone (eps |g| / step ~ 1e-13; atol=0: allclose's default 1e-8 is
    # 7e-6 of this p)
    assert np.allclose(stats["sorm_failure_probability"].values[0], sps.norm.sf(3.0),
                       rtol=1e-9, atol=0)


@pytest.mark.parametrize("gradient", ["central", "solver"])
def test_form_maps_a_lognormal_input_through_the_copula(tmp_path, gradient):
    # x = exp(mu + sigma u): "x exceeds t" fails beyond u* = (ln t - mu) / sigma, reached by
    # HL-RF (Newton's method in one dimension) whatever the finite-difference error of g'
    mu, sigma, threshold = 0.2, 0.3, 3.0
    outcome, raised = run(tmp_path, {"model": "power", "p": 1.0},
                          [{"name": "x", "distribution": "lognormal", "mu": mu,
                            "sigma": sigma}],
                          [{"name": "high", "output": "y", "exceeds": threshold}],
                          {"kind": "form", "u_tolerance": 1e-10, "g_tolerance": 1e-10,
                           "gradient": gradient})
    stats = outcome.statistics
    beta = (math.log(threshold) - mu) / sigma
    assert raised == [] and stats.attrs["converged"] == 1
    # stopped with the next Newton step below 1e-10; Phi(u) near 1 - 6e-3 rounds u by
    # eps / phi(u) ~ 1e-14 in the inverse map: 1e-9 bounds both
    assert float(stats[RELIABILITY_INDEX].values[0]) == pytest.approx(beta, abs=1e-9)
    assert float(stats["design_point"].values[0, 0]) == pytest.approx(threshold, rel=1e-8)


# ----------------------------------------------------------------------------- solver gradients

DECAY = {"model": "exponential_decay", "t": {"start": 0.0, "stop": 10.0, "num": 11}}
DECAY_INPUTS = [("alpha", 1.5, 0.2), ("beta", 0.15, 0.02)]


def test_solver_gradient_takes_the_reduced_element_max(tmp_path):
    """y(t) = alpha exp(-beta t): its max over t is y(0) = alpha, so "max of y exceeds 1.9"
    is linear in alpha, beta = (1.9 - 1.5) / 0.2 = 2 exactly. The solver's derivative at
    the max's element (t = 0: dy/dalpha = 1, dy/dbeta = 0) gives it in one run a round;
    the derivative at any other time would not."""
    outcome, raised = run(tmp_path, DECAY, DECAY_INPUTS,
                          [{"name": "high", "output": "y", "reduce": "max", "exceeds": 1.9}],
                          {"kind": "form", "gradient": "solver"})
    stats = outcome.statistics
    assert raised == [] and stats.attrs["converged"] == 1
    # g linear in u with an exact gradient: the first HL-RF step lands on u* up to rounding
    # (eps |g| / |grad g| ~ 1e-16 relative), far inside 1e-12
    assert float(stats[RELIABILITY_INDEX].values[0]) == pytest.approx(2.0, rel=1e-12)
    # alpha^2 of that gradient (1, 0) exactly: its rounding, 1e-12 absolute (rtol=0: the
    # default 1e-7 would be the real tolerance)
    np.testing.assert_allclose(stats["importance_factor"].values[0], [1.0, 0.0], rtol=0,
                               # bound: alpha^2's own rounding, 1e-12 absolute (above)
                               atol=1e-12)
    search = outcome.runs[STAGE].values == "search"
    assert np.all(outcome.runs["with_sensitivities"].values == search)
    assert search.sum() == stats.attrs["iterations"] == 2    # one run a round


def test_solver_gradient_through_a_nonlinear_limit_state_at_a_time(tmp_path):
    """"y at t = 5 below 0.4": ln(alpha) - 5 beta < ln 0.4 in the two normals, a curved
    limit state. FORM on the solver's derivatives reaches the design point that a
    constrained minimization of |u| (SLSQP, tolerance 1e-12) finds."""
    from scipy import optimize

    outcome, raised = run(tmp_path, DECAY, DECAY_INPUTS,
                          [{"name": "low", "output": "y", "reduce": {"at": {"t": 5.0}},
                            "below": 0.4}],
                          {"kind": "form", "gradient": "solver", "u_tolerance": 1e-6,
                           "g_tolerance": 1e-12})
    stats = outcome.statistics
    assert raised == [] and stats.attrs["converged"] == 1

    def g(u):
        return 1.5 * (1 + 0.2 / 1.5 * u[0]) * math.exp(-5 * (0.15 + 0.02 * u[1])) - 0.4

    reference = optimize.minimize(lambda u: u @ u, [-2.0, 2.0], method="SLSQP", tol=1e-14,
                                  constraints=[{"type": "eq", "fun": g}])
    # FORM stops with its next step below 1e-6; HL-RF contracts by a factor ~0.1 a round
    # here, so u* is within ~1e-6 / (1 - 0.1) of the fixed point: 1e-5 bounds it. On g = 0
    # (|g| < 1e-12 |g(0)|) |u| is stationary at the design point: beta errs by the square
    # of that distance over beta (~1e-12), 1e-9 bounds it and SLSQP's own 1e-14 on |u|^2
    np.testing.assert_allclose(stats["design_point_standard_normal"].values[0], reference.x,
                               atol=1e-5)
    # beta: |u| is stationary on g = 0, its error the square of u*'s over beta
    assert float(stats[RELIABILITY_INDEX].values[0]) == pytest.approx(
        float(np.linalg.norm(reference.x)), abs=1e-9)


def test_solver_gradient_is_refused_by_a_solver_without_derivatives(tmp_path):
    with pytest.raises(StudyError) as error:
        study(tmp_path, {"model": "sobol_g", "a": [0.0, 1.0]}, [(0.5, 0.1)] * 2,
              [{"name": "high", "output": "y", "exceeds": 1.5}],
              {"kind": "form", "gradient": "solver"})
    assert error.value.key == "method.gradient" and "\n" not in str(error.value)
    assert "has no derivatives of its outputs" in str(error.value)
    assert 'gradient = "central"' in str(error.value)


def test_solver_gradient_study_resumes_to_the_uninterrupted_numbers(tmp_path):
    """Killed with the second search round's run pending (its derivatives not yet there):
    the resumed study runs it with its sensitivities and ends identical, bit for bit."""
    from uqflow.store import read_runs

    limit = [{"name": "low", "output": "y", "reduce": {"at": {"t": 5.0}}, "below": 0.4}]
    whole, _ = run(tmp_path, DECAY, DECAY_INPUTS, limit,
                   {"kind": "form", "gradient": "solver"}, name="whole")
    rounds = whole.runs[ROUND].values
    assert rounds.max() >= 3
    keep = int(np.flatnonzero(rounds == 1)[-1]) + 1
    # the round's one run pending: its output and its derivatives NaN in the file
    assert whole.runs["with_sensitivities"].values[keep - 1]
    cut = cut_result(whole.path, keep, [keep - 1], tmp_path / "cut.nc")
    stored = read_runs(cut)[0]
    assert np.isnan(stored["y__gradient"].values[-1]).all() and \
        int(stored["sensitivity_realization"].values[-1]) == keep - 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        resumed = run_study(load_study(tmp_path / "whole.toml"), show_progress=False,
                            resume=True, output=cut)
    assert resumed.resumed == keep - 1

    (runs_w, stats_w), (runs_c, stats_c) = comparable(whole.path), comparable(cut)
    runs_w, runs_c = runs_w.drop_vars(MESSAGE), runs_c.drop_vars(MESSAGE)
    for stats in (stats_w, stats_c):
        stats.attrs.pop("resumed", None)
    xr.testing.assert_identical(runs_w, runs_c)
    xr.testing.assert_identical(stats_w, stats_c)


# ----------------------------------------------------------------------------- several design points

def _two_design_points(x1=0.0, x2=0.0, shift=0.1):
    """g = 3 - |x1 + shift| (x2 has no effect): two failure regions, x1 >= 3 - shift and
    x1 <= -3 - shift, with design points at u = (3 - shift, 0) and (-3 - shift, 0)."""
    return 3.0 - abs(x1 + shift) + 0.0 * x2


def test_form_warns_of_another_design_point(tmp_path):
    """FORM finds u* = (2.9, 0) (the nearer region, beta 2.9); the check's probe at
    -u* = (-2.9, 0) has g = 0.2 < g(0) = 2.9, so along that ray g reaches 0 at about
    2.9 x 2.9 / 2.7 = 3.115 (linear between the medians and the probe): outside FORM's
    half-space, with Phi(-3.115) / Phi(-2.9) = 0.49 of FORM's p_f: a warning."""
    import uqflow

    solver = uqflow.solver_from_function(_two_design_points, outputs="y", units="1")
    uqflow.register_solver("form-two-design-points-test")(solver)

    def form(name, scene=None, **options):
        return run_warned(study_file(
            tmp_path, name, solver="form-two-design-points-test", scene=scene,
            inputs=[{"name": label, "distribution": "normal", "mean": 0.0, "std": 1.0}
                    for label in ("x1", "x2")],
            limit_states=[{"name": "g", "output": "y", "below": 0.0}],
            method={"kind": "form", **options}))

    outcome, raised = form("two")
    stats = outcome.statistics
    # g is linear on x1 >= -0.1: exact up to rounding
    assert float(stats[RELIABILITY_INDEX].values[0]) == pytest.approx(2.9, rel=1e-12)
    assert stats.attrs["other_design_points"] == 1
    expected = 2.9 * 2.9 / 2.7
    warning = [w for w in raised if w.startswith("another design point near u = ")]
    assert len(warning) == 1
    assert f"near u = ({-expected:.3g}, 0) with beta about {expected:.3g}" in warning[0]
    assert "FORM's p_f counts the failure region at u* only" in warning[0]
    # the probes: -u*, and |u*| along x2 either way (the +x1 probe is u* itself); u* is
    # exact to its rounding (a few eps of 2.9), 1e-12 absolute (rtol=0: not the default 1e-7)
    np.testing.assert_allclose(stats["check_point"].values,
                               # bound: u*'s rounding, a few eps of 2.9, 1e-12 absolute (above)
                               [[-2.9, 0.0], [0.0, 2.9], [0.0, -2.9]], rtol=0, atol=1e-12)
    assert np.isinf(stats["check_failure_distance"].values[1:]).all()
    assert warning[0] in summary_table(open_result(outcome.path))
    # without the check: no probe round and no warning
    unchecked, raised = form("unchecked", design_point_check=False)
    assert "check_point" not in unchecked.statistics
    assert not any(w.startswith("another design point") for w in raised)
    # exactly symmetric, g = 3 - |x1|: central differences see no slope at the medians (g is
    # even there), forward ones do; u* = (3, 0) and g(-u*) = 0, so the other region is at
    # beta 3 exactly (g linear along the ray)
    symmetric, raised = form("symmetric", scene={"shift": 0.0}, gradient="forward")
    assert float(symmetric.statistics[RELIABILITY_INDEX].values[0]) == pytest.approx(
        3.0, rel=1e-12)   # g linear on x1 >= 0: exact up to rounding
    assert any(w.startswith("another design point near u = (-3, 0) with beta about 3 ")
               for w in raised)
    central, raised = form("symmetric_central", scene={"shift": 0.0})
    assert central.statistics.attrs["converged"] == 0
    assert any("g or its gradient at the inputs' medians is not available" in w
               for w in raised)


def test_one_linear_region_seen_along_another_ray_is_no_second_design_point(tmp_path):
    """g = 1 - a . u with a 35 degrees off the x1 axis: the probe at |u*| = 1 along x1 (outside
    the 30-degree cone round u*) meets FORM's own half-space at t = 1 / cos 35 = 1.22, whose
    Phi(-t) is 0.7 of Phi(-1): only the half-space test (the failure point lies on the plane
    alpha . u = beta) keeps it from being called another design point."""
    angle = math.radians(35.0)
    a = [math.cos(angle), math.sin(angle)]
    outcome, raised = run(tmp_path, {"model": "linear", "coefficients": a},
                          [(0.0, 1.0)] * 2, [{"name": "high", "output": "y", "exceeds": 1.0}],
                          {"kind": "form"})
    stats = outcome.statistics
    assert raised == [] and stats.attrs["other_design_points"] == 0
    probes = stats["check_point"].values
    # the probe is |u*| e_1 with |u*| = 1 up to the search's rounding (~1e-15)
    along_x1 = int(np.flatnonzero(np.all(np.isclose(probes, [1.0, 0.0], atol=1e-9), axis=1))[0])
    # g linear along the ray: the interpolation is exact up to rounding of g (~1e-16)
    assert float(stats["check_failure_distance"].values[along_x1]) == pytest.approx(
        1 / math.cos(angle), rel=1e-9)


def test_solver_gradient_chains_through_a_lognormal_input(tmp_path):
    """y = x1 + x2, x1 lognormal (mu 0, sigma 0.25), x2 ~ N(0, 0.3): the solver gives
    dy/dx = (1, 1), and dx1/du1 = sigma x1 (phi(z) / f(x)) turns it into grad_u; the design
    point is the one SLSQP finds on g(u) = 1.9 - exp(0.25 u1) - 0.3 u2 = 0."""
    from scipy import optimize

    outcome, raised = run(tmp_path, {"model": "linear", "coefficients": [1.0, 1.0]},
                          [{"name": "x1", "distribution": "lognormal", "mu": 0.0,
                            "sigma": 0.25}, ("x2", 0.0, 0.3)],
                          [{"name": "high", "output": "y", "exceeds": 1.9}],
                          {"kind": "form", "gradient": "solver", "u_tolerance": 1e-6,
                           "g_tolerance": 1e-12})
    stats = outcome.statistics
    assert raised == [] and stats.attrs["converged"] == 1
    reference = optimize.minimize(lambda u: u @ u, [1.0, 1.0], method="SLSQP", tol=1e-14,
                                  constraints=[{"type": "eq", "fun": lambda u: 1.9 - math.exp(
                                      0.25 * u[0]) - 0.3 * u[1]}])
    # as in the test above: the next step below 1e-6 bounds the point by 1e-5, and beta
    # (|u| stationary on g = 0) by its square
    np.testing.assert_allclose(stats["design_point_standard_normal"].values[0], reference.x,
                               atol=1e-5)
    # beta: |u| is stationary on g = 0, its error the square of u*'s over beta
    assert float(stats[RELIABILITY_INDEX].values[0]) == pytest.approx(
        float(np.linalg.norm(reference.x)), abs=1e-9)


def test_solver_gradient_needs_derivatives_of_every_output_the_study_keeps():
    """A search point runs with the derivatives of every (non-diagnostic) output: one the
    solver cannot differentiate, or an input it cannot differentiate by, is refused."""
    from types import SimpleNamespace

    solver = SimpleNamespace(name="stub", local_sensitivities=lambda: {"a": ("x1", "x2")})
    method = Form(gradient="solver")
    method.check_solver(solver, ["a"], ["x1", "x2"])
    for outputs, inputs, words in ((["a", "b"], ["x1"], "output 'b' has no derivative"),
                                   (["a"], ["x1", "x3"], "with respect to input 'x3'")):
        with pytest.raises(StudyError) as error:
            Form(gradient="solver").check_solver(solver, outputs, inputs)
        assert error.value.key == "method.gradient" and words in str(error.value)
    # finite differences need nothing of the solver
    Form().check_solver(SimpleNamespace(local_sensitivities=dict), ["b"], ["x3"])


@pytest.mark.slow
def test_solver_gradient_study_is_the_same_on_two_workers(tmp_path):
    """The rounds with the solver's derivatives (two search rounds and the check round),
    run on two dask workers, give the runs and statistics of the in-process run bit for
    bit."""
    limit = [{"name": "high", "output": "y", "reduce": "max", "exceeds": 1.9}]
    results = []
    for workers in (0, 2):
        path = study_file(tmp_path, f"w{workers}", inputs=DECAY_INPUTS, limit_states=limit,
                          method={"kind": "form", "gradient": "solver"}, scene=DECAY,
                          execution={"workers": workers})
        results.append(comparable(run_quietly(path).path))
    (runs0, stats0), (runs2, stats2) = results
    xr.testing.assert_identical(runs0, runs2)
    xr.testing.assert_identical(stats0, stats2)
