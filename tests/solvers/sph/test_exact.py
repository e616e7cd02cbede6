"""Closed-form references (solvers/sph/exact.py; docs/sph.md § 8)."""

import numpy as np
import pytest

from solvers.sph.exact import (VARIANTS, eshelby_constant, eshelby_displacement,
                               eshelby_radial, hashin_shtrikman_2d,
                               voigt_reuss_2d)
from solvers.sph.stiffness import lame

SEED = (0.01, 1000.0, 0.28, 900.0, 0.33)


@pytest.mark.parametrize("variant, printed", [("plane_strain", 0.14481),
                                              ("plane_strain_3d", 0.18536),
                                              ("plane_stress", 0.13448)])
def test_the_interface_displacement_of_the_seeds_example_1(variant, printed):
    assert 20.0 * eshelby_constant(*SEED, variant) == pytest.approx(printed, abs=0.5e-5)


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_solution_is_in_equilibrium_with_continuous_traction(variant):
    eps, Ei, nui, Em, num = SEED
    C = eshelby_constant(*SEED, variant)
    state = "plane_stress" if variant == "plane_stress" else "plane_strain"
    lam_i, mu_i = lame(Ei, nui, state)
    lam_m, mu_m = lame(Em, num, state)
    star = {"plane_strain": 2 * (lam_i + mu_i) * eps, "plane_stress": 2 * (lam_i + mu_i) * eps,
            "plane_strain_3d": (3 * lam_i + 2 * mu_i) * eps}[variant]

    def srr(r):
        u, err, ett = eshelby_radial(r, 20.0, C)
        inside = np.asarray(r) <= 20.0
        lam = np.where(inside, lam_i, lam_m)
        mu = np.where(inside, mu_i, mu_m)
        return (lam + 2 * mu) * err + lam * ett - np.where(inside, star, 0.0), \
            lam * err + (lam + 2 * mu) * ett - np.where(inside, star, 0.0)
    r = np.array([5.0, 15.0, 30.0, 55.0])
    h = 1e-4
    d = (srr(r + h)[0] - srr(r - h)[0]) / (2 * h)
    s_rr, s_tt = srr(r)
    # central difference of a smooth field: h^2 |s'''| ~ 1e-8 |s| / r^3
    assert np.abs(d + (s_rr - s_tt) / r).max() < 1e-6 * np.abs(s_rr).max()
    below, above = srr(np.array([20.0 - 1e-12]))[0], srr(np.array([20.0 + 1e-12]))[0]
    assert below[0] == pytest.approx(above[0], rel=1e-9)   # traction continuity
    assert abs(srr(np.array([1e6]))[0][0]) < 1e-9 * abs(above[0])


def test_limits_of_the_constant():
    lam, mu = lame(1000.0, 0.3, "plane_strain")
    same = eshelby_constant(0.01, 1000.0, 0.3, 1000.0, 0.3)
    # the same few operations in another order: ~10 eps
    assert same == pytest.approx((lam + mu) * 0.01 / (lam + 2 * mu), rel=1e-14)
    assert eshelby_constant(0.01, 1000.0, 0.3, 1e15, 0.3) < 1e-12     # rigid matrix
    assert np.isfinite(eshelby_constant(0.01, 1000.0, 0.4999999, 900.0, 0.33))
    assert eshelby_constant(0.0, *SEED[1:]) == 0.0


def test_cartesian_displacement_points_radially():
    p = np.array([[3.0, 4.0], [0.0, 0.0], [-30.0, 40.0]])
    u = eshelby_displacement(p, 20.0, eigenstrain=0.01, E_inclusion=1000.0, nu_inclusion=0.28,
                             E_matrix=900.0, nu_matrix=0.33)
    C = eshelby_constant(*SEED)
    # inside, u = (C r / r) p: a product and a quotient of exact values, a few eps
    assert np.allclose(u[0], C * p[0], rtol=1e-15)
    assert np.array_equal(u[1], [0.0, 0.0])
    assert np.allclose(u[2], C * 400.0 / 2500.0 * p[2], rtol=1e-14)


