"""The reliability benchmark's test problems, independent of uqflow (numpy and scipy only).

Each problem is a margin g(x) of physical inputs x (g <= 0 is failure), the inputs as the
tables of a study file's ``[[inputs]]`` (and its ``[correlation]``: the Gaussian copula's), the
map from independent standard normals u to x, a design point in u, and the exact failure
probability where a formula gives it. ``benchmarks/reliability.py`` runs them through uqflow
and OpenTURNS; ``benchmarks/reliability_references.py`` writes the reference values to
``benchmarks/reliability_references.json``; ``tests/test_reliability_problems.py`` checks
the formulas and the margins.

- ``r_minus_s``: R ~ N(4, 1), S ~ N(2, 1), g = R - S, p = Phi(-sqrt 2).
- ``four_branch_6``, ``four_branch_7``: the four-branch series system in two standard
  normals, g = min(3 + (x1 - x2)^2 / 10 -+ (x1 + x2) / sqrt 2, +-(x1 - x2) + k / sqrt 2),
  k = 6 and 7. With a = (x1 + x2)/sqrt 2 and b = (x1 - x2)/sqrt 2 (independent standard
  normals) the safe set is |a| < 3 + b^2/5, |b| < k/2, so
  p = 1 - integral over |b| < k/2 of phi(b) (2 Phi(3 + b^2/5) - 1) db: one smooth integral.
- ``linear_100``: g = 4.75 - sum(u) / 10 in 100 standard normals, p = Phi(-4.75).
- ``two_design_points``: g = min(3 - w, 3.2 + w), w = (u1 + u2)/sqrt 2: two disjoint
  half-planes, design points at w = 3 and w = -3.2, p = Phi(-3) + Phi(-3.2); FORM finds one.
- ``correlated_lognormals``: load L, model factor M and capacity C lognormal with correlated
  normal scores, g = C - L M. ln C - ln L - ln M is normal, so p = Phi(-beta) with
  beta = (mu_C - mu_L - mu_M) / sd, sd^2 = a' S R S a, a = (-1, -1, 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy import integrate
from scipy import stats as sps


@dataclass(frozen=True)
class Problem:
    name: str
    title: str
    #: the study file's [[inputs]] tables, in order
    inputs: tuple[dict, ...]
    #: g of physical inputs x (n, d) -> (n,); g <= 0 fails
    margin: Callable[[np.ndarray], np.ndarray]
    #: the exact failure probability from its formula (None: no formula)
    exact: Callable[[], float] | None
    #: the Gaussian copula's correlation (None: independent inputs)
    correlation: np.ndarray | None = None
    #: the design points in u (one per row), the most probable failure points
    design_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def names(self) -> list[str]:
        return [table["name"] for table in self.inputs]

    @property
    def dimension(self) -> int:
        return len(self.inputs)

    def to_physical(self, u: np.ndarray) -> np.ndarray:
        """Independent standard normals u (n, d) to inputs x (n, d) through the copula."""
        u = np.atleast_2d(np.asarray(u, dtype=float))
        z = u if self.correlation is None else u @ np.linalg.cholesky(self.correlation).T
        x = np.empty_like(z)
        for k, table in enumerate(self.inputs):
            if table["distribution"] == "normal":
                x[:, k] = table["mean"] + table["std"] * z[:, k]
            elif table["distribution"] == "lognormal":
                x[:, k] = np.exp(table["mu"] + table["sigma"] * z[:, k])
            else:
                raise ValueError(f"{self.name}: no map for {table['distribution']}")
        return x

    def margin_u(self, u: np.ndarray) -> np.ndarray:
        return self.margin(self.to_physical(u))


def _standard_normals(names) -> tuple[dict, ...]:
    return tuple({"name": n, "distribution": "normal", "mean": 0.0, "std": 1.0}
                 for n in names)


# ------------------------------------------------------------------------------- R - S

def _r_minus_s(x):
    return x[:, 0] - x[:, 1]


R_MINUS_S = Problem(
    "r_minus_s", "R - S, R ~ N(4, 1), S ~ N(2, 1)",
    ({"name": "R", "distribution": "normal", "mean": 4.0, "std": 1.0},
     {"name": "S", "distribution": "normal", "mean": 2.0, "std": 1.0}),
    _r_minus_s, lambda: float(sps.norm.cdf(-math.sqrt(2.0))),
    design_points=np.array([[-1.0, 1.0]]))


# ------------------------------------------------------------------------ four branches

def four_branch_margin(k: float) -> Callable[[np.ndarray], np.ndarray]:
    def margin(x):
        x1, x2 = x[:, 0], x[:, 1]
        bend = 3.0 + 0.1 * (x1 - x2) ** 2
        a = (x1 + x2) / math.sqrt(2.0)
        c = k / math.sqrt(2.0)
        return np.minimum(np.minimum(bend - a, bend + a),
                          np.minimum((x1 - x2) + c, (x2 - x1) + c))
    margin.__name__ = f"four_branch_{k:g}"
    return margin


def four_branch_exact(k: float) -> tuple[float, float]:
    """p and quad's error estimate: P[|b| > k/2] plus P[|a| > 3 + b^2/5, |b| < k/2] (the
    failure set's own measure, which avoids the cancellation of 1 - P[safe])."""
    def a_tails(b):
        return sps.norm.pdf(b) * 2.0 * sps.norm.sf(3.0 + 0.2 * b * b)
    # the integrand is analytic on a bounded interval: quad meets epsrel 1e-13
    inside, error = integrate.quad(a_tails, -k / 2, k / 2, epsabs=0, epsrel=1e-13, limit=200)
    return float(2.0 * sps.norm.sf(k / 2) + inside), float(error)


