"""Iterative refinement of a solve against its own system (docs/sph.md § 5).

Two solvers reach A^-1 b only approximately: a factorisation of an earlier system with a
low-rank correction (``factor_update``), and A's own factors in single precision
(``linear``, large systems). Either is corrected by x <- x + M(b - A x), the residual formed
in double precision, until the residual is at the level its own evaluation resolves —
the backward error of a fresh double-precision LU (Higham, "Accuracy and Stability of
Numerical Algorithms", ch. 12; in mixed precision: Langou et al. 2006, LAPACK's dsgesv).
Each step multiplies the error by about cond(A) times M's relative error; a step that does
not halve the residual means M is too far from A^-1 for refinement, and the caller
factorises A in double precision instead.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

EPS = np.finfo(float).eps
#: refinement steps, each to halve the residual at least, before a solve counts as stalled
MAX_REFINEMENTS = 8
#: refinement stops at a residual of this many times the bound on its own evaluation error,
#: gamma_{k+1} (|b| + |A||x|) summed (Higham eq. 12.10; k entries a row)
RESIDUAL_SLACK = 4.0


class Refinement:
    """Refines solves of A x = b made through an approximate solver of A."""

    def __init__(self, A):
        self.A = sp.csr_matrix(A)
        # what every solve's stopping test needs, once: gamma_{k+1} ~ (k + 1) eps, and the
        # column sums c = |A|^T 1, since || |A| |x| ||_1 = c . |x| — a dot product, where
        # |A| @ |x| was a second sparse product each step through a copy of A (12 bytes an
        # entry, 132 MB for MS2's 11.0 million at 40,709 particles) kept beside the factors
        self._gamma = (int(np.diff(self.A.indptr).max(initial=0)) + 1) * EPS
        absolute = sp.csr_matrix((np.abs(self.A.data), self.A.indices, self.A.indptr),
                                 shape=self.A.shape)
        self._column_sums = absolute.T @ np.ones(self.A.shape[0])

    def target(self, b, x):
        """The residual ||b - A x||_1 a solve stops at: RESIDUAL_SLACK gamma_{k+1}
        || |b| + |A||x| ||_1, each column of a block its own."""
        return RESIDUAL_SLACK * self._gamma * (np.abs(b).sum(axis=0)
                                               + self._column_sums @ np.abs(x))

    def solve(self, b, approximate):
        """(x, residual b - A x, steps), x refined from ``approximate(b)`` (one b or a block
        of columns, each held to its own target), or None if refinement stalled."""
        x = approximate(b)
        previous, steps = np.inf, 0
        while True:
            r = b - self.A @ x
            size = np.abs(r).sum(axis=0)
            done = size <= self.target(b, x)
            if np.all(done):
                return x, r, steps
            # stalled (or not finite): refinement cannot resolve what M misses
            if steps == MAX_REFINEMENTS or not np.all(done | (size < previous / 2)):
                return None
            x, previous, steps = x + approximate(r), size, steps + 1


class MixedPrecisionFactor:
    """A's factors in single precision — half the memory of double's, and faster
    (benchmarks/sph_precision.py) — each solve refined in double to a double LU's backward
    error. ``factorise(dtype)`` returns factors of
    A in that precision (an object with ``solve`` and ``nnz``). If the single-precision
    factorisation fails (an ArithmeticError: a pivot that vanishes in single precision) or a
    solve's refinement stalls (A too ill-conditioned for single precision: each step's
    contraction is about cond(A) x 6e-8), A is factorised in double precision and used alone
    from then on."""

    def __init__(self, A, factorise):
        self._factorise = factorise
        self._refinement = Refinement(A)
        #: refinement steps of the last solve
        self.steps = 0
        try:
            self.factors, self.precision = factorise(np.float32), "single, refined"
        except ArithmeticError:
            self.factors, self.precision = factorise(np.float64), "double"

    @property
    def nnz(self) -> int:
        return self.factors.nnz

    def solve(self, b):
        b = np.asarray(b, dtype=float)
        if self.precision == "double":
            return self.factors.solve(b)
        refined = self._refinement.solve(b, self.factors.solve)
        if refined is not None:
            self.steps = refined[2]
            return refined[0]
        self.factors, self.precision, self.steps = None, "double", 0
        self.factors = self._factorise(np.float64)
        return self.factors.solve(b)
