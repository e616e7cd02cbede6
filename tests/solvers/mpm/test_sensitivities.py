"""Analytic constitutive sensitivities (johnson_cook.py, mie_gruneisen.py) against
complex-step and finite-difference derivatives, at 1,000 states per model that include every
branch and limit: εp = 0 and εp = e^(−2/n), T* = 0, T* ≥ 1, ε̇* < 1, μ = 0±, the MG pole."""

import numpy as np
import pytest

from solvers.mpm.materials.johnson_cook import (
    DIFFERENTIABLE_PARAMETERS as JC_PARAMETERS, johnson_cook_flow_stress,
    johnson_cook_sensitivities)
from solvers.mpm.materials.mie_gruneisen import (
    DIFFERENTIABLE_PARAMETERS as MG_PARAMETERS, mg_denominator, mie_gruneisen_pressure,
    mie_gruneisen_pressure_value, mie_gruneisen_sensitivities)
from solvers.mpm.materials.state import MG_DEN_MIN

from . import jc_reference as jc_ref

N_STATES = 1000
EPS = np.finfo(float).eps
RHO0, BULK_C = 7830.0, 4569.0
# Complex step h = 1e-30 θ: truncation h²|f'''|/6 ~ 1e-60 relative, no cancellation, so the
# complex-step derivative carries only the rounding of the value formula (~10 flops).
CS_STEP = 1e-30
# Complex step against the analytic formula (Mie–Grüneisen: +, −, ×, ÷ only, correctly
# rounded on every CPU): both are O(10) rounded flops on the same intermediate values; 1e-10
# leaves a 10^4 margin over 10·eps·(term sum / result) for the cancellations of the states
# drawn here (asked by issue 9). Johnson–Cook derives its bound per entry (jc_gradient_bound).
CS_RTOL = 1e-10
# pow, exp, log, sin: within ULP units in the last place of the result on any CPU (glibc is
# < 1 ulp; numpy's AVX-512 SVML paths promise ≤ 4), so ≤ ULP·eps relative; + − × ÷ round
# to ½ eps. Issue 16: numpy's AVX-512 pow and libm's differ in the last bits.
ULP = 4
# a result below the smallest normal double is rounded absolutely, to 2^-1074 (not relatively)
SUBNORMAL = np.finfo(float).smallest_subnormal
# Central differences of the analytic gradient with a step η θ, narrowed where the gradient
# varies faster than θ (n|ln εp|, m|ln T*|, the MG pole) so that each step changes the
# gradient's argument by ≤ η: truncation ≤ η²/6 × (normalised third derivative, ≤ ~10 after
# the narrowing) ≈ 2e-8 for η = 1e-4; rounding 16 eps/η ≈ 4e-11 relative to the gradient's
# terms (see the JC test for where those terms cancel). Tolerance 1e-5 (asked by issue 9).
FD_ETA = 1e-4
FD_RTOL = 1e-5
# A closed form re-evaluated here in another order: ~10 rounded flops → 1e-14 relative
CLOSED_FORM_REL = 1e-14


def _steel_like_jc_parameters(rng):
    """(A, B, C, n, m) per state, ±40 % around AISI 4340 (n, m far from the seed's values too)."""
    A = rng.uniform(400e6, 1200e6, N_STATES)
    B = rng.uniform(100e6, 900e6, N_STATES)
    C = rng.uniform(0.001, 0.05, N_STATES)
    n = rng.uniform(0.08, 0.9, N_STATES)
    m = rng.uniform(0.5, 2.0, N_STATES)
    return A, B, C, n, m


def jc_states(seed=9):
    """Parameters and states: log-uniform εp with εp = 0 and εp = e^(−2/n) (where εp^n ln² εp
    peaks: the largest ∂²σy/∂n²); ε̇* from 10⁻³ (clamped) to 10⁸; T* below 0, at 0, tiny, in
    (0, 1), at 1 and above."""
    rng = np.random.default_rng(seed)
    A, B, C, n, m = _steel_like_jc_parameters(rng)
    eps_p = 10.0 ** rng.uniform(-12, 0.3, N_STATES)
    rate = 10.0 ** rng.uniform(-3, 8, N_STATES)
    T_star = rng.uniform(0.0, 1.0, N_STATES)
    eps_p[0::8] = 0.0
    eps_p[1::8] = np.exp(-2.0 / n[1::8])
    rate[2::8] = 1.0
    rate[3::8] = rng.uniform(0.0, 1.0, len(rate[3::8]))
    T_star[4::8] = 0.0
    T_star[5::16] = rng.uniform(1.0, 1.5, len(T_star[5::16]))
    T_star[13::16] = 1.0
    T_star[6::16] = -rng.uniform(0.0, 0.2, len(T_star[6::16]))
    T_star[14::16] = 1e-300
    T_star[7::16] = 1.0 - 1e-12
    return (A, B, C, n, m), (eps_p, rate, T_star)


