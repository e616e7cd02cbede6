"""Corrected (reproducing-kernel) shape functions and their gradients, phase by phase.

The displacement at a point X of phase k is u(X) = sum_b psi_b(X) u_b over the particles b
of phase k within 2h of X (seed eq. 9, psi_b = V_b W~_b), with the linear correction

    psi_b(X) = V_b W(|X_b - X|) P(X_b - X) . M(X)^-1 e_1,   P(d) = [1, d_x, d_y],
    M(X)     = sum_b V_b W(|X_b - X|) P(X_b - X) P(X_b - X)^T,

so that sum_b psi_b = 1 and sum_b psi_b X_b = X exactly: rigid motions and homogeneous
strains are reproduced, which the constraints need (docs/sph.md, "Corrected interpolation").
The gradient is the exact derivative of psi (M's derivative included), so it reproduces
constant strains too. A support never crosses an interface: the neighbour search runs inside
each phase, which is what makes a debonded pair a free surface.

Every function works on flat neighbour-pair arrays (row = evaluation point, col = particle):
no Python loop over points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from solvers.sph.kernel import kernel

#: reciprocal condition number of M below which a support cannot carry the linear correction
#: (its particles are (nearly) collinear or too few): 1e-12 leaves ~4 digits of the 16
MIN_RCOND = 1e-12


class InterpolationError(ValueError):
    """A support too small for the linear correction, naming the point."""

    def __init__(self, reason: str, point: int):
        super().__init__(reason)
        self.point = point


@dataclass(frozen=True)
class Neighbours:
    """Flat (row, col) pairs: evaluation point ``row`` sees particle ``col`` (same phase)."""
    row: np.ndarray
    col: np.ndarray
    n_points: int
    radius: np.ndarray       # support radius (2h) per evaluation point

    def counts(self) -> np.ndarray:
        return np.bincount(self.row, minlength=self.n_points)


def find_neighbours(points, point_phase, x, phase, radius) -> Neighbours:
    """Particles of the same phase within ``radius`` (scalar) of each point, by one k-d tree
    per phase; pairs sorted by row then column, so every later sum is reproducible."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    point_phase = np.asarray(point_phase)
    rows, cols = [], []
    for k in np.unique(point_phase):
        members = np.flatnonzero(phase == k)
        where = np.flatnonzero(point_phase == k)
        if members.size == 0 or where.size == 0:
            continue
        near = cKDTree(points[where]).sparse_distance_matrix(
            cKDTree(x[members]), radius, output_type="coo_matrix")
        rows.append(where[near.row])
        cols.append(members[near.col])
        # sparse_distance_matrix leaves out exact zero distances (a point on a particle)
        same = cKDTree(points[where]).query(x[members], distance_upper_bound=0.0)
        hit = np.isfinite(same[0])
        rows.append(where[same[1][hit]])
        cols.append(members[hit])
    row = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
    col = np.concatenate(cols) if cols else np.zeros(0, dtype=np.int64)
    key = sorted_unique(row.astype(np.int64) * x.shape[0] + col)
    row, col = np.divmod(key, x.shape[0])
    return Neighbours(row, col, points.shape[0], np.full(points.shape[0], float(radius)))


def sorted_unique(keys: np.ndarray) -> np.ndarray:
    """``np.unique(keys)`` of an integer array, by a sort: numpy 2.3+ finds unique integers
    by hashing, which made most of the neighbour search on numpy 2.4 (MS2 at 40,709
    particles: 0.68 s against 0.11 s with this sort; BENCHMARKS.md "sph-scaling", direct,
    the runs before and after)."""
    s = np.sort(keys)
    return s[np.concatenate(([True], s[1:] != s[:-1]))] if s.size else s


def _moment_sums(rows, n, weight, dx, dy):
    """The six distinct entries of M = sum weight P P^T per row."""
    s = lambda v: np.bincount(rows, weights=v, minlength=n)  # noqa: E731
    return (s(weight), s(weight * dx), s(weight * dy), s(weight * dx * dx),
            s(weight * dx * dy), s(weight * dy * dy))


def _matrix(m00, m01, m02, m11, m12, m22):
    return np.stack([np.stack([m00, m01, m02], -1), np.stack([m01, m11, m12], -1),
                     np.stack([m02, m12, m22], -1)], -2)


@dataclass(frozen=True)
class ShapeFunctions:
    """psi and its gradient on the pairs of ``nb``, and their sparse matrices."""
    nb: Neighbours
    psi: np.ndarray
    dpsi_dx: np.ndarray
    dpsi_dy: np.ndarray
    n_particles: int

    def matrix(self, values=None) -> sp.csr_matrix:
        v = self.psi if values is None else values
        return sp.csr_matrix((v, (self.nb.row, self.nb.col)),
                             shape=(self.nb.n_points, self.n_particles))


