"""The linear solves of the SPH systems (solvers/sph/linear.py; docs/sph.md § 5): which systems
are symmetric, the nested-dissection order against SuperLU's own, and the singularity check."""

import gc
import importlib.util
import sys
import weakref

import numpy as np
import pytest
import scipy.sparse as sp

from solvers.sph.exact import eshelby_displacement
from solvers.sph.layouts import Box, Ellipse, regular_layout
from solvers.sph import linear, pardiso, refinement
from solvers.sph.linear import (Factor, LinearSolveError, MIN_SINGULAR_RATIO, coupling_graph,
                                local_couplings, nested_dissection, smallest_singular_ratio,
                                solve)
from solvers.sph.problem import ElasticProblem
from solvers.sph.stiffness import Discretisation

EPS = np.finfo(float).eps
METHODS = (("master-slave", {}), ("master-slave-cutoff", {"cutoff_threshold": 1e-8}),
           ("master-slave-local", {}), ("penalty", {"penalty": 1e4}))
#: plain MS solved in its Lagrange form (above LAGRANGE_FORM_ABOVE unknowns; here at every size)
LAGRANGE = ("master-slave", {"lagrange_form_above": 0})
SOLVED = METHODS + (LAGRANGE,)
#: PARDISO is an optional extra (Intel MKL, a large binary wheel) that CI's venv, pip install
#: -e ".[test]", does not install; "auto" never chooses it, so no default solve depends on it.
#: With it installed (pip install 'uqflow[pardiso]') these cases run
NEEDS_PARDISO = pytest.mark.skipif(
    importlib.util.find_spec("pypardiso") is None,
    reason="PARDISO is the optional extra uqflow[pardiso] (Intel MKL), which the test extra "
           "does not install and no default solve uses: pip install 'uqflow[pardiso]' runs it")


def plate(side=12):
    """benchmarks/sph_scaling.py's plate: a central inclusion, the exact edge displacement."""
    lay = regular_layout(Box(-side / 2, -side / 2, side / 2, side / 2), 1.0,
                         [Ellipse(0.0, 0.0, side / 4, side / 4)])
    disc = Discretisation(lay, 2.0)
    inside = lay.phase > 0
    eigen = np.zeros((lay.n, 3))
    eigen[inside, :2] = 0.01
    edge = eshelby_displacement(lay.x[lay.boundary], side / 4, eigenstrain=0.01,
                                E_inclusion=1000.0, nu_inclusion=0.28, E_matrix=900.0,
                                nu_matrix=0.33)
    materials = dict(E=np.where(inside, 1000.0, 900.0), nu=np.where(inside, 0.28, 0.33),
                     eigenstrain=eigen)
    return disc, materials, edge


def asymmetry(A):
    A = sp.csr_matrix(A)
    return sp.linalg.norm(A - A.T) / sp.linalg.norm(A)


@pytest.fixture(scope="module")
def small_plate():
    return plate()


@pytest.fixture
def dissect_small(monkeypatch):
    """Nested dissection at test sizes (the solver keeps it for large systems)."""
    monkeypatch.setattr(linear, "DISSECTION_ABOVE", 0)


@pytest.mark.parametrize("method,extra", METHODS)
def test_the_systems_are_symmetric_under_nodal_integration_only(small_plate, method, extra):
    disc, materials, edge = small_plate
    found = {}
    for integration in ("vci", "nodal"):
        p = ElasticProblem(disc, **materials, method=method, integration=integration, **extra)
        p.solve(edge)
        found[integration] = (asymmetry(p.K), asymmetry(p._system[1]["factor"].A))
    # nodal: K = B^T (V D) B, so K_ij and K_ji are the same sum in another order, and
    # P^T K P and K + w L^T L keep that: rounding of sums of ~100 terms, each ~eps relative
    assert max(found["nodal"]) < 100 * EPS
    # vci: the corrected test gradients differ from the trial ones: a few per cent of ||K||;
    # the penalty's w L^T L (symmetric) dominates its norm, which leaves 1e-4 or more
    assert found["vci"][0] > 1e-2
    assert found["vci"][1] > (1e-4 if method == "penalty" else 1e-2)