def test_hashin_shtrikman_bounds_behave():
    for f in (0.0, 1.0):
        b = hashin_shtrikman_2d(f, 150e6, 0.3, 1e6, 0.4)
        for lo, hi in b.values():
            # Walpole sums of one phase: cancellation of ~1e3-size terms, 1e3 eps
            assert lo == pytest.approx(hi, rel=1e-12)
    same = hashin_shtrikman_2d(0.3, 1e6, 0.4, 1e6, 0.4)["E_2D"]
    # equal phases: the same sums, cancellation bounded by 1e3 eps
    assert same[0] == pytest.approx(1e6 / (1 - 0.16), rel=1e-12) == same[1]
    rng = np.random.default_rng(0)
    for _ in range(50):
        f = rng.uniform()
        Ea, Eb = 10 ** rng.uniform(5, 9, 2)
        na, nb = rng.uniform(0.05, 0.45, 2)
        b = hashin_shtrikman_2d(f, Ea, na, Eb, nb)
        ka, ma = lame(Ea, na, "plane_strain")
        kb, mb = lame(Eb, nb, "plane_strain")
        ka, kb = ka + ma, kb + mb
        voigt, reuss = f * ka + (1 - f) * kb, 1 / (f / ka + (1 - f) / kb)
        lo, hi = b["kappa"]
        assert reuss * (1 - 1e-12) <= lo <= hi <= voigt * (1 + 1e-12)
        assert b["mu"][0] <= b["mu"][1] and b["E_2D"][0] <= b["E_2D"][1]
    # dilute limit of the lower bound: kappa_m + f (kappa_i - kappa_m)(kappa_m + mu_m)/(kappa_i + mu_m)
    km, mm = lame(1e6, 0.4, "plane_strain")
    km += mm
    ki = sum(lame(150e6, 0.3, "plane_strain"))
    f = 1e-6
    lo = hashin_shtrikman_2d(f, 150e6, 0.3, 1e6, 0.4)["kappa"][0]
    assert (lo - km) / f == pytest.approx((ki - km) * (km + mm) / (ki + mm), rel=1e-4)


def test_voigt_reuss_bounds_of_the_apparent_modulus():
    # equal phases: both are the plane-strain (plane-stress) modulus; a few roundings of
    # O(1) quotients, 1e-14
    for state, E in (("plane_strain", 1e6 / (1 - 0.16)), ("plane_stress", 1e6)):
        r, v = voigt_reuss_2d([1.0, 3.0], [1e6, 1e6], [0.4, 0.4], state)
        assert r == pytest.approx(E, rel=1e-14) and v == pytest.approx(E, rel=1e-14)  # see above
    rng = np.random.default_rng(1)
    for _ in range(50):
        f = rng.uniform(0.01, 0.99)
        Ei, Em = 10 ** rng.uniform(5, 9, 2)
        ni, nm = rng.uniform(0.05, 0.45, 2)
        r, v = voigt_reuss_2d([f, 1 - f], [Ei, Em], [ni, nm])
        # Reuss: the area mean of the plane-strain uniaxial compliance (1 - nu^2)/E
        reuss = 1 / (f * (1 - ni ** 2) / Ei + (1 - f) * (1 - nm ** 2) / Em)
        assert r == pytest.approx(reuss, rel=1e-12)      # sums of two positive terms
        # Voigt: the uniform strain (e, 1) at its best e (the two forms differ by a
        # cancellation of at most 1/(1 - (nu/(1 - nu))^2) < 4: 1e-12)
        (li, mi), (lm, mm) = lame(Ei, ni, "plane_strain"), lame(Em, nm, "plane_strain")
        c11, c12 = f * (li + 2 * mi) + (1 - f) * (lm + 2 * mm), f * li + (1 - f) * lm
        energy = lambda e: c11 * (1 + e * e) + 2 * c12 * e  # noqa: E731
        best = -c12 / c11
        assert v == pytest.approx(energy(best), rel=1e-12)  # cancellation < 4, see above
        assert energy(best) < min(energy(best - 1e-3), energy(best + 1e-3))
        # the effective-modulus bounds of an isotropic mixture lie between them
        lo, hi = hashin_shtrikman_2d(f, Ei, ni, Em, nm)["E_2D"]
        assert r * (1 - 1e-12) <= lo <= hi <= v * (1 + 1e-12)
