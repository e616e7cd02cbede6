"""Analytic parameter sensitivities of the steel constitutive functions, at a frozen state.

The seed's one-run Taylor method (000, eq. 22–35) differentiates the Mie–Grüneisen pressure
with respect to (S1, S2, S3, γ0, a) and the Johnson–Cook flow stress with respect to
(A, B, C, n, m) while the particle's state (μ, E; εp, ε̇*, T*) is held fixed. These are the
derivatives of OUR formulas (``mie_gruneisen.py``, ``johnson_cook.py``): the tension branch
for μ ≤ 0, the ε̇* ≥ 1 clamp, T* clipped to [0, 1] and Bεp^n = 0 at εp = 0. Where the printed
seed formulas are wrong, and the limits kept here, see docs/mpm_materials.md
§ "Constitutive sensitivities".

Every function is vectorised: states are arrays, parameters scalars or arrays that broadcast
against them. Results: value (N,), gradient (N, 5), Hessian (N, 5, 5), in the parameter order
of ``MG_PARAMETERS`` / ``JC_PARAMETERS``. The value functions also accept complex parameters
(the branch choices depend on the state only), so complex-step differentiation applies to them.
"""

from __future__ import annotations

import numpy as np

from . import johnson_cook, mie_gruneisen
from .johnson_cook import SEED_RATE_STAR_FLOOR
from .state import MG_DEN_MIN

# the parameter order of the gradients and Hessians below: declared by the models
MG_PARAMETERS = mie_gruneisen.DIFFERENTIABLE_PARAMETERS
JC_PARAMETERS = johnson_cook.DIFFERENTIABLE_PARAMETERS


def _mg_denominator_terms(mu, S1, S2, S3):
    """(den, ∂den/∂(S1, S2, S3)) of the compression branch; den is linear in S1, S2, S3."""
    mp1 = mu + 1.0
    dS = (-mu, -mu * mu / mp1, -mu * mu * mu / (mp1 * mp1))
    den = 1.0 - (S1 - 1.0) * mu - S2 * mu * mu / mp1 - S3 * mu * mu * mu / (mp1 * mp1)
    return den, dS


def _mg_states(mu, E, S1, S2, S3):
    """Broadcast state and S arrays; the compression mask; the denominator checked against the
    material's guard (a state past it is one the material refused, so it has no derivative)."""
    mu, E = np.broadcast_arrays(np.asarray(mu, dtype=float), np.asarray(E, dtype=float))
    compressed = mu > 0.0
    mu_c = np.where(compressed, mu, 0.0)       # the tension branch never sees den
    den, dS = _mg_denominator_terms(mu_c, S1, S2, S3)
    den = np.broadcast_to(den, mu.shape)
    bad = compressed & ~(np.real(den) > MG_DEN_MIN)
    if np.any(bad):
        i = int(np.flatnonzero(bad.ravel())[0])
        raise ValueError(f"Mie–Grüneisen sensitivities: {int(bad.sum())} compressed state(s) at "
                         f"or past the denominator guard den ≤ {MG_DEN_MIN:g} (first: index {i}, "
                         f"mu = {mu.ravel()[i]!r}); the material refuses these states")
    return mu, E, compressed, mu_c, np.where(compressed, den, 1.0), dS


def mie_gruneisen_pressure_value(mu, E, rho0, C, S1, S2, S3, gamma0, a):
    """p*(μ, E), seed eq. (10) as in ``mie_gruneisen.py`` (tension branch for μ ≤ 0), for arrays
    of states; the parameters may be complex (complex-step differentiation)."""
    mu, E, compressed, mu_c, den, _ = _mg_states(mu, E, S1, S2, S3)
    k = rho0 * C * C
    num = 1.0 + (1.0 - 0.5 * gamma0) * mu_c - 0.5 * a * mu_c * mu_c
    f = np.where(compressed, k * mu_c * num / (den * den), k * mu)
    return f + (gamma0 + a * mu) * E


