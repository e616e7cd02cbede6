"""Linear solves of the SPH systems and their condition (docs/sph.md § 5).

Direct: SuperLU; or, asked for by name (``"pardiso"``, the optional extra ``uqflow[pardiso]``),
Intel MKL's PARDISO (``pardiso``): a multithreaded supernodal LU in METIS's nested-dissection
order, 2-3 × faster than SuperLU on the large composites (§ 11). It is never chosen for the
user: a study's numbers must not depend on which extras happen to be installed. Above
MIXED_PRECISION_ABOVE unknowns either factorises in single precision and refines every solve in
double to a double LU's backward error (``refinement``). The stiffness, reduced and penalty
systems are not symmetric under the default integration (its corrected test gradients differ
from the trial ones: ||A - A^T|| is a few per cent of ||A||), so no Cholesky. Given the
unknowns' points, many unknowns and local couplings, the fill-reducing ordering is a geometric
nested dissection of the pattern of A + A^T; otherwise SuperLU's own orderings; diagonal pivots
are preferred. Iterative: GMRES with an incomplete-LU preconditioner. A singular system — an
unconstrained rigid mode — is detected by inverse iteration on the factors and refused with the
DOF where it shows, never solved silently.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.sph.pardiso import PardisoError, PardisoLU
from solvers.sph.refinement import MixedPrecisionFactor
from solvers.sph.symbolic import pattern_key

SOLVERS = ("auto", "direct", "iterative", "pardiso")
#: "auto" factorises up to this many unknowns and iterates beyond, where the factors would
#: outgrow the memory of a 24 GiB machine: SuperLU was the faster at every size measured
#: (benchmarks/sph_scaling.py), and its 408,226-unknown factorisation peaked at 9.9 GiB in
#: single precision (780 million entries, growing as n log n)
AUTO_ITERATIVE_ABOVE = 500_000
#: a direct solver factorises in single precision above this many unknowns and refines each
#: solve in double (``refinement.MixedPrecisionFactor``): from 19,586 unknowns (MS2 at 10,353
#: particles) it was the faster with either solver (BENCHMARKS.md "SPH: single-precision
#: factors refined"). The systems of every shipped study are smaller (Example 3: 8,888 unknowns
#: at most): their numbers do not change
MIXED_PRECISION_ABOVE = 10_000
#: smallest singular value below this fraction of the largest entry: singular to working
#: precision (a free rigid mode leaves one at rounding level, ~1e-16 of the largest)
MIN_SINGULAR_RATIO = 1e-13
#: inverse-iteration steps of the singularity check: a free rigid mode's singular value is
#: ~1e12 times below the next, so the second step has converged onto it
INVERSE_STEPS = 2
#: the singularity check's starting vector is drawn from this seed: one answer on every run
CHECK_SEED = 20210
ITERATIVE_RTOL = 1e-12
#: nested dissection stops splitting a set of at most this many unknowns (its own order is
#: kept): below it the separators cost more bookkeeping than they save fill
DISSECTION_LEAF = 64
#: nested dissection only where every unknown couples to at most this many times the median
#: count: plain MS's and MS1's dense slave clusters couple thousands of masters (37x and 16x the
#: median at 10,353 particles), and cutting through those cliques filled 50 % and 40 % more than
#: SuperLU's MMD, which orders a clique whole (MS2's and the penalty's ratio: 2.4 and 1.3)
NONLOCAL_DEGREE_RATIO = 4.0
#: nested dissection only above this many unknowns: on benchmarks/sph_scaling.py's plate it
#: filled MS2's factors 12 % more than SuperLU's MMD at 19,586 unknowns and 40,178, and 13 %
#: less at 79,194 (its n log n against MMD's faster growth on 2-D meshes)
DISSECTION_ABOVE = 60_000
#: in the nested-dissection and MMD orders a diagonal pivot is kept unless below this fraction
#: of its column's largest entry: 0.1 made the penalty systems pivot off the diagonal (their
#: w L^T L couplings match the diagonal) and doubled their fill at 40,709 particles (MMD:
#: quadrupled at 10,353); 0.01 keeps the order (MS2's fill) and bounds each step's growth by 101
DIAGONAL_PIVOT_THRESHOLD = 0.01


class LinearSolveError(ArithmeticError):
    """A singular or unsolved system, naming where it shows."""


@dataclass
class SolveInfo:
    method: str
    iterations: int
    relative_residual: float
    seconds: float
    singular_ratio: float = np.nan


class Factor:
    """A factorised (direct) or preconditioned (iterative) system, solved for many b.
    ``points`` (n, 2): where each unknown lives; the direct solver orders by nested dissection
    of them if there are more than DISSECTION_ABOVE and the couplings are local, else by
    SuperLU's MMD on A^T + A (docs/sph.md § 5). ``single_precision=False``: factors in double
    at every size (a system known to be too ill-conditioned for single precision).
    ``store``: a ``symbolic.SymbolicStore`` that hands the order (direct) or the analysis
    (PARDISO, single precision) of a system of the same pattern to this one, and keeps this
    one's for the next."""

    def __init__(self, A, solver: str = "auto", nearly_symmetric: bool = False, points=None,
                 single_precision: bool = True, store=None):
        if solver not in SOLVERS:
            raise ValueError(f"unknown linear solver {solver!r} (known: {', '.join(SOLVERS)})")
        n = A.shape[0]
        self.method = solver if solver != "auto" else ("direct" if n <= AUTO_ITERATIVE_ABOVE
                                                       else "iterative")
        # each solver's own format, converted once: PARDISO and the products read rows
        self.A = sp.csr_matrix(A) if self.method == "pardiso" else sp.csc_matrix(A)
        t0 = time.perf_counter()
        self.singular_ratio = np.nan
        self.ordering = None
        if self.method == "pardiso":
            self.ordering = "METIS (PARDISO)"
            # partial, not a lambda on self: the factors must not hold their Factor in a
            # reference cycle, or gigabytes wait for the cyclic collector
            self.lu, self.singular_ratio = _checked(self.A, _in_precision(
                self.A, functools.partial(_pardiso, self.A, store=store), single_precision))
        elif self.method == "direct":
            perm = None
            if points is not None and n > DISSECTION_ABOVE:
                perm = _dissection_order(self.A, points, store)
            if points is not None and perm is None:
                nearly_symmetric = True
            self.ordering = ("nested dissection" if perm is not None else
                             "MMD" if nearly_symmetric else "COLAMD")
            self.lu, self.singular_ratio = _checked(self.A, _in_precision(
                self.A, functools.partial(_factorise, self.A, nearly_symmetric, perm),
                single_precision))
        else:
            ilu = spla.spilu(self.A, drop_tol=1e-5, fill_factor=20)
            self.preconditioner = spla.LinearOperator(self.A.shape, ilu.solve)
        self.build_seconds = time.perf_counter() - t0

    @property
    def precision(self) -> str | None:
        """The factors' precision: "double", or "single, refined" (None for the iterative
        solver)."""
        if self.method == "iterative":
            return None
        return getattr(self.lu, "precision", "double")

    @property
    def factor_nnz(self) -> int | None:
        """Entries of the factors L + U (None for the iterative solver)."""
        if self.method == "iterative":
            return None
        return int(self.lu.nnz)

    def solve(self, b):
        """x with A x = b, and a SolveInfo (its time excludes the factorisation,
        ``build_seconds``)."""
        b = np.asarray(b, dtype=float)
        t0 = time.perf_counter()
        if self.method != "iterative":
            x = self.lu.solve(b)
            iterations = getattr(self.lu, "steps", 0)   # refinement steps, if refined
        else:
            x, iterations = _gmres(self.A, b, self.preconditioner)
        if not np.all(np.isfinite(x)):
            raise LinearSolveError(f"{self.method} solve of {b.size} unknowns gave non-finite "
                                   f"values (first at unknown "
                                   f"{int(np.flatnonzero(~np.isfinite(x))[0])})")
        residual = float(np.linalg.norm(self.A @ x - b)) / (float(np.linalg.norm(b)) or 1.0)
        return x, SolveInfo(self.method, iterations, residual, time.perf_counter() - t0,
                            self.singular_ratio)


