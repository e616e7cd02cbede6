"""Low-rank updates of a factorised SPH system when interface pairs break (docs/sph.md § 5).

A break changes few couplings. Under the penalty method the system keeps its unknowns and
loses the broken pairs' penalty and consistency terms (rank at most 6 a pair); under the local
master–slave method (MS2) a broken pair's slave becomes a master: the reduced system gains its
two unknowns, and only the rows and columns that saw it through its own interpolation change.
A factorisation costs many solves with its factors, an update of rank r about r solves, so a
run keeps the last system it factorised (the base) and solves the next ones through it,

    A = E + U V^T,   A^-1 b = E^-1 b - E^-1 U C^-1 V^T E^-1 b,   C = I + V^T E^-1 U

(Sherman–Morrison–Woodbury), E being the base with any new unknowns on their own diagonal.
Taking out a penalty as stiff as the system can cancel digits of C, so every solve is refined
against A itself (``refinement``: fixed-precision iterative refinement) until its residual is
at the level its own evaluation resolves: the backward error of a fresh LU. An update of rank
above MAX_UPDATE_RANK, or whose C is singular to working precision, is refused (``NotLowRank``)
and the system factorised afresh; a refinement that stalls factorises afresh itself.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from solvers.sph.linear import SolveInfo
from solvers.sph.refinement import EPS, Refinement

#: a correction of higher rank is not kept: the system is factorised afresh. Each break
#: costs the solves of its own rank (6 a pair), every later solve one product with the n x r
#: E^-1 U; and E^-1 U is held to a quarter of the factors' entries (or MIN_RANK_ALLOWED
#: columns, which small systems hold easily)
MAX_UPDATE_RANK = 128
MIN_RANK_ALLOWED = 16
#: the changed rows and columns, dense, are factorised by a pivoted QR to find the rank; past
#: this many on the shorter side that QR costs more than the factorisation it would save
MAX_CHANGED_BLOCK = 1200
#: C's smallest singular value this far below 1 + ||V^T E^-1 U||: refinement would contract
#: too slowly (its error per step is about eps times this ratio), if at all; A may be
#: singular. The system is factorised afresh instead, and its own check decides
MAX_CAPACITANCE_CONDITION = 1e10


class NotLowRank(Exception):
    """The change from the base is too large, or too close to singular, for an update."""


class UpdatedFactor:
    """A (on global ``unknowns``) solved through the Factor of an earlier system and a
    low-rank correction. ``previous``: the system solved before A, on ``previous_unknowns``
    (each of them among ``unknowns``), either a Factor, which becomes the base, or an
    UpdatedFactor, whose base and correction are extended by the change since it, so a break
    costs the solves of its own rank only. ``refactorise()`` returns A's own Factor: used if a
    refinement stalls. Raises NotLowRank where an update does not pay or is not safe. Quacks
    like a Factor."""

    def __init__(self, previous, previous_unknowns, A, unknowns, refactorise):
        t0 = time.perf_counter()
        chained = isinstance(previous, UpdatedFactor) and previous.fresh is None
        base = previous.base if chained else getattr(previous, "fresh", None) or previous
        if base.method == "iterative":
            raise NotLowRank("the iterative solver has no factors to update")
        self.A = sp.csr_matrix(A)
        n = self.A.shape[0]
        self.base, self.method, self.singular_ratio = base, base.method, np.nan
        self._refactorise, self.fresh = refactorise, None
        # where the previous system's unknowns are in A's; the unknowns new since it
        moved = _positions(np.asarray(previous_unknowns), np.asarray(unknowns))
        new = np.setdiff1d(np.arange(n), moved)
        new_diagonal = self.A.diagonal()[new]
        if not np.all(new_diagonal != 0):
            raise NotLowRank("a new unknown has no diagonal entry")
        if chained:
            self.position = moved[previous.position]
            self.extra = np.concatenate([moved[previous.extra], new])
            self.extra_diagonal = np.concatenate([previous.extra_diagonal, new_diagonal])
            Vt, EU = _moved_columns(previous.Vt, moved, n), _moved_rows(previous.EU, moved, n)
        else:
            self.position, self.extra, self.extra_diagonal = moved, new, new_diagonal
            Vt, EU = sp.csr_matrix((0, n)), np.zeros((n, 0))
        # the change since the previous system, the new unknowns on their own diagonal
        prior = _embedded(previous.A, moved, new, new_diagonal, n)
        max_rank = min(MAX_UPDATE_RANK,
                       max(MIN_RANK_ALLOWED, base.factor_nnz // (4 * max(n, 1))))
        dU, dVt = _low_rank(self.A - prior, max_rank - EU.shape[1])
        self.Vt = sp.vstack([Vt, dVt]).tocsr()
        self.EU = np.hstack([EU, self._base_solve(dU)])       # U itself is not needed again
        self.rank = self.EU.shape[1]
        M = self.Vt @ self.EU
        C = np.eye(self.rank) + M
        # C's smallest singular value against the terms it is the sum of: a cancellation
        # deeper than MAX_CAPACITANCE_CONDITION is a (nearly) singular A
        if self.rank and (np.linalg.svd(C, compute_uv=False)[-1] * MAX_CAPACITANCE_CONDITION
                          <= 1.0 + np.linalg.norm(M, 2)):
            raise NotLowRank(f"the update's capacitance matrix is singular to working "
                             f"precision (rank {self.rank})")
        self.capacitance = sla.lu_factor(C) if self.rank else None
        self.ordering = f"{base.ordering} + rank-{self.rank} update"
        self.factor_nnz = base.factor_nnz
        self._refinement = Refinement(self.A)
        self.build_seconds = time.perf_counter() - t0

    # -- solves --------------------------------------------------------------------------

    def _base_solve(self, b):
        """E^-1 b, for one b or a block of columns."""
        x = np.empty_like(b, dtype=float)
        x[self.position] = self.base.lu.solve(np.ascontiguousarray(b[self.position]))
        scale = self.extra_diagonal if b.ndim == 1 else self.extra_diagonal[:, None]
        x[self.extra] = b[self.extra] / scale
        return x

    def _apply(self, b):
        """Woodbury's A^-1 b, to C's accuracy."""
        y = self._base_solve(b)
        if not self.rank:
            return y
        return y - self.EU @ sla.lu_solve(self.capacitance, self.Vt @ y)

    def solve(self, b):
        """x with A x = b, and a SolveInfo (iterations: the refinement steps)."""
        if self.fresh is not None:
            return self.fresh.solve(b)
        b = np.asarray(b, dtype=float)
        t0 = time.perf_counter()
        refined = self._refinement.solve(b, self._apply)
        if refined is None:
            # what the base cannot resolve, A's factors can
            self.fresh = self._refactorise()
            return self.fresh.solve(b)
        x, r, steps = refined
        return x, SolveInfo(self.method, steps, float(np.linalg.norm(r)) /
                            (float(np.linalg.norm(b)) or 1.0), time.perf_counter() - t0,
                            self.singular_ratio)


def _positions(previous_unknowns, unknowns):
    """Index in ``unknowns`` of each of ``previous_unknowns``; NotLowRank if one is gone."""
    order = np.argsort(unknowns, kind="stable")
    at = np.searchsorted(unknowns, previous_unknowns, sorter=order).clip(0, unknowns.size - 1)
    position = order[at]
    if not np.array_equal(unknowns[position], previous_unknowns):
        raise NotLowRank("the system lost unknowns (a detached inclusion)")
    return position


def _embedded(M, position, extra, extra_diagonal, n):
    """M's entries moved to ``position``, ``extra_diagonal`` on the ``extra`` unknowns."""
    M = sp.coo_matrix(M)
    return sp.csr_matrix((np.concatenate([M.data, extra_diagonal]),
                          (np.concatenate([position[M.row], extra]),
                           np.concatenate([position[M.col], extra]))), shape=(n, n))


