"""FORM and SORM: the probability of one limit state's failure from its design point.

Both work in the standard normal space u of the study's inputs: independent standard normals
mapped to the inputs through the input space's Gaussian copula (z = L u with L the Cholesky
factor of the copula correlation, x_k = F_k^-1(Phi(z_k)); a normal input is x_k = mean + std
z_k exactly). The limit state g(u) (> 0 safe, <= 0 failure) is the study's limit state
(``uqflow.limit_states``) evaluated on the runs.

FORM searches the design point u* (the failure point nearest the origin) by the improved
HL-RF iteration of Zhang and Der Kiureghian (1995): from u_k the HL-RF step
d_k = ((grad g . u_k - g) / |grad g|^2) grad g - u_k, scaled by the largest lambda in
1, 1/2, 1/4, ... that lowers the merit function m(u) = |u|^2 / 2 + c_k |g(u)| enough (Armijo).
Every trial point runs in one round with its finite-difference neighbours (``extend``), so its
gradient is at hand when the line search accepts it. The search stops when |g(u_k)| is below
``g_tolerance`` times |g(0)| and the next full step |u_{k+1} - u_k| = |d_k| is below
``u_tolerance``, or after ``max_iterations`` rounds (then the result says it did not
converge). beta = alpha . u* with alpha = -grad g / |grad g|, p_f = Phi(-beta); the importance
factors are gamma_k^2, gamma = L^-T alpha / |L^-T alpha| (alpha_k^2 for independent inputs;
Der Kiureghian 2005 for correlated ones).

SORM adds one round at the design point: the Hessian of g by central second differences
along an orthonormal basis whose last axis is alpha; the principal curvatures kappa_i are the
eigenvalues of its first n - 1 rows and columns over |grad g|. From them: Breitung (1984),
Hohenbichler-Rackwitz (1988) and Tvedt's three-term formula (1984, 1990); p_f is Tvedt's.
docs/reliability.md.
"""

from __future__ import annotations

import math
import warnings as pywarnings
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np
import xarray as xr
from pydantic import Field
from scipy import special
from scipy import stats as sps

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.layout import (FAILURE_PROBABILITY, INPUT_CORRELATION, INPUT_STD, INPUTS,
                           LIMIT_STATE, PARAMETER, PARAMETER_UNITS, RELIABILITY_INDEX,
                           REALIZATION, ROUND, SOLVER_RUNS, STATISTIC, UNITS,
                           WITH_SENSITIVITIES, is_diagnostic, ok_mask, output_names)
from uqflow.limit_states import EXCEEDS, LimitStateSystem
from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 make_design, register_method)
from uqflow.realization import sensitivity_arrays
from uqflow.report import Column, FigureSpec, MethodReport, Sensitivity, new_figure, number

# Armijo's sufficient decrease: the merit must fall by this fraction of its slope times the
# step. On a linear limit state the full HL-RF step lowers the merit by exactly half its
# slope (for c_k = |u + d|^2 / |g|), so a fraction below one half accepts it with margin.
ARMIJO = 0.1
# c_k = MERIT_FACTOR x the least weight that makes d_k a descent direction of the merit
# (Zhang and Der Kiureghian: any c_k > |u_k| / |grad g| does).
MERIT_FACTOR = 2.0
# Halvings of the step after which the line search gives up: lambda = 2^-10 of a step that
# found no decrease means the finite-difference gradient does not describe g there.
MAX_HALVINGS = 10
# Relative disagreement of the three SORM formulas above which the curvatures are called
# large: they agree to second order in kappa beta; beyond this the asymptotics are doubtful.
SORM_AGREEMENT = 0.1
# The design-point check: a probe direction within this angle of u* looks at FORM's own
# failure region (cos 30 degrees); a failure point found along another probe counts as
# another region when it lies outside FORM's half-space alpha . u >= beta by more than
# OUTSIDE_HALF_SPACE of beta (a linear limit state's own points lie on the plane, up to
# the search's tolerances), and is reported when its first-order share Phi(-t) is at least
# OTHER_REGION_SHARE of FORM's Phi(-beta): a region that changes p_f by 10 % or more.
PROBE_CONE = math.cos(math.radians(30.0))
OUTSIDE_HALF_SPACE = 0.01
OTHER_REGION_SHARE = 0.1

#: what a row of the design is: a point of the FORM search (with its gradient stencil) or a
#: point of the curvature stencil at the design point
STAGE_SEARCH, STAGE_CURVATURE, STAGE_CHECK = "search", "curvature", "design_point_check"
#: design coordinates: the row's point in standard normal space, its stencil offset (in u for
#: the search, in the rotated basis for the curvature round) and its stage
STANDARD_NORMAL, STENCIL_OFFSET, STAGE = "standard_normal", "stencil_offset", "stage"
#: design coordinate with gradient = "solver": dx_k/dz_k of each input at the row's point (the
#: slope of the copula's marginal map, so the chain rule needs no input distribution later)
INPUT_SLOPE = "input_slope"
#: the statistics of the design-point check: its probe points, g there, and the estimated
#: distance to failure along each probe's ray
CHECK_POINT, CHECK_MARGIN, CHECK_DISTANCE = ("check_point", "check_margin",
                                             "check_failure_distance")
#: labels of the outputs' statistics: each output at the inputs' medians (u = 0) and at u*
AT_MEDIANS, AT_DESIGN_POINT = "at_medians", "at_design_point"
#: the method's statistics besides the layout's p_f and beta
FORM_INDEX, FORM_PROBABILITY = "form_reliability_index", "form_failure_probability"
SORM_PROBABILITY, CURVATURES = "sorm_failure_probability", "curvatures"
DESIGN_POINT, DESIGN_POINT_U = "design_point", "design_point_standard_normal"
IMPORTANCE = "importance_factor"
#: SORM formulas, in the order of the statistics' ``sorm_formula`` dim
SORM_FORMULAS = ("breitung", "hohenbichler-rackwitz", "tvedt")


