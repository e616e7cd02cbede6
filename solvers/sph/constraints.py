"""Linear constraints L u = p imposed by master–slave elimination or by a penalty (seed §2, §4).

Master–slave (seed eq. 3-7, 27): each row r names the DOF it eliminates, ``slaves[r]``;
with Phi_ss = L[:, slaves] and Phi_sm = L[:, masters],

    u_s = T u_m + q,   T = -Phi_ss^-1 Phi_sm,   q = Phi_ss^-1 p,
    u = P u_m + u_q,   P = [I; T] scattered into DOF order,   u_q = [0; q],
    K^ u_m = f^,       K^ = P^T K P,   f^ = P^T (f - K u_q).

Phi_ss is block diagonal over the connected components of its sparsity graph ("clusters":
the slaves whose rows share a slave), so T is computed cluster by cluster with one small
dense LU each, never as a global dense inverse. The cut-off variant (MS1, seed §4.2) drops
|T_ij| below a threshold, and optionally every master farther than a radius from the row's
point before the numbers are computed (the symbolic pattern of §4.2).

Penalty: (K + w L^T L) u = f + w L^T p with w = relative weight × mean diag K.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

#: a slave cluster whose Phi_ss has a reciprocal 1-norm condition below this cannot be
#: solved to more than a few digits: refused
MIN_CLUSTER_RCOND = 1e-13


class ConstraintError(ValueError):
    """A constraint set that leaves a slave unsolvable, naming the row."""


@dataclass
class Constraints:
    rows: sp.csr_matrix      # L (m x ndof)
    rhs: np.ndarray          # p (m,)
    slaves: np.ndarray       # DOF eliminated by each row (distinct)
    points: np.ndarray       # (m, 2) where each row is evaluated
    label: np.ndarray        # (m,) text naming each row

    def __post_init__(self):
        self.rows = sp.csr_matrix(self.rows)
        self.rhs = np.asarray(self.rhs, dtype=float)
        self.slaves = np.asarray(self.slaves, dtype=np.int64)
        if np.unique(self.slaves).size != self.slaves.size:
            raise ConstraintError("two constraint rows eliminate the same DOF")

    def without(self, drop) -> "Constraints":
        keep = ~np.asarray(drop, dtype=bool)
        return Constraints(self.rows[keep], self.rhs[keep], self.slaves[keep],
                           self.points[keep], np.asarray(self.label)[keep])


@dataclass
class MasterSlave:
    masters: np.ndarray
    slaves: np.ndarray
    T: sp.csr_matrix
    q: np.ndarray
    P: sp.csr_matrix
    u_q: np.ndarray
    K_hat: sp.csr_matrix
    f_hat: np.ndarray
    clusters: int
    largest_cluster: int
    time_transformation: float

    @property
    def nnz_T(self) -> int:
        return int(self.T.nnz)

    def expand(self, u_m: np.ndarray) -> np.ndarray:
        return self.P @ u_m + self.u_q


def slave_clusters(phi_ss: sp.csr_matrix) -> tuple[int, np.ndarray]:
    """Connected components of the sparsity graph of Phi_ss (rows and columns are slaves)."""
    graph = (abs(phi_ss) + abs(phi_ss).T).tocsr()
    return connected_components(graph, directed=False)


def _clusters(phi_ss):
    """(cluster count, the slaves sorted by cluster, each cluster's bounds in that order)."""
    n_clusters, label = slave_clusters(phi_ss)
    order = np.argsort(label, kind="stable")
    return n_clusters, order, np.searchsorted(label[order], np.arange(n_clusters + 1))


def relation_matrix(c: Constraints, masters: np.ndarray, master_points=None,
                    threshold: float = 0.0, pattern_radius: float | None = None):
    """T (ns x nm CSR), q, and the slave clusters it was computed by (``_clusters``: the
    slaves in cluster order and each cluster's bounds in it)."""
    L = c.rows.tocsc()
    phi_ss = L[:, c.slaves].tocsr()
    phi_sm = L[:, masters].tocsr()
    _, order, bounds = _clusters(phi_ss)
    rows_out, cols_out, vals_out = [], [], []
    q = np.zeros(c.slaves.size)
    sizes = np.diff(bounds)
    # single-slave clusters (all of them under master-slave-local): one division per row
    alone = order[bounds[:-1][sizes == 1]]
    if alone.size:
        diag = _single_slave_diagonal(c, phi_ss, phi_sm, alone)
        q[alone] = c.rhs[alone] / diag
        sub = sp.diags(-1.0 / diag) @ phi_sm[alone]
        if pattern_radius is not None and master_points is not None:
            sub = sub.tocoo()
            far = np.hypot(*(c.points[alone][sub.row] - master_points[sub.col]).T) > pattern_radius
            sub.data[far] = 0.0
        sub = sp.coo_matrix(sub)
        if threshold > 0.0:
            sub.data[np.abs(sub.data) < threshold] = 0.0
        nz = sub.data != 0.0
        rows_out.append(alone[sub.row[nz]])
        cols_out.append(sub.col[nz])
        vals_out.append(sub.data[nz])
    for k in np.flatnonzero(sizes > 1):
        members = order[bounds[k]:bounds[k + 1]]
        lu = _cluster_lu(c, phi_ss, members)
        sub = phi_sm[members]
        used = np.unique(sub.indices)
        q[members] = la.lu_solve(lu, c.rhs[members], check_finite=False)
        if used.size == 0:
            continue
        dense = sub[:, used].toarray()
        if pattern_radius is not None and master_points is not None:
            # the symbolic pattern: only masters near some row of the cluster take part
            d = np.hypot(c.points[members, 0][:, None] - master_points[used, 0][None, :],
                         c.points[members, 1][:, None] - master_points[used, 1][None, :])
            near = d.min(axis=0) <= pattern_radius
            used, dense, d = used[near], dense[:, near], d[:, near]
        t = -la.lu_solve(lu, dense, check_finite=False)
        if pattern_radius is not None and master_points is not None:
            t[d > pattern_radius] = 0.0
        if threshold > 0.0:
            t[np.abs(t) < threshold] = 0.0
        r, col = np.nonzero(t)
        rows_out.append(members[r])
        cols_out.append(used[col])
        vals_out.append(t[r, col])
    cat = (lambda a, dt: np.concatenate(a) if a else np.zeros(0, dt))  # noqa: E731
    T = sp.csr_matrix((cat(vals_out, float), (cat(rows_out, np.int64), cat(cols_out, np.int64))),
                      shape=(c.slaves.size, masters.size))
    return T, q, order, bounds


def _single_slave_diagonal(c, phi_ss, phi_sm, alone) -> np.ndarray:
    """The own coefficients of the slaves alone in their clusters (rows ``alone``), or
    ConstraintError naming the first that is zero next to its row's masters."""
    picked = phi_ss[alone, alone]
    diag = picked.A1 if hasattr(picked, "A1") else np.asarray(picked).ravel()
    bad = ~(np.abs(diag) > MIN_CLUSTER_RCOND * np.abs(phi_sm[alone]).max(axis=1).toarray().ravel())
    if bad.any():
        first = alone[np.flatnonzero(bad)[0]]
        raise ConstraintError(
            f"constraint '{c.label[first]}' at ({c.points[first, 0]:.6g}, "
            f"{c.points[first, 1]:.6g}): its slave has a zero coefficient in its own row")
    return diag


def _cluster_lu(c, phi_ss, members):
    """LAPACK's LU of the cluster's block of Phi_ss, or ConstraintError naming its first row
    if the block is singular to working precision."""
    block = phi_ss[members][:, members].toarray()
    with warnings.catch_warnings():
        # a singular block is reported below, with the row that names it
        warnings.simplefilter("ignore", la.LinAlgWarning)
        lu = la.lu_factor(block, check_finite=False)
    rcond = _rcond(block, lu)
    if not rcond > MIN_CLUSTER_RCOND:
        first = members[0]
        raise ConstraintError(
            f"constraint '{c.label[first]}' at ({c.points[first, 0]:.6g}, "
            f"{c.points[first, 1]:.6g}): its slave cluster of {members.size} rows is "
            f"singular (reciprocal condition {rcond:.2g})")
    return lu


def _rcond(block, lu):
    """LAPACK's estimate of the reciprocal 1-norm condition of the factored ``block``."""
    norm = float(np.abs(block).sum(axis=0).max())
    if norm == 0.0 or not np.all(np.isfinite(lu[0])):
        return 0.0
    rcond, info = la.lapack.dgecon(lu[0], norm, norm="1")
    return float(rcond) if info == 0 else 0.0


def master_slave(K, f, c: Constraints, dof_points=None, *, threshold: float = 0.0,
                 pattern_radius: float | None = None) -> MasterSlave:
    """The reduced system of seed eq. 6-7 for the constraints ``c``."""
    t0 = time.perf_counter()
    ndof = K.shape[0]
    is_slave = np.zeros(ndof, dtype=bool)
    is_slave[c.slaves] = True
    masters = np.flatnonzero(~is_slave)
    master_points = None if dof_points is None else np.asarray(dof_points)[masters]
    T, q, order, bounds = relation_matrix(c, masters, master_points, threshold, pattern_radius)
    identity = sp.csr_matrix((np.ones(masters.size), (masters, np.arange(masters.size))),
                             shape=(ndof, masters.size))
    scatter = sp.csr_matrix((np.ones(c.slaves.size), (c.slaves, np.arange(c.slaves.size))),
                            shape=(ndof, c.slaves.size))
    P = (identity + scatter @ T).tocsr()
    u_q = scatter @ q
    K = sp.csr_matrix(K)
    K_hat = reduced_stiffness(K, P, T, c.slaves, order, bounds)
    f_hat = P.T @ (np.asarray(f, dtype=float) - K @ u_q)
    sizes = np.diff(bounds)
    return MasterSlave(masters, c.slaves, T, q, P, u_q, K_hat, f_hat, sizes.size,
                       int(sizes.max()) if sizes.size else 0, time.perf_counter() - t0)


#: a slave cluster whose rows of T fill at least this fraction of the masters they use has
#: its part of P^T K P formed as one dense product: a sparse product's cost per multiply is
#: many times BLAS's, so it only pays where most of the block is zero
DENSE_CLUSTER_FILL = 0.5


def reduced_stiffness(K, P, T, slaves, order, bounds) -> sp.csr_matrix:
    """K^ = P^T K P. Under plain MS a cluster's rows of T are dense over every master near it
    (Phi_ss^-1 of a chain of slaves decays but has no zeros), and a sparse product costs ~ the
    square of that row length per slave: such a cluster's term T_k^T (K P)_k is one dense
    product instead, its exact zeros dropped. The rest of P (the masters' identity rows and
    every other slave's row) goes through one sparse product: slicing K P into master and
    slave rows and summing the parts as triplets made most of MS2's transformation phase,
    1.69 s against 0.20 s with the one product at 40,709 particles (BENCHMARKS.md
    "sph-scaling", direct, the runs before and after). ``order``, ``bounds``: the slave
    clusters T was computed by (``relation_matrix``)."""
    KP = (K @ P).tocsr()
    rows, cols, vals = [], [], []
    dense_rows = []
    for k in np.flatnonzero(np.diff(bounds) > 1):
        members = order[bounds[k]:bounds[k + 1]]
        Tk = T[members]
        used_t = np.unique(Tk.indices)
        if Tk.nnz < DENSE_CLUSTER_FILL * members.size * used_t.size:
            continue
        Xk = KP[slaves[members]]
        used_x = np.unique(Xk.indices)
        block = Tk[:, used_t].toarray().T @ Xk[:, used_x].toarray()
        r, col = np.nonzero(block)
        rows.append(used_t[r])
        cols.append(used_x[col])
        vals.append(block[r, col])
        dense_rows.append(slaves[members])
    if dense_rows:      # those rows of P are summed above, not again in the sparse product
        keep = np.ones(P.shape[0])
        keep[np.concatenate(dense_rows)] = 0.0
        P = sp.diags(keep) @ P
    K_hat = (P.T.tocsr() @ KP).tocsr()
    if not rows:
        return K_hat
    return K_hat + sp.csr_matrix((np.concatenate(vals),
                                  (np.concatenate(rows), np.concatenate(cols))),
                                 shape=K_hat.shape)


@dataclass
class LagrangeForm:
    """Plain MS (seed eq. 6-7, 27) as the equivalent saddle-point system of K and L,

        [K    s L^T] [u]   [f  ]
        [s L  0    ] [mu] = [s p],

    with each constraint row swapped with its slave's equilibrium row (``row_order``), so that
    every diagonal entry is nonzero: the slave's own coefficient s Phi_ss[r, r], in both
    places. Its first n unknowns are u. Why it is the same solution: L P = Phi_sm + Phi_ss T =
    0, so P^T times the first block row is P^T K u = P^T f with u = P u_m + u_q, MS's
    equations; and its factors never see T, whose rows are dense over every master near a
    slave cluster (docs/sph.md § 5)."""
    A: sp.csr_matrix
    row_order: np.ndarray
    scale: float
    n: int

    def rhs(self, f, p) -> np.ndarray:
        return np.concatenate([f, self.scale * np.asarray(p, dtype=float)])[self.row_order]


def lagrange_form(K, c: Constraints, scale: float) -> LagrangeForm:
    """Plain MS's system in the Lagrange form, after the checks MS's T makes: a slave cluster
    whose Phi_ss is singular is the same ConstraintError (the form itself only needs L of
    full rank, but the method must not depend on how it is solved). ``scale``: the
    constraint rows' weight, about K's diagonal, so that neither block's rounding hides the
    other's."""
    n, m = K.shape[0], c.rhs.size
    L = c.rows.tocsc()
    phi_ss = L[:, c.slaves].tocsr()
    _, order, bounds = _clusters(phi_ss)
    sizes = np.diff(bounds)
    alone = order[bounds[:-1][sizes == 1]]
    if alone.size:
        is_slave = np.zeros(n, dtype=bool)
        is_slave[c.slaves] = True
        _single_slave_diagonal(c, phi_ss, L[:, ~is_slave].tocsr(), alone)
    for k in np.flatnonzero(sizes > 1):
        _cluster_lu(c, phi_ss, order[bounds[k]:bounds[k + 1]])
    A = sp.bmat([[sp.csr_matrix(K), scale * c.rows.T], [scale * c.rows, None]], format="csr")
    row_order = np.arange(n + m)
    row_order[c.slaves] = n + np.arange(m)
    row_order[n + np.arange(m)] = c.slaves
    return LagrangeForm(A[row_order].tocsr(), row_order, float(scale), n)


def penalty_system(K, f, c: Constraints, relative_weight: float, scale: float | None = None):
    """(A, b, w): A = K + w L^T L, b = f + w L^T p, w = relative_weight × ``scale``, by
    default mean diag K."""
    K = sp.csr_matrix(K)
    w = float(relative_weight) * float(np.mean(K.diagonal()) if scale is None else scale)
    L = c.rows
    return (K + w * (L.T @ L)).tocsr(), np.asarray(f, dtype=float) + w * (L.T @ c.rhs), w