def mie_gruneisen_sensitivities(mu, E, rho0, C, S1, S2, S3, gamma0, a):
    """(p*, ∂p*/∂θ, ∂²p*/∂θ²) with θ = (S1, S2, S3, γ0, a), for arrays of states (μ, E).

    Compression, p* = kμN/den² + (γ0 + aμ)E with k = ρ0C², N = 1 + (1 − γ0/2)μ − (a/2)μ²,
    d_i = ∂den/∂S_i = −(μ, μ²/(μ+1), μ³/(μ+1)²) (den and N are linear in θ):
      ∂p/∂S_i = −2kμN d_i/den³,  ∂p/∂γ0 = −kμ²/(2den²) + E,  ∂p/∂a = −kμ³/(2den²) + μE;
      ∂²p/∂S_i∂S_j = 6kμN d_i d_j/den⁴,  ∂²p/∂γ0∂S_i = kμ² d_i/den³,
      ∂²p/∂a∂S_i = kμ³ d_i/den³,  the (γ0, a) block 0.
    Tension (μ ≤ 0, including μ = 0): p* = kμ + (γ0 + aμ)E; ∂p/∂γ0 = E, ∂p/∂a = μE, rest 0.
    Raises ValueError for a compressed state at or past the material's denominator guard.
    """
    mu, E, compressed, mu_c, den, dS = _mg_states(mu, E, S1, S2, S3)
    k = rho0 * C * C
    num = 1.0 + (1.0 - 0.5 * gamma0) * mu_c - 0.5 * a * mu_c * mu_c
    den2 = den * den
    den3 = den2 * den
    f = np.where(compressed, k * mu_c * num / den2, k * mu)
    p = f + (gamma0 + a * mu) * E

    shape = mu.shape
    grad = np.zeros(shape + (len(MG_PARAMETERS),))
    hess = np.zeros(shape + (len(MG_PARAMETERS),) * 2)
    d = [np.broadcast_to(np.asarray(di, dtype=float), shape) for di in dS]   # 0 in tension
    for i in range(3):
        grad[..., i] = -2.0 * k * mu_c * num * d[i] / den3
        for j in range(i, 3):
            hess[..., i, j] = hess[..., j, i] = 6.0 * k * mu_c * num * d[i] * d[j] / (den2 * den2)
        hess[..., i, 3] = hess[..., 3, i] = k * mu_c ** 2 * d[i] / den3
        hess[..., i, 4] = hess[..., 4, i] = k * mu_c ** 3 * d[i] / den3
    grad[..., 3] = -0.5 * k * mu_c ** 2 / den2 + E
    grad[..., 4] = -0.5 * k * mu_c ** 3 / den2 + mu * E
    return p, grad, hess


def _jc_state_factors(eps_p, eps_rate_star, T_star, rate_clamped=True):
    """Broadcast states; ln εp where εp > 0, ln ε̇* of the clamped rate (0 for ε̇* ≤ 1; with
    ``rate_clamped`` False, the seed conventions: ln max(ε̇*, SEED_RATE_STAR_FLOOR)),
    ln T* on 0 < T* < 1 (0 elsewhere, where the factor it multiplies is masked, so no NaN reaches a product)."""
    eps_p, rate, T_star = np.broadcast_arrays(np.asarray(eps_p, dtype=float),
                                              np.asarray(eps_rate_star, dtype=float),
                                              np.asarray(T_star, dtype=float))
    hardened = eps_p > 0.0
    log_eps = np.log(np.where(hardened, eps_p, 1.0))
    log_rate = np.log(np.maximum(rate, 1.0 if rate_clamped else SEED_RATE_STAR_FLOOR))
    softened = (T_star > 0.0) & (T_star < 1.0)
    log_T = np.log(np.where(softened, T_star, 1.0))
    melted = T_star >= 1.0
    return eps_p, hardened, log_eps, log_rate, T_star, softened, log_T, melted


def johnson_cook_flow_stress_value(A, B, C, n, m, eps_p, eps_rate_star, T_star,
                                   rate_clamped=True):
    """σy(εp, ε̇*, T*), seed eq. (11) with the clamps of ``johnson_cook_flow_stress`` (with
    ``rate_clamped`` False: of ``johnson_cook_flow_stress_seed``), for arrays of states; the
    parameters may be complex (complex-step differentiation)."""
    eps_p, hardened, _, log_rate, T_star, softened, _, melted = _jc_state_factors(
        eps_p, eps_rate_star, T_star, rate_clamped)
    power_eps = np.where(hardened, np.power(np.where(hardened, eps_p, 1.0), n), 0.0)
    power_T = np.power(np.where(softened, T_star, 1.0), m)
    hardening = A + B * power_eps
    rate_factor = 1.0 + C * log_rate
    thermal = np.where(melted, 0.0, np.where(softened, 1.0 - power_T, 1.0))
    return hardening * rate_factor * thermal


