"""Kernel, corrected shape functions, gradients and particle stiffness (docs/sph.md)."""

from types import SimpleNamespace

import numpy as np
import pytest

from solvers.sph.interpolation import (InterpolationError, find_neighbours,
                                       restricted_neighbours, shape_functions, sorted_unique)
from solvers.sph.kernel import KERNELS, kernel
from solvers.sph.stiffness import Discretisation, elasticity_matrices

EPS = np.finfo(float).eps


def lattice(n_side, spacing=1.0, jitter=0.0, seed=0):
    g = np.arange(n_side) * spacing
    X, Y = np.meshgrid(g, g)
    x = np.c_[X.ravel(), Y.ravel()]
    if jitter:
        x = x + jitter * spacing * np.random.default_rng(seed).uniform(-1, 1, x.shape)
    return SimpleNamespace(x=x, volume=np.full(x.shape[0], spacing ** 2),
                           phase=np.zeros(x.shape[0], dtype=np.int32))


def operators(layout, ratio=2.0, points=None, kern="cubic_spline"):
    a = np.sqrt(layout.volume.mean() / np.pi)
    h = ratio * a
    pts = layout.x if points is None else points
    nb = find_neighbours(pts, np.zeros(len(pts), int), layout.x, layout.phase, 2 * h)
    sf = shape_functions(pts, layout.x, layout.volume, nb, h, kern)
    return sf.matrix(), sf.matrix(sf.dpsi_dx), sf.matrix(sf.dpsi_dy)


@pytest.mark.parametrize("name", KERNELS)
def test_kernels_are_normalised_and_vanish_smoothly_at_two_h(name):
    h = 0.7
    r = np.linspace(0.0, 2.0 * h, 200001)
    w, dw = kernel(name, r, h)
    # trapezoid rule on a smooth integrand with 2e5 intervals: error ~ (dr)^2 |f''| ~ 1e-10
    assert np.trapezoid(2 * np.pi * r * w, r) == pytest.approx(1.0, abs=1e-8)
    w2, dw2 = kernel(name, np.array([2.0 * h, 2.5 * h]), h)
    assert np.all(w2 == 0.0) and np.all(dw2 == 0.0)
    inner = r[1:-1:997]
    step = 1e-6
    fd = (kernel(name, inner + step, h)[0] - kernel(name, inner - step, h)[0]) / (2 * step)
    # central difference: truncation step^2 |W'''| / 6 plus rounding eps |W| / step (~1e-9 here)
    assert np.allclose(kernel(name, inner, h)[1], fd, rtol=0, atol=1e-7 * np.abs(w).max())


def test_an_interior_particle_of_a_square_lattice_sees_21_neighbours_with_h_twice_a():
    lay = lattice(11)
    a = np.sqrt(1.0 / np.pi)
    counts = find_neighbours(lay.x, lay.phase, lay.x, lay.phase, 2 * 2.0 * a).counts()
    assert counts[5 * 11 + 5] == 21
    assert counts[0] == 8  # a corner keeps the quarter disc: 1 + 2 + 2 + 1 + 2


@pytest.mark.parametrize("jitter", [0.0, 0.3])
@pytest.mark.parametrize("kern", KERNELS)
def test_corrected_shape_functions_reproduce_linear_fields_and_their_gradients(jitter, kern):
    lay = lattice(12, spacing=0.01, jitter=jitter)
    rng = np.random.default_rng(3)
    pts = rng.uniform(0.0, 0.11, (200, 2))
    for points in (None, pts):
        phi, gx, gy = operators(lay, points=points, kern=kern)
        X = lay.x if points is None else points
        # sums of ~21 terms of size ~1 through M^-1 (rcond > 1e-4 on these supports)
        tol = 1e4 * 21 * EPS
        assert np.abs(phi.sum(axis=1).A1 - 1.0).max() < tol
        assert np.abs(phi @ lay.x - X).max() < tol * 0.11
        assert np.abs(gx.sum(axis=1)).max() < tol / 0.01
        assert np.abs(gx @ lay.x[:, 0] - 1.0).max() < tol
        assert np.abs(gx @ lay.x[:, 1]).max() < tol
        assert np.abs(gy @ lay.x[:, 1] - 1.0).max() < tol
        assert np.abs(gy @ lay.x[:, 0]).max() < tol


def test_gradients_are_the_derivatives_of_the_shape_functions():
    lay = lattice(10, jitter=0.25)
    p = np.array([[4.3, 4.7], [0.2, 8.9]])
    step = 1e-5
    _, gx, gy = operators(lay, points=p)
    for k, g in enumerate((gx, gy)):
        e = np.zeros(2)
        e[k] = step
        fd = (operators(lay, points=p + e)[0] - operators(lay, points=p - e)[0]) / (2 * step)
        # central difference on a C1 kernel (cubic spline): truncation step^2 |psi'''| ~ 1e-10
        # and rounding eps / step ~ 1e-11; 1e-7 keeps a factor for the kernel's kinks
        assert np.abs((fd - g).toarray()).max() < 1e-7


def test_a_support_never_crosses_into_another_phase():
    lay = lattice(9)
    lay.phase = (lay.x[:, 0] > 4.0).astype(np.int32)
    nb = find_neighbours(lay.x, lay.phase, lay.x, lay.phase, 2.3)
    assert np.all(lay.phase[nb.row] == lay.phase[nb.col])
    assert nb.counts().min() >= 4