def _four_branch(k: int) -> Problem:
    c = k / 2.0
    # the design points: the two straight branches at |b| = k/2 (beta = k/2 = 3 or 3.5) and
    # the two curved ones at a = +-3 (beta = 3)
    points = np.array([[3 / math.sqrt(2), 3 / math.sqrt(2)], [-3 / math.sqrt(2), -3 / math.sqrt(2)],
                       [c / math.sqrt(2), -c / math.sqrt(2)], [-c / math.sqrt(2), c / math.sqrt(2)]])
    return Problem(f"four_branch_{k}", f"four-branch series system, k = {k}",
                   _standard_normals(["x1", "x2"]), four_branch_margin(float(k)),
                   lambda: four_branch_exact(float(k))[0], design_points=points)


# ------------------------------------------------------------------ linear in 100 normals

LINEAR_BETA, LINEAR_N = 4.75, 100


def _linear_100(x):
    return LINEAR_BETA - x.sum(axis=1) / math.sqrt(LINEAR_N)


LINEAR_100 = Problem(
    "linear_100", "linear, 100 standard normals, beta = 4.75",
    _standard_normals([f"u{k:03d}" for k in range(1, LINEAR_N + 1)]), _linear_100,
    lambda: float(sps.norm.cdf(-LINEAR_BETA)),
    design_points=np.full((1, LINEAR_N), LINEAR_BETA / math.sqrt(LINEAR_N)))


# --------------------------------------------------------------------- two design points

BETA_NEAR, BETA_FAR = 3.0, 3.2


def _two_design_points(x):
    w = (x[:, 0] + x[:, 1]) / math.sqrt(2.0)
    return np.minimum(BETA_NEAR - w, BETA_FAR + w)


TWO_DESIGN_POINTS = Problem(
    "two_design_points", "two design points, beta = 3 and 3.2",
    _standard_normals(["x1", "x2"]), _two_design_points,
    # the two half-planes w >= 3 and w <= -3.2 are disjoint
    lambda: float(sps.norm.cdf(-BETA_NEAR) + sps.norm.cdf(-BETA_FAR)),
    design_points=np.array([[BETA_NEAR, BETA_NEAR], [-BETA_FAR, -BETA_FAR]]) / math.sqrt(2.0))


# ----------------------------------------------------------------- correlated lognormals

LOGNORMAL_INPUTS = (
    {"name": "load", "distribution": "lognormal", "mu": 0.0, "sigma": 0.25},
    {"name": "model_factor", "distribution": "lognormal", "mu": 0.0, "sigma": 0.1},
    {"name": "capacity", "distribution": "lognormal", "mu": math.log(3.0), "sigma": 0.15},
)
LOGNORMAL_CORRELATION = np.array([[1.0, 0.3, 0.2], [0.3, 1.0, 0.0], [0.2, 0.0, 1.0]])
_LOG_WEIGHTS = np.array([-1.0, -1.0, 1.0])


def _lognormal_margin(x):
    return x[:, 2] - x[:, 0] * x[:, 1]


def lognormal_beta() -> float:
    mu = np.array([t["mu"] for t in LOGNORMAL_INPUTS])
    s = np.array([t["sigma"] for t in LOGNORMAL_INPUTS])
    cov = np.outer(s, s) * LOGNORMAL_CORRELATION
    return float(_LOG_WEIGHTS @ mu / math.sqrt(_LOG_WEIGHTS @ cov @ _LOG_WEIGHTS))


def _lognormal_design_point() -> np.ndarray:
    # ln C - ln L - ln M = a . (mu + S L u) is linear in u: its design point is
    # -beta c / |c| with c = L' S a
    s = np.array([t["sigma"] for t in LOGNORMAL_INPUTS])
    c = np.linalg.cholesky(LOGNORMAL_CORRELATION).T @ (s * _LOG_WEIGHTS)
    return (-lognormal_beta() * c / np.linalg.norm(c))[None, :]


CORRELATED_LOGNORMALS = Problem(
    "correlated_lognormals", "capacity - load x model factor, correlated lognormals",
    LOGNORMAL_INPUTS, _lognormal_margin, lambda: float(sps.norm.cdf(-lognormal_beta())),
    correlation=LOGNORMAL_CORRELATION, design_points=_lognormal_design_point())


PROBLEMS = {p.name: p for p in (R_MINUS_S, _four_branch(6), _four_branch(7), LINEAR_100,
                                TWO_DESIGN_POINTS, CORRELATED_LOGNORMALS)}
