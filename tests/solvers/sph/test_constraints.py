"""Master–slave, cut-off and penalty on synthetic systems; singular constraint sets and
systems (solvers/sph/constraints.py, linear.py; docs/sph.md § 5)."""

import numpy as np
import pytest
import scipy.sparse as sp

from solvers.sph.constraints import (ConstraintError, Constraints, lagrange_form,
                                     master_slave, penalty_system, slave_clusters)
from solvers.sph.linear import LinearSolveError, condition_estimate, solve

EPS = np.finfo(float).eps


def laplacian_1d(n, nonsymmetric=0.0):
    K = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tolil()
    if nonsymmetric:
        K.setdiag(-1.0 - nonsymmetric, 1)
    return K.tocsr()


def rows(n, slaves, spread=3, seed=0):
    """Partition-of-unity-like rows: a dominant diagonal at each slave, neighbours around."""
    rng = np.random.default_rng(seed)
    L = sp.lil_matrix((len(slaves), n))
    for r, s in enumerate(slaves):
        for j in range(max(0, s - spread), min(n, s + spread + 1)):
            L[r, j] = 0.1 * rng.uniform(0.2, 1.0)
        L[r, s] = 1.0
    return L.tocsr()


def constraints(n, slaves, rhs=None):
    slaves = np.asarray(slaves)
    return Constraints(rows(n, slaves), np.zeros(len(slaves)) if rhs is None else rhs, slaves,
                       np.c_[slaves.astype(float), np.zeros(len(slaves))],
                       np.array([f"row {i}" for i in range(len(slaves))]))


@pytest.mark.parametrize("nonsymmetric", [0.0, 0.3])
def test_master_slave_equals_the_lagrange_multiplier_solution(nonsymmetric):
    n = 40
    K = laplacian_1d(n, nonsymmetric)
    f = np.sin(np.arange(n))
    c = constraints(n, [0, 1, 2, 20, 21, 38, 39], rhs=np.array([0.1, 0.2, 0.0, 1.0, 1.1, -1.0, 0.5]))
    ms = master_slave(K, f, c, np.c_[np.arange(n, dtype=float), np.zeros(n)])
    u = ms.expand(solve(ms.K_hat, ms.f_hat)[0])
    L = c.rows.toarray()
    # KKT with multipliers on the test side L^T, matching master-slave's P^T (...) = 0
    kkt = np.block([[K.toarray(), L.T], [L, np.zeros((L.shape[0],) * 2)]])
    ref = np.linalg.solve(kkt, np.concatenate([f, c.rhs]))[:n]
    cond = np.linalg.cond(kkt)
    # both solve the same linear system: agreement to eps times its condition
    assert np.abs(u - ref).max() < 10 * EPS * cond * np.abs(ref).max()
    assert np.abs(L @ u - c.rhs).max() < 10 * EPS * np.linalg.cond(L[:, c.slaves]) * 2
    assert ms.clusters == 3 and ms.largest_cluster == 3


@pytest.mark.parametrize("nonsymmetric", [0.0, 0.3])
def test_the_lagrange_form_gives_master_slaves_solution(nonsymmetric):
    n = 40
    K = laplacian_1d(n, nonsymmetric)
    f = np.sin(np.arange(n))
    p = np.array([0.1, 0.2, 0.0, 1.0, 1.1, -1.0, 0.5])
    c = constraints(n, [0, 1, 2, 20, 21, 38, 39], rhs=p)
    ms = master_slave(K, f, c, np.c_[np.arange(n, dtype=float), np.zeros(n)])
    u_ms = ms.expand(solve(ms.K_hat, ms.f_hat)[0])
    scale = 2.0
    form = lagrange_form(K, c, scale)
    A = form.A.toarray()
    # the swap puts the slave's own coefficient on the diagonal twice: no zero pivot there
    own = scale * c.rows[np.arange(p.size), c.slaves].A1
    assert np.array_equal(A.diagonal()[c.slaves], own)
    assert np.array_equal(A.diagonal()[n:], own)
    assert np.count_nonzero(A.diagonal()) == n + p.size
    u = np.linalg.solve(A, form.rhs(f, p))[:form.n]
    # two solutions of one linear system: agreement to eps times its condition
    assert np.abs(u - u_ms).max() < 10 * EPS * np.linalg.cond(A) * np.abs(u_ms).max()
    # a form that lost a row's scale or its swap is another system: far outside that bound
    wrong = lagrange_form(K, c, scale)
    wrong.row_order = np.arange(n + p.size)
    assert np.abs(np.linalg.solve(A, wrong.rhs(f, p))[:n] - u_ms).max() > 1e-3