def mg_states(seed=10):
    """Parameters (S1, S2, S3, γ0, a) around steel and water and states (μ, E): μ in tension and
    compression, μ = 0, ±10⁻³⁰⁰, ±10⁻¹²; an eighth of the states sit at den = 10⁻⁵…10⁻² of the
    pole of the compression branch (S2 = S3 = 0 there, where the pole is at (1 − den)/(S1 − 1))."""
    rng = np.random.default_rng(seed)
    S1 = rng.uniform(1.2, 2.8, N_STATES)
    S2 = rng.uniform(-2.5, 0.5, N_STATES)
    S3 = rng.uniform(-0.5, 0.5, N_STATES)
    gamma0 = rng.uniform(0.3, 2.5, N_STATES)
    a = rng.uniform(0.05, 1.5, N_STATES)
    mu = rng.uniform(-0.3, 0.5, N_STATES)
    E = rng.uniform(-1e8, 5e9, N_STATES)
    special = [0.0, 1e-300, -1e-300, 1e-12, -1e-12, -0.0]
    for k, value in enumerate(special):
        mu[k::64] = value
    pole = slice(7, None, 8)
    S2[pole] = S3[pole] = 0.0
    den_target = 10.0 ** rng.uniform(-5, -2, len(mu[pole]))
    mu[pole] = (1.0 - den_target) / (S1[pole] - 1.0)
    # states the material itself refuses (den ≤ guard) are redrawn well inside the branch
    for i in range(N_STATES):
        while mu[i] > 0.0 and not mg_denominator(S1[i], S2[i], S3[i], mu[i]) > 1e-4 \
                and i % 8 != 7:
            mu[i] = rng.uniform(-0.3, 0.5)
    return (S1, S2, S3, gamma0, a), (mu, E)


def _scales(theta):
    """Parameter scales: |θ|, 1 where θ = 0 (S2, S3 are dimensionless, of order 1)."""
    return [np.where(t != 0.0, np.abs(t), 1.0) for t in theta]


def complex_step_gradient(value, theta, scales):
    """∂value/∂θ_j = Im value(θ + i h e_j)/h, h = CS_STEP·scale_j, for every state at once."""
    columns = []
    for j in range(len(theta)):
        h = CS_STEP * scales[j]
        shifted = [t.astype(complex) for t in theta]
        shifted[j] = shifted[j] + 1j * h
        columns.append(np.imag(value(shifted)) / h)
    return np.stack(columns, axis=-1)


def central_difference_hessian(gradient, theta, steps):
    """∂(analytic gradient)/∂θ_j by central differences with per-state steps."""
    columns = []
    for j in range(len(theta)):
        up = [t.copy() for t in theta]
        down = [t.copy() for t in theta]
        up[j] = up[j] + steps[j]
        down[j] = down[j] - steps[j]
        columns.append((gradient(up) - gradient(down)) / (2.0 * steps[j][:, None]))
    return np.stack(columns, axis=-1)


def assert_gradient_matches(reference, analytic, scales, rtol, label):
    """|ref − an| ≤ rtol·max(|an|, largest normalised entry of the state), in θ·∂/∂θ units:
    relative where an entry is of the state's size, scaled absolute where it vanishes."""
    S = np.stack(scales, axis=-1)
    ref_n, an_n = reference * S, analytic * S
    floor = np.max(np.abs(an_n), axis=-1, keepdims=True)
    bound = rtol * np.maximum(np.abs(an_n), floor)
    bad = ~(np.abs(ref_n - an_n) <= bound)
    assert not bad.any(), (f"{label}: {bad.sum()} entries off, worst at state "
                           f"{np.argwhere(bad)[0]}: ref {ref_n[bad][0]!r} an {an_n[bad][0]!r}")


