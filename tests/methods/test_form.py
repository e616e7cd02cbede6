"""FORM and SORM against exact failure probabilities of the analytic polynomial model.

The model is y = c0 + c . x + x' Q x with normal inputs, so the limit state "y below 0" (or
"y exceeds t") is a polynomial of degree two in the standard normal space u: central
differences of it are exact up to rounding, and the only errors left are the roundings and,
for SORM, the asymptotic formulas themselves. Studies run through ``run_study`` in process
(workers = 0): the rounds go through ``extend`` as in any study.
"""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
import xarray as xr
from scipy import integrate
from scipy import stats as sps

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.execute import run_study
from uqflow.layout import (FAILURE_PROBABILITY, INPUTS, MESSAGE, RELIABILITY_INDEX, ROUND,
                           STATUS, STATUS_FAILED)
from uqflow.methods import get_method
from uqflow.methods.form import (STAGE, STAGE_CURVATURE, Form, Sorm, sorm_probabilities)
from uqflow.report import open_result, summary_table, write_figures
from uqflow.study import load_study

EPS = np.finfo(float).eps


def toml(value) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(toml(v) for v in value) + "]"
    return repr(float(value)) if isinstance(value, (float, np.floating)) else repr(value)


def study(tmp_path, scene, inputs, limit_states, method, correlation=None, seed=1,
          name="form", execution=None):
    """Load a study of the analytic model ``scene`` with normal ``inputs`` [(mean, std)] named
    x1, x2, ... (or [(name, mean, std)])."""
    lines = [f'name = "{name}"', 'solver = "analytic"', f"scene = {toml(scene)}", ""]
    for k, spec in enumerate(inputs):
        if isinstance(spec, dict):  # any distribution, as its table
            lines += ["[[inputs]]"] + [f"{key} = {toml(v)}" for key, v in spec.items()] + [""]
            continue
        label, mean, std = spec if len(spec) == 3 else (f"x{k + 1}", *spec)
        lines += ["[[inputs]]", f'name = "{label}"', 'distribution = "normal"',
                  f"mean = {mean!r}", f"std = {std!r}", 'units = "m"', ""]
    if correlation is not None:
        lines += ["[correlation]", f'inputs = {toml([f"x{k + 1}" for k in range(len(inputs))])}',
                  f"matrix = {toml(np.asarray(correlation).tolist())}", ""]
    for table in limit_states:
        lines += ["[[limit_states]]"] + [f"{k} = {toml(v)}" for k, v in table.items()] + [""]
    lines += ["[method]"] + [f"{k} = {toml(v)}" for k, v in method.items()]
    lines += ["", "[execution]", "workers = 0", f"seed = {seed}"]
    lines += [f"{k} = {toml(v)}" for k, v in (execution or {}).items()]
    lines += ["", "[output]",
              f'path = "{name}.nc"', "figures = false", ""]
    path = tmp_path / f"{name}.toml"
    path.write_text("\n".join(lines))
    return load_study(path)