def test_the_relation_matrix_is_minus_phi_ss_inverse_phi_sm():
    n = 30
    c = constraints(n, [3, 4, 5, 15, 16])
    ms = master_slave(laplacian_1d(n), np.zeros(n), c)
    L = c.rows.toarray()
    dense = -np.linalg.solve(L[:, c.slaves], L[:, ms.masters])
    assert np.abs(ms.T.toarray() - dense).max() < 1e3 * EPS   # cond(Phi_ss) ~ 2
    n_clusters, _ = slave_clusters(c.rows[:, c.slaves])
    assert n_clusters == 2


def test_the_cut_off_drops_small_entries_and_distant_masters():
    n = 60
    c = constraints(n, list(range(10, 20)))
    pts = np.c_[np.arange(n, dtype=float), np.zeros(n)]
    full = master_slave(laplacian_1d(n), np.ones(n), c, pts)
    cut = master_slave(laplacian_1d(n), np.ones(n), c, pts, threshold=1e-3)
    near = master_slave(laplacian_1d(n), np.ones(n), c, pts, pattern_radius=2.0)
    assert cut.nnz_T < full.nnz_T and near.nnz_T < full.nnz_T
    assert np.abs(cut.T.data).min() >= 1e-3
    t = near.T.tocoo()
    assert np.all(np.abs(c.points[t.row, 0] - pts[near.masters[t.col], 0]) <= 2.0)
    same = master_slave(laplacian_1d(n), np.ones(n), c, pts, threshold=0.0)
    assert (same.T != full.T).nnz == 0


def test_penalty_error_falls_as_one_over_the_weight():
    n = 40
    K = laplacian_1d(n)
    c = constraints(n, [0, 20, 39], rhs=np.array([0.0, 1.0, 0.0]))
    errors = []
    for w in (1e2, 1e4, 1e6):
        A, b, w_abs = penalty_system(K, np.zeros(n), c, w)
        # a mean of equal entries times w: one rounding, eps
        assert w_abs == pytest.approx(w * 2.0, rel=1e-15)
        assert abs(A - A.T).max() == 0.0
        u = solve(A, b)[0]
        errors.append(np.abs(c.rows @ u - c.rhs).max())
    slopes = np.diff(np.log10(errors)) / 2
    assert np.allclose(slopes, -1.0, atol=0.1)


def test_a_singular_slave_cluster_names_its_row():
    n = 20
    L = rows(n, [5, 6])
    L = sp.vstack([L[0], L[0]]).tocsr()          # two identical rows
    c = Constraints(L, np.zeros(2), np.array([5, 6]), np.array([[5.0, 0.0], [6.0, 0.0]]),
                    np.array(["pair 3 x", "pair 3 y"]))
    with pytest.raises(ConstraintError, match=r"'pair 3 x' at \(5, 0\).*singular"):
        master_slave(laplacian_1d(n), np.zeros(n), c)
    # the Lagrange form needs only L of full rank, but the method refuses what MS refuses
    with pytest.raises(ConstraintError, match=r"'pair 3 x' at \(5, 0\).*singular"):
        lagrange_form(laplacian_1d(n), c, 1.0)


def test_a_lone_slave_absent_from_its_own_row_is_refused_in_either_form():
    n = 20
    L = rows(n, [5, 12]).tolil()
    L[1, 12] = 0.0
    c = Constraints(L.tocsr(), np.zeros(2), np.array([5, 12]),
                    np.array([[5.0, 0.0], [12.0, 0.0]]), np.array(["row 0", "edge 7 y"]))
    for form in (lambda: master_slave(laplacian_1d(n), np.zeros(n), c),
                 lambda: lagrange_form(laplacian_1d(n), c, 1.0)):
        with pytest.raises(ConstraintError, match=r"'edge 7 y' at \(12, 0\).*zero coeff"):
            form()


def test_a_free_rigid_mode_is_refused_not_solved():
    n = 30
    K = laplacian_1d(n).tolil()
    K[0, 0] = K[n - 1, n - 1] = 1.0               # free-free: constant mode has no energy
    with pytest.raises(LinearSolveError, match="singular"):
        solve(K.tocsr(), np.ones(n))


def test_direct_and_iterative_agree_and_the_condition_estimate_is_close():
    n = 400
    K = laplacian_1d(n, 0.1) + sp.identity(n) * 1.0      # diagonally dominant: cond ~ 10
    b = np.cos(np.arange(n))
    x1, i1 = solve(K, b, "direct")
    x2, i2 = solve(K, b, "iterative")
    assert i2.iterations > 0
    # GMRES to a relative residual of 1e-12 on a system of condition ~10
    assert np.abs(x1 - x2).max() < 1e-12 * 1e4 * np.abs(x1).max()
    small = laplacian_1d(50, 0.2) + sp.identity(50) * 0.1
    exact = np.linalg.cond(small.toarray(), 1)
    est = condition_estimate(small)
    assert exact / 3 <= est <= exact * (1 + 1e-9)   # onenormest: a lower bound within ~3
