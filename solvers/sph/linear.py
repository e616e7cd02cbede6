"""Linear solves of the SPH systems and their condition (docs/sph.md § 5).

Direct: SuperLU with a COLAMD fill-reducing ordering (the reduced and penalty systems are
not symmetric under the default integration, so no Cholesky). Iterative: GMRES with an
incomplete-LU preconditioner. A singular system — an unconstrained rigid mode — is detected
from SuperLU's pivots and refused with the DOF where it shows, never solved silently.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

SOLVERS = ("auto", "direct", "iterative")
#: "auto" factorises up to this many unknowns and iterates beyond (benchmarks/sph_scaling.py:
#: SuperLU stayed the faster of the two on every size measured, up to 40,000 particles)
AUTO_ITERATIVE_ABOVE = 200_000
#: a pivot below this fraction of the largest: singular to working precision (a free rigid
#: mode leaves a pivot at rounding level, ~1e-16 of the largest)
MIN_PIVOT_RATIO = 1e-13
ITERATIVE_RTOL = 1e-12


class LinearSolveError(ArithmeticError):
    """A singular or unsolved system, naming where it shows."""


@dataclass
class SolveInfo:
    method: str
    iterations: int
    relative_residual: float
    seconds: float
    min_pivot_ratio: float = np.nan


class Factor:
    """A factorised (direct) or preconditioned (iterative) system, solved for many b."""

    def __init__(self, A, solver: str = "auto", nearly_symmetric: bool = False):
        if solver not in SOLVERS:
            raise ValueError(f"unknown linear solver {solver!r} (known: {', '.join(SOLVERS)})")
        self.A = sp.csc_matrix(A)
        n = self.A.shape[0]
        self.method = solver if solver != "auto" else ("direct" if n <= AUTO_ITERATIVE_ABOVE
                                                       else "iterative")
        t0 = time.perf_counter()
        self.pivot_ratio = np.nan
        if self.method == "direct":
            self.lu, self.pivot_ratio = _factorise(self.A, nearly_symmetric)
        else:
            ilu = spla.spilu(self.A, drop_tol=1e-5, fill_factor=20)
            self.preconditioner = spla.LinearOperator(self.A.shape, ilu.solve)
        self.build_seconds = time.perf_counter() - t0

    def solve(self, b):
        """x with A x = b, and a SolveInfo (its time excludes the factorisation,
        ``build_seconds``)."""
        b = np.asarray(b, dtype=float)
        t0 = time.perf_counter()
        if self.method == "direct":
            x, iterations = self.lu.solve(b), 0
        else:
            x, iterations = _gmres(self.A, b, self.preconditioner)
        if not np.all(np.isfinite(x)):
            raise LinearSolveError(f"{self.method} solve of {b.size} unknowns gave non-finite "
                                   f"values (first at unknown "
                                   f"{int(np.flatnonzero(~np.isfinite(x))[0])})")
        residual = float(np.linalg.norm(self.A @ x - b)) / (float(np.linalg.norm(b)) or 1.0)
        return x, SolveInfo(self.method, iterations, residual, time.perf_counter() - t0,
                            self.pivot_ratio)


def solve(A, b, solver: str = "auto", nearly_symmetric: bool = False):
    """x with A x = b, and a SolveInfo. ``nearly_symmetric``: order for A + A^T and prefer
    diagonal pivots (the master–slave reduced systems: 4x faster factorisations than COLAMD
    on Example 1; the penalty systems factor faster with COLAMD — docs/sph.md § 5)."""
    return Factor(A, solver, nearly_symmetric).solve(b)


def _factorise(A, nearly_symmetric=False):
    options = ({"permc_spec": "MMD_AT_PLUS_A", "diag_pivot_thresh": 0.1,
                "options": {"SymmetricMode": True}} if nearly_symmetric
               else {"permc_spec": "COLAMD"})
    try:
        lu = spla.splu(A, **options)
    except RuntimeError as e:          # SuperLU: "Factor is exactly singular"
        raise LinearSolveError(f"the system of {A.shape[0]} unknowns is singular ({e})") from None
    pivots = np.abs(lu.U.diagonal())
    ratio = float(pivots.min() / pivots.max()) if pivots.size else 1.0
    if not ratio > MIN_PIVOT_RATIO:
        where = int(lu.perm_c[np.argmin(pivots)])
        raise LinearSolveError(f"the system of {A.shape[0]} unknowns is singular to working "
                               f"precision: pivot ratio {ratio:.2g} at unknown {where} (a free "
                               f"rigid mode?)")
    return lu, ratio


def _gmres(A, b, M):
    count = [0]

    def tick(_):
        count[0] += 1
    x, info = spla.gmres(A, b, M=M, rtol=ITERATIVE_RTOL, atol=0.0, restart=200, maxiter=50,
                         callback=tick, callback_type="pr_norm")
    if info != 0:
        raise LinearSolveError(f"GMRES did not converge on {A.shape[0]} unknowns in "
                               f"{count[0]} iterations (info {info})")
    return x, count[0]


#: columns of the 1-norm estimator's blocks: 2 (scipy's default) left the penalty estimate of
#: Example 1 anywhere in 1.4e5-2.0e5 from run to run; 4 reaches the top of that range
ESTIMATE_COLUMNS = 4
#: onenormest draws its starting columns from numpy's global generator: a fixed seed makes the
#: estimate one number on every run and machine (the global state is restored after)
ESTIMATE_SEED = 20210


def condition_estimate(A) -> float:
    """The 1-norm condition number estimated from one sparse LU (Hager/Higham's block
    estimator in onenormest: a lower bound, in practice within a factor of about 3), with
    fixed starting columns so that it is reproducible."""
    A = sp.csc_matrix(A)
    lu = spla.splu(A, permc_spec="COLAMD")
    inverse = spla.LinearOperator(A.shape, matvec=lu.solve,
                                  rmatvec=lambda y: lu.solve(y, trans="T"))
    state = np.random.get_state()
    try:
        np.random.seed(ESTIMATE_SEED)
        return float(spla.onenormest(A, t=ESTIMATE_COLUMNS)
                     * spla.onenormest(inverse, t=ESTIMATE_COLUMNS))
    finally:
        np.random.set_state(state)