def shape_functions(points, x, volume, nb: Neighbours, h, kernel_name="cubic_spline",
                    gradients=True) -> ShapeFunctions:
    """Corrected shape functions psi_b(X) = V_b W~_b(X) (and gradients) on the pairs ``nb``;
    ``h`` per evaluation point. InterpolationError names the first point whose moment matrix
    cannot be inverted (too few or collinear particles in its support)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    row, col, n = nb.row, nb.col, nb.n_points
    dx = x[col, 0] - points[row, 0]
    dy = x[col, 1] - points[row, 1]
    r = np.hypot(dx, dy)
    h_pair = np.broadcast_to(np.asarray(h, dtype=float), (n,))[row]
    w, dw = kernel(kernel_name, r, h_pair)
    w = w * volume[col]
    dw = dw * volume[col]
    M = _matrix(*_moment_sums(row, n, w, dx, dy))
    # scale-free test: M's entries carry powers of the spacing, so use the scaled basis
    scale = np.broadcast_to(np.asarray(h, dtype=float), (n,))
    S = np.stack([np.ones(n), 1.0 / scale, 1.0 / scale], -1)
    Ms = M * S[:, :, None] * S[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        rcond = 1.0 / np.linalg.cond(Ms, p=1)
    bad = ~(rcond > MIN_RCOND)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        count = int(np.count_nonzero(row == i))
        raise InterpolationError(
            f"point {i} at ({points[i, 0]:.6g}, {points[i, 1]:.6g}) has {count} particle(s) in its "
            f"support of radius {nb.radius[i]:.6g}: too few or collinear for the linear correction",
            i)
    c = np.linalg.solve(M, np.broadcast_to(np.array([1.0, 0.0, 0.0]), (n, 3))[..., None])[..., 0]
    basis = c[row, 0] + c[row, 1] * dx + c[row, 2] * dy
    psi = w * basis
    if not gradients:
        return ShapeFunctions(nb, psi, None, None, x.shape[0])
    # d/dX of psi: d(dx)/dX = -1; dw/dX = -dW/dr * d/r; dc/dX = -M^-1 (dM/dX) c
    with np.errstate(invalid="ignore", divide="ignore"):
        ux = np.where(r > 0.0, dx / r, 0.0)
        uy = np.where(r > 0.0, dy / r, 0.0)
    grads = []
    for e, (ex, ey) in zip((ux, uy), ((1.0, 0.0), (0.0, 1.0))):
        dwk = -dw * e                                   # d(weight)/dX_k
        dm = _moment_sums(row, n, dwk, dx, dy)
        # the basis moves with X: d(P)/dX_k = [0, -ex, -ey]
        dm = [dm[0], dm[1] - ex * _s(row, n, w), dm[2] - ey * _s(row, n, w),
              dm[3] - 2.0 * ex * _s(row, n, w * dx),
              dm[4] - ex * _s(row, n, w * dy) - ey * _s(row, n, w * dx),
              dm[5] - 2.0 * ey * _s(row, n, w * dy)]
        dM = _matrix(*dm)
        dc = -np.linalg.solve(M, (dM @ c[..., None]))[..., 0]
        dbasis = dc[row, 0] + dc[row, 1] * dx + dc[row, 2] * dy - c[row, 1] * ex - c[row, 2] * ey
        grads.append(dwk * basis + w * dbasis)
    return ShapeFunctions(nb, psi, grads[0], grads[1], x.shape[0])


def _s(rows, n, v):
    return np.bincount(rows, weights=v, minlength=n)


def restricted_neighbours(nb: Neighbours, points, x, phase, point_phase, invisible, keep,
                          min_support: int) -> Neighbours:
    """The pairs of ``nb`` without the ``invisible`` particles (bool per particle), except
    ``keep[row]`` (a particle each row keeps, or -1): the modified interpolation of seed §4.3
    where slaves do not see each other. A row left with fewer than ``min_support`` particles is
    compensated with the nearest visible particles of its phase, its radius grown to reach
    them (docs/sph.md, "MS2")."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    keep = np.asarray(keep)
    visible = ~invisible[nb.col] | (nb.col == keep[nb.row])
    row, col = nb.row[visible], nb.col[visible]
    radius = nb.radius.copy()
    short = np.flatnonzero(np.bincount(row, minlength=nb.n_points) < min_support)
    if short.size == 0:
        return Neighbours(row, col, nb.n_points, radius)
    # few rows (corners, tight curves): a direct search per row is cheap
    rows, cols = [row[~np.isin(row, short)]], [col[~np.isin(row, short)]]
    for i in short:
        members = np.flatnonzero((phase == point_phase[i]) & ~invisible)
        d = np.hypot(x[members, 0] - points[i, 0], x[members, 1] - points[i, 1])
        order = np.argsort(d, kind="stable")[:min_support]
        # just past the farthest of the nearest: the kernel vanishes at 2h
        radius[i] = max(radius[i], 1.05 * float(d[order[-1]])) if order.size else radius[i]
        chosen = members[d < radius[i]]
        if keep[i] >= 0:
            chosen = np.union1d(chosen, [keep[i]])
        rows.append(np.full(chosen.size, i))
        cols.append(chosen)
    row_all, col_all = np.concatenate(rows), np.concatenate(cols)
    key = sorted_unique(row_all.astype(np.int64) * x.shape[0] + col_all)
    row, col = np.divmod(key, x.shape[0])
    return Neighbours(row, col, nb.n_points, radius)