def solve(A, b, solver: str = "auto", nearly_symmetric: bool = False, points=None):
    """x with A x = b, and a SolveInfo. ``nearly_symmetric``: order for A + A^T and prefer
    diagonal pivots (the master–slave reduced systems: 4x faster factorisations than COLAMD
    on Example 1); ``points``: nested dissection of them instead (docs/sph.md § 5)."""
    return Factor(A, solver, nearly_symmetric, points).solve(b)


class _SuperLU:
    """SuperLU's factors (``lu``) of P A P^T in ``dtype``, solving A x = b for float64 b
    (P: ``perm``, or the identity)."""

    def __init__(self, lu, dtype, perm=None):
        self.lu, self.dtype, self.perm, self.nnz = lu, dtype, perm, lu.nnz

    def solve(self, b):
        b = np.asarray(b)
        if self.perm is None:
            return np.asarray(self.lu.solve(b.astype(self.dtype, copy=False)), dtype=float)
        x = np.empty_like(b, dtype=float)
        x[self.perm] = self.lu.solve(b[self.perm].astype(self.dtype, copy=False))
        return x


def _in_precision(A, factorise, single_precision=True):
    """``factorise(dtype)``'s factors: in single precision, refined, above
    MIXED_PRECISION_ABOVE unknowns (if ``single_precision``); else in double."""
    if single_precision and A.shape[0] > MIXED_PRECISION_ABOVE:
        return MixedPrecisionFactor(A, factorise)
    return factorise(np.float64)