def johnson_cook_sensitivities(A, B, C, n, m, eps_p, eps_rate_star, T_star, rate_clamped=True):
    """(σy, ∂σy/∂θ, ∂²σy/∂θ²) with θ = (A, B, C, n, m), for arrays of states (εp, ε̇*, T*).
    ``rate_clamped`` False: the seed conventions' rate factor (no clamp, ε̇* floored).

    With h = A + BP, P = εp^n, Lε = ln εp; r = 1 + CΛ, Λ = ln max(ε̇*, 1); t = 1 − Q,
    Q = T*^m, LT = ln T*:
      ∂σ/∂A = rt, ∂σ/∂B = Prt, ∂σ/∂C = hΛt, ∂σ/∂n = BPLε rt, ∂σ/∂m = −hrQLT;
      second: (A,C) Λt, (A,m) −rQLT, (B,C) PΛt, (B,n) PLε rt, (B,m) −PrQLT,
      (C,n) BPLεΛt, (C,m) −hΛQLT, (n,n) BPLε² rt, (n,m) −BPLε rQLT, (m,m) −hrQLT²; the rest 0.
    Limits: P Lεᵏ = 0 at εp = 0 (σy = A there, for every n); Q LTᵏ = 0 at T* ≤ 0 (t = 1);
    every derivative 0 for T* ≥ 1 (t = 0, σy = 0 whatever θ); Λ = 0 where the rate is clamped,
    so every C-derivative vanishes there.
    """
    eps_p, hardened, log_eps, log_rate, T_star, softened, log_T, melted = _jc_state_factors(
        eps_p, eps_rate_star, T_star, rate_clamped)
    P = np.where(hardened, np.power(np.where(hardened, eps_p, 1.0), n), 0.0)
    Q = np.where(softened, np.power(np.where(softened, T_star, 1.0), m), 0.0)
    h = A + B * P
    r = 1.0 + C * log_rate
    t = np.where(melted, 0.0, 1.0 - Q)
    QL = Q * log_T                           # T*^m ln T*, 0 outside 0 < T* < 1 (Q = 0 there)
    QL2 = QL * log_T
    PL = P * log_eps                         # εp^n ln εp, 0 at εp = 0 (P = 0, log_eps = 0)
    PL2 = PL * log_eps
    Lam = log_rate

    sigma = h * r * t
    shape = sigma.shape
    grad = np.zeros(shape + (len(JC_PARAMETERS),))
    grad[..., 0] = r * t
    grad[..., 1] = P * r * t
    grad[..., 2] = h * Lam * t
    grad[..., 3] = B * PL * r * t
    grad[..., 4] = -h * r * QL

    hess = np.zeros(shape + (len(JC_PARAMETERS),) * 2)
    entries = {
        (0, 2): Lam * t,
        (0, 4): -r * QL,
        (1, 2): P * Lam * t,
        (1, 3): PL * r * t,
        (1, 4): -P * r * QL,
        (2, 3): B * PL * Lam * t,
        (2, 4): -h * Lam * QL,
        (3, 3): B * PL2 * r * t,
        (3, 4): -B * PL * r * QL,
        (4, 4): -h * r * QL2,
    }
    for (i, j), value in entries.items():
        hess[..., i, j] = value
        hess[..., j, i] = value
    return sigma, grad, hess


