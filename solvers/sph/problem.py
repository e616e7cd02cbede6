"""One elastic problem on a discretised layout: stiffness, constraints, and a solve.

The constraint points are the outer-boundary particles (essential conditions, seed eq.
11-14) and the interface pairs (continuity u+ = u-, seed eq. 15-21). They are also the
boundary quadrature of the integration correction: with ``integration = "vci"`` the test
gradients get a constant per particle, xi_b, so that

    sum_c V_c grad^psi_b(X_c) = sum_q w_q psi_b(X_q) n_q      (q: constraint points)

— the discrete divergence theorem on each phase — and a homogeneous strain is reproduced
exactly (the patch test) whatever the constraint method: a master–slave test function
vanishes at every q, and the penalty method gets the matching consistency term, the
point-quadrature form of Nitsche's -∮ v·σn. ``integration = "nodal"`` is the seed's plain
particle integration; it fails the patch test near boundaries and interfaces (docs/sph.md,
"Integration").
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from solvers.sph.constraints import Constraints, lagrange_form, master_slave, penalty_system
from solvers.sph.factor_update import NotLowRank, UpdatedFactor
from solvers.sph.linear import Factor, condition_estimate
from solvers.sph.stiffness import block_diagonal, elasticity_matrices, lame, strain_operator
from uqflow.errors import SolverError

METHODS = ("master-slave", "master-slave-cutoff", "master-slave-local", "penalty")
#: a penalty system's condition number grows with the penalty's relative weight (its
#: constrained directions that much stiffer than the mean diagonal), and single-precision
#: factors refine only while cond(A) x 6e-8 is well below 1: at 1e4 three steps; at 1e6
#: refinement stalled and the solve paid a single and a double factorisation
#: (benchmarks/sph_precision.py before this rule). Above this weight: double factors only
SINGLE_PRECISION_MAX_PENALTY = 1e5
#: plain MS solves its equivalent Lagrange form (constraints.LagrangeForm) above this many
#: unknowns: its factors keep K's sparsity where K^'s have a dense block over every master
#: near a slave cluster (benchmarks/sph_scaling.py's plate at 10,353 particles: 17.2 against
#: 34.9 million entries in L + U, MS2's 16.9). Every shipped study is smaller: its numbers
#: do not change
LAGRANGE_FORM_ABOVE = 10_000
INTEGRATIONS = ("vci", "nodal")
EIGENSTRAIN_MODES = ("in_plane", "dilatation_3d")


@dataclass
class Solution:
    u: np.ndarray                 # parameters (2n,), interleaved; NaN on detached inclusions
    displacement: np.ndarray      # (n, 2) interpolated displacement at the particles
    strain: np.ndarray            # (n, 3) [xx, yy, xy engineering]
    stress: np.ndarray            # (n, 3)
    constraint_residual: float    # max |L u - p| over the rows imposed
    pair_error: float             # max over intact pairs of |u+ - u-| / max |u|
    timings: dict = field(default_factory=dict)   # this solve's: assembly (constraint rows),
    #                                               transformation, solve
    condition: float | None = None
    solve_info: object = None


def _traction_operator(normals: np.ndarray, D: np.ndarray) -> np.ndarray:
    """(m, 2, 3): traction t = N D eps at points with unit ``normals``, Voigt [xx, yy, xy]."""
    N = np.zeros((normals.shape[0], 2, 3))
    N[:, 0, 0] = normals[:, 0]
    N[:, 0, 2] = normals[:, 1]
    N[:, 1, 1] = normals[:, 1]
    N[:, 1, 2] = normals[:, 0]
    return N @ D


def _block_rows(blocks: np.ndarray) -> sp.csr_matrix:
    """(2m x 3m) block-diagonal sparse matrix of (m, 2, 3) blocks."""
    m = blocks.shape[0]
    rows = np.repeat(np.arange(2 * m), 3)
    cols = (3 * np.repeat(np.arange(m), 2)[:, None] + np.arange(3)).ravel()
    return sp.csr_matrix((blocks.reshape(-1), (rows, cols)), shape=(2 * m, 3 * m))


class ElasticProblem:
    """Linear elasticity of one layout under one constraint method; ``solve`` per load."""

    def __init__(self, disc, E, nu, state: str = "plane_strain", *, eigenstrain=None,
                 eigenstrain_zz=None, method: str = "master-slave", integration: str = "vci",
                 penalty: float = 1e4, cutoff_threshold: float = 1e-12,
                 cutoff_radius: float | None = None, min_support: int = 5,
                 linear_solver: str = "auto", stabilisation: float = 0.0,
                 dissection: bool = True, update_factors: bool = True,
                 lagrange_form_above: int = LAGRANGE_FORM_ABOVE, symbolic=None):
        if method not in METHODS:
            raise ValueError(f"unknown constraint method {method!r} (known: {', '.join(METHODS)})")
        if integration not in INTEGRATIONS:
            raise ValueError(f"unknown integration {integration!r} "
                             f"(known: {', '.join(INTEGRATIONS)})")
        t0 = time.perf_counter()
        self._system = None               # (pattern key, factorised system) of the last solve
        self.disc, self.method, self.integration = disc, method, integration
        self.penalty, self.linear_solver = float(penalty), linear_solver
        #: order the direct factorisation by nested dissection of the particles (False:
        #: SuperLU's own orders, kept for benchmarks/sph_scaling.py's comparison)
        self.dissection = bool(dissection)
        #: solve a system after breaks through a low-rank update of the last factorised one
        #: (factor_update.py) where the change allows, instead of factorising it afresh
        self.update_factors = bool(update_factors)
        #: plain MS's systems of more unknowns than this are solved in the Lagrange form
        self.lagrange_form_above = int(lagrange_form_above)
        #: a symbolic.SymbolicStore shared by the problems of one layout (a study's
        #: realizations): the first system's order or analysis comes from the last problem's.
        #: Only the first: the systems after breaks differ from run to run
        self._symbolic = symbolic
        self._factored = None             # (factor, its unknowns' global DOFs) of the last build
        self._penalty_scale = None        # mean diag K of the first system built
        self.cutoff_threshold, self.cutoff_radius = float(cutoff_threshold), cutoff_radius
        lay = disc.layout
        n = disc.n
        E = np.broadcast_to(np.asarray(E, dtype=float), (n,))
        nu = np.broadcast_to(np.asarray(nu, dtype=float), (n,))
        self.D = elasticity_matrices(E, nu, state)
        self.eigenstress = np.zeros((n, 3))
        if eigenstrain is not None:
            self.eigenstress = np.einsum("nij,nj->ni", self.D,
                                         np.asarray(eigenstrain, dtype=float).reshape(n, 3))
        if eigenstrain_zz is not None:
            lam, _ = lame(E, nu, state)
            self.eigenstress[:, :2] += (lam * np.asarray(eigenstrain_zz, dtype=float))[:, None]

        self.boundary = np.asarray(lay.boundary)
        self.pairs = np.asarray(lay.pairs).reshape(-1, 2)
        self.pair_inclusion = np.asarray(lay.pair_inclusion)
        nb = self.boundary.size
        slaves = np.concatenate([self.boundary, self.pairs[:, 0]])
        local = method == "master-slave-local"
        if local:
            # seed §4.3: a slave's row sees no other slave, so Phi_ss is diagonal
            invisible = np.zeros(n, dtype=bool)
            invisible[slaves] = True
            slave_rows = disc.memo(("local slave rows", min_support), lambda: disc.interpolation(
                disc.x[slaves], disc.phase[slaves], invisible=invisible, keep=slaves,
                min_support=min_support))
        else:
            slave_rows = disc.phi[slaves]
        self.boundary_rows = slave_rows[:nb]
        self.pair_matrix_rows = slave_rows[nb:]
        self.pair_inclusion_rows = disc.phi[self.pairs[:, 1]]
        # the interpolation operator of reported displacements: slaves by their own rows (a
        # particle listed twice takes its last row), picked from [phi; slave_rows]
        last = slaves.size - 1 - np.unique(slaves[::-1], return_index=True)[1]
        pick = np.arange(n)
        pick[slaves[last]] = n + last
        self.report_rows = sp.vstack([disc.phi, slave_rows]).tocsr()[pick]

        # boundary quadrature: outer edge, then each side of every interface (outward normals)
        pair_normal = np.asarray(lay.pair_normal, dtype=float).reshape(-1, 2)
        self.quad_rows = sp.vstack([self.boundary_rows, self.pair_matrix_rows,
                                    self.pair_inclusion_rows]).tocsr()
        self.quad_normal = np.concatenate([np.asarray(lay.boundary_normal, dtype=float).reshape(-1, 2),
                                           -pair_normal, pair_normal])
        self.quad_weight = np.concatenate([np.asarray(lay.boundary_weight, dtype=float),
                                           np.asarray(lay.pair_weight, dtype=float),
                                           np.asarray(lay.pair_weight, dtype=float)])
        self.quad_particle = np.concatenate([self.boundary, self.pairs[:, 0], self.pairs[:, 1]])

        test = None
        if integration == "vci":
            test = disc.memo(("corrected test operator", local, min_support),
                             self._corrected_test_operator)
        self.test = disc.B if test is None else test
        self.K = disc.stiffness(self.D, test)
        if stabilisation > 0.0:
            self.K = (self.K + self._stabilisation(stabilisation)).tocsr()
        self.f = self.test.T @ (self.eigenstress * disc.volume[:, None]).reshape(-1)
        # stress at each quadrature point: its own particle's on the outer edge; on an
        # interface the mean of the two sides', so the interface term -sum w (v+ - v-) {t}
        # vanishes on every test function continuous at the pair (Nitsche's average flux)
        n_q = self.quad_particle.size
        rows3 = lambda idx: disc.B[(3 * idx[:, None] + np.arange(3)).ravel()]  # noqa: E731
        stress_at = lambda idx: block_diagonal(self.D[idx]) @ rows3(idx)  # noqa: E731
        pair_mean = 0.5 * (stress_at(self.pairs[:, 0]) + stress_at(self.pairs[:, 1]))
        stress_q = sp.vstack([stress_at(self.boundary), pair_mean, pair_mean]).tocsr()
        eigen_q = np.concatenate([self.eigenstress[self.boundary],
                                  np.tile(0.5 * (self.eigenstress[self.pairs[:, 0]]
                                                 + self.eigenstress[self.pairs[:, 1]]), (2, 1))])
        normals = _traction_operator(self.quad_normal, np.broadcast_to(np.eye(3), (n_q, 3, 3)))
        self.traction = (_block_rows(normals) @ stress_q).tocsr()
        self.eigen_traction = np.einsum("qij,qj->qi", normals, eigen_q).reshape(-1)
        #: one-off costs (s): neighbour search, and shape functions plus stiffness
        self.setup_timings = {"neighbours": disc.timings["neighbours"],
                              "assembly": disc.timings["shape_functions"]
                              + time.perf_counter() - t0}

    # -- integration ---------------------------------------------------------------------

    def _corrected_test_operator(self) -> sp.csr_matrix:
        """B^ with grad^psi_b = grad psi_b + xi_b psi_b (docs/sph.md, "Integration")."""
        d = self.disc
        boundary_sum = np.stack([self.quad_rows.T @ (self.quad_weight * self.quad_normal[:, k])
                                 for k in range(2)], 1)
        volume_sum = np.stack([d.gx.T @ d.volume, d.gy.T @ d.volume], 1)
        psi_sum = d.phi.T @ d.volume
        xi = (boundary_sum - volume_sum) / psi_sum[:, None]
        gx = (d.gx + d.phi @ sp.diags(xi[:, 0])).tocsr()
        gy = (d.gy + d.phi @ sp.diags(xi[:, 1])).tocsr()
        return strain_operator(gx, gy)

    def _stabilisation(self, beta: float) -> sp.csr_matrix:
        """beta * sum_c mu_c V_c / h^2 |u_c - (phi u)_c|^2: the parameters' departure from their
        own interpolant. It is zero on every linear field (phi reproduces them), so the patch
        test still holds, and it stiffens the checkerboard modes that particle integration
        leaves without energy (docs/sph.md, "Zero-energy modes")."""
        d = self.disc
        mu = self.D[:, 2, 2]
        R = (sp.identity(d.n, format="csr") - d.phi).tocsr()
        scalar = R.T @ sp.diags(beta * mu * d.volume / d.h ** 2) @ R
        return sp.kron(scalar, sp.identity(2, format="csr"), format="csr")

    # -- constraints ---------------------------------------------------------------------

    def constraints(self, boundary_values, intact) -> tuple[Constraints, np.ndarray]:
        """The rows imposed: every prescribed boundary component and both components of every
        intact pair; and, per quadrature point and component, whether it is imposed."""
        d = self.disc
        bv = np.asarray(boundary_values, dtype=float).reshape(-1, 2)
        intact = np.asarray(intact, dtype=bool)
        b_on = np.isfinite(bv)
        p_on = np.repeat(intact[:, None], 2, axis=1)
        rows = sp.vstack([d.dof_matrix(self.boundary_rows),
                          d.dof_matrix(self.pair_matrix_rows) - d.dof_matrix(self.pair_inclusion_rows)]).tocsr()
        on = np.concatenate([b_on.ravel(), p_on.ravel()])
        rhs = np.concatenate([np.where(b_on, bv, 0.0).ravel(), np.zeros(p_on.size)])
        slave_particle = np.concatenate([self.boundary, self.pairs[:, 0]])
        slaves = (2 * slave_particle[:, None] + np.arange(2)).ravel()
        points = np.repeat(d.x[slave_particle], 2, axis=0)
        kinds = np.concatenate([np.repeat([f"boundary particle {i}" for i in self.boundary], 2),
                                np.repeat([f"pair {k}" for k in range(self.pairs.shape[0])], 2)])
        comp = np.tile(["x", "y"], slave_particle.size)
        label = np.char.add(np.char.add(kinds.astype(str), " "), comp)
        sel = np.flatnonzero(on)
        c = Constraints(rows=rows[sel], rhs=rhs[sel], slaves=slaves[sel], points=points[sel],
                        label=label[sel])
        quad_on = np.concatenate([b_on, p_on, p_on])
        return c, quad_on

    def _build(self, c, quad_on, detached) -> dict:
        """The factorised system of one constraint pattern (reused while no pair breaks)."""
        d = self.disc
        K, f = self.K, self.f.copy()
        if self.method == "penalty" and self.integration == "vci":
            # Nitsche's consistency term in point quadrature, on the imposed components only
            # (the seed's plain penalty, with nodal integration, has none)
            weight = (self.quad_weight[:, None] * quad_on).ravel()
            Q = d.dof_matrix(self.quad_rows)
            K = (K - Q.T @ sp.diags(weight) @ self.traction).tocsr()
            f = f - Q.T @ (weight * self.eigen_traction)
        free = np.ones(d.ndof, dtype=bool)
        removed = np.flatnonzero(np.isin(d.phase, np.flatnonzero(detached) + 1))
        free[2 * removed] = free[2 * removed + 1] = False
        keep = np.flatnonzero(free)
        if removed.size:
            K = K[keep][:, keep].tocsr()
            f = f[keep]
            c = Constraints(rows=c.rows[:, keep], rhs=c.rhs,
                            slaves=np.searchsorted(keep, c.slaves), points=c.points,
                            label=c.label)
        out = {"keep": keep, "removed": removed, "K": K, "f": f}
        dof_points = np.repeat(d.x, 2, axis=0)[keep]
        t0 = time.perf_counter()
        if self.method == "penalty":
            # one weight for the whole run, from the first system's stiffness (the intact
            # plate's): a weight that followed the consistency term through the breaks would
            # change every constraint row at each, and the system's update with it
            # (factor_update.py)
            if self._penalty_scale is None:
                self._penalty_scale = float(np.mean(K.diagonal()))
            A, _, w = penalty_system(K, f, c, self.penalty, self._penalty_scale)
            out.update(w=w, transformation=time.perf_counter() - t0)
            out.update(factor=self._factorised(A, keep, dof_points))
            return out
        if self.method == "master-slave" and K.shape[0] > self.lagrange_form_above:
            form = lagrange_form(K, c, float(np.mean(K.diagonal())))
            out["transformation"] = time.perf_counter() - t0
            # its unknowns (the multipliers among them) are not the next system's: no update
            out.update(lagrange=form, factor=self._factorised(
                form.A, None, np.concatenate([dof_points, c.points]), nearly_symmetric=True))
            return out
        threshold = self.cutoff_threshold if self.method == "master-slave-cutoff" else 0.0
        radius = self.cutoff_radius if self.method == "master-slave-cutoff" else None
        ms = master_slave(K, f, c, dof_points, threshold=threshold, pattern_radius=radius)
        out["transformation"] = time.perf_counter() - t0
        rows = c.rows.tocsc()[:, c.slaves].tocsc()
        out.update(ms=ms, factor=self._factorised(ms.K_hat, keep[ms.masters],
                                                  dof_points[ms.masters], nearly_symmetric=True),
                   scatter=sp.csr_matrix((np.ones(c.slaves.size),
                                          (c.slaves, np.arange(c.slaves.size))),
                                         shape=(keep.size, c.slaves.size)),
                   phi_ss=functools.cache(lambda: splu(rows)))
        return out

    def _factorised(self, A, unknowns, points, nearly_symmetric=False):
        """A's factors: a low-rank update of the last system built, where the breaks since
        allow one, else a fresh Factor. ``unknowns``: the global DOF of each row of A, how the
        last system's rows are found in A's; None: A is never updated nor updates another
        (the Lagrange form, whose multipliers are no DOF)."""
        store, self._symbolic = self._symbolic, None

        def fresh():
            return Factor(A, self.linear_solver, nearly_symmetric,
                          points if self.dissection else None,
                          single_precision=not (self.method == "penalty"
                                                and self.penalty > SINGLE_PRECISION_MAX_PENALTY),
                          store=store)
        if self.update_factors and self._factored is not None and unknowns is not None:
            t0 = time.perf_counter()
            try:
                factor = UpdatedFactor(*self._factored, A, unknowns, fresh)
            except NotLowRank:
                factor = fresh()
                # the refused update's time is the factors' too, not the assembly's
                factor.build_seconds = time.perf_counter() - t0
        else:
            factor = fresh()
        self._factored = (factor, unknowns) if unknowns is not None else None
        return factor

    # -- solve ---------------------------------------------------------------------------

    def solve(self, boundary_values, intact=None, detached=None,
              condition: bool = False) -> Solution:
        d = self.disc
        npair = self.pairs.shape[0]
        intact = np.ones(npair, dtype=bool) if intact is None else np.asarray(intact, dtype=bool)
        n_incl = len(getattr(d.layout, "inclusions", ())) or (int(self.pair_inclusion.max()) + 1
                                                             if npair else 0)
        detached = np.zeros(n_incl, dtype=bool) if detached is None else np.asarray(detached)
        intact = intact & ~detached[self.pair_inclusion] if npair else intact
        counts = np.bincount(self.pair_inclusion[intact], minlength=n_incl) if npair else []
        for k in range(n_incl):
            if not detached[k] and counts[k] < 2:
                raise SolverError(f"inclusion {k} keeps {counts[k]} intact pair(s): its rigid "
                                  f"{'motion' if counts[k] == 0 else 'rotation'} is unconstrained "
                                  f"(detach it)")
        t0 = time.perf_counter()
        c, quad_on = self.constraints(boundary_values, intact)
        key = (quad_on.tobytes(), detached.tobytes())
        built = self._system is None or self._system[0] != key
        if built:
            self._system = (key, self._build(c, quad_on, detached))
        system = self._system[1]
        keep = system["keep"]
        if keep.size < d.ndof:
            c = Constraints(rows=c.rows[:, keep], rhs=c.rhs,
                            slaves=np.searchsorted(keep, c.slaves), points=c.points,
                            label=c.label)
        t1 = time.perf_counter()
        if self.method == "penalty":
            b = system["f"] + system["w"] * (c.rows.T @ c.rhs)
            t2 = time.perf_counter()
            u_free, info = system["factor"].solve(b)
        elif "lagrange" in system:
            form = system["lagrange"]
            b = form.rhs(system["f"], c.rhs)
            t2 = time.perf_counter()
            x, info = system["factor"].solve(b)
            u_free = x[:form.n]
        else:
            ms = system["ms"]
            if not built:
                # same constraint pattern, new prescribed values: only q and f^ change
                ms.q = system["phi_ss"]().solve(c.rhs)
                ms.u_q = system["scatter"] @ ms.q
                ms.f_hat = ms.P.T @ (system["f"] - system["K"] @ ms.u_q)
            t2 = time.perf_counter()
            x, info = system["factor"].solve(ms.f_hat)
            u_free = ms.expand(x)
        A = system["factor"].A
        removed = system["removed"]
        t3 = time.perf_counter()
        u = np.full(d.ndof, np.nan)
        u[keep] = u_free
        u_calc = np.where(np.isfinite(u), u, 0.0)
        U = u_calc.reshape(-1, 2)
        disp = self.report_rows @ U
        strain = d.strain(u_calc)
        stress = np.einsum("nij,nj->ni", self.D, strain) - self.eigenstress
        if removed.size:
            disp[removed] = np.nan
            strain[removed] = np.nan
            stress[removed] = np.nan
        residual = float(np.max(np.abs(c.rows @ u_free - c.rhs))) if c.rhs.size else 0.0
        pair_error = 0.0
        if intact.any():
            jump = (self.pair_matrix_rows @ U - self.pair_inclusion_rows @ U)[intact]
            scale = float(np.nanmax(np.abs(disp))) or 1.0
            pair_error = float(np.max(np.abs(jump))) / scale
        cond = condition_estimate(A) if condition else None
        return Solution(u, disp, strain, stress, residual, pair_error,
                        {"assembly": t1 - t0 - (system["transformation"] + system["factor"].build_seconds
                                                if built else 0.0),
                         "transformation": t2 - t1 + (system["transformation"] if built else 0.0),
                         "solve": t3 - t2 + (system["factor"].build_seconds if built else 0.0)},
                        cond, info)