def grid_laplacian(m):
    one = sp.diags([-np.ones(m - 1), 2.0 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
    A = (sp.kron(one, sp.identity(m)) + sp.kron(sp.identity(m), one)).tocsr()
    x, y = np.meshgrid(np.arange(m, dtype=float), np.arange(m, dtype=float), indexing="ij")
    return A, np.c_[x.ravel(), y.ravel()]


def test_nested_dissection_is_a_permutation_whose_separators_cut_the_grid():
    A, points = grid_laplacian(40)
    perm = nested_dissection(A, points)
    assert np.array_equal(np.sort(perm), np.arange(A.shape[0]))
    # the last unknowns are the top separator: the grid line next to the median cut
    # (columns 0-19 below it, 20-39 above), one whole line of 40 points
    top = points[perm[-40:]]
    assert np.all(top[:, 0] == 19.0)


def factor_fill(A, perm):
    import scipy.sparse.linalg as spla
    lu = spla.splu(A[perm][:, perm].tocsc(), permc_spec="NATURAL")
    return lu.L.nnz + lu.U.nnz


def test_nested_dissection_fills_less_than_the_band_and_gains_with_size():
    # George's bounds on an m x m grid: O(m^2 log m) fill under nested dissection, O(m^3) in
    # the band (natural) order, so the ratio falls like log m / m
    ratios = []
    for m in (20, 40):
        A, points = grid_laplacian(m)
        ratios.append(factor_fill(A, nested_dissection(A, points))
                      / factor_fill(A, np.arange(m * m)))
    assert ratios[1] < ratios[0] < 1.0


def test_the_coupling_graph_is_the_pattern_of_abs_a_plus_its_transpose():
    rng = np.random.default_rng(3)
    dense = np.where(rng.uniform(size=(60, 60)) < 0.08, rng.uniform(-1, 1, (60, 60)), 0.0)
    dense[[5, 7, 9, 2], [7, 5, 2, 9]] = [0.0, 0.0, 1.0, -1.0]   # a pair that sums to zero
    A = sp.coo_matrix(dense)
    # (5, 7) and (7, 5) stored as explicit zeros: no coupling
    A = sp.csc_matrix((np.r_[A.data, 0.0, 0.0], (np.r_[A.row, 5, 7], np.r_[A.col, 7, 5])),
                      shape=A.shape)                   # the direct solver's format
    assert A.nnz == np.count_nonzero(dense) + 2
    graph = coupling_graph(A)
    expected = (abs(sp.csr_matrix(A)) + abs(sp.csr_matrix(A)).T).tocsr()
    assert np.array_equal(graph.indptr, expected.indptr)
    assert np.array_equal(graph.indices, expected.indices)
    assert np.all(graph.data > 0.0) and graph[5, 7] == 0.0 and graph[9, 2] > 0.0
    # the check and the order read only which entries are positive: the graph of |A| gives
    # the same ones
    assert local_couplings(A) == local_couplings(A, expected)
    points = rng.uniform(size=(60, 2))
    assert np.array_equal(nested_dissection(A, points, leaf=4),
                          nested_dissection(A, points, leaf=4, graph=expected))


def test_nested_dissection_of_coincident_points_keeps_their_order():
    A, _ = grid_laplacian(10)
    assert np.array_equal(nested_dissection(A, np.zeros((100, 2))), np.arange(100))


def lu_residual_bound(factor, A, x):
    """LU's backward error: (A + dA) x = b with |dA| <= gamma_n |L||U| (Higham, Thm 9.4), so
    ||b - A x||_1 <= gamma_n || |L||U| ||_1 ||x||_1, plus the residual's own evaluation, k
    terms a row: k eps ||A||_1 ||x||_1."""
    n = A.shape[0]
    gamma = n * EPS / (1 - n * EPS)
    k = int(np.diff(sp.csr_matrix(A).indptr).max())
    lu = getattr(factor.lu, "lu", factor.lu)
    growth = float((abs(lu.L).sum(axis=0) @ abs(lu.U)).max())
    return (gamma * growth + k * EPS * abs(A).sum(axis=0).max()) * np.abs(x).sum()


def right_hand_side(problem, edge):
    system = problem._system[1]
    if "ms" in system:
        return system["ms"].f_hat
    c, _ = problem.constraints(edge, np.ones(problem.pairs.shape[0], dtype=bool))
    if "lagrange" in system:
        return system["lagrange"].rhs(system["f"], c.rhs)
    return system["f"] + system["w"] * (c.rows.T @ c.rhs)


def parameters_map(problem):
    """The matrix that takes a system's unknowns to the parameters u (its homogeneous part):
    P for the reduced systems, the identity for the penalty's, [I 0] for the Lagrange form's."""
    system = problem._system[1]
    n = system["factor"].A.shape[0]
    if "ms" in system:
        return system["ms"].P
    if "lagrange" in system:
        return sp.eye(system["lagrange"].n, n)
    return sp.identity(n)


@pytest.mark.parametrize("method,extra", SOLVED)
def test_the_dissected_factor_gives_the_displacements_of_superlus_own_order(
        small_plate, dissect_small, method, extra):
    disc, materials, edge = small_plate
    new = ElasticProblem(disc, **materials, method=method, **extra)
    u_new = new.solve(edge).u
    # the order before nested dissection: SuperLU's MMD on A^T + A (master-slave) or COLAMD
    old = ElasticProblem(disc, **materials, method=method, dissection=False, **extra)
    u_old = old.solve(edge).u

    A = new._system[1]["factor"].A
    assert (A != old._system[1]["factor"].A).nnz == 0          # the same system, two orders
    b = right_hand_side(new, edge)
    bounds, solutions = [], []
    for problem in (new, old):
        factor = problem._system[1]["factor"]
        x = factor.solve(b)[0]
        bound = lu_residual_bound(factor, A, x)
        assert np.abs(b - A @ x).sum() <= bound
        bounds.append(bound)
        solutions.append(x)
    # x_new - x_old = A^-1 (r_old - r_new)
    inverse_norm = np.abs(np.linalg.inv(A.toarray())).sum(axis=0).max()
    difference = inverse_norm * sum(bounds)
    assert np.abs(solutions[0] - solutions[1]).sum() <= difference
    # the parameters: u = P x + u_q (master-slave) or x (penalty): at most ||P||_1 times that
    P = parameters_map(new)
    # bound: the 1e-12 only absorbs the roundings of the bound's own two sums (a few eps
    # in any order, any BLAS/numpy): the bound itself is the backward-error estimate above
    assert np.abs(u_new - u_old).sum() <= abs(P).sum(axis=0).max() * difference * (1 + 1e-12)

def test_plain_ms_in_the_lagrange_form_gives_the_reduced_systems_displacements(small_plate):
    disc, materials, edge = small_plate
    reduced = ElasticProblem(disc, **materials, method="master-slave")
    u_reduced = reduced.solve(edge).u
    lagrange = ElasticProblem(disc, **materials, method="master-slave", lagrange_form_above=0)
    u_lagrange = lagrange.solve(edge).u
    system = lagrange._system[1]
    assert "lagrange" in system and "ms" in reduced._system[1]
    form, K, f = system["lagrange"], system["K"], system["f"]
    c, _ = lagrange.constraints(edge, np.ones(lagrange.pairs.shape[0], dtype=bool))
    A, b = system["factor"].A, form.rhs(f, c.rhs)
    # MS's solution with the multipliers its own slave rows imply (s Phi_ss^T mu = (f - K u)_s)
    # solves the Lagrange form to within MS's own residuals: both agree to within the two
    # residuals times ||A^-1||
    phi_ss = c.rows[:, c.slaves].toarray()
    mu = np.linalg.solve(form.scale * phi_ss.T, (f - K @ u_reduced)[c.slaves])
    x_reduced = np.concatenate([u_reduced, mu])
    x_lagrange = system["factor"].solve(b)[0]
    assert np.array_equal(x_lagrange[:form.n], u_lagrange)
    bound = agreement_bound(A, b, x_reduced, x_lagrange)
    assert np.abs(u_reduced - u_lagrange).sum() <= bound
    # and the bound is one of rounding, or it proves nothing: two consistent solves' residuals
    # are each within k eps ||A||_1 ||x||_1 times the LU's growth (k <= 100 entries a row,
    # growth a few), so the bound is within 1e3 cond_1(A) eps ||x||_1; a solve of another
    # system (a constraint's value off by 1e-4 of itself) leaves one 1e5 times larger
    cond = np.linalg.cond(A.toarray(), 1)
    assert int(np.diff(sp.csr_matrix(A).indptr).max()) <= 100
    assert bound <= 1e3 * cond * EPS * np.abs(x_lagrange).sum()


def free_grid(m, shift=0.0):
    """A grid Laplacian with free edges (its constant vector has no energy) plus shift I."""
    A, points = grid_laplacian(m)
    A = A - sp.diags(np.asarray(A.sum(axis=1)).ravel()) + shift * sp.identity(m * m)
    return A.tocsr(), points


def test_the_singularity_check_bounds_the_smallest_singular_value_from_above(dissect_small):
    A, points = free_grid(12, shift=0.05)
    A = (A + sp.diags(0.3 * np.ones(143), 1)).tocsc()                 # not symmetric
    sigma = np.linalg.svd(A.toarray(), compute_uv=False)
    ratio, _ = smallest_singular_ratio(A, Factor(A, "direct", points=points).lu)
    exact = sigma[-1] / abs(A).max()
    # ||A^-1 z|| <= 1/sigma_min for unit z; the computed solves carry ~cond eps relative error
    assert ratio >= exact * (1 - 100 * (sigma[0] / sigma[-1]) * EPS)


def test_an_exactly_free_mode_is_refused_on_the_dissected_path(dissect_small):
    A, points = free_grid(12)
    with pytest.raises(LinearSolveError, match="singular"):
        solve(A, np.ones(144), "direct", points=points)


def test_a_mode_at_rounding_level_is_refused_naming_where_it_shows(dissect_small):
    A, points = free_grid(12, 1e-15)            # sigma_min 1e-15 of the largest entry (4)
    with pytest.raises(LinearSolveError, match="singular to working precision.*at unknown"):
        solve(A, np.ones(144), "direct", points=points)


def test_a_well_posed_system_reports_its_singular_ratio(dissect_small):
    A, points = free_grid(12, 1e-3)
    x, info = solve(A, np.ones(144), "direct", points=points)
    # A = L + 1e-3 I with L's null vector the constant: x = 1000 everywhere, to cond eps
    cond = 8.0 / 1e-3
    assert np.abs(x - 1000.0).max() <= 100 * cond * EPS * 1000.0
    # sigma_min = 1e-3, largest entry 4: the check's bound is at least that, far above 1e-13
    assert MIN_SINGULAR_RATIO < 1e-3 / 4 * (1 - 1e-6) <= info.singular_ratio


def test_small_or_nonlocal_systems_are_ordered_by_superlus_mmd_not_dissected(monkeypatch):
    A, points = grid_laplacian(20)
    assert Factor(A, "direct", points=points).ordering == "MMD"          # 400 unknowns
    monkeypatch.setattr(linear, "DISSECTION_ABOVE", 100)
    assert Factor(A, "direct", points=points).ordering == "nested dissection"
    # one unknown coupled to every other, as plain MS couples the masters near a cluster
    clique = sp.lil_matrix(A.shape)
    clique[0, :] = clique[:, 0] = 0.01
    coupled = (A + clique.tocsr()).tocsr()
    factor = Factor(coupled, "direct", points=points)
    assert factor.ordering == "MMD"
    b = np.arange(A.shape[0], dtype=float)
    x = factor.solve(b)[0]
    assert np.abs(b - coupled @ x).sum() <= lu_residual_bound(factor, coupled, x)


# -- PARDISO (the optional extra uqflow[pardiso]) ----------------------------------------------

def agreement_bound(A, b, x, y):
    """A bound on ||x - y||_1 for two solves of A z = b: x - y = A^-1 (r_y - r_x), each
    residual computed to within k eps ||A||_1 ||z||_1 (k entries a row)."""
    k = int(np.diff(sp.csr_matrix(A).indptr).max())
    residuals = sum(np.abs(b - A @ z).sum() + k * EPS * abs(A).sum(axis=0).max() * np.abs(z).sum()
                    for z in (x, y))
    return np.abs(np.linalg.inv(sp.csr_matrix(A).toarray())).sum(axis=0).max() * residuals


def assert_same_solution(ref, method, A, b, fast, slow):
    """Two solves (x, u) of one plate's system agree within their residuals, the
    displacements u = P x (+ the prescribed part) within ||P||_1 times that."""
    (x_fast, u_fast), (x_ref, u_ref) = fast, slow
    difference = agreement_bound(A, b, x_fast, x_ref)
    assert np.abs(x_fast - x_ref).sum() <= difference
    P = parameters_map(ref)
    # bound: the 1e-12 only absorbs the roundings of the bound's own sums (a few eps in any
    # order, any BLAS/numpy): the bound itself is the residual-based estimate above
    assert np.abs(u_fast - u_ref).sum() <= abs(P).sum(axis=0).max() * difference * (1 + 1e-12)


def test_pardiso_without_the_extra_says_how_to_install_it(monkeypatch):
    # None in sys.modules makes `import pypardiso` raise ImportError, installed or not; and
    # the library an earlier test found is forgotten
    monkeypatch.setitem(sys.modules, "pypardiso", None)
    monkeypatch.setattr(pardiso, "_library", None)
    A, _ = free_grid(4, shift=1.0)
    with pytest.raises(LinearSolveError, match=r"pip install 'uqflow\[pardiso\]'"):
        Factor(A, "pardiso")


def test_auto_never_chooses_pardiso():
    # a study's numbers must not depend on which extras are installed
    A, _ = free_grid(4, shift=1.0)
    assert Factor(A, "auto").method == "direct"


@NEEDS_PARDISO
@pytest.mark.parametrize("method,extra", SOLVED)
def test_pardiso_gives_superlus_displacements_within_their_backward_errors(
        small_plate, method, extra):
    disc, materials, edge = small_plate
    fast = ElasticProblem(disc, **materials, method=method, linear_solver="pardiso", **extra)
    u_fast = fast.solve(edge).u
    ref = ElasticProblem(disc, **materials, method=method, linear_solver="direct", **extra)
    u_ref = ref.solve(edge).u
    A = ref._system[1]["factor"].A
    assert fast._system[1]["factor"].ordering == "METIS (PARDISO)"
    assert (abs(fast._system[1]["factor"].A - A)).nnz == 0          # the same system
    b = right_hand_side(ref, edge)
    x_fast = fast._system[1]["factor"].solve(b)[0]
    x_ref = ref._system[1]["factor"].solve(b)[0]
    # PARDISO is held to the backward error SuperLU's own factors guarantee (its L and U are
    # not readable): a wrong order, pivot or system would leave a far larger residual
    assert np.abs(b - A @ x_fast).sum() <= lu_residual_bound(ref._system[1]["factor"], A, x_fast)
    assert_same_solution(ref, method, A, b, (x_fast, u_fast), (x_ref, u_ref))


@NEEDS_PARDISO
def test_pardiso_refuses_an_empty_row_naming_it():
    A, _ = free_grid(4, shift=1.0)
    A = A.tolil()
    A[3, :] = 0.0
    with pytest.raises(LinearSolveError, match=r"singular \(empty row 3\)"):
        Factor(sp.csr_matrix(A), "pardiso")


@NEEDS_PARDISO
def test_pardiso_refuses_singular_systems_naming_where_they_show():
    # PARDISO perturbs a tiny pivot instead of stopping: the inverse-iteration check finds it
    A, _ = free_grid(12)
    with pytest.raises(LinearSolveError, match="singular"):
        solve(A, np.ones(144), "pardiso")
    A, _ = free_grid(12, 1e-15)
    with pytest.raises(LinearSolveError, match="singular to working precision.*at unknown"):
        solve(A, np.ones(144), "pardiso")
    A, _ = free_grid(12, 1e-3)
    x, info = solve(A, np.ones(144), "pardiso")
    # A = L + 1e-3 I, L's null vector the constant: x = 1000 everywhere, to cond eps
    assert info.method == "pardiso" and np.abs(x - 1000.0).max() <= 100 * 8e3 * EPS * 1000.0


# -- single-precision factors refined in double (above MIXED_PRECISION_ABOVE unknowns) --------

SOLVERS = ("direct", pytest.param("pardiso", marks=NEEDS_PARDISO))


@pytest.fixture
def mixed(monkeypatch):
    """Single-precision factors at test sizes."""
    monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", 0)


def refinement_target(A, x, b):
    """What a refined solve promises: its residual within RESIDUAL_SLACK times the bound on the
    residual's own evaluation, gamma_{k+1} (|b| + |A||x|) summed, column by column."""
    k = int(np.diff(sp.csr_matrix(A).indptr).max()) + 1
    return refinement.RESIDUAL_SLACK * k * EPS * (np.abs(b) + abs(A) @ np.abs(x)).sum(axis=0)


@pytest.mark.parametrize("columns", [None, 1, 3])
def test_the_refinement_target_takes_abs_a_abs_x_from_the_column_sums_of_abs_a(columns):
    # an unsymmetric A whose row and column sums of |A| differ, entries of both signs, and a
    # column of b and x zero: the target from |A|'s column sums is the one from |A| @ |x|
    rng = np.random.default_rng(11)
    n = 300
    A = sp.random(n, n, density=0.03, random_state=rng, format="csr")
    A.data = rng.standard_normal(A.nnz) * np.exp(rng.uniform(-5, 5, A.nnz))
    A = (A + sp.diags(np.arange(1.0, n + 1.0))).tocsr()
    shape = (n,) if columns is None else (n, columns)
    b, x = rng.standard_normal(shape), rng.standard_normal(shape)
    if columns == 3:
        b[:, 2] = x[:, 2] = 0.0
    got, want = refinement.Refinement(A).target(b, x), refinement_target(A, x, b)
    # both sum at most nnz + n nonnegative terms: each within (nnz + n) eps of the exact sum
    assert np.all(np.abs(got - want) <= 2 * (A.nnz + n) * EPS * want)
    assert got.shape == want.shape


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("method,extra", SOLVED)
def test_single_precision_factors_refined_give_the_double_factors_displacements(
        small_plate, monkeypatch, solver, method, extra):
    disc, materials, edge = small_plate
    ref = ElasticProblem(disc, **materials, method=method, linear_solver=solver, **extra)
    u_ref = ref.solve(edge).u
    monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", 0)
    fast = ElasticProblem(disc, **materials, method=method, linear_solver=solver, **extra)
    u_fast = fast.solve(edge).u
    factor, double = fast._system[1]["factor"], ref._system[1]["factor"]
    assert factor.precision == "single, refined" and double.precision == "double"
    A = double.A
    b = right_hand_side(ref, edge)
    (x_fast, info), x_ref = factor.solve(b), double.solve(b)[0]
    # the single-precision solve alone is ~1e-7 off: the target needs refinement steps
    assert info.iterations >= 1
    assert np.abs(b - A @ x_fast).sum() <= refinement_target(A, x_fast, b)
    assert_same_solution(ref, method, A, b, (x_fast, u_fast), (x_ref, u_ref))


@pytest.mark.parametrize("solver", SOLVERS)
def test_each_column_of_a_block_is_refined_to_its_own_target(mixed, solver):
    # the block solves of a low-rank update (factor_update: E^-1 U) go through the same factors
    A, _ = free_grid(12, shift=0.05)
    factor = Factor(A, solver)
    assert factor.precision == "single, refined"
    rng = np.random.default_rng(3)
    B = np.column_stack([rng.standard_normal(144), 1e-9 * rng.standard_normal(144),
                         np.zeros(144)])
    X = factor.lu.solve(B)
    assert np.all(np.abs(B - A @ X).sum(axis=0) <= refinement_target(A, X, B))


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_system_too_ill_conditioned_for_single_precision_is_factorised_in_double(
        monkeypatch, solver):
    # cond ~ 8 / 1e-9: single precision's relative error, cond x 6e-8, is far above 1, so its
    # factors cannot be refined; the matrix is well inside double's range (singular ratio
    # ~1e-10 against the refusal's 1e-13)
    A, _ = free_grid(12, shift=1e-9)
    b = np.linspace(1.0, 2.0, 144)
    double = Factor(A, solver)
    monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", 0)
    factor = Factor(A, solver)
    assert factor.precision == "double"
    x, x_ref = factor.solve(b)[0], double.solve(b)[0]
    if solver == "direct":                  # the same SuperLU factorisation of the same matrix
        assert np.array_equal(x, x_ref)
    # and either solver within its residual of SuperLU's double solve
    superlu = Factor(A, "direct").solve(b)[0]
    assert np.abs(x - superlu).sum() <= agreement_bound(A, b, x, superlu)


@pytest.mark.parametrize("solver", SOLVERS)
def test_single_precision_factors_do_not_hide_a_singular_system(mixed, solver):
    for shift in (0.0, 1e-15):
        A, _ = free_grid(12, shift)
        with pytest.raises(LinearSolveError, match="singular"):
            solve(A, np.ones(144), solver)


def test_a_stiff_penalty_is_factorised_in_double_without_trying_single(
        small_plate, mixed, monkeypatch):
    disc, materials, edge = small_plate
    precisions = {}
    for weight in (1e4, 1e6):
        problem = ElasticProblem(disc, **materials, method="penalty", penalty=weight)
        if weight > 1e5:
            # cond(A) grows as the weight: at 1e6 refinement would stall, so single-precision
            # factors are not even built (their factorisation would be wasted)
            monkeypatch.setattr(linear, "MixedPrecisionFactor",
                                lambda *a: pytest.fail("single precision tried"))
        problem.solve(edge)
        precisions[weight] = problem._system[1]["factor"].precision
    assert precisions == {1e4: "single, refined", 1e6: "double"}


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("limit", [0, 10**9], ids=["single-refined", "double"])
def test_a_factor_is_freed_as_soon_as_it_is_dropped(monkeypatch, solver, limit):
    # no reference cycle through the factors: a large system's gigabytes of factors must go
    # when the last reference does, not at the cyclic collector's next full pass
    monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", limit)
    A, _ = free_grid(8, shift=0.05)
    gc.disable()
    try:
        factor = Factor(A, solver)
        dropped = weakref.ref(factor)
        del factor
        assert dropped() is None
    finally:
        gc.enable()


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("limit", [0, 10**9], ids=["single-refined", "double"])
def test_a_factorisation_and_its_solves_leave_nothing_to_the_cyclic_collector(
        monkeypatch, solver, limit):
    # nor any cycle through what the calls pass: pointers made by ndarray.ctypes.data_as kept
    # PARDISO's copy of A and every right-hand side alive until the collector's next pass
    monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", limit)
    A, _ = free_grid(8, shift=0.05)
    Factor(A, solver)           # the first PARDISO call loads MKL: one-off garbage of imports
    gc.collect()
    gc.disable()
    try:
        factor = Factor(A, solver)
        factor.solve(np.ones(A.shape[0]))
        del factor
        assert gc.collect() == 0
    finally:
        gc.enable()
