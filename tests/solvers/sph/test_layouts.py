"""Particle layouts (solvers/sph/layouts.py; docs/sph.md § 6)."""

import math

import numpy as np
import pytest
from scipy.special import ellipe

from solvers.sph.layouts import (Box, Ellipse, LayoutError, polar_layout, random_layout,
                                 regular_layout)

EPS = np.finfo(float).eps


def as_set(x):
    return set(map(tuple, x))


def phase_sums(lay):
    return np.array([lay.volume[lay.phase == k].sum() for k in range(lay.phase_area.size)])


@pytest.mark.parametrize("make", [
    lambda: regular_layout(Box(-12.0, -12.0, 12.0, 12.0), 1.0, [Ellipse(0.5, -1.0, 6.0, 3.5, 0.4)]),
    lambda: regular_layout(Box(0.0, 0.0, 40.0, 30.0), 1.0,
                           [Ellipse(10.0, 10.0, 5.0, 5.0), Ellipse(28.0, 17.0, 6.0, 2.5, 1.0)]),
    lambda: polar_layout(20.0, 60.0, 2.0)])
def test_each_phase_sums_to_its_exact_area(make):
    lay = make()
    # a sum of n positive terms: n eps relative
    assert np.allclose(phase_sums(lay), lay.phase_area, rtol=lay.n * EPS, atol=0)
    assert np.all(lay.volume > 0)


def test_a_plain_lattice_gives_full_half_and_quarter_cells():
    lay = regular_layout(Box(0.0, 0.0, 10.0, 8.0), 1.0)
    assert lay.n == 11 * 9
    x, v = lay.x, lay.volume
    edge_x, edge_y = np.isin(x[:, 0], (0.0, 10.0)), np.isin(x[:, 1], (0.0, 8.0))
    # a cell of 36 samples rescaled by an exact area ratio: a few eps
    assert np.allclose(v[~edge_x & ~edge_y], 1.0, rtol=8 * EPS)
    assert np.allclose(v[edge_x ^ edge_y], 0.5, rtol=8 * EPS)
    assert np.allclose(v[edge_x & edge_y], 0.25, rtol=8 * EPS)
    assert lay.boundary.size == 2 * (10 + 8)
    # 36 exact unit weights
    assert lay.boundary_weight.sum() == pytest.approx(36.0, rel=1e-15)


def test_pairs_sit_on_their_ellipse_with_outward_normals_and_the_perimeter():
    e = Ellipse(1.0, 2.0, 7.0, 3.0, 0.3)
    lay = regular_layout(Box(-15.0, -15.0, 15.0, 15.0), 1.0, [e])
    m, i = lay.pairs[:, 0], lay.pairs[:, 1]
    assert np.array_equal(lay.x[m], lay.x[i])
    assert np.all(lay.phase[m] == 0) and np.all(lay.phase[i] == 1)
    # on the ellipse to the rounding of cos/sin and the rotation
    assert np.abs(e.level(lay.x[m]) - 1.0).max() < 1e-13
    assert np.allclose(np.hypot(*lay.pair_normal.T), 1.0, rtol=1e-15)
    assert np.all(np.sum(lay.pair_normal * (lay.x[m] - (e.cx, e.cy)), axis=1) > 0)
    # n equal shares of the perimeter summed: n eps with n ~ 40
    assert lay.pair_weight.sum() == pytest.approx(4 * 7.0 * ellipe(1 - (3 / 7) ** 2), rel=1e-12)
    # ellipe(0) = pi/2 to rounding: a few eps
    assert Ellipse(0, 0, 5, 5).perimeter == pytest.approx(10 * math.pi, rel=1e-15)


@pytest.mark.parametrize("lay", [regular_layout(Box(-15.0, -15.0, 15.0, 15.0), 1.0,
                                                [Ellipse(0.0, 0.0, 6.0, 6.0)]),
                                 polar_layout(20.0, 60.0, 2.0)])
