"""Low-rank updates of the factorised SPH systems after breaks (solvers/sph/factor_update.py;
docs/sph.md § 5): each updated solve meets a fresh LU's accuracy, the debonding runs break the
same pairs at the same steps as with a factorisation per break, and what an update cannot
serve is factorised afresh."""

import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from solvers.sph import SPHSolver, factor_update, linear, refinement
from solvers.sph.factor_update import NotLowRank, UpdatedFactor
from solvers.sph.linear import Factor
from solvers.sph.loading import run_tension
from solvers.sph.problem import ElasticProblem
from solvers.sph.stiffness import Discretisation

from .test_linear import NEEDS_PARDISO

sys.path.insert(0, str(Path(__file__).parent))
from _scenes import example3  # noqa: E402

EPS = np.finfo(float).eps
STIFF = 1e6          # a penalty spring as stiff, relative to the grid, as Example 2's


def grid(m, springs=(), anchor=True):
    """An m x m grid Laplacian with free edges, made unsymmetric by a one-sided drift (as
    the vci systems are, a few per cent), plus stiff springs between pairs of unknowns and,
    with ``anchor``, one to the ground that removes its free constant mode."""
    one = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m)).tolil()
    one[0, 0] = one[-1, -1] = 1.0
    drift = sp.diags([1.0, -1.0], [0, 1], shape=(m, m)).tolil()
    drift[-1, -1] = 0.0                       # rows summing to zero: constants stay free
    eye = sp.identity(m)
    A = sp.kron(eye, one) + sp.kron(one, eye) + 0.03 * sp.kron(eye, drift)
    A = sp.lil_matrix(A)
    for i, j in springs:
        A[i, i] += STIFF
        A[j, j] += STIFF
        A[i, j] -= STIFF
        A[j, i] -= STIFF
    if anchor:
        A[0, 0] += STIFF
    return sp.csc_matrix(A)


SPRINGS = ((5, 40), (17, 60), (22, 23), (70, 71), (90, 33))


def residual_bound(A, x, b):
    """What the update promises: a residual within RESIDUAL_SLACK times the bound on its
    own evaluation, gamma_{k+1} (|b| + |A||x|)."""
    k = int(np.diff(sp.csr_matrix(A).indptr).max()) + 1
    return refinement.RESIDUAL_SLACK * k * EPS * float((np.abs(b) + abs(A) @ np.abs(x)).sum())


def agree_within_residuals(A, x, y, b):
    """x and y both solve A z = b: x - y = A^-1 (r_y - r_x), so ||x - y||_1 is at most
    ||A^-1||_1 times the two residuals, each computed to within k eps (|b| + |A||z|)."""
    k = int(np.diff(sp.csr_matrix(A).indptr).max()) + 1
    slack = sum(k * EPS * float((np.abs(b) + abs(A) @ np.abs(z)).sum()) for z in (x, y))
    residuals = sum(float(np.abs(b - A @ z).sum()) for z in (x, y))
    inverse_norm = np.abs(np.linalg.inv(A.toarray())).sum(axis=0).max()
    # bound: the 1e-12 only absorbs the roundings of the bound's own sums (a few eps in any
    # order, any BLAS/numpy): the bound itself is the residual-based estimate above
    return np.abs(x - y).sum() <= inverse_norm * (residuals + slack) * (1 + 1e-12)


def fresh(A, solver="direct"):
    return lambda: Factor(A, solver)


@pytest.mark.parametrize("mixed", [False, True], ids=["double", "single-refined"])
@pytest.mark.parametrize("solver", ["direct", pytest.param("pardiso", marks=NEEDS_PARDISO)])
def test_removing_stiff_springs_is_solved_as_accurately_as_a_fresh_factorisation(
        monkeypatch, solver, mixed):
    if mixed:
        # a base in single precision, refined: springs 1e6 times the grid's stiffness make the
        # system too ill-conditioned for that (cond x 6e-8 > 1: it falls back to double), 100
        # times leave it well inside
        monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", 0)
        monkeypatch.setitem(globals(), "STIFF", 100.0)
    before = grid(10, SPRINGS)
    after = grid(10, SPRINGS[2:])             # two springs broken: a rank-2 change
    ids = np.arange(100)
    update = UpdatedFactor(Factor(before, solver), ids, after, ids, fresh(after, solver))
    assert update.rank == 2
    assert update.base.precision == ("single, refined" if mixed else "double")
    b = np.random.default_rng(0).standard_normal(100)
    x, info = update.solve(b)
    # the base's solves are refined to a double LU's residual, so the update's need no step
    assert update.fresh is None and info.iterations == 0
    assert np.abs(b - after @ x).sum() <= residual_bound(after, x, b)
    assert agree_within_residuals(after, x, Factor(after, "direct").solve(b)[0], b)


def test_a_chain_of_breaks_and_new_unknowns_keeps_one_base():
    # the master-slave case: each break adds unknowns (the freed slave) and changes the rows
    # that saw it; two breaks in a row are chained on the first factorisation
    full = grid(10, SPRINGS)
    ids = np.arange(100)
    first_ids = np.setdiff1d(ids, [12, 13, 55])
    second_ids = np.setdiff1d(ids, [55])
    first = Factor(full[first_ids][:, first_ids], "direct")
    second_A = grid(10, SPRINGS[1:])[second_ids][:, second_ids]
    second = UpdatedFactor(first, first_ids, second_A, second_ids, fresh(second_A))
    third_A = grid(10, SPRINGS[2:])
    third = UpdatedFactor(second, second_ids, third_A, ids, fresh(third_A))
    assert third.base is first
    assert third.rank > second.rank > 0
    b = np.linspace(-1.0, 2.0, 100)
    x, info = third.solve(b)
    assert third.fresh is None and info.iterations == 0
    assert np.abs(b - third_A @ x).sum() <= residual_bound(third_A, x, b)
    assert agree_within_residuals(third_A, x, Factor(third_A, "direct").solve(b)[0], b)