def _moved_rows(X, position, n):
    out = np.zeros((n, X.shape[1]))
    out[position] = X
    return out


def _moved_columns(Xt, position, n):
    Xt = sp.coo_matrix(Xt)
    return sp.csr_matrix((Xt.data, (Xt.row, position[Xt.col])), shape=(Xt.shape[0], n))


def _low_rank(change, max_rank):
    """(U, V^T) with change = U V^T but for rounding, U dense (n x r), V^T sparse: the
    change's nonzero rows and columns as a dense block, whose pivoted QR drops only the
    directions below its rounding level. NotLowRank past ``max_rank``."""
    change = sp.coo_matrix(change)
    change.eliminate_zeros()
    n = change.shape[0]
    rows, cols = np.unique(change.row), np.unique(change.col)
    if min(rows.size, cols.size) > MAX_CHANGED_BLOCK:
        raise NotLowRank(f"{rows.size} rows and {cols.size} columns changed")
    if not change.nnz:
        return np.zeros((n, 0)), sp.csr_matrix((0, n))
    block = sp.csr_matrix(change)[rows][:, cols].toarray()
    Q, R, pivot = sla.qr(block, mode="economic", pivoting=True)
    diagonal = np.abs(np.diag(R))
    rank = int(np.count_nonzero(diagonal > max(block.shape) * EPS * diagonal[0]))
    if rank > max_rank:
        raise NotLowRank(f"a change of rank {rank} (at most {max_rank} more is updated)")
    U = np.zeros((n, rank))
    U[rows] = Q[:, :rank]
    Vt_block = np.empty((rank, cols.size))
    Vt_block[:, pivot] = R[:rank]
    return U, _moved_columns(Vt_block, cols, n)