def _dissection_order(A, points, store=None):
    """A's nested-dissection order of ``points``, or None where its couplings are not local
    (``local_couplings``): from ``store`` if it holds this pattern's and points', else
    computed (and kept there)."""
    key = None if store is None else pattern_key("dissection", A, points)
    kept = None if key is None else store.lookup(key)
    if kept is not None:
        return kept[0]
    graph = coupling_graph(A)
    perm = nested_dissection(A, points, graph=graph) if local_couplings(A, graph) else None
    if perm is not None:
        perm.flags.writeable = False        # shared by every factorisation that reuses it
    if key is not None:
        store.keep(key, (perm,))
    return perm


def _pardiso(A, dtype, store=None):
    try:
        return PardisoLU(A, dtype, store)
    except PardisoError as e:
        raise LinearSolveError(str(e)) from None


def _factorise(A, nearly_symmetric=False, perm=None, dtype=np.float64):
    """SuperLU's factors of A in ``dtype``, in the order ``perm`` (nested dissection) or in
    SuperLU's own."""
    if perm is not None:
        target = A[perm][:, perm].tocsc()
        options = {"permc_spec": "NATURAL", "diag_pivot_thresh": DIAGONAL_PIVOT_THRESHOLD,
                   "options": {"SymmetricMode": True}}
    else:
        perm, target = None, A
        options = ({"permc_spec": "MMD_AT_PLUS_A",
                    "diag_pivot_thresh": DIAGONAL_PIVOT_THRESHOLD,
                    "options": {"SymmetricMode": True}} if nearly_symmetric
                   else {"permc_spec": "COLAMD"})
    try:
        lu = spla.splu(target.astype(dtype, copy=False), **options)
    except RuntimeError as e:          # SuperLU: "Factor is exactly singular"
        raise LinearSolveError(f"the system of {A.shape[0]} unknowns is singular ({e})") from None
    return _SuperLU(lu, dtype, perm)


def _checked(A, factor):
    """(factor, its singular ratio), or LinearSolveError for a system singular to working
    precision (``smallest_singular_ratio``)."""
    ratio, where = smallest_singular_ratio(A, factor)
    if not ratio > MIN_SINGULAR_RATIO:
        raise LinearSolveError(f"the system of {A.shape[0]} unknowns is singular to working "
                               f"precision: smallest singular value at most {ratio:.2g} of its "
                               f"largest entry, its vector largest at unknown {where} (a free "
                               f"rigid mode?)")
    return factor, ratio