def assert_hessian_matches(reference, analytic, gradient, scales, rtol, label,
                           rounding_floor=0.0):
    """Hessian in θ_iθ_j ∂²/∂θ_i∂θ_j units against rtol·max(|entry|, largest normalised first
    or second derivative of the state), or ``rounding_floor`` (N, 5) per difference direction:
    the rounding bound of differencing a gradient whose terms cancel (1 − T*^m near T* = 1)."""
    S = np.stack(scales, axis=-1)
    SS = S[..., :, None] * S[..., None, :]
    ref_n, an_n = reference * SS, analytic * SS
    floor = np.maximum(np.max(np.abs(an_n), axis=(-2, -1)), np.max(np.abs(gradient * S), -1))
    bound = rtol * np.maximum(np.abs(an_n), floor[:, None, None])
    bound = np.maximum(bound, np.broadcast_to(rounding_floor, bound.shape[:-2] + (5,))[:, None, :])
    bad = ~(np.abs(ref_n - an_n) <= bound)
    assert not bad.any(), (f"{label}: {bad.sum()} entries off, worst at "
                           f"{np.argwhere(bad)[0]}: ref {ref_n[bad][0]!r} an {an_n[bad][0]!r}")


# ---------------------------------------------------------------- Johnson–Cook

def jc_conditioning(theta, eps_p, T_star):
    """Per state: n|ln εp| and m|ln T*| (the factors by which an error in the exponent's
    logarithm grows in εp^n and T*^m computed as exp(n ln εp): numpy's complex pow), and
    T*^m/(1 − T*^m), the cancellation of t = 1 − T*^m (0 where t is exactly 1 or 0)."""
    _, _, _, n, m = theta
    hardened = eps_p > 0.0
    softened = (T_star > 0.0) & (T_star < 1.0)
    a_P = np.where(hardened, n * np.abs(np.log(np.where(hardened, eps_p, 1.0))), 0.0)
    a_Q = np.where(softened, np.abs(m * np.log(np.where(softened, T_star, 0.5))), 0.0)
    return a_P, a_Q, thermal_cancellation(m, T_star)


def thermal_cancellation(m, T_star):
    """T*^m/(1 − T*^m) on 0 < T* < 1, else 0: how much 1 − T*^m magnifies an error in T*^m."""
    m, T_star = np.asarray(m, dtype=float), np.asarray(T_star, dtype=float)
    softened = (T_star > 0.0) & (T_star < 1.0)
    m_log_T = m * np.log(np.where(softened, T_star, 0.5))
    # −expm1 evaluates 1 − T*^m without the cancellation this factor measures
    return np.where(softened, np.exp(m_log_T) / -np.expm1(m_log_T), 0.0)


def jc_value_rtol(m, T_star):
    """Relative bound between two evaluations of σy = h·r·t in the same order with different
    pow/log (numpy's SIMD loops, libm): per evaluation h = A + Bεp^n and r = 1 + C ln ε̇* carry
    ULP + 1, t = 1 − T*^m ULP·T*^m/t + ½ (the cancellation), the two products 1, in eps."""
    return 2 * (2 * ULP + 3.5 + ULP * thermal_cancellation(m, T_star)) * EPS