def johnson_cook_return_sensitivities(A, B, C, n, m, G, eps_p, delta_eps_p, eps_rate_star,
                                      T_star, rate_fixed=False):
    """(∂σ̄/∂θ, ∂²σ̄/∂θ²), θ = (A, B, C, n, m), of the flow stress σ̄ a radial return reaches
    from a FIXED trial deviator (the seed's frozen state of the step), for arrays of returns.

    State after the return: εp = εp_n + Δεp (``eps_p``, ``delta_eps_p`` > 0: plastic; 0:
    elastic, all derivatives 0), the ε̇* and T* it used. The return solves
    3GΔ + F(Δ, θ) = σeq* with F(Δ, θ) = h(εp_n + Δ)·r·t, h = A + Bεp^n, t = 1 − T*^m and
    r = 1 + C ln(Δ/(Δt ε̇0)) above the clamp (rate-dependent, uqflow), 1 below it, or
    r = 1 + C ln ε̇* fixed over the step (``rate_fixed``, seed conventions). With σ̄ = σeq* − 3GΔ
    and K = 3G + H, H = F_Δ (the consistent tangent of OUR return):

        Δ_θ = −F_θ/K,   ∂σ̄/∂θ = 3G F_θ/K,
        Δ_θφ = −(F_θφ + F_Δθ Δ_φ + F_Δφ Δ_θ + F_ΔΔ Δ_θ Δ_φ)/K,   ∂²σ̄/∂θ∂φ = −3G Δ_θφ.

    Each deviator component follows as s_ij = (s*_ij/σeq*) σ̄ (the scaling is fixed by the
    trial), so its derivatives are s_ij/σ̄ times these (seed eq. 29–30, corrected: per
    component, and with the tangent K). F_θ, F_θφ are ``johnson_cook_sensitivities`` at the
    state the return used; the Δ-derivatives, with ε = εp, P = ε^n, Lε = ln ε, Λ = ln ε̇*,
    ρ = r_Δ = C/Δ above the clamp (0 when clamped or fixed):
      F_Δ  = t(Bnε^(n−1) r + hρ),  F_ΔΔ = t(Bn(n−1)ε^(n−2) r + 2Bnε^(n−1)ρ − hρ/Δ),
      F_ΔA = tρ,  F_ΔB = t(nε^(n−1) r + Pρ),  F_ΔC = t(Bnε^(n−1)Λ + h ρ/C) [ρ/C = 1/Δ],
      F_Δn = t(Bε^(n−1)(1 + nLε) r + BPLε ρ),  F_Δm = −T*^m ln T*·(Bnε^(n−1) r + hρ).
    """
    eps_p, dep, rate, T_star = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (
        eps_p, delta_eps_p, eps_rate_star, T_star)))
    shape = eps_p.shape
    grad = np.zeros(shape + (len(JC_PARAMETERS),))
    hess = np.zeros(shape + (len(JC_PARAMETERS),) * 2)
    plastic = dep > 0.0
    if not np.any(plastic):
        return grad, hess
    A, B, C, n, m, G = (np.broadcast_to(np.asarray(v, dtype=float), shape)[plastic]
                        for v in (A, B, C, n, m, G))
    ep, dep, rate, T_star = eps_p[plastic], dep[plastic], rate[plastic], T_star[plastic]
    _, F_t, F_tt = johnson_cook_sensitivities(A, B, C, n, m, ep, rate, T_star,
                                              rate_clamped=not rate_fixed)
    _, _, log_eps, log_rate, _, softened, log_T, melted = _jc_state_factors(
        ep, rate, T_star, rate_clamped=not rate_fixed)
    Q = np.where(softened, np.power(np.where(softened, T_star, 1.0), m), 0.0)
    t = np.where(melted, 0.0, 1.0 - Q)
    P = np.power(ep, n)                        # ep ≥ Δεp > 0
    P1 = P / ep                                # ε^(n−1)
    h = A + B * P
    r = 1.0 + C * log_rate
    rate_dependent = (rate > 1.0) if not rate_fixed else np.zeros(ep.shape, dtype=bool)
    inv_dep = np.where(rate_dependent, 1.0 / dep, 0.0)          # r_ΔC = 1/Δ above the clamp
    rho = C * inv_dep                                           # r_Δ
    H = t * (B * n * P1 * r + h * rho)
    F_dd = t * (B * n * (n - 1.0) * P1 / ep * r + 2.0 * B * n * P1 * rho - h * rho * inv_dep)
    F_dt = np.stack([t * rho,
                     t * (n * P1 * r + P * rho),
                     t * (B * n * P1 * log_rate + h * inv_dep),
                     t * (B * P1 * (1.0 + n * log_eps) * r + B * P * log_eps * rho),
                     -Q * log_T * (B * n * P1 * r + h * rho)], axis=-1)
    g3 = 3.0 * G
    K = g3 + H
    d_t = -F_t / K[:, None]                                     # Δ_θ
    cross = F_dt[:, :, None] * d_t[:, None, :]
    cross = cross + np.swapaxes(cross, 1, 2)                    # a + b = b + a: symmetric
    d_tt = -(F_tt + cross + F_dd[:, None, None] * (d_t[:, :, None] * d_t[:, None, :])) \
        / K[:, None, None]
    grad[plastic] = -g3[:, None] * d_t
    hess[plastic] = -g3[:, None, None] * d_tt
    return grad, hess
