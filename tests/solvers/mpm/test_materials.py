"""MPM material kernels on their own (solvers/mpm/materials, docs/mpm_materials.md)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from numba import njit
from scipy.optimize import minimize_scalar

from solvers.mpm.materials import elastic, johnson_cook as jc, jwl, library, state as st, water
from solvers.mpm.materials.mie_gruneisen import (mg_bulk_sound_speed_sq, mg_coefficients,
                                                 mie_gruneisen_pressure)
from uqflow.errors import SceneError, SolverError

from . import jc_reference as jc_ref
from .test_sensitivities import EPS, jc_value_rtol

MODULES = [jc, jwl, water, elastic]
REPO = Path(__file__).resolve().parents[3]


def fresh(module, values=None):
    prm = module.pack(values)
    S = st.new_state(1)
    assert module.init(prm, S, 0) == st.OK
    return prm, S


def step(module, prm, S, Lxx=0.0, Lxy=0.0, Lyx=0.0, Lyy=0.0, dt=1e-8, time=0.0, x=0.0, y=0.0):
    return module.update(prm, S, 0, Lxx, Lxy, Lyx, Lyy, dt, time, x, y)


# --- layout, parameters, library -------------------------------------------------------------
def test_state_layout_is_a_permutation_of_the_columns():
    idx = [getattr(st, name) for name in st.COLUMNS]
    assert sorted(idx) == list(range(st.N_STATE)) and len(st.COLUMNS) == st.N_STATE
    codes = [st.OK, st.ERR_NONFINITE, st.ERR_DENSITY, st.ERR_MG_DENOMINATOR, st.ERR_OTHER,
             st.ERR_SHAPE]
    assert len(set(codes)) == len(codes) and st.OK == 0
    assert all(c in st.ERROR_TEXT for c in codes)


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.NAME)
def test_pack_orders_and_checks_parameters(module):
    names = list(module.PARAMETERS)
    prm = module.pack()
    assert prm.tolist() == [float(v) for v in module.PARAMETERS.values()]
    assert module.NPRM == len(names)
    prm2 = module.pack({names[1]: 2.5 * module.PARAMETERS[names[1]] + 1.0})
    assert prm2[1] == 2.5 * module.PARAMETERS[names[1]] + 1.0 and prm2[0] == prm[0]
    with pytest.raises(SceneError, match="no parameter 'bogus'"):
        module.pack({"bogus": 1.0})
    with pytest.raises(SolverError, match="rho0"):
        module.pack({"rho0": -1.0})
    with pytest.raises(SolverError, match="not finite"):
        module.pack({names[0]: float("nan")})


def test_library_holds_the_design_data():
    mod, prm = library.material("steel_4340")
    assert mod is jc and mod.NAME == "mie_gruneisen_johnson_cook"
    want = {"rho0": 7830, "eos.C": 4569, "eos.S1": 1.49, "eos.S2": 0, "eos.S3": 0,
            "eos.gamma0": 2.17, "eos.a": 0.46, "shear_modulus": 81.8e9, "jc.A": 792e6,
            "jc.B": 510e6, "jc.n": 0.26, "jc.C": 0.014, "jc.m": 1.03, "jc.eps0_dot": 1,
            "jc.T_room": 294, "jc.T_melt": 1793, "cp": 477, "taylor_quinney": 0.9}
    assert {k: prm[list(jc.PARAMETERS).index(k)] for k in want} == pytest.approx(want)
    _, w = library.material("water")
    assert w.tolist() == [1480, 2.56, -1.986, 0.2268, 0.4934, 1.3937, 1000, -0.1e6]
    _, t = library.material("tnt", {"det_x": 0.01})
    assert t.tolist()[:9] == [1630, 6930, 371.2e9, 3.231e9, 4.15, 0.95, 0.30, 7.0e9, 0.01]
    assert set(library.MATERIALS) == {"steel_4340", "tnt", "water", "elastic"}
    with pytest.raises(SceneError):
        library.material("unobtainium")


# --- Johnson-Cook ----------------------------------------------------------------------------
def random_jc_states(rng, k):
    d = jc.PARAMETERS
    A = d["jc.A"] * rng.uniform(0.7, 1.3, k)
    B = d["jc.B"] * rng.uniform(0.7, 1.3, k)
    n = d["jc.n"] * rng.uniform(0.7, 1.3, k)
    C = d["jc.C"] * rng.uniform(0.7, 1.3, k)
    m = d["jc.m"] * rng.uniform(0.7, 1.3, k)
    ep = np.where(rng.random(k) < 0.25, 0.0, 10 ** rng.uniform(-6, 0, k))
    rs = np.where(rng.random(k) < 0.25, rng.uniform(0, 1, k), 10 ** rng.uniform(0, 6, k))
    u = rng.random(k)
    Ts = np.where(u < 0.2, 0.0, np.where(u < 0.3, -rng.random(k),
                  np.where(u < 0.4, 1.0 + rng.random(k), rng.random(k))))
    return A, B, n, C, m, ep, rs, Ts


@pytest.mark.numerics
def test_johnson_cook_flow_stress_matches_numpy_at_1000_states():
    rng = np.random.default_rng(11)
    A, B, n, C, m, ep, rs, Ts = random_jc_states(rng, 1000)
    ref = jc_ref.flow_stress(A, B, C, n, m, ep, rs, Ts)
    got = np.array([jc.johnson_cook_flow_stress(*args) for args in zip(A, B, n, C, m, ep, rs, Ts)])
    # numpy's pow/log (SIMD on AVX-512) against numba's libm, the same operations: ≤ ULP per
    # function, amplified by T*^m/(1 − T*^m) in 1 − T*^m (test_sensitivities.jc_value_rtol)
    assert (np.abs(got - ref) <= jc_value_rtol(m, Ts) * np.abs(ref)).all()
    # the limits, explicitly
    a = dict(A=792e6, B=510e6, n=0.26, C=0.014, m=1.03)
    f = jc.johnson_cook_flow_stress
    assert f(*a.values(), 0.0, 1.0, 0.0) == 792e6                  # eps_p = 0, T* = 0
    assert f(*a.values(), 0.0, 0.3, 0.0) == 792e6                  # rate* < 1 clamped to 1
    assert f(*a.values(), 0.1, 1.0, -0.5) == f(*a.values(), 0.1, 1.0, 0.0)   # T* < 0 → 0
    assert f(*a.values(), 0.1, 10.0, 1.0) == 0.0                   # melt
    # numba's pow/log against numpy's: any two within ULP (jc_value_rtol, 3.4e-15 at T* = 0.5)
    assert f(*a.values(), 0.1, 10.0, 0.5) == pytest.approx(
        float(jc_ref.flow_stress(792e6, 510e6, 0.014, 0.26, 1.03, 0.1, 10.0, 0.5)),
        rel=float(jc_value_rtol(1.03, 0.5)))


def random_deviators(rng, k, scale):
    """Traceless plane-strain deviators (s_xx, s_yy, s_xy, s_zz) with σeq = scale."""
    a, b, c = rng.normal(size=(3, k))
    sxx, syy, sxy = a, b, c
    szz = -(sxx + syy)
    seq = np.sqrt(1.5 * (sxx**2 + syy**2 + szz**2 + 2 * sxy**2))
    f = scale / seq
    return sxx * f, syy * f, sxy * f, szz * f


@pytest.mark.numerics
def test_radial_return_lands_on_the_yield_surface():
    rng = np.random.default_rng(5)
    G = jc.PARAMETERS["shear_modulus"]
    k = 400
    A, B, n, C, m, ep, _, Ts = random_jc_states(rng, k)
    Ts = np.clip(Ts, 0.0, 0.9)
    dt = 10 ** rng.uniform(-9, -6, k)
    sy0 = jc_ref.flow_stress(A, B, C, n, m, ep, np.ones(k), Ts)
    ratio = np.where(rng.random(k) < 0.25, rng.uniform(0.2, 0.999, k), rng.uniform(1.0001, 5, k))
    devs = random_deviators(rng, k, ratio * sy0)
    for j in range(k):
        s = [d[j] for d in devs]
        out = jc.jc_radial_return(*s, G, dt[j], A[j], B[j], n[j], C[j], m[j], 1.0, ep[j], Ts[j])
        nxx, nyy, nxy, nzz, dep, sy, code = out
        assert code == st.OK
        seq_trial = ratio[j] * sy0[j]
        seq = jc.von_mises(nxx, nyy, nxy, nzz)
        if ratio[j] < 1.0:                       # inside: unchanged, no plastic flow
            assert (nxx, nyy, nxy, nzz) == tuple(s) and dep == 0.0
            assert sy == pytest.approx(sy0[j], rel=1e-14)
            continue
        assert abs(seq - sy) / sy < 1e-10                                  # on the surface
        assert dep > 0.0
        assert abs(dep - (seq_trial - sy) / (3 * G)) <= 1e-12 * seq_trial / (3 * G)  # eq. 18
        ref = jc_ref.flow_stress(A[j], B[j], C[j], n[j], m[j], ep[j] + dep, dep / dt[j], Ts[j])
        # σy = JC(final): numba's libm against numpy's (jc_value_rtol), + 2 eps for the rate
        # Δεp·(1/Δt) against Δεp/Δt (C ln ε̇* moves by C·eps)
        assert sy == pytest.approx(float(ref), rel=float(jc_value_rtol(m[j], Ts[j])) + 2 * EPS)
        mfac = sy / seq_trial                                             # radial: one factor
        assert np.allclose([nxx, nyy, nxy, nzz], mfac * np.array(s), rtol=1e-13, atol=1e-6)
        assert abs(nxx + nyy + nzz) <= 1e-9 * sy                           # still traceless


def test_radial_return_perfect_plasticity_increment():
    G, A = 81.8e9, 792e6
    rng = np.random.default_rng(3)
    for C in (0.0, 0.014):
        for _ in range(50):
            seq_t = A * rng.uniform(1.01, 4.0)
            s = [d[0] for d in random_deviators(rng, 1, seq_t)]
            dt = 1e-7
            *_, dep, sy, code = jc.jc_radial_return(*s, G, dt, A, 0.0, 0.26, C, 1.03, 1.0,
                                                    0.3, 0.0)
            assert code == st.OK
            if C == 0.0:
                assert sy == A
                # bound: seq_t − A cancels with condition seq_t/(seq_t − A) ≤ 101 (seq_t ≥ 1.01 A) on ~10 eps of rounding: 2e-13
                assert dep == pytest.approx((seq_t - A) / (3 * G), rel=1e-12)
            else:   # rate-hardened: still Δεp = (σeq* − σy)/(3G) with σy = A(1 + C ln ε̇*)
                assert sy == pytest.approx(float(jc_ref.flow_stress(A, 0.0, C, 0.26, 1.03, 0.3,
                                                                    dep / dt, 0.0)), rel=1e-13)
                assert dep == pytest.approx((seq_t - sy) / (3 * G), rel=1e-10)


def test_plane_strain_szz_scaled_with_the_other_components():
    prm, S = fresh(jc)
    # start on the yield surface with a deviator that has s_zz ≠ 0, then shear (no spin)
    s0 = np.array([0.5, -0.8, 0.2, 0.3])
    s0 *= 792e6 / jc.von_mises(*s0)
    S[0, [st.SXX, st.SYY, st.SXY, st.SZZ]] = s0              # P = Q = 0: σ = s
    G, dt, gdot = 81.8e9, 1e-7, 2e3
    assert step(jc, prm, S, Lxy=gdot / 2, Lyx=gdot / 2, dt=dt) == st.OK
    trial = s0 + 2 * G * dt * np.array([0, 0, gdot / 2, 0])
    s1 = st.deviatoric(S)[0]
    mfac = s1[0] / trial[0]
    assert mfac < 1.0 and S[0, st.EPS_P] > 0.0
    assert s1 == pytest.approx(mfac * trial, rel=1e-12)                 # s_zz scaled too
    assert S[0, st.SZZ] == pytest.approx(s1[3] - S[0, st.P] - S[0, st.Q], rel=1e-12)
    assert jc.von_mises(*s1) == pytest.approx(S[0, st.SY], rel=1e-10)


# Return-mapping robustness. Rows captured from the Monte Carlo study
# studies/smpm_jc_thin_plate_mc.toml (Sobol realizations 4, 23, 51 of 64): first yield of a plate
# particle (εp = 0, n < 1) with a trial overstress of 3e-7–2e-5 σy. The root Δεp ~ 1e-26 lies
# ~18 decades below the bracket top (σeq* − σy0)/(3G); the former Newton/bisection in Δεp
# bisected linearly and ran out of its 60 iterations: ERR_OTHER, realization lost.
MC_FAILED_STATES = {   # realization: (A, B, C, n, m), row, (Lxx, Lxy, Lyx, Lyy), dt, time, x, y
    4: ((732298412.3222697, 516325425.5395385, 0.01298975312361104, 0.20748047162496258,
         0.8545558387961768),
        [-6328909.78904891, -795745311.1035823, 88927982.28269444, -231944427.7425977,
         341938197.6449967, 2621591.268446343, 7846.2025072901015, 1414823.7825856772, 0.0, 0.0,
         294.0, 0.0, 732298412.3222697, 5911.705333732874, 0.0],
        (200.01974356243045, -57.16794377363597, 122.81345297494693, -387.67107709226127),
        1.3479783211079756e-07, 5.38652021678892e-05, 0.04123722076882357, 0.2713293356878951),
    23: ((765875662.4415749, 483313296.08894473, 0.01515417913106952, 0.24277511303333987,
          0.7867175196233394),
         [-27531346.827847958, -844239814.7334905, -1750564.1168796623, -252899527.76276696,
          370070799.9607222, 4412351.615468611, 7847.535263463322, 1508208.671524587, 0.0, 0.0,
          294.0, 0.0, 765875662.4415749, 5912.699948670669, 0.0],
         (377.15137374470504, -28.209857339311366, -14.97738171366975, -692.0336854604113),
         2.3042501808455325e-07, 2.9e-05, 0.048748196077308806, 0.14880730911306203),
    51: ((612813294.0117497, 508900453.929818, 0.015273376275220817, 0.185197925050666,
          1.0248566593738366),
         [-9154569.18918103, -674497754.9531701, 1119396.1370109858, -197671411.38814384,
          290890026.0266043, 2730231.2725584074, 7843.810841744438, 977832.7163273271, 0.0, 0.0,
          294.0, 0.0, 612813294.0117497, 5909.905028819524, 0.0],
         (184.97462332053686, -4.494883555842739, 26.916860555058435, -380.4888345481966),
         2.3106805955789557e-07, 4.9999999999999996e-05, 0.04874851578902474,
         0.25381384921551237),
}


def jc_trial_deviator(S, i, L, dt, G):
    """The trial deviator ``advance`` hands to ``jc_radial_return`` (Jaumann + 2G D′ dt)."""
    Lxx, Lxy, Lyx, Lyy = L
    sxx, syy, sxy, szz = st.deviator_of(S, i)
    sxx, syy, sxy = st.jaumann_rotate(sxx, syy, sxy, dt, 0.5 * (Lxy - Lyx))
    t3, g2 = (Lxx + Lyy) / 3.0, 2.0 * G * dt
    return (sxx + g2 * (Lxx - t3), syy + g2 * (Lyy - t3), sxy + g2 * 0.5 * (Lxy + Lyx),
            szz - g2 * t3)


@pytest.mark.parametrize("realization", sorted(MC_FAILED_STATES))
def test_jc_update_converges_on_the_mc_thin_plate_states(realization):
    (A, B, C, n, m), row, L, dt, time, x, y = MC_FAILED_STATES[realization]
    prm = jc.pack({"jc.A": A, "jc.B": B, "jc.C": C, "jc.n": n, "jc.m": m})
    S = np.zeros((1, st.N_STATE))      # the rows were captured with the first 15 columns
    S[0, :len(row)] = row
    G = prm[jc.I_G]
    trial = jc_trial_deviator(S, 0, L, dt, G)
    seq_t = jc.von_mises(*trial)
    sy0 = jc.johnson_cook_flow_stress(A, B, n, C, m, 0.0, 1.0, 0.0)
    assert 0.0 < seq_t / sy0 - 1.0 < 1e-4                  # first yield, tiny overstress
    assert jc.update(prm, S, 0, *L, dt, time, x, y) == st.OK           # was ERR_OTHER (4)
    dep, sy = S[0, st.EPS_P], S[0, st.SY]
    assert 0.0 < dep < 1e-20                               # Δεp ~ 1e-26: ε̇* < 1, εp^n steep
    assert sy == pytest.approx(float(jc_ref.flow_stress(A, B, C, n, m, dep, dep / dt, 0.0)),
                               rel=1e-13)
    assert abs(seq_t - 3 * G * dep - sy) <= 1e-13 * seq_t               # consistency
    assert jc_ref.hardening_increase(B, n, dep) == pytest.approx(seq_t - 3 * G * dep - A,
                                                                 rel=1e-6)      # rate factor 1
    s1 = st.deviatoric(S)[0]
    assert jc.von_mises(*s1) == pytest.approx(sy, rel=1e-10)            # on the surface
    assert s1 == pytest.approx(np.array(trial) * (sy / seq_t), rel=1e-9, abs=1e-3)
    assert np.all(np.isfinite(S[0])) and S[0, st.T] >= 294.0


def jc_return_check(args, devs, sy0, G, dt, eps0, ep):
    """Run ``jc_radial_return`` on each state; assert code OK, the consistency condition to
    2e-13 σeq*, the stress on the yield surface to 1e-10, σy = JC(final state) to 1e-13 (numpy
    evaluation); returns Δεp and the plastic strain rates."""
    A, B, n, C, m, Ts = args
    k = len(A)
    dep = np.zeros(k)
    for j in range(k):
        s = devs[j]
        nxx, nyy, nxy, nzz, dep[j], sy, code = jc.jc_radial_return(
            *s, G[j], dt[j], A[j], B[j], n[j], C[j], m[j], eps0[j], ep[j], Ts[j])
        assert code == st.OK, j
        seq_t = jc.von_mises(*s)
        assert dep[j] >= 0.0 and sy >= sy0[j] * (1 - 1e-13)
        assert abs(seq_t - 3 * G[j] * dep[j] - sy) <= 2e-13 * seq_t, j
        assert abs(jc.von_mises(nxx, nyy, nxy, nzz) - sy) <= 1e-10 * sy, j
        ref = jc_ref.flow_stress(A[j], B[j], C[j], n[j], m[j], ep[j] + dep[j],
                                 dep[j] / (dt[j] * eps0[j]), Ts[j])
        assert abs(sy - ref) <= 1e-13 * sy, j
        # bound: one scale factor sy/seq_t applied to s_zz, 3 roundings ≈ 7e-16; abs for s_zz ≈ 0
        assert nzz == pytest.approx(s[3] * sy / seq_t, rel=1e-13, abs=1e-9 * sy)
    return dep


def test_jc_return_converges_over_the_physical_range():
    """12,000 random plastic states: overstress 1e-15..100 σy0, εp_n 0..1 (30 % exactly 0),
    n in (0.05, 1), C in (0, 0.1), m in (0.5, 2), T* in [0, 0.99], dt 1e-10..1e-3 s, ε̇0
    1e-3..1e3 /s; half of them built from a known root with ε̇p in 1e-3..1e7 /s."""
    rng = np.random.default_rng(2024)
    k = 12000
    A, B = rng.uniform(1e8, 2e9, k), rng.uniform(0.0, 2e9, k)
    n, C, m = rng.uniform(0.05, 1.0, k), rng.uniform(0.0, 0.1, k), rng.uniform(0.5, 2.0, k)
    G = 10 ** rng.uniform(10.0, 11.5, k)
    ep = np.where(rng.random(k) < 0.3, 0.0,
                  np.where(rng.random(k) < 0.5, 10 ** rng.uniform(-12, 0, k), rng.random(k)))
    Ts = np.where(rng.random(k) < 0.2, 0.0, rng.uniform(0.0, 0.99, k))
    eps0 = np.where(rng.random(k) < 0.5, 1.0, 10 ** rng.uniform(-3, 3, k))
    dt = 10 ** rng.uniform(-10, -3, k)
    sy0 = jc_ref.flow_stress(A, B, C, n, m, ep, np.ones(k), Ts)
    over = np.where(rng.random(k) < 0.5, 10 ** rng.uniform(-15, 2, k), rng.uniform(0, 100, k))
    seq = sy0 * (1.0 + over)
    # second half: trial stress from a known root Δεp = ε̇p dt, ε̇p log-uniform in 1e-3..1e7 /s
    h = slice(k // 2, k)
    rate = 10 ** rng.uniform(-3, 7, k - k // 2)
    dt[h] = np.minimum(dt[h], 0.05 / rate)                  # Δεp ≤ 0.05: overstress ≲ 100
    dep_true = rate * dt[h]
    seq[h] = 3 * G[h] * dep_true + jc_ref.flow_stress(A[h], B[h], C[h], n[h], m[h],
                                                       ep[h] + dep_true,
                                                       dep_true / (dt[h] * eps0[h]), Ts[h])
    keep = seq > sy0 * (1 + 1e-15)
    assert keep.mean() > 0.99
    devs = np.stack(random_deviators(rng, k, seq), axis=1)
    dep = jc_return_check((A, B, n, C, m, Ts), devs, sy0, G, dt, eps0, ep)
    known = np.zeros(k, bool)
    known[h] = True
    sel = known & keep
    # the recovered root: Δεp to the accuracy the 1e-13 residual allows (slope ≥ 3G)
    err = np.abs(dep[sel] - (rate * dt[h])[keep[h]]) * 3 * G[sel] / seq[sel]
    assert err.max() <= 2e-13
    rates = dep / dt
    assert rates[keep & (rates > 0)].min() < 1e-3 and rates.max() > 1e7


def test_jc_return_tiny_overstress_at_first_yield():
    """εp = 0, n < 1, σeq* = σy0 (1 + δ): the root Δεp = (δ σy0 / B)^(1/n) (rate factor 1) spans
    some 300 decades; each return takes at most a handful of Newton steps in ln Δεp."""
    G, A, B, C, m, dt = 81.8e9, 792e6, 510e6, 0.014, 1.03, 1e-7
    for n in (0.05, 0.1, 0.26, 0.5, 0.9):
        for delta in (1e-12, 1e-9, 1e-6, 1e-3):
            s = [d[0] for d in random_deviators(np.random.default_rng(1), 1, A * (1 + delta))]
            *_, dep, sy, code = jc.jc_radial_return(*s, G, dt, A, B, n, C, m, 1.0, 0.0, 0.0)
            assert code == st.OK
            # 3GΔεp and the rate term negligible: B Δεp^n = A δ
            approx = jc_ref.strain_for_hardening_increase(B, n, A * delta)
            if approx < 1e-3 * dt and approx * 3 * G < 1e-6 * A * delta:
                assert dep == pytest.approx(approx, rel=1e-6)
            assert abs(A * (1 + delta) - 3 * G * dep - sy) <= 1e-13 * A * (1 + delta)


def test_jc_return_outside_the_steel_range_never_fails():
    """Beyond the sweep above (n down to 0.01 and up to 3, C to 0.3, T* to 1 − 1e-6, G 1e9..1e12,
    overstress 1e-16..1e3): never ERR_OTHER, never an exception (no 0/0 in numba). For εp_n = 0
    and n < 0.045 the root can lie below the smallest normal double; the return then keeps the
    deviator, Δεp = 0 and σy = σeq* (= σeq* − 3GΔεp to double precision)."""
    rng = np.random.default_rng(77)
    k = 6000
    A, B = rng.uniform(1e8, 2e9, k), rng.uniform(0.0, 2e9, k)
    n, C, m = rng.uniform(0.01, 3.0, k), rng.uniform(0.0, 0.3, k), rng.uniform(0.5, 2.0, k)
    n[: k // 4] = rng.uniform(0.01, 0.05, k // 4)
    G = 10 ** rng.uniform(9.0, 12.0, k)
    ep = np.where(rng.random(k) < 0.5, 0.0, 10 ** rng.uniform(-12, 0, k))
    Ts = np.where(rng.random(k) < 0.2, 0.0, rng.uniform(0.0, 1 - 1e-6, k))
    dt, eps0 = 10 ** rng.uniform(-10, -3, k), 10 ** rng.uniform(-3, 3, k)
    sy0 = jc_ref.flow_stress(A, B, C, n, m, ep, np.ones(k), Ts)
    devs = np.stack(random_deviators(rng, k, sy0 * (1 + 10 ** rng.uniform(-16, 3, k))), axis=1)
    underflow = 0
    for j in range(k):
        s = devs[j]
        seq_t = jc.von_mises(*s)
        nxx, nyy, nxy, nzz, dep, sy, code = jc.jc_radial_return(
            *s, G[j], dt[j], A[j], B[j], n[j], C[j], m[j], eps0[j], ep[j], Ts[j])
        assert code == st.OK, j
        if seq_t <= sy0[j]:
            continue
        assert abs(seq_t - 3 * G[j] * dep - sy) <= 2e-13 * seq_t, j
        assert abs(jc.von_mises(nxx, nyy, nxy, nzz) - sy) <= 1e-10 * sy, j
        if dep == 0.0 and sy == seq_t:
            assert ep[j] == 0.0 and n[j] < 0.045, j
            underflow += 1
        else:
            ref = jc_ref.flow_stress(A[j], B[j], C[j], n[j], m[j], ep[j] + dep,
                                     dep / (dt[j] * eps0[j]), Ts[j])
            assert abs(sy - ref) <= 1e-13 * sy, j
    assert 0 < underflow < 0.05 * k


def test_jc_return_error_only_without_a_time_step():
    """ERR_OTHER is left for a plastic trial state with dt·ε̇0 ≤ 0 (the plastic strain rate is
    undefined) or a non-finite residual; never an exception."""
    s = [d[0] for d in random_deviators(np.random.default_rng(3), 1, 2 * 792e6)]
    for dt in (0.0, -1e-7):
        out = jc.jc_radial_return(*s, 81.8e9, dt, 792e6, 510e6, 0.26, 0.014, 1.03, 1.0, 0.1, 0.0)
        assert out[-1] == st.ERR_OTHER and out[:4] == tuple(s)
    out = jc.jc_radial_return(*s, 81.8e9, 1e-7, 792e6, 510e6, 0.0, 0.014, 1.03, 1.0, 0.0, 0.0)
    assert out[-1] == st.OK                                # n = 0 (pack refuses it): no 0/0
    out = jc.jc_radial_return(*s, 81.8e9, 1e-7, 792e6, 510e6, 0.26, 0.014, 1.03, 1.0, 0.1, 1.0)
    assert out[-1] == st.OK and out[5] == 0.0              # at melt: σy = 0, all deviator goes


@pytest.mark.slow
def test_mc_thin_plate_realizations_that_failed_now_run():
    """The three Sobol realizations of studies/smpm_jc_thin_plate_mc.toml that ended with
    'failed return mapping [code 4]' run to the end (≈ 4 s each once compiled)."""
    import tomllib

    from solvers.mpm.solver import MPMSolver

    study = REPO / "studies" / "smpm_jc_thin_plate_mc.toml"
    with open(study, "rb") as fh:
        scene = tomllib.load(fh)["scene"]
    if isinstance(scene, str):                 # the study names its scene file
        with open(study.parent / scene, "rb") as fh:
            scene = tomllib.load(fh)
    solver = MPMSolver.from_scene(scene)
    for realization in sorted(MC_FAILED_STATES):
        A, B, C, n, m = MC_FAILED_STATES[realization][0]
        ds = solver.run({"steel.jc.A": A, "steel.jc.B": B, "steel.jc.C": C, "steel.jc.n": n,
                         "steel.jc.m": m})
        eps = ds["plastic_strain"].values
        assert np.all(np.isfinite(eps)) and 0.1 < np.nanmax(eps) < 1.0


# --- Mie-Gruneisen ---------------------------------------------------------------------------
def mg_direct(rho0, C, S1, S2, S3, g0, a, rho, E):
    mu = rho / rho0 - 1.0
    if mu > 0:
        den = 1 - (S1 - 1) * mu - S2 * mu**2 / (mu + 1) - S3 * mu**3 / (mu + 1) ** 2
        return (rho0 * C**2 * mu * (1 + (1 - g0 / 2) * mu - a / 2 * mu**2) / den**2
                + (g0 + a * mu) * E)
    return rho0 * C**2 * mu + (g0 + a * mu) * E


@pytest.mark.parametrize("module", [jc, water], ids=["steel", "water"])
def test_mie_gruneisen_pressure_both_branches(module):
    d = module.PARAMETERS
    eos = [d[k] for k in ("rho0", "eos.C", "eos.S1", "eos.S2", "eos.S3", "eos.gamma0", "eos.a")]
    rng = np.random.default_rng(2)
    rho0 = eos[0]
    for rho in rho0 * np.concatenate([rng.uniform(0.7, 1.0, 100), rng.uniform(1.0, 1.4, 100)]):
        E = rng.uniform(-1e8, 2e9)
        p, code = mie_gruneisen_pressure(*eos, rho, E)
        assert code == st.OK
        # bound: the same polynomial in μ in another order, ~20 flops ≈ 4e-15 relative; abs 1e-3 Pa near p = 0
        assert p == pytest.approx(mg_direct(*eos, rho, E), rel=1e-12, abs=1e-3)
    for E in (0.0, 3.7e8):        # μ = 0: both branches give γ0 E, continuously
        p0, _ = mie_gruneisen_pressure(*eos, rho0, E)
        assert p0 == eos[5] * E
        pm, _ = mie_gruneisen_pressure(*eos, rho0 * (1 - 1e-10), E)
        pp, _ = mie_gruneisen_pressure(*eos, rho0 * (1 + 1e-10), E)
        slope = rho0 * eos[1] ** 2 * 1e-10
        tol = 2 * slope + 1e-9 * abs(p0)
        assert abs(pm - p0) < tol and abs(pp - p0) < tol


@pytest.mark.parametrize("module", [jc, water], ids=["steel", "water"])
def test_mie_gruneisen_sound_speed_is_the_isentropic_derivative(module):
    d = module.PARAMETERS
    eos = [d[k] for k in ("rho0", "eos.C", "eos.S1", "eos.S2", "eos.S3", "eos.gamma0", "eos.a")]
    rho0 = eos[0]
    for rho, E in [(0.9 * rho0, 1e7), (rho0, 0.0), (1.1 * rho0, 2e8), (1.3 * rho0, 1e9)]:
        f, g, dfdmu, _ = mg_coefficients(*eos, rho)
        p = f + g * E
        c2 = mg_bulk_sound_speed_sq(rho0, eos[1], eos[6], g, dfdmu, rho, E, p)
        h = 1e-6 * rho
        # along the isentrope dE = p ρ0 dρ/ρ² (E per reference volume)
        pr = [mie_gruneisen_pressure(*eos, rho + s * h,
                                     E + p * rho0 * (1 / rho - 1 / (rho + s * h)))[0]
              for s in (-1, 1)]
        assert c2 == pytest.approx((pr[1] - pr[0]) / (2 * h), rel=1e-5)


def test_mie_gruneisen_denominator_guard():
    prm, S = fresh(jc)
    mu_pole = 1.0 / (1.49 - 1.0)              # den = 1 − 0.49 μ = 0
    eos = [7830.0, 4569.0, 1.49, 0.0, 0.0, 2.17, 0.46]
    for mu in (mu_pole, mu_pole * (1 - 1e-8), mu_pole * 1.2):
        _, code = mie_gruneisen_pressure(*eos, 7830.0 * (1 + mu), 0.0)
        assert code == st.ERR_MG_DENOMINATOR
    _, code = mie_gruneisen_pressure(*eos, 7830.0 * (1 + 0.99 * mu_pole), 0.0)
    assert code == st.OK
    before = S.copy()                          # through the kernel: one huge compression
    dt = 1e-6
    assert step(jc, prm, S, Lxx=-math.log(1 + mu_pole) / dt, dt=dt) == st.ERR_MG_DENOMINATOR
    assert np.array_equal(S, before)           # transactional: the row is untouched


# --- Hugoniot --------------------------------------------------------------------------------
UP = 250.0


def steel_hugoniot():
    d = jc.PARAMETERS
    rho0, C, s1 = d["rho0"], d["eos.C"], d["eos.S1"]
    Us = C + s1 * UP
    eta = UP / Us
    return rho0, Us, rho0 * Us * UP, eta, 0.5 * rho0 * Us * UP * eta   # ρ0, U_s, p_H, η, E_H


def test_hugoniot_one_step_shock_jump():
    """From rest to the shocked density in one step: the trapezoidal energy update is then the
    Rankine–Hugoniot energy jump ½ p (V0 − V), so p* is the linear U_s–u_p Hugoniot pressure
    (exactly, because eq. 10's compression branch is built on that Hugoniot)."""
    rho0, Us, pH, eta, EH = steel_hugoniot()
    prm, S = fresh(jc, {"shear_modulus": 0.0})    # hydrodynamic: the Hugoniot of the EOS
    dt = 1e-7
    assert step(jc, prm, S, Lxx=math.log(1 - eta) / dt, dt=dt) == st.OK
    assert S[0, st.RHO] == pytest.approx(rho0 / (1 - eta), rel=1e-14)
    assert abs(S[0, st.P] / pH - 1) < 1e-10         # brief: 1 %; here ~1e-15
    assert S[0, st.E] == pytest.approx(EH, rel=1e-10)
    assert pH == pytest.approx(9.673e9, rel=1e-3)


def rayleigh_path(prm, nsteps, Us, eta, rho0):
    """Uniaxial strain from rest to V_H in nsteps with q chosen each step so that the mean
    longitudinal stress of the step, ½(σ'_n + σ'_{n+1}) + q, follows the Rayleigh line
    p_R(V) = ρ0 U_s² (1 − V) (what artificial viscosity does inside a resolved steady shock)."""
    S = st.new_state(1)
    jc.init(prm, S, 0)
    dt = 1e-8
    Lxx = math.log(1 - eta) / (nsteps * dt)

    def sig(row):            # −σ'_xx without q = p − s_xx
        return row[st.P] - (row[st.SXX] + row[st.P] + row[st.Q])

    for _ in range(nsteps):
        Vn = rho0 / S[0, st.RHO]
        Vm = 0.5 * (Vn + Vn * math.exp(Lxx * dt))
        pR = rho0 * Us**2 * (1 - Vm)
        q = 0.0
        for _ in range(30):                          # fixed point on q (p_{n+1} depends on q)
            trial = S.copy()
            trial[0, st.Q] = q
            assert jc.update(prm, trial, 0, Lxx, 0.0, 0.0, 0.0, dt, 0.0, 0.0, 0.0) == st.OK
            q_new = pR - 0.5 * (sig(S[0]) + sig(trial[0]))
            if abs(q_new - q) <= 1e-9 * pR:
                break
            q = q_new
        S[0, st.Q] = q
        assert jc.update(prm, S, 0, Lxx, 0.0, 0.0, 0.0, dt, 0.0, 0.0, 0.0) == st.OK
    return S


def test_hugoniot_along_the_rayleigh_line_with_strength():
    rho0, Us, pH, eta, EH = steel_hugoniot()
    prm = jc.pack()                                   # full 4340: MG + JC
    S = rayleigh_path(prm, 200, Us, eta, rho0)
    assert S[0, st.RHO] == pytest.approx(rho0 / (1 - eta), rel=1e-12)
    assert S[0, st.E] == pytest.approx(EH, rel=1e-8)   # total work = Rayleigh-line area
    assert abs(S[0, st.P] / pH - 1) < 1e-8             # brief: 1 %
    # uniaxial strain on the yield surface: s_xx = −2/3 σy, s_yy = s_zz = σy/3
    s = st.deviatoric(S)[0]
    sy = S[0, st.SY]
    assert S[0, st.EPS_P] > 0.02
    # bound: 200 steps of return mapping, each consistent to 1e-13 (consistency test above): ≈ 2e-11
    assert s == pytest.approx([-2 * sy / 3, sy / 3, 0.0, sy / 3], rel=1e-9, abs=1e-3)
    assert S[0, st.T] > 294.0 and S[0, st.PLASTIC_WORK] > 0.0


def test_isentropic_path_stays_within_one_percent_below_the_hugoniot():
    rho0, Us, pH, eta, EH = steel_hugoniot()
    prm, S = fresh(jc, {"shear_modulus": 0.0})
    n, dt = 200, 1e-8
    for _ in range(n):
        assert step(jc, prm, S, Lxx=math.log(1 - eta) / (n * dt), dt=dt) == st.OK
    assert -0.01 < S[0, st.P] / pH - 1 < 0.0          # isentrope below the Hugoniot
    # and back: a reversible cycle returns E and p to ~0 (second order in the step)
    for _ in range(n):
        assert step(jc, prm, S, Lxx=-math.log(1 - eta) / (n * dt), dt=dt) == st.OK
    assert S[0, st.RHO] == pytest.approx(rho0, rel=1e-12)
    assert abs(S[0, st.E]) < 1e-9 * EH and abs(S[0, st.P]) < 1e-9 * pH   # trapezoid: symmetric


# --- JWL -------------------------------------------------------------------------------------
def cj_state():
    d = jwl.PARAMETERS
    A, B, R1, R2, om, E0, rho0 = (d[k] for k in ("eos.A", "eos.B", "eos.R1", "eos.R2",
                                                  "eos.omega", "eos.E0", "rho0"))

    def p_hug(V):            # products Hugoniot from (V=1, p=0, E0): E = E0 + ½ p (1 − V)
        f, g, _ = jwl.jwl_coefficients(A, B, R1, R2, om, V)
        return (f + g * E0) / (1 - 0.5 * g * (1 - V))

    # CJ: the Rayleigh line is tangent to the products Hugoniot ⇔ D² = p/(ρ0 (1 − V)) minimal
    r = minimize_scalar(lambda V: p_hug(V) / (rho0 * (1 - V)), bounds=(0.5, 0.95),
                        method="bounded", options={"xatol": 1e-12})
    return r.x, math.sqrt(r.fun), p_hug(r.x)


def test_jwl_fully_burnt_cj_state():
    V, D_cj, P_cj = cj_state()
    prm, S = fresh(jwl)
    dt = 1e-7
    # long after lighting: F = 1; compress to ρ_CJ in one step (Hugoniot energy jump)
    assert step(jwl, prm, S, Lxx=math.log(V) / dt, dt=dt, time=1e-3, x=0.01) == st.OK
    assert S[0, st.BURN] == 1.0
    assert S[0, st.P] == pytest.approx(21e9, rel=0.10)           # Dobratz & Crawford P_CJ
    assert S[0, st.P] == pytest.approx(P_cj, rel=1e-10)
    assert D_cj == pytest.approx(6930.0, rel=0.01)               # JWL set consistent with D
    assert S[0, st.C] == pytest.approx(D_cj * V, rel=1e-6)       # CJ: c = D − u = D V
    assert S[0, st.SXX] == S[0, st.SYY] == S[0, st.SZZ] == -S[0, st.P] and S[0, st.SXY] == 0


def test_jwl_burn_fraction_and_lighting_time():
    D, w = 6930.0, 0.0075
    prm, S = fresh(jwl, {"det_x": 0.01, "det_y": -0.02, "burn_width": w})
    x, y = 0.04, 0.02
    tl = math.hypot(x - 0.01, y + 0.02) / D
    dt = 1e-8
    # before the lighting time: F = 0, p = 0 even when compressed; wave speed D
    assert step(jwl, prm, S, Lxx=-1e4, dt=dt, time=tl - 2 * dt, x=x, y=y) == st.OK
    assert S[0, st.BURN] == 0.0 and S[0, st.P] == 0.0 and S[0, st.C] == D
    assert S[0, st.E] == 7.0e9
    # ramp: F = (t − t_l) D / w, t = time + dt (end of step)
    t_end = tl + 0.4 * w / D
    assert step(jwl, prm, S, dt=dt, time=t_end - dt, x=x, y=y) == st.OK
    assert S[0, st.BURN] == pytest.approx(0.4, rel=1e-9) and S[0, st.C] == D
    # bound: the same JWL formula scaled by F, with F from (t − t_l) D / w to ≈ 10 eps: 2e-15
    assert S[0, st.P] == pytest.approx(0.4 * jwl.jwl_pressure(*prm[2:7], 1630.0 / S[0, st.RHO],
                                                              S[0, st.E]), rel=1e-12)
    # never decreases (an earlier time does not un-burn)
    assert step(jwl, prm, S, dt=dt, time=0.0, x=x, y=y) == st.OK
    assert S[0, st.BURN] == pytest.approx(0.4, rel=1e-9)
    assert step(jwl, prm, S, dt=dt, time=tl + 2 * w / D, x=x, y=y) == st.OK
    assert S[0, st.BURN] == 1.0 and S[0, st.C] < D
    assert jwl.burn_fraction(D, 0.0, 0.0, 0.0, 1e-6, 0.0075, 0.0) == 0.0      # step variant
    assert jwl.burn_fraction(D, 0.0, 0.0, 0.0, 1e-6, 0.0069, 0.0) == 1.0


# --- water -----------------------------------------------------------------------------------
def test_water_cavitation_cutoff():
    prm, S = fresh(water)
    dt = 1e-6
    assert step(water, prm, S, Lxx=0.01 / dt, dt=dt) == st.OK      # 1 % expansion: ~ −22 MPa
    assert S[0, st.P] == -0.1e6
    assert S[0, st.SXX] == S[0, st.SYY] == S[0, st.SZZ] == 0.1e6 and S[0, st.SXY] == 0.0
    E1 = S[0, st.E]
    dv = 1000 / S[0, st.RHO] - 1.0
    assert E1 == pytest.approx(-0.5 * (0.0 - 0.1e6) * dv, rel=1e-12)  # work done at the cut-off
    for _ in range(20):                                               # keeps holding
        assert step(water, prm, S, Lxx=0.05 / dt, dt=dt) == st.OK
        assert S[0, st.P] >= -0.1e6
    prm0, S = fresh(water, {"cavitation_pressure": 0.0})
    assert step(water, prm0, S, Lxx=0.01 / dt, dt=dt) == st.OK and S[0, st.P] == 0.0
    # compression is untouched by the cut-off; q enters σ but not P
    prm, S = fresh(water)
    S[0, st.Q] = 1e5
    assert step(water, prm, S, Lxx=-0.01 / dt, dt=dt) == st.OK
    assert S[0, st.P] > 2e7 and S[0, st.SXX] == -(S[0, st.P] + 1e5) and S[0, st.Q] == 1e5


# --- elastic ---------------------------------------------------------------------------------
def test_elastic_pure_spin_preserves_invariants():
    prm, S = fresh(elastic)
    sig0 = np.array([[-3e8, 1.2e8], [1.2e8, 2e8]])
    S[0, [st.SXX, st.SYY, st.SXY, st.SZZ]] = [sig0[0, 0], sig0[1, 1], sig0[0, 1], -5e7]
    S[0, st.P] = -(sig0[0, 0] + sig0[1, 1] - 5e7) / 3
    w, dt, n = 2e4, 1e-6, 1000                         # spin 2e4 rad/s, 20 rad in total
    for _ in range(n):
        assert step(elastic, prm, S, Lxy=w, Lyx=-w, dt=dt) == st.OK
    sig = np.array([[S[0, st.SXX], S[0, st.SXY]], [S[0, st.SXY], S[0, st.SYY]]])
    # bound: 1000 rotation steps, each exact up to ≈ 10 eps: ≤ 1e4 eps = 2e-12 → 1e-11
    assert np.linalg.eigvalsh(sig) == pytest.approx(np.linalg.eigvalsh(sig0), rel=1e-11)
    assert S[0, st.SZZ] == pytest.approx(-5e7, rel=1e-12)
    assert S[0, st.RHO] == 7830.0 and S[0, st.E] == pytest.approx(0.0, abs=1e-6)
    th = w * dt * n                                     # Jaumann: σ(t) = R σ0 Rᵀ, R = exp(W t)
    R = np.array([[math.cos(th), math.sin(th)], [-math.sin(th), math.cos(th)]])
    assert sig == pytest.approx(R @ sig0 @ R.T, rel=1e-10, abs=1e-10 * 3e8)


def test_elastic_small_uniaxial_strain():
    prm, S = fresh(elastic)
    Y, nu = 210e9, 0.286
    lam, G = Y * nu / ((1 + nu) * (1 - 2 * nu)), Y / (2 * (1 + nu))
    eps, dt = -1e-5, 1e-7
    assert step(elastic, prm, S, Lxx=eps / dt, dt=dt) == st.OK
    # bound: one step of σ = λ tr D I + 2G D, a few flops on each term: ≈ 10 eps = 2e-15
    assert S[0, st.SXX] == pytest.approx((lam + 2 * G) * eps, rel=1e-12)
    assert S[0, st.SYY] == pytest.approx(lam * eps, rel=1e-12)
    assert S[0, st.SZZ] == pytest.approx(lam * eps, rel=1e-12)
    assert S[0, st.E] == pytest.approx(0.5 * (lam + 2 * G) * eps**2, rel=1e-4)
    # bound: the same expression from the same parameters, a few roundings: ≈ 5 eps
    assert S[0, st.C] == pytest.approx(math.sqrt((lam + 2 * G) / S[0, st.RHO]), rel=1e-12)


# --- guards ----------------------------------------------------------------------------------
ARGS = ["Lxx", "Lxy", "Lyx", "Lyy", "dt", "time", "x", "y"]


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.NAME)
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_nonfinite_input_returns_error_and_leaves_the_row(module, bad):
    prm, S = fresh(module)
    base = dict(zip(ARGS, [-10.0, 1.0, 2.0, 3.0, 1e-8, 0.0, 0.01, 0.0]))
    for col in range(st.N_STATE):
        T = S.copy()
        T[0, col] = bad
        ref = T.copy()
        assert module.update(prm, T, 0, *base.values()) == st.ERR_NONFINITE, st.COLUMNS[col]
        assert np.array_equal(T, ref, equal_nan=True)
    for name in ARGS:
        T = S.copy()
        args = dict(base, **{name: bad})
        assert module.update(prm, T, 0, *args.values()) == st.ERR_NONFINITE, name
        assert np.array_equal(T, S)
    for k in range(module.NPRM):
        p = prm.copy()
        p[k] = bad
        T = S.copy()
        assert module.update(p, T, 0, *base.values()) == st.ERR_NONFINITE
        assert np.array_equal(T, S)


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.NAME)
def test_shape_density_and_dt_guards(module):
    prm, S = fresh(module)
    a = (0.0, 0.0, 0.0, 0.0, 1e-8, 0.0, 0.0, 0.0)
    assert module.update(prm, S, 1, *a) == st.ERR_SHAPE
    assert module.update(prm, S, -1, *a) == st.ERR_SHAPE
    assert module.update(prm[:-1], S, 0, *a) == st.ERR_SHAPE
    assert module.update(prm, S[:, :-1].copy(), 0, *a) == st.ERR_SHAPE
    assert module.init(prm, S, 3) == st.ERR_SHAPE
    T = S.copy()
    T[0, st.RHO] = 0.0
    assert module.update(prm, T, 0, *a) == st.ERR_DENSITY
    T[0, st.RHO] = -5.0
    assert module.update(prm, T, 0, *a) == st.ERR_DENSITY
    assert module.update(prm, S, 0, 1e3, 0.0, 0.0, 1e3, 0.0, 0.0, 0.0, 0.0) == st.ERR_OTHER
    assert module.update(prm, S, 0, -2e3, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0) == st.ERR_DENSITY