class FormOptions(MethodOptions):
    limit_state: str | None = Field(None, description="the study's limit state to analyse "
                                    "(default: its only one)")
    step: float = Field(0.01, gt=0, le=1, description="finite-difference step of the "
                        "gradient, in standard normal units")
    gradient: Literal["central", "forward", "solver"] = Field(
        "central", description="central (2n + 1 runs a round, error O(step^2)) or forward "
                               "(n + 1 runs, error O(step)) differences, or the solver's "
                               "own derivatives (1 run a round; local_sensitivities)")
    u_tolerance: float = Field(1e-3, gt=0, description="largest next step |u_{k+1} - u_k| "
                               "at convergence, in standard normal units")
    g_tolerance: float = Field(1e-3, gt=0, description="largest |g| at convergence, as a "
                               "fraction of |g| at the inputs' medians")
    max_iterations: int = Field(30, ge=1, le=10_000, description="most rounds of the search "
                                "(line-search trials included)")
    design_point_check: bool = Field(True, description="after convergence, one round of g at "
                                     "-u* and at |u*| along the other axes, to detect "
                                     "another design point")


class SormOptions(FormOptions):
    curvature_step: float = Field(0.1, gt=0, le=1, description="finite-difference step of "
                                  "the Hessian at the design point, in standard normal units")


# --------------------------------------------------------------------- standard normal space

def cholesky_of(correlation: np.ndarray) -> np.ndarray:
    return np.linalg.cholesky(correlation) if correlation.size else np.zeros((0, 0))


def to_inputs(space, u: np.ndarray) -> np.ndarray:
    """Parameter values of points ``u`` (n_points, n_inputs) of the standard normal space,
    through the input space's Gaussian copula (the map ``from_unit_hypercube`` applies to
    Phi(u)); a normal input directly as mean + std z, without the round trip through Phi."""
    u = np.atleast_2d(np.asarray(u, dtype=float))
    z = u @ cholesky_of(space.correlation).T
    columns = []
    for k, inp in enumerate(space.inputs):
        if inp.kind == "normal" or inp.variance == 0:
            columns.append(inp.mean + inp.std * z[:, k])
        else:
            p = np.clip(sps.norm.cdf(z[:, k]), 1e-15, 1 - 1e-15)
            columns.append(inp.inverse_cdf(p))
    return np.column_stack(columns) if columns else np.zeros((u.shape[0], 0))


def input_slopes(space, u: np.ndarray) -> np.ndarray:
    """dx_k/dz_k at points ``u`` (n_points, n_inputs): std_k for a normal input (exactly), and
    phi(z_k) / f_k(x_k) for another (the derivative of F_k^-1(Phi(z))); 0 for an input
    without spread. With dx/du = diag(slopes) L, the chain rule of ``solver_gradient``."""
    u = np.atleast_2d(np.asarray(u, dtype=float))
    z = u @ cholesky_of(space.correlation).T
    x = to_inputs(space, u)
    columns = []
    for k, inp in enumerate(space.inputs):
        if inp.variance == 0:
            columns.append(np.zeros(u.shape[0]))
        elif inp.kind == "normal":
            columns.append(np.full(u.shape[0], inp.std))
        else:
            density = np.asarray(inp.distribution.pdf(x[:, k]), dtype=float)
            columns.append(sps.norm.pdf(z[:, k]) / density)
    return np.column_stack(columns) if columns else np.zeros((u.shape[0], 0))


def reduced_element(state, values: xr.DataArray) -> int | None:
    """The flat index, over the output's dims, of the element whose value the limit state's
    reduction of ``values`` (one realization, with its realization dim) takes; None where the
    reduction gives no value. Every reduction (max, min, final, at, max over labels, the worst
    of the dims left) picks one element by selection and order alone, so reducing the
    elements' ranks (ties broken by position) instead of their values picks the same one and
    names it."""
    flat = np.asarray(values.values, dtype=float).ravel()
    ranks = np.empty(flat.size)
    ranks[np.argsort(flat, kind="stable")] = np.arange(flat.size, dtype=float)
    ranks[~np.isfinite(flat)] = np.nan
    picked = np.asarray(state.reduce.apply(values.copy(data=ranks.reshape(values.shape)),
                                           state.comparison).values, dtype=float).ravel()
    if picked.size != 1 or not np.isfinite(picked[0]):
        return None
    return int(np.flatnonzero(ranks == picked[0])[0])


