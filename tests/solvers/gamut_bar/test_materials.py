"""Materials, Ramberg–Osgood, R (eq. 17/18) and the calibration of the critical strains."""

from __future__ import annotations

import numpy as np
import pytest

from solvers.gamut_bar.materials import (MATERIALS, calibrate, family_weights,
                                         modulus_of_softness, ro_strain, ro_stress,
                                         ro_tangent_ratio, staircase_stress)

from ._common import EPS

ULP = 4   # exp, log, pow: within 4 units in the last place on any CPU (numpy's AVX-512 loops)

BISECTION_STOP = 1e-15   # ro_stress bisects until hi − lo ≤ 1e-15·hi


def ro_inversion_bound(n_ro):
    """Relative error of ro_strain(ro_stress(ε)): the stress is exact to the bisection stop
    plus a rounding, and RO's strain amplifies a relative stress error by at most n_ro."""
    return n_ro * (BISECTION_STOP + EPS) + EPS


def R_of(m):
    return modulus_of_softness(m["E"], m["sigma_f"], m["eps_f"], m["sigma_y"], m["n_ro"],
                               m["K_ro"])


def test_R_material1_is_0_851():
    # seed eq. 17 with Material 1 (design note: R ≈ 0.851)
    assert R_of(MATERIALS["M1"]) == pytest.approx(0.851, abs=5e-4)
    assert R_of(MATERIALS["M1"]) == pytest.approx(0.8514067, rel=1e-6)


def test_R_material2_in_unit_interval():
    r = R_of(MATERIALS["M2"])
    assert 0.96 < r < 0.975          # 0.9691: M2 is far more ductile (ε_f = 0.516)


def test_yield_strain_of_the_seed_is_derived():
    for m in MATERIALS.values():
        eps_y = m["sigma_y"] / m["E"] + m["K_ro"]
        assert eps_y == pytest.approx({"M1": 0.009522, "M2": 0.009494}[
            "M1" if m is MATERIALS["M1"] else "M2"], abs=2e-6)


@pytest.mark.parametrize("eps", [1e-4, 0.004, 0.0095, 0.05, 0.115, 0.516])
def test_ro_stress_inverts_ro_strain(eps):
    m = MATERIALS["M1"]
    s = ro_stress(eps, m["E"], m["sigma_y"], m["n_ro"], m["K_ro"])
    assert float(ro_strain(s, m["E"], m["sigma_y"], m["n_ro"], m["K_ro"])) == \
        pytest.approx(eps, rel=ro_inversion_bound(m["n_ro"]))   # bound: n_ro·(stop + eps)


@pytest.mark.numerics
def test_family_weights_one_sided_gaussian():
    w = family_weights(8.0, 3.0)
    assert w.size == 23                          # families 2..24 (3σ = 24 spacings)
    assert w.sum() == pytest.approx(1.0, rel=w.size * EPS)    # a sum of n terms: n·eps
    assert np.all(np.diff(w) < 0)
    # three exp at different arguments, each within ULP (any libm or SIMD loop), and three
    # divisions and the arguments' roundings: (3 ULP + 2) eps
    assert w[1] / w[0] == pytest.approx(np.exp(-(9 - 4) / 128.0), rel=(3 * ULP + 2) * EPS)
    assert family_weights(8.0, 4.0).size == 31


@pytest.mark.parametrize("name, overrides", [("M1", {}), ("M2", {}), ("M2", {"n_ro": 21.0})])
def test_calibration_staircase_matches_ro(name, overrides):
    m = dict(MATERIALS[name], **overrides)
    R = R_of(m)
    cal = calibrate(m["E"], m["sigma_y"], m["n_ro"], m["K_ro"], m["eps_f"], R,
                    family_weights(8.0, 3.0))
    ec = np.concatenate([[cal.eps_local], cal.eps_family])
    assert np.all(np.diff(ec) > 0)               # slip order: local first, then by weight
    e = cal.match_strains
    assert np.all(ec >= np.concatenate([[0.0], e[:-1]]) - 1e-15) and np.all(ec <= e + 1e-15)
    # the staircase equals RO at every match strain, the last one being ε_f
    # Bound: the last unslipped share 1 − S_last = h is a cancellation in a cumsum of the
    # shares (error ≈ shares·eps, relative to h); the power 1/(n−1) and RO's strain (× n)
    # undo each other; the stress at ε_f carries the bisection's error times n_ro.
    bound = (cal.weights.size + 2) * EPS / cal.hardening + ro_inversion_bound(m["n_ro"])
    assert e[-1] == pytest.approx(m["eps_f"], rel=bound)
    ro = np.array([ro_stress(v, m["E"], m["sigma_y"], m["n_ro"], m["K_ro"]) for v in e])
    assert staircase_stress(e, cal, m["E"]) == pytest.approx(ro, rel=bound)   # same sums
    # hardening share = RO tangent at ε_f
    assert cal.hardening == pytest.approx(ro_tangent_ratio(ro[-1], m["E"], m["sigma_y"],
                                                           m["n_ro"], m["K_ro"]), rel=bound)


def test_local_share_slips_below_yield():
    m = MATERIALS["M1"]
    cal = calibrate(m["E"], m["sigma_y"], m["n_ro"], m["K_ro"], m["eps_f"], R_of(m),
                    family_weights(8.0, 3.0))
    # RO tangent falls to R·E at 0.822 σ_y; the staircase's local share slips at 0.774 σ_y
    assert m["E"] * cal.eps_local / m["sigma_y"] == pytest.approx(0.774, abs=2e-3)
    e1 = cal.match_strains[0]
    s1 = ro_stress(e1, m["E"], m["sigma_y"], m["n_ro"], m["K_ro"])
    assert s1 / m["sigma_y"] == pytest.approx(0.822, abs=2e-3)