def run(tmp_path, *args, **kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = run_study(study(tmp_path, *args, **kwargs), show_progress=False, force=True)
    raised = [str(w.message) for w in caught if issubclass(w.category, AccuracyWarning)]
    return outcome, raised


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


def paraboloid_exact(beta, kappa, n):
    """P[w > beta + kappa/2 Q], Q ~ chi2(n - 1) independent of w ~ N(0, 1)."""
    def integrand(q):
        return sps.norm.sf(beta + kappa / 2 * q) * sps.chi2.pdf(q, n - 1)
    return integrate.quad(integrand, 0, np.inf, epsabs=0, epsrel=1e-12)[0]


def test_registered_under_form_and_sorm():
    assert get_method("form") is Form and get_method("sorm") is Sorm


# ----------------------------------------------------------------------------- FORM, linear

MEANS, STDS = [1.0, -2.0, 0.5], [0.2, 0.5, 0.1]
CORR = [[1.0, 0.4, -0.3], [0.4, 1.0, 0.2], [-0.3, 0.2, 1.0]]
C0, C = 0.5, np.array([2.0, -1.0, 3.0])


@pytest.mark.parametrize("gradient", ["central", "forward"])
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
    assert np.allclose(stats["importance_factor"].values[0], share / share.sum(), atol=1e-9)
    # the first step lands on the design point; the second round only confirms it
    assert stats.attrs["iterations"] == 2
    per_round = 2 * 3 + 1 if gradient == "central" else 3 + 1
    assert stats.attrs["solver_runs"] == 2 * per_round


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
    # kappa errs by 1e-13 (above), so 1 + beta kappa by 1e-13 relative
    assert breitung == pytest.approx(sps.norm.sf(beta) / (1 + beta * kappa), rel=1e-9)
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
    # flat: every formula is FORM's Phi(-beta)
    assert np.allclose(sorm_probabilities(2.0, np.zeros(3))[0], sps.norm.sf(2.0), rtol=1e-14)
    # the origin in the failure domain: 1 - P[safe] with the safe side's index and curvatures
    got, _ = sorm_probabilities(-2.0, np.array([0.1, -0.2]))
    safe, _ = sorm_probabilities(2.0, np.array([-0.1, 0.2]))
    # the same arithmetic on both sides: only the subtraction 1 - safe rounds (eps / p)
    assert np.allclose(got, 1 - safe, rtol=1e-14)
    # Hohenbichler-Rackwitz: psi = phi(beta) / Phi(-beta) in place of beta
    psi = sps.norm.pdf(3.0) / sps.norm.sf(3.0)
    got, why = sorm_probabilities(3.0, np.array([0.2, -0.1]))
    # psi from exp(logpdf - logsf) and from pdf / sf differ by a few ulp of log terms ~ 5:
    # 1e-15 relative, and the product of two square roots adds a few eps
    assert got[1] == pytest.approx(sps.norm.sf(3.0) / math.sqrt((1 + 0.2 * psi) *
                                                                (1 - 0.1 * psi)), rel=1e-13)
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


def test_form_says_when_it_did_not_converge(tmp_path):
    outcome, raised = run(tmp_path, CURVED, [(0.0, 1.0)] * 2, BELOW_ZERO,
                          {"kind": "sorm", "max_iterations": 4})
    stats = outcome.statistics
    assert stats.attrs["converged"] == 0 and stats.attrs["iterations"] == 4
    assert any("FORM did not converge (max_iterations = 4 rounds reached)" in w
               for w in raised)
    assert any("SORM needs a converged design point" in w for w in outcome.warnings)
    # no curvature round after a search that did not converge
    assert not np.any(outcome.runs[STAGE].values == STAGE_CURVATURE)
    assert np.isnan(float(stats[FAILURE_PROBABILITY].values[0]))
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
    runs = first.runs
    rounds = runs[ROUND].values
    for r in range(int(rounds.max())):
        prefix = runs.isel(realization=np.flatnonzero(rounds <= r))
        more = method.extend(prefix, prefix)
        assert np.array_equal(more[INPUTS].values, runs[INPUTS].values[rounds == r + 1])
    assert method.extend(runs, runs) is None


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
    written = [p.name for p in write_figures(tree, tmp_path / "figures")]
    assert "y_sensitivities.png" in written


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
    assert raised == [] and outcome.runs.sizes["realization"] == 2 * 3
    # linear: rounding alone (eps |g| / step ~ 1e-13)
    assert np.allclose(stats["sorm_failure_probability"].values[0], sps.norm.sf(3.0),
                       rtol=1e-9)


def test_form_maps_a_lognormal_input_through_the_copula(tmp_path):
    # x = exp(mu + sigma u): "x exceeds t" fails beyond u* = (ln t - mu) / sigma, reached by
    # HL-RF (Newton's method in one dimension) whatever the finite-difference error of g'
    mu, sigma, threshold = 0.2, 0.3, 3.0
    outcome, raised = run(tmp_path, {"model": "power", "p": 1.0},
                          [{"name": "x", "distribution": "lognormal", "mu": mu,
                            "sigma": sigma}],
                          [{"name": "high", "output": "y", "exceeds": threshold}],
                          {"kind": "form", "u_tolerance": 1e-10, "g_tolerance": 1e-10})
    stats = outcome.statistics
    beta = (math.log(threshold) - mu) / sigma
    assert raised == [] and stats.attrs["converged"] == 1
    # stopped with the next Newton step below 1e-10; Phi(u) near 1 - 6e-3 rounds u by
    # eps / phi(u) ~ 1e-14 in the inverse map: 1e-9 bounds both
    assert float(stats[RELIABILITY_INDEX].values[0]) == pytest.approx(beta, abs=1e-9)
    assert float(stats["design_point"].values[0, 0]) == pytest.approx(threshold, rel=1e-8)
