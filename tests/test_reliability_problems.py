"""The reliability benchmark's problems (benchmarks/reliability_problems.py) and their
reference values (benchmarks/reliability_references.json, written by
benchmarks/reliability_references.py): the stored values are the formulas', the formulas are
the problems' (importance sampling in numpy around each design point checks each margin and
input map against its formula), and the stored 10^8-sample Monte Carlo checks agree."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as sps

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import reliability_problems as problems  # noqa: E402

PROBLEMS = problems.PROBLEMS
REFERENCES = json.loads((ROOT / "benchmarks" / "reliability_references.json").read_text())


def test_every_problem_has_a_reference():
    assert sorted(REFERENCES) == sorted(PROBLEMS)


@pytest.mark.parametrize("name, quoted, last_digit", [
    ("r_minus_s", 0.0786496, 1e-7),        # the issue's Phi(-sqrt 2) to its 6 digits
    ("linear_100", 1.017e-6, 1e-9),        # the issue's Phi(-4.75) to its 4 digits
    ("four_branch_6", 4.46e-3, 1e-5),      # the literature's 3 digits
    ("four_branch_7", 2.22e-3, 1e-5),
])
def test_the_exact_values_match_the_issue_and_the_literature(name, quoted, last_digit):
    # a quoted figure is rounded: within half a unit of its last digit
    assert abs(REFERENCES[name]["p_f"] - quoted) <= 0.5 * last_digit


@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_the_stored_reference_is_the_formula_recomputed(name):
    # the same formula on the same scipy: only libm's last bits differ between CPUs (the
    # normal tail, or quad's sum of densities a few ulp each: a few ulp of P[safe], which
    # 1 - P[safe] of the four-branch system multiplies by 1/p < 500: 4e-13 at 4 ulp): 1e-12
    # (abs=0: approx's default 1e-12 is 1e-6 of linear_100's p_f)
    assert REFERENCES[name]["p_f"] == pytest.approx(PROBLEMS[name].exact(), rel=1e-12, abs=0)


def test_the_closed_forms_by_hand():
    # each from its own derivation, not through the problem module's functions
    assert REFERENCES["r_minus_s"]["p_f"] == pytest.approx(
        0.5 * math.erfc(math.sqrt(2.0) / math.sqrt(2.0)), rel=1e-12, abs=0)  # erfc: a few ulp
    assert REFERENCES["two_design_points"]["p_f"] == pytest.approx(
        # bound: erfc to a few ulp, two terms added: 1e-12
        0.5 * math.erfc(3 / math.sqrt(2)) + 0.5 * math.erfc(3.2 / math.sqrt(2)), rel=1e-12,
        abs=0)      # a few ulp of each tail (abs=0: approx's default is 5e-10 of this p)
    # the lognormal p: beta ~ 3.6 from a few flops, each a few ulp; p's relative error is
    # beta * phi/Phi(-beta) ~ beta^2 = 13 times beta's: 1e-14, inside 1e-12
    s = np.array([0.25, 0.1, 0.15])
    r = np.array([[1.0, 0.3, 0.2], [0.3, 1.0, 0.0], [0.2, 0.0, 1.0]])
    a = np.array([-1.0, -1.0, 1.0])
    beta = math.log(3.0) / math.sqrt(a @ (np.outer(s, s) * r) @ a)
    assert REFERENCES["correlated_lognormals"]["p_f"] == pytest.approx(
        0.5 * math.erfc(beta / math.sqrt(2)), rel=1e-12, abs=0)    # bound: the comment above
    # the four-branch integral's error estimate from quad, against its epsrel 1e-13
    for k in ("6", "7"):
        entry = REFERENCES[f"four_branch_{k}"]
        assert entry["quadrature_error_estimate"] < 1e-13 * entry["p_f"]


@pytest.mark.parametrize("name", sorted(n for n in PROBLEMS if "monte_carlo" in REFERENCES[n]))
def test_the_stored_monte_carlo_check_agrees(name):
    mc = REFERENCES[name]["monte_carlo"]
    assert mc["samples"] >= 10**8
    # the stored stderr is this formula's value, written to 17 digits by json: 1e-12
    # (abs=0: the stderr is 1e-6 to 3e-5, where approx's default abs 1e-12 is up to 1e-6 of it)
    assert mc["stderr"] == pytest.approx(math.sqrt(mc["p_f"] * (1 - mc["p_f"]) / mc["samples"]),
                                         # bound: json's 17 digits of the same formula: 1e-12
                                         rel=1e-12, abs=0)
    # 4 standard errors: a correct reference fails this 1 in 16,000 times
    assert abs(mc["p_f"] - REFERENCES[name]["p_f"]) < 4 * mc["stderr"]


def _importance_sampling(problem, n, seed):
    """P[g <= 0] by an equal mixture of unit normals centred on the design points: unbiased
    for any margin, and a tight check of margin and input map against the formula."""
    rng = np.random.default_rng(seed)
    centres = problem.design_points
    pick = rng.integers(len(centres), size=n)
    u = rng.standard_normal((n, problem.dimension)) + centres[pick]
    # log density ratio phi(u) / mean_j phi(u - c_j)
    log_terms = u @ centres.T - 0.5 * np.sum(centres ** 2, axis=1)
    log_mix = np.log(np.mean(np.exp(log_terms - log_terms.max(axis=1, keepdims=True)),
                             axis=1)) + log_terms.max(axis=1)
    weights = np.where(problem.margin_u(u) <= 0, np.exp(-log_mix), 0.0)
    return weights.mean(), weights.std(ddof=1) / math.sqrt(n)


@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_each_margin_and_input_map_gives_its_formula(name):
    problem = PROBLEMS[name]
    # 2e5 points (2e4 in 100 dimensions, where each is 100 draws): a stderr near 0.5 % of p
    # (1.6 %), so a margin off by a few per cent in p fails (four-branch bend 0.1 -> 0.15: -4 %)
    small = problem.dimension < 10
    estimate, stderr = _importance_sampling(problem, 200_000 if small else 20_000, seed=5)
    assert stderr < (0.01 if small else 0.02) * REFERENCES[name]["p_f"]   # the check is tight
    # 4 standard errors: fails 1 in 16,000 runs when the margin is right
    assert abs(estimate - REFERENCES[name]["p_f"]) < 4 * stderr


@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_the_design_points_lie_on_the_limit_state(name):
    problem = PROBLEMS[name]
    g = problem.margin_u(problem.design_points)
    # g is O(1) there; rounding of a few operations on O(5) numbers
    assert np.all(np.abs(g) < 1e-12)
    # and each is the nearest failure point along its own direction: g > 0 just short of it
    assert np.all(problem.margin_u(0.999 * problem.design_points) > 0)


def test_the_lognormal_copula_is_the_normal_scores_correlation():
    problem = PROBLEMS["correlated_lognormals"]
    u = np.random.default_rng(3).standard_normal((200_000, 3))
    scores = np.log(problem.to_physical(u)) - [t["mu"] for t in problem.inputs]
    scores /= [t["sigma"] for t in problem.inputs]
    # sample correlation of 2e5 normals: standard error (1 - r^2)/sqrt(n) < 2.3e-3; 4 of them
    assert np.allclose(np.corrcoef(scores.T), problem.correlation, atol=0.01)
    # the stored value of the same formula: a few ulp of the tail (abs=0: not approx's 1e-12)
    assert sps.norm.cdf(-problems.lognormal_beta()) == pytest.approx(
        # bound: the same formula, a few ulp of the normal tail: 1e-12
        REFERENCES["correlated_lognormals"]["p_f"], rel=1e-12, abs=0)


def test_the_table_of_docs_reliability_is_the_references():
    text = (ROOT / "docs" / "reliability.md").read_text()
    section = text.split("## Benchmark: uqflow against OpenTURNS", 1)[1]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[0].startswith("`"):
            rows[cells[0].strip("`")] = cells[2]
    assert sorted(rows) == sorted(PROBLEMS)
    for name, shown in rows.items():
        # a figure shown to its last digit: within half a unit of that digit
        mantissa, _, exponent = shown.partition("e")
        decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
        unit = 10.0 ** (int(exponent or 0) - decimals)
        assert abs(float(shown) - REFERENCES[name]["p_f"]) <= 0.5 * unit, name