def jc_gradient_bound(theta, eps_p, rate, T_star, an_n):
    """|complex step − analytic| bound per entry of the JC gradient, in θ·∂/∂θ units.

    Analytic (real numpy): P = εp^n, Q = T*^m, ln εp, ln ε̇*, ln T* each within ULP; h, r
    within ULP + 1; t within ULP·c + ½ with c = Q/t. Complex step: numpy's complex pow is
    exp((n + ih) ln εp) (libm cpow), so P and Q also carry the error of their exponent,
    a_P (ULP + 1) and a_Q (ULP + 1), and the imaginary parts sin(h ln x) another ULP + 1;
    every complex operation 1, the division by h ½. Summed per entry over the factors it
    holds (∂A = rt, ∂B = Prt, ∂C = hΛt, ∂n = BP ln εp rt, ∂m = −hrQ ln T*), plus the
    underflow floor: an imaginary part below the smallest normal is rounded to ULP·2^-1074,
    which the division by h = CS_STEP·θ turns into ULP·2^-1074·(1 + hr(1 + |ln T*|))/CS_STEP.
    """
    A, B, C, n, m = theta
    a_P, a_Q, c = jc_conditioning(theta, eps_p, T_star)
    h_an, r_an, t_an, P_an, log_an = ULP + 1, ULP + 1, ULP * c + 0.5, ULP, ULP
    h_cs = ULP + 2 + a_P * (ULP + 1)
    r_cs = ULP + 2
    t_cs = c * (ULP + a_Q * (ULP + 1)) + 1
    P_cs = ULP + a_P * (ULP + 1)
    Q_cs = ULP + a_Q * (ULP + 1)
    im_cs = ULP + 1                  # sin(h ln x) and h ln x of the imaginary part
    ops = 8                          # rounded products and the division, both sides
    r_t = r_an + r_cs + t_an + t_cs + ops
    rho = np.stack([
        r_t,
        P_an + P_cs + r_t,
        h_an + h_cs + 2 * log_an + t_an + t_cs + ops,
        P_an + log_an + P_cs + im_cs + r_t,
        h_an + h_cs + r_an + r_cs + ULP + log_an + Q_cs + im_cs + ops,
    ], axis=-1) * EPS
    log_T = np.abs(np.log(np.where((T_star > 0.0) & (T_star < 1.0), T_star, 1.0)))
    hr = jc_ref.hardening(A, B, n, eps_p) * jc_ref.rate_factor(C, rate)
    floor = 2 * ULP * SUBNORMAL * (1 + hr * (1 + log_T)) / CS_STEP
    return rho * np.abs(an_n) + floor[:, None]


@pytest.mark.numerics
def test_jc_value_is_the_material_flow_stress_and_finite():
    theta, (eps_p, rate, T_star) = jc_states()
    sigma, grad, hess = johnson_cook_sensitivities(*theta, eps_p, rate, T_star)
    A, B, C, n, m = theta
    material = np.array([johnson_cook_flow_stress(A[i], B[i], n[i], C[i], m[i], eps_p[i],
                                                  rate[i], T_star[i]) for i in range(N_STATES)])
    # the same formula in the same order, but numpy's pow/log (SIMD on AVX-512) against numba's
    # libm: per evaluation h = A + Bεp^n and r = 1 + C ln ε̇* carry ULP + 1, t = 1 − T*^m
    # ULP·T*^m/t + ½ (the cancellation), the two products 1 (in eps); twice that between them
    rtol = jc_value_rtol(theta[4], T_star)
    assert (np.abs(sigma - material) <= rtol * np.abs(material)).all(), \
        np.flatnonzero(~(np.abs(sigma - material) <= rtol * np.abs(material)))
    assert np.isfinite(sigma).all() and np.isfinite(grad).all() and np.isfinite(hess).all()
    np.testing.assert_array_equal(hess, np.swapaxes(hess, -1, -2))


@pytest.mark.numerics
def test_jc_gradient_matches_complex_step():
    theta, state = jc_states()
    _, grad, _ = johnson_cook_sensitivities(*theta, *state)
    cs = complex_step_gradient(lambda t: jc_ref.flow_stress(*t, *state), theta, _scales(theta))
    assert np.isfinite(cs).all()
    S = np.stack(_scales(theta), axis=-1)
    ref_n, an_n = cs * S, grad * S
    bound = jc_gradient_bound(theta, *state, an_n)
    bad = ~(np.abs(ref_n - an_n) <= bound)
    assert not bad.any(), (f"JC gradient: {bad.sum()} entries off, worst at state "
                           f"{np.argwhere(bad)[0]}: ref {ref_n[bad][0]!r} an {an_n[bad][0]!r}")