def test_an_update_is_refused_when_unknowns_go_or_the_rank_is_too_high(monkeypatch):
    A = grid(8, SPRINGS[:2])
    ids = np.arange(64)
    base = Factor(A, "direct")
    smaller = A[1:][:, 1:]
    with pytest.raises(NotLowRank, match="lost unknowns"):
        UpdatedFactor(base, ids, smaller, ids[1:], fresh(smaller))
    monkeypatch.setattr(factor_update, "MAX_UPDATE_RANK", 1)
    after = grid(8)
    with pytest.raises(NotLowRank, match="rank"):
        UpdatedFactor(base, ids, after, ids, fresh(after))


def test_a_break_that_leaves_a_free_mode_is_not_updated():
    # the only anchor goes: the new system is singular, and so is the capacitance matrix
    A = grid(8)
    free = grid(8, anchor=False)
    ids = np.arange(64)
    with pytest.raises(NotLowRank, match="singular"):
        UpdatedFactor(Factor(A, "direct"), ids, free, ids, fresh(free))


def test_a_refinement_that_cannot_reach_its_target_factorises_afresh(monkeypatch):
    before, after = grid(8, SPRINGS[:3]), grid(8, SPRINGS[1:3])
    ids = np.arange(64)
    update = UpdatedFactor(Factor(before, "direct"), ids, after, ids, fresh(after))
    monkeypatch.setattr(refinement, "RESIDUAL_SLACK", 0.0)
    b = np.ones(64)
    x, _ = update.solve(b)
    assert update.fresh is not None
    assert np.array_equal(x, Factor(after, "direct").solve(b)[0])


# -- the debonding runs ----------------------------------------------------------------------

RUN_METHODS = (("penalty", {"penalty": 1e6}), ("master-slave-local", {}), ("master-slave", {}))


@pytest.fixture(scope="module")
def plate():
    # 1,201 particles: 112 pairs, the first breaks at step 16 and a third by step 24
    return SPHSolver.from_scene(example3(spacing=3.125e-6)).layout


@pytest.mark.parametrize("method,extra", RUN_METHODS)
def test_updated_runs_break_the_pairs_of_refactorised_runs(plate, monkeypatch, method, extra):
    disc = Discretisation(plate, 2.0)
    inside = plate.phase > 0
    E, nu = np.where(inside, 150e6, 1e6), np.where(inside, 0.3, 0.4)
    built = []
    original = UpdatedFactor.__init__

    def counted(self, *args):
        original(self, *args)
        built.append(self)

    monkeypatch.setattr(UpdatedFactor, "__init__", counted)
    runs = {}
    for update in (True, False):
        problem = ElasticProblem(disc, E, nu, method=method, update_factors=update, **extra)
        runs[update] = (problem, run_tension(problem, plate, 0.04e6, 0.05e-6, 24))
    updated, refactorised = runs[True][1], runs[False][1]
    assert refactorised.intact_pairs[-1] < refactorised.intact_pairs[0]     # the plate debonds
    assert built and all(f.fresh is None for f in built)                   # and was updated
    assert np.array_equal(updated.pair_break_step, refactorised.pair_break_step)
    assert np.array_equal(updated.pair_break_resolve, refactorised.pair_break_resolve)
    # the last system, solved both ways for a right-hand side of its own scale
    factor = runs[True][0]._system[1]["factor"]
    assert isinstance(factor, UpdatedFactor)
    A = sp.csr_matrix(factor.A)
    b = A @ np.random.default_rng(1).standard_normal(A.shape[0])
    x, info = factor.solve(b)
    # the Woodbury solve alone meets the target (its residuals measured ~1e-3 of it on every
    # solve of these runs): refinement is a guard, not how the accuracy is reached
    assert info.iterations == 0
    assert np.abs(b - A @ x).sum() <= residual_bound(A, x, b)
    assert agree_within_residuals(A, x, Factor(A, "direct", nearly_symmetric=True).solve(b)[0], b)


def test_plain_ms_in_the_lagrange_form_debonds_like_its_reduced_system(plate):
    disc = Discretisation(plate, 2.0)
    inside = plate.phase > 0
    E, nu = np.where(inside, 150e6, 1e6), np.where(inside, 0.3, 0.4)
    runs = []
    for above in (0, 10**9):        # the Lagrange form at every size, then never
        problem = ElasticProblem(disc, E, nu, method="master-slave", lagrange_form_above=above)
        runs.append(run_tension(problem, plate, 0.04e6, 0.05e-6, 24))
        assert ("lagrange" in problem._system[1]) == (above == 0)
    lagrange, reduced = runs
    assert reduced.intact_pairs[-1] < reduced.intact_pairs[0]               # the plate debonds
    assert np.array_equal(lagrange.pair_break_step, reduced.pair_break_step)
    assert np.array_equal(lagrange.pair_break_resolve, reduced.pair_break_resolve)