def test_symmetric_geometry_gives_bitwise_symmetric_particles(lay):
    pts = as_set(lay.x)
    for mirror in (lambda x: np.c_[-x[:, 0], x[:, 1]], lambda x: np.c_[x[:, 0], -x[:, 1]],
                   lambda x: x[:, ::-1]):
        assert as_set(mirror(lay.x)) == pts
    on_x = np.sort(lay.x[(lay.x[:, 1] == 0) & (lay.x[:, 0] > 0), 0])
    on_y = np.sort(lay.x[(lay.x[:, 0] == 0) & (lay.x[:, 1] > 0), 1])
    assert np.array_equal(on_x, on_y) and on_x.size > 3


@pytest.mark.numerics
def test_polar_boundary_is_the_outer_ring():
    lay = polar_layout(20.0, 60.0, 2.0)
    r = np.hypot(*lay.x[lay.boundary].T)
    # hypot of exactly mirrored cos/sin points: a few eps
    assert np.allclose(r, 60.0, rtol=1e-15)
    # n shares (each a few roundings of cos/sin-free arithmetic) summed in any order: the
    # recursive-summation bound (n + 4) eps, whatever the order numpy's pairwise sum takes
    n = lay.boundary_weight.size
    assert lay.boundary_weight.sum() == pytest.approx(120 * math.pi, rel=(n + 4) * EPS)


def test_random_sequential_addition_keeps_its_gap_and_follows_its_seed():
    box = Box(-50.0, -50.0, 50.0, 50.0)
    draw = lambda s, n=9: random_layout(box, 1.0, n, ((6.0, 3.0), (10.0, 6.0)),  # noqa: E731
                                        np.random.default_rng(s), min_gap=4.5)
    a, b, c = draw(0), draw(0), draw(1)
    assert np.array_equal(a.x, b.x) and not np.array_equal(a.x, c.x)
    for lay in (a, c):
        for k, e in enumerate(lay.inclusions):
            dense = e.samples(0.05)
            assert box.x1 - np.abs(dense).max() >= 4.5 - 0.05
            for o in lay.inclusions[:k]:
                d = np.min(np.hypot(*(dense[:, None, :] - o.samples(0.05)[None, :, :]).T))
                assert d >= 4.5 - 0.1           # sampled at 0.05: within two sample spacings
        assert 0.05 < lay.volume_fraction < 0.2
    one = draw(3, n=1)
    assert one.n_inclusions == 1
    thin = random_layout(box, 1.0, 2, ((10.0, 1.0), (10.0, 1.0)), np.random.default_rng(0),
                         min_gap=4.5)
    assert np.allclose(phase_sums(thin), thin.phase_area, rtol=thin.n * EPS)


@pytest.mark.parametrize("args, key", [
    ((Box(0.0, 0.0, 10.5, 10.0), 1.0, []), "width"),
    ((Box(-10.0, -10.0, 10.0, 10.0), 1.0, [Ellipse(0, 0, 4, 4), Ellipse(5, 0, 3, 3)]),
     "inclusions[1]"),
    ((Box(-10.0, -10.0, 10.0, 10.0), 1.0, [Ellipse(8.0, 0, 3, 2)]), "inclusions[0]"),
    ((Box(-10.0, -10.0, 10.0, 10.0), 1.0, [Ellipse(0.0, 0, 0.5, 0.5)]), "inclusions[0]"),
    ((Box(-10.0, -10.0, 10.0, 10.0), -1.0, []), "spacing"),
])
def test_bad_geometry_names_its_key(args, key):
    with pytest.raises(LayoutError) as e:
        regular_layout(*args)
    assert e.value.key == key


def test_a_crowded_plate_is_refused():
    with pytest.raises(LayoutError, match="placed"):
        random_layout(Box(-10.0, -10.0, 10.0, 10.0), 1.0, 20, ((3.0, 3.0), (3.0, 3.0)),
                      np.random.default_rng(0), min_gap=2.0, max_attempts=500)