@pytest.mark.numerics
def test_jc_hessian_matches_central_differences_of_the_gradient():
    theta, (eps_p, rate, T_star) = jc_states()
    state = (eps_p, rate, T_star)
    _, grad, hess = johnson_cook_sensitivities(*theta, *state)
    scales = _scales(theta)
    # n and m enter through εp^n and T*^m: a relative step η/(1 + |θ ln x|) keeps n·Δ ln x ≤ η
    log_eps = np.abs(np.log(np.where(eps_p > 0, eps_p, 1.0)))
    log_T = np.abs(np.log(np.where((T_star > 0) & (T_star < 1), T_star, 1.0)))
    widen = [1.0, 1.0, 1.0, 1.0 + theta[3] * log_eps, 1.0 + theta[4] * log_T]
    steps = [FD_ETA * s / w for s, w in zip(scales, widen)]
    fd = central_difference_hessian(lambda t: johnson_cook_sensitivities(*t, *state)[1],
                                    theta, steps)
    # each gradient entry is a sum of terms of at most T = h r (1 + T*^m)(1 + n|ln εp|)
    # (1 + m|ln T*|) in θ units, rounded to (3 ULP + 8) eps·T (a pow and two logs or pows
    # within ULP each, ≤ 8 roundings); differencing with the step θ_j η/widen_j turns that
    # into 2 (3 ULP + 8) eps·T·widen_j/η (this is what bounds the FD near T* = 1, where the
    # gradient is 1 − T*^m ≈ m(1 − T*), 10⁻¹², computed from terms of order 1)
    A, B, C, n, m = theta
    terms = (jc_ref.hardening(A, B, n, eps_p) * jc_ref.rate_factor(C, rate)
             * (1 + jc_ref.thermal_power(m, T_star))
             * (1 + n * log_eps) * (1 + m * log_T))
    rounding = np.stack([2 * (3 * ULP + 8) * EPS * terms * w / FD_ETA * np.ones(N_STATES)
                         for w in widen], -1)
    assert_hessian_matches(fd, hess, grad, scales, FD_RTOL, "JC Hessian", rounding)


@pytest.mark.numerics
def test_jc_limits_and_printed_defects():
    """The seed prints ∂²σy/∂n² = ∂²σy/∂m² = 0 and ln(a + b) for products of logarithms."""
    A, B, C, n, m = 792e6, 510e6, 0.014, 0.26, 1.03
    eps_p, rate, T_star = 0.05, 1e4, 0.2
    sigma, grad, hess = johnson_cook_sensitivities(A, B, C, n, m, eps_p, rate, T_star)
    _, written_out = jc_ref.flow_stress_derivatives(A, B, C, n, m, eps_p, rate, T_star)
    for entry in ((3, 3), (4, 4), (2, 3), (2, 4)):     # the seed's four defective entries
        assert written_out[entry] != 0
        assert hess[entry] == pytest.approx(written_out[entry], rel=CLOSED_FORM_REL)
    # limits: εp = 0, T* = 0, T* ≥ 1, clamped rate
    _, g0, h0 = johnson_cook_sensitivities(A, B, C, n, m, 0.0, rate, T_star)
    assert g0[1] == 0 and g0[3] == 0 and not h0[3].any() and h0[1, 2] == 0
    _, gT, hT = johnson_cook_sensitivities(A, B, C, n, m, eps_p, rate, 0.0)
    assert gT[4] == 0 and not hT[4].any()
    for hot in (1.0, 1.3):
        s1, g1, h1 = johnson_cook_sensitivities(A, B, C, n, m, eps_p, rate, hot)
        assert s1 == 0 and not g1.any() and not h1.any()
    _, gr, hr = johnson_cook_sensitivities(A, B, C, n, m, eps_p, 0.3, T_star)
    assert gr[2] == 0 and not hr[2].any()


# ---------------------------------------------------------------- Mie–Grüneisen

@pytest.mark.numerics
def test_mg_value_is_the_material_pressure_and_finite():
    theta, (mu, E) = mg_states()
    p, grad, hess = mie_gruneisen_sensitivities(mu, E, RHO0, BULK_C, *theta)
    S1, S2, S3, gamma0, a = theta
    # the material takes ρ; this ρ gives back μ to a few ulp, so compare through the material's
    # own μ = ρ/ρ0 − 1 evaluated here
    rho = RHO0 * (1.0 + mu)
    mu_back = rho / RHO0 - 1.0
    p_ours = mie_gruneisen_pressure_value(mu_back, E, RHO0, BULK_C, *theta)
    material = np.array([mie_gruneisen_pressure(RHO0, BULK_C, S1[i], S2[i], S3[i], gamma0[i],
                                                a[i], rho[i], E[i])[0] for i in range(N_STATES)])
    # the same operations in the same order on the same μ (den is computed identically, so its
    # cancellation near the pole is shared); rounding of ~12 flops on the terms of f and gE,
    # which may cancel: 16 eps times the sum of the terms' magnitudes
    k = RHO0 * BULK_C ** 2
    mu_c = np.maximum(mu_back, 0.0)
    den = np.array([mg_denominator(S1[i], S2[i], S3[i], mu_c[i]) for i in range(N_STATES)])
    num_terms = 1.0 + np.abs(1.0 - 0.5 * gamma0) * mu_c + 0.5 * a * mu_c ** 2
    term_scale = (k * np.abs(mu_back) * num_terms / den ** 2
                  + np.abs(gamma0 * E) + np.abs(a * mu_back * E))
    assert (np.abs(p_ours - material) <= 16 * EPS * term_scale).all()
    assert np.isfinite(p).all() and np.isfinite(grad).all() and np.isfinite(hess).all()
    np.testing.assert_array_equal(hess, np.swapaxes(hess, -1, -2))