def test_solver_error_message_names_step_particle_material():
    prm, S = fresh(jc)
    err = st.solver_error(st.ERR_MG_DENOMINATOR, step=12, particle=345, material="steel_4340",
                          row=S[0])
    assert isinstance(err, SolverError)
    text = str(err)
    assert "step 12" in text and "particle 345" in text and "steel_4340" in text
    assert "Mie-Gruneisen" in text and "rho = 7830" in text


@njit(cache=True)
def _loop(prm, S, L, dt):
    bad = 0
    for i in range(S.shape[0]):
        if jc.update(prm, S, i, L[i, 0], L[i, 1], L[i, 2], L[i, 3], dt, 0.0, 0.0, 0.0) != 0:
            bad += 1
    return bad


def test_kernels_are_callable_from_a_numba_loop():
    prm = jc.pack()
    S = st.new_state(64)
    for i in range(64):
        jc.init(prm, S, i)
    L = np.random.default_rng(0).normal(scale=1e3, size=(64, 4))
    L[7, 2] = np.nan
    assert _loop(prm, S, L, 1e-7) == 1
    assert np.isnan(S).sum() == 0


GUARD_SCRIPT = textwrap.dedent("""
    import math, numpy as np
    from solvers.mpm.materials import elastic, johnson_cook as jc, jwl, water, state as st
    for mod in (jc, jwl, water, elastic):
        prm = mod.pack(); S = st.new_state(1); assert mod.init(prm, S, 0) == 0
        a = (-10.0, 1.0, 2.0, 3.0, 1e-8, 0.0, 0.01, 0.0)
        assert mod.update(prm, S, 0, *a) == 0
        assert mod.update(prm, S, 1, *a) == st.ERR_SHAPE          # no IndexError / segfault
        assert mod.update(prm[:2], S, 0, *a) == st.ERR_SHAPE
        assert mod.update(prm, S[:, :3].copy(), 0, *a) == st.ERR_SHAPE
        T = S.copy(); T[0, st.E] = math.nan
        assert mod.update(prm, T, 0, *a) == st.ERR_NONFINITE
        assert mod.update(prm, S, 0, math.nan, *a[1:]) == st.ERR_NONFINITE
    prm = jc.pack(); S = st.new_state(1); jc.init(prm, S, 0)
    assert jc.update(prm, S, 0, -math.log(1 + 1 / 0.49) / 1e-6, 0, 0, 0, 1e-6, 0, 0, 0) \\
        == st.ERR_MG_DENOMINATOR
    print("GUARDS-OK")
""")


def test_guards_with_numba_boundscheck(tmp_path):
    env = dict(os.environ, NUMBA_BOUNDSCHECK="1", NUMBA_CACHE_DIR=str(tmp_path),
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", GUARD_SCRIPT], cwd=REPO, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "GUARDS-OK" in out.stdout
