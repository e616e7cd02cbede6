"""Particle (nodal) integration of linear elasticity on the corrected shape functions.

K = sum_c V_c B^_c^T D_c B_c (seed eq. 10): B_c holds the exact gradients of the shape
functions at particle c (the trial strain, exact for linear fields), B^_c the test gradients —
the same, or with the variationally consistent correction of ``problem`` (docs/sph.md,
"Integration"). Voigt order [xx, yy, xy] with engineering shear; DOFs interleaved, 2*i + c.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from solvers.sph.interpolation import find_neighbours, restricted_neighbours, shape_functions

STATES = ("plane_strain", "plane_stress")


def lame(E, nu, state):
    """In-plane Lamé constants (lambda, mu); plane stress uses lambda* = 2 lambda mu /
    (lambda + 2 mu) = E nu / (1 - nu^2)."""
    E, nu = np.asarray(E, dtype=float), np.asarray(nu, dtype=float)
    mu = E / (2.0 * (1.0 + nu))
    if state == "plane_strain":
        lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    elif state == "plane_stress":
        lam = E * nu / (1.0 - nu * nu)
    else:
        raise ValueError(f"unknown state {state!r} (known: {', '.join(STATES)})")
    return lam, mu


def elasticity_matrices(E, nu, state) -> np.ndarray:
    """D per particle, shape (n, 3, 3), Voigt [xx, yy, xy] with engineering shear."""
    lam, mu = lame(E, nu, state)
    lam, mu = np.broadcast_arrays(np.atleast_1d(lam), np.atleast_1d(mu))
    D = np.zeros(lam.shape + (3, 3))
    D[:, 0, 0] = D[:, 1, 1] = lam + 2.0 * mu
    D[:, 0, 1] = D[:, 1, 0] = lam
    D[:, 2, 2] = mu
    return D


def strain_operator(gx: sp.csr_matrix, gy: sp.csr_matrix) -> sp.csr_matrix:
    """B (3 n_points x 2 n): strains [xx, yy, xy] at the points from the parameters."""
    gx, gy = gx.tocoo(), gy.tocoo()
    r, c = gx.row, gx.col
    rows = np.concatenate([3 * r, 3 * gy.row + 1, 3 * gy.row + 2, 3 * r + 2])
    cols = np.concatenate([2 * c, 2 * gy.col + 1, 2 * gy.col, 2 * c + 1])
    vals = np.concatenate([gx.data, gy.data, gy.data, gx.data])
    return sp.csr_matrix((vals, (rows, cols)), shape=(3 * gx.shape[0], 2 * gx.shape[1]))


def block_diagonal(blocks: np.ndarray) -> sp.csr_matrix:
    """A (3n x 3n) sparse block-diagonal matrix of the (n, 3, 3) ``blocks``."""
    n = blocks.shape[0]
    return sp.bsr_matrix((blocks, np.arange(n), np.arange(n + 1)), shape=(3 * n, 3 * n)).tocsr()


class Discretisation:
    """Neighbours, shape functions and gradients of a layout, built once."""

    def __init__(self, layout, smoothing_ratio: float = 2.0, kernel: str = "cubic_spline"):
        self.layout = layout
        self.kernel = kernel
        self.x = np.asarray(layout.x, dtype=float)
        self.volume = np.asarray(layout.volume, dtype=float)
        self.phase = np.asarray(layout.phase)
        self.n = self.x.shape[0]
        self.ndof = 2 * self.n
        self.a = float(np.sqrt(self.volume.mean() / np.pi))
        self.h = smoothing_ratio * self.a
        self.radius = 2.0 * self.h
        t0 = time.perf_counter()
        self.neighbours = find_neighbours(self.x, self.phase, self.x, self.phase, self.radius)
        t1 = time.perf_counter()
        sf = shape_functions(self.x, self.x, self.volume, self.neighbours, self.h, kernel)
        self.phi = sf.matrix()
        self.gx = sf.matrix(sf.dpsi_dx)
        self.gy = sf.matrix(sf.dpsi_dy)
        self.B = strain_operator(self.gx, self.gy)
        self.timings = {"neighbours": t1 - t0, "shape_functions": time.perf_counter() - t1}
        self._memo = {}

    def memo(self, key, build):
        """``build()``, built once per ``key``: what the layout and a method's options decide
        alone (the slave rows, the corrected test gradients), shared by the problems of a
        study's realizations, which differ in the moduli."""
        if key not in self._memo:
            self._memo[key] = build()
        return self._memo[key]

    def interpolation(self, points, phases, invisible=None, keep=None,
                      min_support: int = 0) -> sp.csr_matrix:
        """Rows of psi at ``points`` (each in its phase), optionally with the ``invisible``
        particles removed from every row but the one that ``keep``s it (seed §4.3)."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        phases = np.asarray(phases)
        nb = find_neighbours(points, phases, self.x, self.phase, self.radius)
        if invisible is not None:
            keep = np.full(points.shape[0], -1) if keep is None else np.asarray(keep)
            nb = restricted_neighbours(nb, points, self.x, self.phase, phases, invisible,
                                       keep, min_support)
        sf = shape_functions(points, self.x, self.volume, nb, 0.5 * nb.radius, self.kernel,
                             gradients=False)
        return sf.matrix()

    def dof_matrix(self, rows: sp.csr_matrix) -> sp.csr_matrix:
        """(2m x 2n): the rows of a scalar interpolation for both components, interleaved."""
        return sp.kron(rows, sp.identity(2, format="csr"), format="csr")

    def stiffness(self, D: np.ndarray, test: sp.csr_matrix | None = None) -> sp.csr_matrix:
        """K = B^T diag(V D) B, with ``test`` (3n x 2n) as B^ when given."""
        weighted = block_diagonal(D * self.volume[:, None, None])
        Bt = self.B if test is None else test
        return (Bt.T @ weighted @ self.B).tocsr()

    def strain(self, u: np.ndarray) -> np.ndarray:
        return (self.B @ u).reshape(self.n, 3)

    def displacement(self, u: np.ndarray) -> np.ndarray:
        return self.phi @ u.reshape(self.n, 2)