@pytest.mark.numerics
def test_mg_gradient_matches_complex_step():
    theta, (mu, E) = mg_states()
    _, grad, _ = mie_gruneisen_sensitivities(mu, E, RHO0, BULK_C, *theta)
    cs = complex_step_gradient(
        lambda t: mie_gruneisen_pressure_value(mu, E, RHO0, BULK_C, *t), theta, _scales(theta))
    assert np.isfinite(cs).all()
    assert_gradient_matches(cs, grad, _scales(theta), CS_RTOL, "MG gradient")


@pytest.mark.numerics
def test_mg_hessian_matches_central_differences_of_the_gradient():
    theta, (mu, E) = mg_states()
    _, grad, hess = mie_gruneisen_sensitivities(mu, E, RHO0, BULK_C, *theta)
    scales = _scales(theta)
    # near the pole den varies fast in S_i: step so that |∂den/∂S_i|·Δ ≤ η·den
    mp1 = 1.0 + np.maximum(mu, 0.0)
    mu_c = np.maximum(mu, 0.0)
    den = np.array([mg_denominator(*(t[i] for t in theta[:3]), mu_c[i]) for i in range(N_STATES)])
    d = [mu_c, mu_c ** 2 / mp1, mu_c ** 3 / mp1 ** 2]
    steps = [FD_ETA * np.minimum(scales[i], den / np.maximum(d[i], 1e-300)) for i in range(3)]
    steps += [FD_ETA * scales[3], FD_ETA * scales[4]]
    fd = central_difference_hessian(
        lambda t: mie_gruneisen_sensitivities(mu, E, RHO0, BULK_C, *t)[1], theta, steps)
    assert_hessian_matches(fd, hess, grad, scales, FD_RTOL, "MG Hessian")


@pytest.mark.numerics
def test_mg_branches_and_the_corrected_entry():
    """Tension: only ∂/∂γ0 = E and ∂/∂a = μE; compression (S1, S1) = 6μB3 with the seed's
    B3 = ρ0C²μ²N/den⁴ (printed as μB3)."""
    theta = (1.49, 0.3, 0.1, 2.17, 0.46)
    E = 2e9
    for mu in (-0.1, 0.0, -0.0, -1e-300):
        p, g, h = mie_gruneisen_sensitivities(mu, E, RHO0, BULK_C, *theta)
        np.testing.assert_array_equal(g, [0, 0, 0, E, mu * E])
        assert not h.any()
    mu = 0.2
    p, g, h = mie_gruneisen_sensitivities(mu, E, RHO0, BULK_C, *theta)
    k = RHO0 * BULK_C ** 2
    N = 1 + (1 - theta[3] / 2) * mu - theta[4] / 2 * mu ** 2
    den = mg_denominator(theta[0], theta[1], theta[2], mu)
    B3 = k * mu ** 2 * N / den ** 4
    assert h[0, 0] == pytest.approx(6 * mu * B3, rel=CLOSED_FORM_REL)
    assert (h[3:, 3:] == 0).all()


def test_mg_states_past_the_guard_have_no_derivative():
    S1 = 1.49
    mu_pole = 1.0 / (S1 - 1.0)
    for mu in (mu_pole, mu_pole * (1 - MG_DEN_MIN / 2), mu_pole * 1.1):
        with pytest.raises(ValueError, match="denominator guard"):
            mie_gruneisen_sensitivities(np.array([0.1, mu]), 0.0, RHO0, BULK_C, S1, 0.0, 0.0,
                                        2.17, 0.46)


def test_parameter_orders_are_the_material_names():
    assert MG_PARAMETERS == ("eos.S1", "eos.S2", "eos.S3", "eos.gamma0", "eos.a")
    assert JC_PARAMETERS == ("jc.A", "jc.B", "jc.C", "jc.n", "jc.m")