def smallest_singular_ratio(A, factor) -> tuple[float, int]:
    """An upper bound on sigma_min(A) / max |A_ij| from inverse iteration on the factors, and
    the unknown where the iterate is largest. ||A^-1 z|| <= 1 / sigma_min for every unit z,
    so ||y_k|| / ||y_k+1|| bounds sigma_min from above: a small ratio proves near-singularity,
    and a free rigid mode (sigma_min ~1e12 below the next) is reached in two steps. Two
    solves: far cheaper than extracting SuperLU's U to read its pivots."""
    n = A.shape[0]
    scale = float(np.abs(A.data).max()) if A.nnz else 0.0     # abs(A) would copy A
    if n == 0 or scale == 0.0:
        return (1.0 if n == 0 else 0.0), 0
    y = np.random.default_rng(CHECK_SEED).standard_normal(n)
    sigma = np.inf
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(INVERSE_STEPS):
            norm = float(np.linalg.norm(y))
            y = factor.solve(y / norm)
            grown = float(np.linalg.norm(y))
            if not np.isfinite(grown) or grown == 0.0:
                return 0.0, int(np.argmax(~np.isfinite(y)))
            sigma = min(sigma, 1.0 / grown)
    return sigma / scale, int(np.argmax(np.abs(y)))


def coupling_graph(A) -> sp.csr_matrix:
    """Which unknowns couple: the pattern of |A| + |A|^T (its entries positive), from A's
    nonzero entries — built once per factorisation for ``local_couplings`` and
    ``nested_dissection``, from A's pattern rather than two copies of |A|: for MS2's 79,194
    unknowns at 40,709 particles (11 million entries) the graph took 0.47 s against 1.0 s,
    and the two checks and the order 0.5-0.8 s against 2.2-2.7 s (one ad hoc run, the
    same order)."""
    if not (sp.issparse(A) and A.format in ("csr", "csc")):
        A = sp.csr_matrix(A)
    # the union is symmetric: a CSC A's arrays, read as the CSR of A^T, give it without the
    # conversion (the direct solver's A is CSC)
    pattern = sp.csr_matrix(((A.data != 0.0).astype(float), A.indices, A.indptr),
                            shape=A.shape[::-1] if A.format == "csc" else A.shape)
    return (pattern + pattern.T).tocsr()


def local_couplings(A, graph=None) -> bool:
    """Whether no unknown of A + A^T couples to more than NONLOCAL_DEGREE_RATIO times the
    median count: the systems nested dissection orders well. ``graph``: A's
    ``coupling_graph``, if built already."""
    degree = np.diff((coupling_graph(A) if graph is None else graph).indptr)
    return degree.size == 0 or degree.max() <= NONLOCAL_DEGREE_RATIO * np.median(degree)


def nested_dissection(A, points, leaf: int = DISSECTION_LEAF, graph=None) -> np.ndarray:
    """A fill-reducing elimination order of A (George's nested dissection, split by the
    unknowns' coordinates): each set is cut at the median of its longer extent, the unknowns
    of the lower half coupled (in A + A^T) to the upper half form the separator, and the order
    is lower interior, upper half, separator, recursively. The separator is read from the
    matrix, so the order is valid for any coupling; the points only choose the cuts."""
    graph = coupling_graph(A) if graph is None else graph
    points = np.asarray(points, dtype=float).reshape(A.shape[0], -1)
    upper_flag = np.zeros(A.shape[0])
    order = []

    def dissect(idx):
        if idx.size <= leaf:
            order.append(idx)
            return
        p = points[idx]
        axis = int(np.argmax(p.max(axis=0) - p.min(axis=0)))
        lower = p[:, axis] < np.median(p[:, axis])
        if not lower.any():
            lower = p[:, axis] <= np.median(p[:, axis])
        if lower.all() or not lower.any():          # all at one point: nothing to cut
            order.append(idx)
            return
        low, high = idx[lower], idx[~lower]
        upper_flag[high] = 1.0
        touches = (graph[low] @ upper_flag) > 0.0
        upper_flag[high] = 0.0
        dissect(low[~touches])
        dissect(high)
        order.append(low[touches])

    dissect(np.arange(A.shape[0]))
    return np.concatenate(order) if order else np.zeros(0, dtype=np.int64)


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