@pytest.mark.parametrize("keys", [np.zeros(0, dtype=np.int64), np.array([7]),
                                  np.array([3, -2, 3, 3, 9, -2, 0]),
                                  np.random.default_rng(1).integers(-10**12, 10**12, 5000),
                                  np.random.default_rng(2).integers(0, 50, 5000)])
def test_sorted_unique_is_numpys_unique(keys):
    out = sorted_unique(keys)
    assert out.dtype == keys.dtype and np.array_equal(out, np.unique(keys))


def test_the_neighbour_pairs_are_every_same_phase_pair_within_the_radius_sorted():
    lay = lattice(12, jitter=0.3, seed=4)
    lay.phase = (lay.x[:, 1] > 5.0).astype(np.int32)
    points = np.vstack([lay.x[::5], lay.x[7]])        # one point on a particle, exactly
    point_phase = np.r_[lay.phase[::5], lay.phase[7]]
    radius = 2.2
    nb = find_neighbours(points, point_phase, lay.x, lay.phase, radius)
    d = np.hypot(points[:, None, 0] - lay.x[None, :, 0], points[:, None, 1] - lay.x[None, :, 1])
    # no distance within 1e-9 of the radius here, so rounding cannot decide a pair
    assert np.abs(d - radius).min() > 1e-9
    row, col = np.nonzero((d <= radius) & (point_phase[:, None] == lay.phase[None, :]))
    assert np.array_equal(nb.row, row) and np.array_equal(nb.col, col)


@pytest.mark.parametrize("where", ["too_small", "collinear"])
def test_a_support_too_small_for_the_correction_names_its_point(where):
    if where == "too_small":
        lay = lattice(5)
        ratio = 0.5          # 2h = 0.56 spacing: a support holds only its own particle
    else:
        x = np.c_[np.arange(6.0), np.zeros(6)]
        lay = SimpleNamespace(x=x, volume=np.ones(6), phase=np.zeros(6, np.int32))
        ratio = 2.0
    with pytest.raises(InterpolationError, match=r"point 0 at .*too few or collinear") as e:
        operators(lay, ratio=ratio)
    assert e.value.point == 0


def test_restricted_supports_hide_slaves_from_each_other_and_compensate():
    lay = lattice(9)
    edge = np.flatnonzero(lay.x[:, 1] == 0.0)
    invisible = np.zeros(lay.x.shape[0], bool)
    invisible[edge] = True
    nb = find_neighbours(lay.x[edge], np.zeros(edge.size, int), lay.x, lay.phase, 2.26)
    for min_support in (5, 14):
        r = restricted_neighbours(nb, lay.x[edge], lay.x, lay.phase, np.zeros(edge.size, int),
                                  invisible, edge, min_support)
        seen_slaves = invisible[r.col] & (r.col != edge[r.row])
        assert not seen_slaves.any()
        assert r.counts().min() >= min_support
        sf = shape_functions(lay.x[edge], lay.x, lay.volume, r, 0.5 * r.radius)
        phi = sf.matrix()
        assert np.allclose(phi[:, edge].toarray(), np.diag(np.diag(phi[:, edge].toarray())))
        # the modified rows still reproduce linear fields (rounding through M^-1)
        assert np.abs(phi @ lay.x - lay.x[edge]).max() < 1e-12 * 9
    grown = restricted_neighbours(nb, lay.x[edge], lay.x, lay.phase, np.zeros(edge.size, int),
                                  invisible, edge, 14)
    assert grown.radius.max() > nb.radius.max()


def test_rigid_motions_cost_no_energy_and_others_do():
    lay = lattice(8, jitter=0.2)
    d = Discretisation(lay, 2.0)
    D = elasticity_matrices(np.full(d.n, 1e9), np.full(d.n, 0.3), "plane_strain")
    K = d.stiffness(D)
    x = lay.x
    scale = abs(K).max() * np.abs(x).max()
    for rigid in (np.c_[np.ones(d.n), np.zeros(d.n)], np.c_[-x[:, 1], x[:, 0]]):
        # linear reproduction makes the strain of a rigid motion zero to rounding
        assert np.abs(K @ rigid.ravel()).max() < 1e3 * EPS * scale
    u = np.random.default_rng(0).standard_normal(d.ndof)
    assert u @ K @ u > 0
    assert abs(K - K.T).max() < 1e3 * EPS * abs(K).max()  # B^T D B is symmetric to rounding


@pytest.mark.numerics
@pytest.mark.parametrize("state, compliance", [("plane_strain", (1 - 0.3 ** 2) / 2e9),
                                               ("plane_stress", 1 / 2e9)])
def test_elasticity_matrices_give_the_uniaxial_compliance(state, compliance):
    D = elasticity_matrices(np.array([2e9]), np.array([0.3]), state)[0]
    strain = np.linalg.solve(D, [1.0, 0.0, 0.0])
    # LU with partial pivoting on 3x3 (any LAPACK kernel): relative error <= 9 kappa eps
    # (Higham Thm 9.4, gamma_3n), plus 4 eps for the reference's own roundings
    bound = (9 * np.linalg.cond(D) + 4) * EPS
    assert strain[0] == pytest.approx(compliance, rel=bound)
    assert strain[2] == 0.0