def moving_axes(stds: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """The axes of u that move some input: u_k enters the inputs j with L_jk != 0, and moves
    them only if they have a spread."""
    return np.flatnonzero(((lower != 0) & (stds[:, None] > 0)).any(axis=0))


def rotated_basis(search, stds: np.ndarray, lower: np.ndarray):
    """The basis (columns, within the moving axes) whose last vector is alpha at the search's
    point, and those axes."""
    axes = moving_axes(stds, lower)
    gradient = search.point.gradient[axes]
    return householder_basis(-gradient / np.linalg.norm(gradient)), axes


def householder_basis(alpha: np.ndarray) -> np.ndarray:
    """An orthonormal basis (columns) whose last column is the unit vector ``alpha``: the
    reflection that swaps the last coordinate axis and alpha (closed form, no LAPACK)."""
    n = alpha.size
    e = np.zeros(n)
    e[-1] = 1.0
    w = alpha - e
    ww = float(w @ w)
    if ww == 0.0:
        return np.eye(n)
    return np.eye(n) - 2.0 * np.outer(w, w) / ww


def importance_factors(alpha: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """gamma_k^2 with gamma = L^-T alpha / |L^-T alpha| (alpha_k^2 for independent inputs)."""
    gamma = np.linalg.solve(lower.T, alpha) if lower.size else alpha
    norm = np.linalg.norm(gamma)
    return gamma**2 / norm**2 if norm > 0 else np.full(alpha.shape, np.nan)


# --------------------------------------------------------------------- SORM formulas

def sorm_probabilities(beta: float, kappa: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """(Breitung, Hohenbichler-Rackwitz, Tvedt) p_f for the reliability index ``beta`` and
    the principal curvatures ``kappa`` (> 0: the failure domain curves away from the origin),
    with the reasons a formula is undefined. A negative beta (the origin fails) is treated
    through the safe domain: its index -beta, its curvatures -kappa, p_f = 1 - P[safe]."""
    if not np.isfinite(beta) or not np.all(np.isfinite(kappa)):
        return np.full(3, np.nan), ["the reliability index or a curvature is not a number"]
    if beta < 0:
        safe, why = sorm_probabilities(-beta, -kappa)
        return 1.0 - safe, why
    kappa = np.asarray(kappa, dtype=float)
    tail = float(sps.norm.sf(beta))
    density = float(sps.norm.pdf(beta))
    psi = math.exp(sps.norm.logpdf(beta) - sps.norm.logsf(beta))  # phi / Phi(-beta)
    why = []

    def factor(scale, name):
        terms = 1.0 + scale * kappa
        if np.any(terms <= 0):
            k = int(np.argmin(terms))
            why.append(f"{name} is undefined: 1 + {scale:.4g} x kappa = {terms[k]:.4g} <= 0 "
                       f"(curvature {kappa[k]:.4g}: the limit state bends towards the origin "
                       f"too strongly)")
            return math.nan
        return float(np.prod(terms ** -0.5))

    breitung = factor(beta, "Breitung's formula")
    hohenbichler = factor(psi, "Hohenbichler-Rackwitz's formula")
    shifted = factor(beta + 1.0, "Tvedt's formula")
    if np.isnan(breitung):
        shifted = math.nan
    complex_terms = np.prod((1.0 + (beta + 1j) * kappa + 0j) ** -0.5)
    t = beta * tail - density
    tvedt = tail * breitung + t * (breitung - shifted) + \
        (beta + 1.0) * t * (breitung - float(complex_terms.real))
    return np.array([tail * breitung, tail * hohenbichler, tvedt]), why


# --------------------------------------------------------------------- the search, replayed

@dataclass
class Iteration:
    """One round of the search: its point, g and gradient there, and the line search's
    verdict."""

    round: int
    u: np.ndarray
    g: float
    gradient: np.ndarray
    step: float           # lambda of the trial (1 for the start)
    merit: float
    accepted: bool


@dataclass
class Search:
    """The state of the iHL-RF search after the rounds so far (a pure function of them)."""

    iterations: list[Iteration] = field(default_factory=list)
    point: Iteration | None = None     # the last accepted point
    direction: np.ndarray | None = None
    weight: float = math.nan           # c_k
    slope: float = math.nan            # merit slope along d_k
    step: float = 1.0
    halvings: int = 0
    converged: bool = False
    stopped: str = ""                  # why the search ended without converging
    scale: float = math.nan            # |g(0)|: the unit of g_tolerance

    def next_point(self) -> np.ndarray | None:
        if self.converged or self.stopped or self.point is None:
            return None
        return self.point.u + self.step * self.direction


def merit(u, g, weight) -> float:
    return 0.5 * float(u @ u) + weight * abs(g)


@register_method("form")
class Form(PropagationMethod):
    """FORM: the improved HL-RF search of the design point in standard normal space."""

    Options: ClassVar = FormOptions
    extends = True
    uses_limit_states: ClassVar[bool] = True
    #: whether the method adds the curvature round at the design point
    curvatures: ClassVar[bool] = False

    # ------------------------------------------------------------------ the limit state
    #: the solver's ``local_sensitivities()`` and the uncertain inputs (``check_solver``),
    #: for gradient = "solver"
    derivatives: dict | None = None
    uncertain: tuple = ()

    def solver_gradients(self) -> bool:
        """Whether the search takes g's gradient from the solver (gradient = "solver"; a
        subclass whose options have no gradient never does)."""
        return getattr(self.options, "gradient", "") == "solver"

    def check_solver(self, solver, outputs, parameter_names) -> None:
        if not self.solver_gradients():
            return
        available = solver.local_sensitivities() if hasattr(solver, "local_sensitivities") \
            else {}
        label = getattr(solver, "name", "") or type(solver).__name__
        if not available:
            raise StudyError(f"solver '{label}' has no derivatives of its outputs "
                             f"(local_sensitivities is empty): use gradient = \"central\"",
                             key="method.gradient")
        # a search point runs with the derivatives of every output the study keeps (but
        # diagnostics): the solver must have them all, or that run fails
        template = solver.outputs() if hasattr(solver, "outputs") else {}
        for out in outputs:
            if out in template and is_diagnostic(template[out]):
                continue
            if out not in available:
                raise StudyError(f"output '{out}' has no derivative in solver '{label}' "
                                 f"(those with one: {', '.join(available)}), and with "
                                 f"gradient = \"solver\" every output of the study runs with "
                                 f"its derivatives: list only those in outputs, or use "
                                 f"gradient = \"central\"", key="method.gradient")
            missing = [p for p in parameter_names if p not in available[out]]
            if missing:
                raise StudyError(f"output '{out}' has no derivative with respect to input "
                                 f"'{missing[0]}' in solver '{label}': use gradient = "
                                 f"\"central\"", key="method.gradient")
        self.derivatives, self.uncertain = dict(available), tuple(parameter_names)

    def check_limit_states(self, limit_states) -> None:
        if limit_states is None or not list(limit_states.names):
            raise StudyError(f"method '{self.name}' needs a limit state: add a "
                             f"[[limit_states]] table", key="limit_states")
        chosen = limit_states.choose(self.options.limit_state, self.name, False)
        kind = system_kind(limit_states, chosen)
        if kind:
            raise StudyError(f"'{chosen}' is a {kind} system: {self.name} linearizes one limit "
                             f"state at one design point; use monte-carlo (or name one member "
                             f"with limit_state = \"...\")", key="method.limit_state")
        if hasattr(limit_states, "require_continuous"):
            limit_states.require_continuous(chosen, self.name)
        if self.derivatives is not None:
            output = limit_states[chosen].output
            if output not in self.derivatives:
                raise StudyError(f"the solver has no derivatives of '{output}', the output of "
                                 f"limit state '{chosen}' (it has them of "
                                 f"{', '.join(self.derivatives)}): use gradient = \"central\"",
                                 key="method.gradient")
            missing = [p for p in self.uncertain if p not in self.derivatives[output]]
            if missing:
                raise StudyError(f"the solver has no derivative of '{output}' with respect to "
                                 f"input '{missing[0]}': use gradient = \"central\"",
                                 key="method.gradient")
        self.limit_states = limit_states
        self.limit_state = chosen

    def margins(self, runs: xr.Dataset) -> np.ndarray:
        """g of every realization for the chosen limit state (NaN where a run did not
        finish ok: a solver error is not a failure)."""
        g = self.limit_states.margins(runs).sel({LIMIT_STATE: self.limit_state})
        return np.where(ok_mask(runs), np.asarray(g.values, dtype=float), np.nan)

    # ------------------------------------------------------------------ designs
    def plan(self, space, fields, seed):
        self.check(space, fields)
        if getattr(self, "limit_states", None) is None:
            raise StudyError(f"method '{self.name}' needs a limit state: add a "
                             f"[[limit_states]] table", key="limit_states")
        self._space = space
        return self.search_rows(np.zeros(len(space)), 0)

    def search_rows(self, centre: np.ndarray, round_: int) -> xr.Dataset:
        """A search round: ``centre`` and its gradient stencil along the moving axes."""
        space = self._space
        lower = cholesky_of(space.correlation)
        h = self.options.step
        offsets = [np.zeros(len(space))]
        # the solver's derivatives come with the centre's run: no stencil
        axes = [] if self.solver_gradients() else moving_axes(space.stds, lower)
        for k in axes:
            for sign in ((1.0, -1.0) if self.options.gradient == "central" else (1.0,)):
                row = np.zeros(len(space))
                row[k] = sign * h
                offsets.append(row)
        offsets = np.array(offsets)
        return self.rows(centre + offsets, offsets, round_, STAGE_SEARCH)

    def curvature_rows(self, search: Search, round_: int) -> xr.Dataset:
        """The curvature round: u* + h (+-b_i) and u* + h (+-b_i +-b_j) for the basis vectors
        b_i orthogonal to alpha (within the moving axes)."""
        space = self._space
        basis, axes = rotated_basis(search, space.stds, cholesky_of(space.correlation))
        h = self.options.curvature_step
        coefficients = []
        m = basis.shape[1] - 1
        for i in range(m):
            for s in (1.0, -1.0):
                c = np.zeros(m + 1)
                c[i] = s * h
                coefficients.append(c)
        for i in range(m):
            for j in range(i + 1, m):
                for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                    c = np.zeros(m + 1)
                    c[i], c[j] = si * h, sj * h
                    coefficients.append(c)
        coefficients = np.array(coefficients).reshape(-1, m + 1)
        u = np.tile(search.point.u, (coefficients.shape[0], 1))
        u[:, axes] += coefficients @ basis.T
        offsets = np.zeros_like(u)
        offsets[:, axes] = coefficients
        return self.rows(u, offsets, round_, STAGE_CURVATURE)

    def rows(self, u, offsets, round_, stage) -> xr.Dataset:
        n = u.shape[0]
        extra = {}
        if self.solver_gradients():
            # a search point runs with the solver's derivatives; every row says whether, so
            # the rounds' designs concatenate
            extra[WITH_SENSITIVITIES] = (REALIZATION, np.full(n, stage == STAGE_SEARCH))
        design = make_design(self._space, to_inputs(self._space, u),
                             **{ROUND: (REALIZATION, np.full(n, round_, dtype=np.int64))},
                             **extra)
        if self.solver_gradients():
            design = design.assign_coords({INPUT_SLOPE: (
                (REALIZATION, PARAMETER), input_slopes(self._space, u),
                {"long_name": "dx/dz of each input at the row's point (copula marginal map)"})})
        # coordinates, not data variables: everything in the runs with a realization dim
        # is taken for a solver output
        return design.assign_coords({
            STANDARD_NORMAL: ((REALIZATION, PARAMETER), u,
                              {"long_name": "point in standard normal space"}),
            STENCIL_OFFSET: ((REALIZATION, PARAMETER), offsets,
                             {"long_name": "finite-difference offset (search: in u; "
                                           "curvature: in the basis rotated to alpha)"}),
            STAGE: (REALIZATION, np.full(n, stage, dtype=object))})

    def extend(self, design, runs):
        search = self.replay(runs)
        rounds = int(runs[ROUND].values.max())
        following = search.next_point()
        if following is not None:
            return self.search_rows(following, rounds + 1)
        if getattr(self.options, "design_point_check", False) and search.converged and \
                not np.any(runs[STAGE].values == STAGE_CHECK):
            probes = self.probe_points(search)
            if probes.size:
                return self.rows(probes, np.zeros_like(probes), rounds + 1, STAGE_CHECK)
        # one moving axis has no curvature to measure: SORM is FORM there
        curved = len(moving_axes(self._space.stds, cholesky_of(self._space.correlation))) > 1
        if self.curvatures and search.converged and curved and \
                not np.any(runs[STAGE].values == STAGE_CURVATURE):
            return self.curvature_rows(search, rounds + 1)
        return None

    # ------------------------------------------------------------------ the search
    def round_values(self, runs: xr.Dataset, g: np.ndarray, rows: np.ndarray):
        """(centre u, g there, gradient) of one search round; the gradient is NaN if a run
        of its stencil failed."""
        u = runs[STANDARD_NORMAL].values[rows]
        offsets = runs[STENCIL_OFFSET].values[rows]
        centre = int(np.flatnonzero(~offsets.any(axis=1))[0])
        n = u.shape[1]
        if self.solver_gradients():
            return u[centre], float(g[rows[centre]]), self.solver_gradient(runs, rows[centre]), \
                rows[centre]
        gradient = np.zeros(n)
        for k in range(n):
            plus = np.flatnonzero(offsets[:, k] > 0)
            minus = np.flatnonzero(offsets[:, k] < 0)
            if not plus.size:
                continue  # an axis that moves no input: g does not depend on it
            top = plus[0]
            bottom = minus[0] if minus.size else centre
            # the realized spacing of the stored points, not the nominal step
            gradient[k] = (g[rows[top]] - g[rows[bottom]]) / (u[top, k] - u[bottom, k])
        return u[centre], float(g[rows[centre]]), gradient, rows[centre]

    def solver_gradient(self, runs: xr.Dataset, row: int) -> np.ndarray:
        """grad_u g at realization ``row`` from the solver's derivatives of the limit state's
        output: the derivative at the element the reduction picked (the max's argmax, the
        value at the coordinates), signed as g (-dy/dx for exceeds), then the chain rule
        through the copula, grad_u g = L^T (dx/dz * grad_x g). NaN if the run failed."""
        state = self.limit_states[self.limit_state]
        n = runs.sizes[PARAMETER]
        indices, gradients, _ = sensitivity_arrays(runs, state.output)
        found = np.flatnonzero(indices == row)
        if not found.size:
            return np.full(n, np.nan)
        values = runs[state.output].isel({REALIZATION: [row]})
        element = reduced_element(state, values)
        if element is None:
            return np.full(n, np.nan)
        dy_dx = gradients[found[0]].reshape(-1, n)[element]
        dg_dx = -dy_dx if state.comparison == EXCEEDS else dy_dx
        slopes = np.asarray(runs[INPUT_SLOPE].values[row], dtype=float)
        # an input without spread does not move: its (possibly NaN) derivative does not count
        dg_dz = np.where(slopes == 0, 0.0, slopes * dg_dx)
        lower = cholesky_of(np.asarray(runs[INPUT_CORRELATION].values, dtype=float))
        return lower.T @ dg_dz

    def probe_points(self, search: Search) -> np.ndarray:
        """The design-point check's points: the mirror -u*, and |u*| along each moving axis
        either way, but those within PROBE_CONE of u* (FORM's own region) and repeats."""
        u_star = search.point.u
        beta = float(np.linalg.norm(u_star))
        if beta == 0:
            return np.zeros((0, u_star.size))
        lower = cholesky_of(self._space.correlation)
        found = [-u_star]
        for k in moving_axes(self._space.stds, lower):
            for sign in (1.0, -1.0):
                probe = np.zeros(u_star.size)
                probe[k] = sign * beta
                if probe @ u_star / beta**2 >= PROBE_CONE or \
                        any(np.allclose(probe, f, rtol=0, atol=1e-12 * beta) for f in found):
                    continue
                found.append(probe)
        return np.array(found)

    def replay(self, runs: xr.Dataset) -> Search:
        """The search state after the finished rounds, computed from the runs alone (so a
        resumed study asks the same questions of the same runs)."""
        opts = self.options
        g = self.margins(runs)
        rounds = runs[ROUND].values
        stage = runs[STAGE].values
        search = Search()
        for r in np.unique(rounds[stage == STAGE_SEARCH]):
            rows = np.flatnonzero((rounds == r) & (stage == STAGE_SEARCH))
            u, g_c, gradient, _ = self.round_values(runs, g, rows)
            usable = np.isfinite(g_c) and np.all(np.isfinite(gradient)) and \
                np.linalg.norm(gradient) > 0
            if search.point is None:
                search.iterations.append(Iteration(int(r), u, g_c, gradient, 1.0, math.nan,
                                                   usable))
                if not usable:
                    search.stopped = ("g or its gradient at the inputs' medians is not "
                                      "available (a run failed, or g does not change there)")
                    break
                search.scale = abs(g_c) if g_c != 0 else float(np.linalg.norm(gradient))
                self.accept(search, search.iterations[-1])
            else:
                value = merit(u, g_c, search.weight) if usable else math.nan
                base = merit(search.point.u, search.point.g, search.weight)
                accepted = bool(usable and value <= base + ARMIJO * search.step * search.slope)
                iteration = Iteration(int(r), u, g_c, gradient, search.step, value, accepted)
                search.iterations.append(iteration)
                if accepted:
                    self.accept(search, iteration)
                else:
                    search.halvings += 1
                    search.step *= 0.5
                    if search.halvings > MAX_HALVINGS:
                        search.stopped = (f"the line search found no decrease of the merit "
                                          f"function in {MAX_HALVINGS} halvings of the step")
            if not search.converged and not search.stopped and \
                    len(search.iterations) >= opts.max_iterations:
                search.stopped = f"max_iterations = {opts.max_iterations} rounds reached"
        return search

    def accept(self, search: Search, iteration: Iteration) -> None:
        """Make ``iteration`` the current point: its HL-RF direction, merit weight and
        slope, and whether the search has converged there."""
        u, g, grad = iteration.u, iteration.g, iteration.gradient
        norm2 = float(grad @ grad)
        direction = ((grad @ u - g) / norm2) * grad - u
        least = math.sqrt(float(u @ u) / norm2)
        if g != 0:
            least = max(least, 0.5 * float((u + direction) @ (u + direction)) / abs(g))
        weight = MERIT_FACTOR * least
        iteration.merit = merit(u, g, weight)
        search.point, search.direction, search.weight = iteration, direction, weight
        search.slope = float(u @ direction) + weight * float(np.sign(g)) * float(
            grad @ direction)
        search.step, search.halvings = 1.0, 0
        search.converged = bool(abs(g) <= self.options.g_tolerance * search.scale and
                                np.linalg.norm(direction) <= self.options.u_tolerance)

    # ------------------------------------------------------------------ statistics
    def analyze(self, design, runs):
        search = self.replay(runs)
        warnings = self.failure_notes(runs)
        space_names = [str(p) for p in design[PARAMETER].values]
        n = len(space_names)
        lower = cholesky_of(np.asarray(design[INPUT_CORRELATION].values, dtype=float))
        point = search.point
        beta, alpha, importance = math.nan, np.full(n, np.nan), np.full(n, np.nan)
        u_star, x_star = np.full(n, np.nan), np.full(n, np.nan)
        if point is not None:
            alpha = -point.gradient / np.linalg.norm(point.gradient)
            beta = float(alpha @ point.u)
            importance = importance_factors(alpha, lower)
            u_star = point.u
            centre = self.centre_row(runs, point.round)
            x_star = np.asarray(runs[INPUTS].values[centre], dtype=float)
        if not search.converged:
            warnings.append(f"FORM did not converge ({search.stopped or 'the search stopped'}"
                            f"): beta and the design point are those of the last accepted "
                            f"point and cannot be trusted")
        form_pf = float(sps.norm.sf(beta)) if np.isfinite(beta) else math.nan
        data = {
            RELIABILITY_INDEX: ((LIMIT_STATE,), [beta], {"long_name": "reliability index "
                                                         "beta = -Phi^-1(p_f)", UNITS: "1"}),
            FORM_INDEX: ((LIMIT_STATE,), [beta], {
                "long_name": "FORM reliability index alpha . u*", UNITS: "1"}),
            FORM_PROBABILITY: ((LIMIT_STATE,), [form_pf], {
                "long_name": "FORM failure probability Phi(-beta)", UNITS: "1"}),
            FAILURE_PROBABILITY: ((LIMIT_STATE,), [form_pf], {
                "long_name": "failure probability", UNITS: "1"}),
            DESIGN_POINT: ((LIMIT_STATE, PARAMETER), [x_star], {
                "long_name": "design point in the inputs' units"}),
            DESIGN_POINT_U: ((LIMIT_STATE, PARAMETER), [u_star], {
                "long_name": "design point u* in standard normal space", UNITS: "1"}),
            "alpha": ((LIMIT_STATE, PARAMETER), [alpha], {
                "long_name": "unit vector alpha = -grad g / |grad g| at u*", UNITS: "1"}),
            IMPORTANCE: ((LIMIT_STATE, PARAMETER), [importance], {
                "long_name": "importance factor gamma^2 (alpha^2 for independent inputs)",
                UNITS: "1"}),
        }
        data.update(self.history(search, n))
        stats = xr.Dataset(data, coords={LIMIT_STATE: [self.limit_state],
                                         PARAMETER: space_names})
        if self.curvatures:
            warnings += self.add_sorm(stats, runs, search, beta)
        if point is not None:
            warnings += self.add_check(stats, runs, search, beta, alpha)
        for out in output_names(runs):
            values = np.asarray(runs[out].values, dtype=float)
            ok = ok_mask(runs)
            at_medians = values[0] if ok[0] else np.full(values.shape[1:], np.nan)
            at_design = np.full(values.shape[1:], np.nan)
            if point is not None:
                centre = self.centre_row(runs, point.round)
                at_design = values[centre] if ok[centre] else at_design
            stats[out] = xr.DataArray(np.stack([at_medians, at_design]),
                                      dims=(STATISTIC, *runs[out].dims[1:]))
        stats = stats.assign_coords({STATISTIC: [AT_MEDIANS, AT_DESIGN_POINT]})
        stats = stats.assign_coords({d: runs[d] for d in runs.coords
                                     if d not in (REALIZATION, PARAMETER) and d in stats.dims})
        for message in warnings:
            pywarnings.warn(message, AccuracyWarning, stacklevel=2)
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        state = self.limit_states[self.limit_state]
        stats.attrs[LIMIT_STATE] = self.limit_state
        stats.attrs.update(limit_state_output=state.output,
                           limit_state_event=state.describe(),
                           converged=int(search.converged), stop_reason=search.stopped,
                           iterations=len(search.iterations), step=self.options.step,
                           gradient=self.options.gradient,
                           g_tolerance=self.options.g_tolerance,
                           u_tolerance=self.options.u_tolerance)
        stats.attrs.update(convergence_diagnostics(search, alpha))
        return stats

    def add_check(self, stats, runs, search, beta, alpha) -> list[str]:
        """The design-point check's round: along each probe's ray from the origin, the
        distance t where g, interpolated linearly between the medians and the probe, reaches
        0; a failure point t p/|p| outside FORM's half-space, whose Phi(-t) is a tenth of
        Phi(-beta) or more, is another design point: a warning says where."""
        rows = np.flatnonzero(runs[STAGE].values == STAGE_CHECK)
        if not rows.size:
            return []
        g = self.margins(runs)
        probes = np.asarray(runs[STANDARD_NORMAL].values[rows], dtype=float)
        at_probe = g[rows]
        g0 = float(search.iterations[0].g)
        radius = np.linalg.norm(probes, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            distance = np.where((at_probe < g0) & np.isfinite(at_probe),
                                radius * g0 / (g0 - at_probe), np.inf)
        if not (g0 > 0 and beta > 0):
            distance[:] = np.nan   # the medians fail: no region "beyond" them to compare
        stats[CHECK_POINT] = (("check", PARAMETER), probes, {
            "long_name": "probe point of the design-point check in standard normal space",
            UNITS: "1"})
        stats[CHECK_MARGIN] = (("check",), at_probe, {"long_name": "g at the probe point"})
        stats[CHECK_DISTANCE] = (("check",), distance, {
            "long_name": "distance to g = 0 along the probe's ray (g linear between the "
                         "medians and the probe; inf: g does not fall)", UNITS: "1"})
        others = []
        for k in np.argsort(distance):
            t = distance[k]
            if not np.isfinite(t):
                continue
            failure = t * probes[k] / radius[k]
            outside = float(alpha @ failure) < (1 - OUTSIDE_HALF_SPACE) * beta
            if outside and sps.norm.sf(t) >= OTHER_REGION_SHARE * sps.norm.sf(beta):
                others.append((t, failure, k))
        stats.attrs["other_design_points"] = len(others)
        names = [str(p) for p in runs[PARAMETER].values]
        found = []

        def point(u):
            return ", ".join(f"{v + 0.0:.3g}" for v in u)   # + 0.0: no "-0"

        for t, failure, k in others:
            x = np.asarray(runs[INPUTS].values[rows[k]], dtype=float)
            found.append(
                f"another design point near u = ({point(failure)}) "
                f"with beta about {t:.3g} (FORM's beta {beta:.3g}): g = {at_probe[k]:.3g} at "
                f"the probe u = ({point(probes[k])}), "
                + ", ".join(f"{p} = {v + 0.0:.4g}" for p, v in zip(names, x))
                + "; FORM's p_f counts the failure region at u* only (use monte-carlo or "
                  "importance sampling)")
        return found

    def centre_row(self, runs, round_: int) -> int:
        rows = np.flatnonzero((runs[ROUND].values == round_) &
                              (runs[STAGE].values == STAGE_SEARCH))
        offsets = runs[STENCIL_OFFSET].values[rows]
        return int(rows[np.flatnonzero(~offsets.any(axis=1))[0]])

    @staticmethod
    def history(search: Search, n: int) -> dict:
        its = search.iterations
        u = np.array([it.u for it in its]).reshape(len(its), n)
        return {
            "iteration_point": (("iteration", PARAMETER), u, {
                "long_name": "trial point u of each round", UNITS: "1"}),
            "iteration_margin": (("iteration",), [it.g for it in its], {
                "long_name": "g at the trial point"}),
            "iteration_distance": (("iteration",), np.linalg.norm(u, axis=1) if its else [],
                                   {"long_name": "|u| of the trial point", UNITS: "1"}),
            "iteration_step": (("iteration",), [it.step for it in its], {
                "long_name": "line-search step lambda of the trial", UNITS: "1"}),
            "iteration_accepted": (("iteration",), np.array([it.accepted for it in its],
                                                            dtype=np.int8), {
                "long_name": "1 where the line search accepted the trial"}),
        }

    def failure_notes(self, runs) -> list[str]:
        failed = int((~ok_mask(runs)).sum())
        if not failed:
            return []
        return [f"{failed} of {runs.sizes[REALIZATION]} runs did not finish ok: a trial point "
                f"with a failed run of its stencil is treated as one the line search rejects "
                f"(a failed curvature run leaves SORM undefined)"]

    def add_sorm(self, stats, runs, search, beta) -> list[str]:
        """The curvature round's Hessian, the principal curvatures and the SORM p_f."""
        warnings = []
        rows = np.flatnonzero(runs[STAGE].values == STAGE_CURVATURE)
        stds = np.asarray(runs[INPUT_STD].values, dtype=float)
        lower = cholesky_of(np.asarray(runs[INPUT_CORRELATION].values, dtype=float))
        m = max(len(moving_axes(stds, lower)) - 1, 0)
        kappa = np.full(m, np.nan)
        if search.point is None or not search.converged:
            warnings.append("SORM needs a converged design point; it is not computed")
        elif m == 0:
            kappa = np.zeros(0)  # one moving axis: the limit state is a point, not curved
        elif not rows.size:
            warnings.append("the curvature round did not run: SORM is undefined")
        else:
            g = self.margins(runs)
            _, axes = rotated_basis(search, stds, lower)
            coefficients = runs[STENCIL_OFFSET].values[rows][:, axes]
            centre = float(search.point.g)
            hessian = np.full((m, m), np.nan)

            def value_at(target):
                hit = np.flatnonzero(np.all(np.sign(coefficients) == target, axis=1))
                return (g[rows[hit[0]]], coefficients[hit[0]]) if hit.size else \
                    (math.nan, None)

            for i in range(m):
                plus, cp = value_at(_signs(m + 1, {i: 1}))
                minus, cm = value_at(_signs(m + 1, {i: -1}))
                if cp is not None and cm is not None:
                    hp, hm = cp[i], -cm[i]
                    hessian[i, i] = 2 * ((plus - centre) / hp - (centre - minus) / hm) / \
                        (hp + hm)
                for j in range(i + 1, m):
                    corners = [value_at(_signs(m + 1, {i: a, j: b}))
                               for a, b in ((1, 1), (1, -1), (-1, 1), (-1, -1))]
                    if all(c is not None for _, c in corners):
                        (pp, c1), (pm, _), (mp, _), (mm, c4) = corners
                        spread = (c1[i] - c4[i]) * (c1[j] - c4[j])
                        hessian[i, j] = hessian[j, i] = (pp - pm - mp + mm) / spread
            if np.all(np.isfinite(hessian)):
                kappa = np.sort(np.linalg.eigvalsh(hessian)) / np.linalg.norm(
                    search.point.gradient)
            else:
                warnings.append("a run of the curvature round failed: SORM is undefined")
        if search.converged and np.all(np.isfinite(kappa)):
            probabilities, why = sorm_probabilities(beta, kappa)
        else:
            probabilities, why = np.full(3, np.nan), []
        warnings += [f"SORM: {w}" for w in why]
        finite = probabilities[np.isfinite(probabilities)]
        if finite.size >= 2 and (finite.max() - finite.min()) > SORM_AGREEMENT * finite.min():
            warnings.append(f"SORM: large curvatures (kappa beta up to "
                            f"{np.max(np.abs(kappa)) * abs(beta):.3g}): Breitung, "
                            f"Hohenbichler-Rackwitz and Tvedt disagree by more than "
                            f"{SORM_AGREEMENT:.0%} ({', '.join(f'{p:.3g}' for p in finite)}); "
                            f"check with a sampling method")
        chosen = probabilities[2]
        stats[CURVATURES] = (("curvature",), kappa, {
            "long_name": "principal curvatures of the limit state at u*", UNITS: "1"})
        stats[SORM_PROBABILITY] = ((LIMIT_STATE, "sorm_formula"), [probabilities], {
            "long_name": "SORM failure probability", UNITS: "1"})
        stats = stats.assign_coords(sorm_formula=list(SORM_FORMULAS))
        stats[FAILURE_PROBABILITY].values[:] = chosen
        with np.errstate(invalid="ignore"):
            stats[RELIABILITY_INDEX].values[:] = -special.ndtri(chosen) \
                if np.isfinite(chosen) else math.nan
        return warnings

    # ------------------------------------------------------------------ report
    @classmethod
    def report(cls, view):
        """beta, p_f, the design point and the importance factors (as a Sensitivity, so the
        framework draws their bar chart); the runs are search points, not draws."""
        stats = view.stats
        attrs = stats.attrs
        name = str(attrs.get(LIMIT_STATE, "?"))
        converged = bool(int(attrs.get("converged", 0)))
        runs = int(attrs.get(SOLVER_RUNS, 0))
        beta = float(stats[RELIABILITY_INDEX].values[0]) if RELIABILITY_INDEX in stats \
            else math.nan
        pf = float(stats[FAILURE_PROBABILITY].values[0]) if FAILURE_PROBABILITY in stats \
            else math.nan
        kind = "SORM" if SORM_PROBABILITY in stats else "FORM"
        event = f" ({attrs['limit_state_event']})" if attrs.get("limit_state_event") else ""
        notes = [f"{kind}, limit state '{name}'{event}: beta = {number(beta)}, "
                 f"p_f = {number(pf)}"
                 + ("" if converged else f" (NOT converged: {attrs.get('stop_reason', '')})")
                 + f"; {int(attrs.get('iterations', 0))} search rounds"]
        if SORM_PROBABILITY in stats:
            values = stats[SORM_PROBABILITY].values[0]
            notes.append("SORM p_f: " + ", ".join(
                f"{f} {number(v)}" for f, v in zip(SORM_FORMULAS, values))
                + f"; FORM {number(float(stats[FORM_PROBABILITY].values[0]))}")
            notes.append("principal curvatures: " + ", ".join(
                number(k) for k in stats[CURVATURES].values))
        if DESIGN_POINT in stats:
            units = [str(u) for u in stats[PARAMETER_UNITS].values] \
                if PARAMETER_UNITS in stats.coords else [""] * stats.sizes[PARAMETER]
            notes.append("design point: " + ", ".join(
                f"{p} = {number(v)}{(' ' + u) if u else ''}" for p, v, u in zip(
                    stats[PARAMETER].values, stats[DESIGN_POINT].values[0], units)))
        if "final_step" in attrs:
            how = "from the solver" if attrs.get("gradient") == "solver" else \
                f"by {attrs.get('gradient', '?')} differences"
            notes.append(
                f"convergence: |g(u*)| / |g(medians)| = "
                f"{number(float(attrs['final_relative_margin']))} (g_tolerance "
                f"{number(float(attrs.get('g_tolerance', math.nan)))}), next step |d| = "
                f"{number(float(attrs['final_step']))} (u_tolerance "
                f"{number(float(attrs.get('u_tolerance', math.nan)))}), 1 - cos(u*, -grad g) "
                f"= {number(float(attrs['alignment_error']))}; gradients {how}")
        if CHECK_MARGIN in stats:
            count = int(attrs.get("other_design_points", 0))
            notes.append(f"design-point check: g at {stats.sizes['check']} probe points at "
                         f"|u*| (-u* and along the other axes): "
                         + ("no other design point found" if not count else
                            f"{count} other design point(s), see the warnings"))
        output = str(attrs.get("limit_state_output", ""))

        def importance(out):
            if IMPORTANCE not in stats or (output and out != output):
                return None
            values = stats[IMPORTANCE].isel({LIMIT_STATE: 0}).expand_dims(
                {"index": ["importance factor alpha²"]}, axis=1)
            return Sensitivity(title=f"{kind} importance factors of '{name}'", values=values,
                               quantity="share of beta² (sums to 1)",
                               note="" if converged else "FORM did not converge")

        return MethodReport(
            description=f"{kind} of limit state '{name}', {runs} run{'' if runs == 1 else 's'}",
            columns=[Column("at design point [u]", lambda out, focus: number(
                stats[out].sel({STATISTIC: AT_DESIGN_POINT}).isel(focus)), right_aligned=True)],
            notes=notes, sensitivities=importance,
            figures=[FigureSpec("form_convergence", convergence_figure, per_output=False)])


def convergence_diagnostics(search: Search, alpha: np.ndarray) -> dict:
    """How close the last accepted point is to a design point, as attributes: |g| there over
    |g(0)| (the unit of g_tolerance), the next HL-RF step |d| (u_tolerance), and the angle
    between u and -grad g, 1 - alpha . u / |u| (0 at a design point, where u = beta alpha)."""
    point = search.point
    if point is None:
        return {}
    norm = float(np.linalg.norm(point.u))
    return {"final_relative_margin": abs(point.g) / search.scale if search.scale else math.nan,
            "final_step": float(np.linalg.norm(search.direction)),
            "alignment_error": 1.0 - float(alpha @ point.u) / norm if norm > 0 else 0.0}


def convergence_figure(view, _output=None):
    """The search round by round: |g| / |g(0)| on a log axis and |u| of each trial point,
    the trials the line search rejected marked apart."""
    stats = view.stats
    if "iteration_margin" not in stats or stats.sizes.get("iteration", 0) < 1:
        return None
    g = np.abs(np.asarray(stats["iteration_margin"].values, dtype=float))
    scale = g[0] if g.size and g[0] > 0 else 1.0
    distance = np.asarray(stats["iteration_distance"].values, dtype=float)
    accepted = np.asarray(stats["iteration_accepted"].values, dtype=bool)
    rounds = np.arange(g.size)
    fig, (top, bottom) = new_figure(height=5.2, rows=2)
    relative = np.where(g > 0, g / scale, np.nan)
    top.semilogy(rounds[accepted], relative[accepted], "o-", color="#1f4e79",
                 label="accepted point")
    top.semilogy(rounds[~accepted], relative[~accepted], "x", color="#c0392b",
                 label="trial the line search rejected")
    tolerance = stats.attrs.get("g_tolerance")
    if tolerance:
        top.axhline(float(tolerance), color="0.4", linestyle="--", linewidth=1,
                    label="g_tolerance")
    top.set_ylabel("|g| / |g(medians)|")
    top.legend(loc="best", fontsize="small")
    bottom.plot(rounds[accepted], distance[accepted], "o-", color="#2e7d32")
    bottom.plot(rounds[~accepted], distance[~accepted], "x", color="#c0392b")
    bottom.set_ylabel("|u| of the trial point")
    bottom.set_xlabel("search round")
    from matplotlib.ticker import MaxNLocator   # rounds are whole numbers

    bottom.xaxis.set_major_locator(MaxNLocator(integer=True))
    converged = "converged" if int(stats.attrs.get("converged", 0)) else "NOT converged"
    top.set_title(f"{view.study}: FORM search of '{stats.attrs.get(LIMIT_STATE, '?')}' "
                  f"({converged})")
    return fig


def _signs(n: int, which: dict[int, int]) -> np.ndarray:
    s = np.zeros(n)
    for k, v in which.items():
        s[k] = v
    return s


def system_kind(limit_states, name: str) -> str:
    """'series' or 'parallel' when ``name`` is a system of the study's limit states, '' for
    a single limit state."""
    item = limit_states[name]
    return str(item.kind) if isinstance(item, LimitStateSystem) else ""


@register_method("sorm")
class Sorm(Form):
    """SORM: FORM's design point and the principal curvatures there."""

    Options: ClassVar = SormOptions
    curvatures = True
