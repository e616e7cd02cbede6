"""Steel: Mie–Grüneisen EOS (seed eq. 10) + Johnson–Cook flow stress (eq. 11–12) + von Mises
radial return with the Jaumann rate (eq. 13–20), plane strain (s_xx, s_yy, s_xy, s_zz).

Defaults: AISI 4340 (seed Tables 2 and 5, AUTODYN "STEEL 4340"; docs/design/mpm.md).

Flow stress  σy = (A + B εp^n)(1 + C ln ε̇*)(1 − T*^m),  ε̇* = max(ε̇p/ε̇0, 1),
T* = clip((T − T_room)/(T_melt − T_room), 0, 1);  B εp^n = 0 at εp = 0, T*^m = 0 at T* = 0.

Return mapping: the seed's eq. (20) linearises σy in Δεp (σy_{n+1} = σy_n + H Δεp). Here the
consistency condition is solved exactly for the nonlinear, rate-dependent JC law,

    σeq* − 3G Δεp = σy(εp_n + Δεp, Δεp/(Δt ε̇0), T_n),

by Newton's method in ln Δεp (monotone there: the residual is convex in ln Δεp, also across
the ε̇* ≥ 1 clamp and for εp_n = 0 with n < 1), started at an upper bound of the root and kept
in a sign bracket inside [0, (σeq* − σy(εp_n, 1, T_n))/(3G)]; the deviator is scaled by
m = σy/σeq* (eq. 15–16), so the stress lies on the yield surface to round-off. The trial state
is plastic when σeq* > σy(εp_n, ε̇* = 1, T_n).

Seed conventions (parameter ``seed_conventions`` = 1, set by the solver from the scene's
``conventions = "seed"``; docs/mpm_materials.md § 3a): ε̇* is the step's total equivalent
deviatoric strain rate √(2/3 D′:D′) over ε̇0 (ε̇0 = 1e6 /s, the seed's 1/µs, unless the scene
sets ``jc.eps0_dot``), held fixed over the return, without the ε̇* ≥ 1 clamp but floored at
``SEED_RATE_STAR_FLOOR``; no adiabatic heating (T stays T_room).

Besides the state, ``advance`` records what the return used (state.py: T_RETURN, RATE_STAR,
DT) and the flow stress at the total strain rate (EQ_STRAIN_RATE, SY_TOTAL_RATE), the output
that does not jump when a particle stops yielding.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .mie_gruneisen import eos_parameters, mg_bulk_sound_speed_sq, mg_coefficients
from .parameters import ParameterSpec, defaults
from .state import (BURN, C as COL_C, DT, E, EPS_P, EPS_P_RATE, EQ_STRAIN_RATE, ERR_DENSITY,
                    ERR_NONFINITE, ERR_OTHER, OK, P, PLASTIC_WORK, Q, RATE_STAR, RHO, SXX, SXY,
                    SY, SY_TOTAL_RATE, SYY, SZZ, T, T_RETURN, check_update, density_update,
                    deviator_of, energy_update_linear_eos, jaumann_rotate, pack_parameters,
                    require, reset_row)

NAME = "mie_gruneisen_johnson_cook"
HAS_STRENGTH = True

PARAMETER_SPECS = (
    *eos_parameters(C=4569.0, S1=1.49, S2=0.0, S3=0.0, gamma0=2.17, a=0.46),
    ParameterSpec("rho0", 7830.0, "kg m-3", "reference density"),
    ParameterSpec("shear_modulus", 81.8e9, "Pa", "shear modulus G"),
    ParameterSpec("jc.A", 792e6, "Pa", "Johnson–Cook initial yield stress A"),
    ParameterSpec("jc.B", 510e6, "Pa", "Johnson–Cook hardening modulus B"),
    ParameterSpec("jc.n", 0.26, "", "Johnson–Cook hardening exponent n"),
    ParameterSpec("jc.C", 0.014, "", "Johnson–Cook strain-rate coefficient C"),
    ParameterSpec("jc.m", 1.03, "", "Johnson–Cook thermal-softening exponent m"),
    ParameterSpec("jc.eps0_dot", 1.0, "s-1", "reference strain rate ε̇0"),
    ParameterSpec("jc.T_room", 294.0, "K", "room temperature"),
    ParameterSpec("jc.T_melt", 1793.0, "K", "melting temperature"),
    ParameterSpec("cp", 477.0, "J kg-1 K-1", "specific heat capacity"),
    ParameterSpec("taylor_quinney", 0.9, "", "fraction of plastic work turned into heat"),
    ParameterSpec("seed_conventions", 0.0, "",
                  "1: seed 000's rate measure and no heating (set by the solver)"),
)
PARAMETERS = defaults(PARAMETER_SPECS)
# the flow-stress parameters with analytic derivatives (below), in their gradients' order
DIFFERENTIABLE_PARAMETERS = ("jc.A", "jc.B", "jc.C", "jc.n", "jc.m")
NPRM = len(PARAMETERS)
(I_C, I_S1, I_S2, I_S3, I_G0, I_A, I_RHO0, I_G, I_JA, I_JB, I_JN, I_JC, I_JM, I_EPS0, I_TROOM,
 I_TMELT, I_CP, I_TQ, I_SEED) = range(NPRM)
CONVENTIONS_PARAMETER = "seed_conventions"   # set by the solver from the scene, not sampled
SEED_EPS0_DOT = 1e6        # 1/s: the seed's rate term is in 1/µs
# ε̇* floor under the seed conventions (no clamp): 1e-9 is ε̇ = 1e-3 /s at ε̇0 = 1e6 /s, the
# quasi-static end of the rates at which Johnson–Cook constants are fitted. Below it the log
# law is an extrapolation that at ε̇ = 0 is −∞ (NaN when C = 0) and turns σy negative for
# ε̇* < e^(−1/C) (1e-31 at C = 0.014); with the floor 1 + C ln ε̇* ≥ 1 − 20.7 C, kept > 0 by
# ``check`` (C < 1/20.7 = 0.048 under the seed conventions).
SEED_RATE_STAR_FLOOR = 1e-9

RETURN_MAXIT = 60          # a 200,000-state sweep needs at most 12 (docs/mpm_materials.md §3)
RETURN_RTOL = 1e-13
RETURN_SHRINK = 1e-3       # round-off guard step when no lower bracket point is known yet
RETURN_TINY = 2.2250738585072014e-308   # smallest normal double: floor of the Δεp iterate


def pack(values: dict | None = None) -> np.ndarray:
    """Parameter vector in PARAMETERS order (missing names take the 4340 defaults)."""
    prm = pack_parameters(PARAMETERS, values, NAME)
    check(prm)
    return prm


def check(prm: np.ndarray) -> None:
    """Raise SolverError for a parameter outside its physical range."""
    pos, nonneg = (lambda v: v > 0, "> 0"), (lambda v: v >= 0, ">= 0")
    rules = [(k, *pos) for k in ("eos.C", "rho0", "jc.A", "jc.n", "jc.m", "jc.eps0_dot",
                                 "cp")]
    rules += [(k, *nonneg) for k in ("shear_modulus", "jc.B", "jc.C", "jc.T_room")]
    rules += [("taylor_quinney", lambda v: 0 <= v <= 1, "in [0, 1]"),
              ("jc.T_melt", lambda v: v > prm[I_TROOM], "> jc.T_room"),
              ("seed_conventions", lambda v: v in (0.0, 1.0), "0 or 1")]
    if prm[I_SEED] == 1.0:
        c_max = -1.0 / math.log(SEED_RATE_STAR_FLOOR)
        rules.append(("jc.C", lambda v: v < c_max,
                      f"< {c_max:.4g} under the seed conventions (the rate factor 1 + C ln ε̇* "
                      f"must stay > 0 down to the floor ε̇* = {SEED_RATE_STAR_FLOOR:g})"))
    require(NAME, prm, list(PARAMETERS), rules)


@njit(cache=True, fastmath=False)
def johnson_cook_flow_stress(A, B, n, C, m, eps_p, eps_rate_star, T_star):
    """Seed eq. (11) with the limits: B εp^n = 0 for εp ≤ 0; rate factor 1 for ε̇* ≤ 1
    (ε̇* clamped ≥ 1, so ln ε̇* ≥ 0); T* clipped to [0, 1] (T*^m = 0 at T* = 0, σy = 0 at melt)."""
    r = 1.0
    if eps_rate_star > 1.0:
        r += C * math.log(eps_rate_star)
    return hardening(A, B, n, eps_p) * r * thermal_factor(m, T_star)


@njit(cache=True, fastmath=False)
def hardening(A, B, n, eps_p):
    """A + B εp^n, with B εp^n = 0 for εp ≤ 0 (the limit, not 0^n evaluated)."""
    h = A
    if eps_p > 0.0:
        h += B * eps_p ** n
    return h


@njit(cache=True, fastmath=False)
def thermal_factor(m, T_star):
    """1 − T*^m with T* clipped to [0, 1]: 1 at T* ≤ 0, 0 at melt."""
    if T_star <= 0.0:
        return 1.0
    if T_star >= 1.0:
        return 0.0
    return 1.0 - T_star ** m


@njit(cache=True, fastmath=False)
def seed_rate_factor(C, eps_rate_star):
    """1 + C ln ε̇* without the ε̇* ≥ 1 clamp, ε̇* floored at SEED_RATE_STAR_FLOOR (seed
    conventions): < 1 below ε̇0, finite and > 0 for every ε̇* ≥ 0 when ``check`` passed."""
    return 1.0 + C * math.log(max(eps_rate_star, SEED_RATE_STAR_FLOOR))


@njit(cache=True, fastmath=False)
def johnson_cook_flow_stress_seed(A, B, n, C, m, eps_p, eps_rate_star, T_star):
    """Seed eq. (11) under the seed conventions: as ``johnson_cook_flow_stress`` but with the
    unclamped, floored rate factor ``seed_rate_factor``."""
    return (hardening(A, B, n, eps_p) * seed_rate_factor(C, eps_rate_star)
            * thermal_factor(m, T_star))


@njit(cache=True, fastmath=False)
def von_mises(sxx, syy, sxy, szz):
    """σeq = sqrt(3/2 s:s) of a plane-strain deviator (seed eq. 14)."""
    return math.sqrt(1.5 * (sxx * sxx + syy * syy + szz * szz + 2.0 * sxy * sxy))


@njit(cache=True, fastmath=False)
def _jc_return_start(seq, A, B, n, eps_p, th, hi):
    """Start of the return iteration: min(hi, Δεp_h) with Δεp_h the strain increment at which
    th (A + B (εp_n + Δεp)^n) = σeq* (rate factor 1). Both bound the root from above (σy ≥ the
    rate-free value, 3GΔεp > 0), so Newton in ln Δεp descends monotonically from there.
    Δεp_h is what matters for εp_n = 0 and n < 1, where the root can be ~20 decades below hi;
    round-off in σeq* − th A can put it on either side of the root, which the bracket absorbs."""
    x = hi
    if n > 0.0 and th * B > 0.0:
        z = (seq - th * A) / (th * B)    # (εp_n + Δεp_h)^n
        if z > 0.0:
            xh = z ** (1.0 / n) - eps_p
            if xh > 0.0 and xh < x:
                x = xh
    return x


@njit(cache=True, fastmath=False)
def jc_radial_return(sxx, syy, sxy, szz, G, dt, A, B, n, C, m, eps0_dot, eps_p, T_star):
    """Radial return of a trial deviator for the rate-dependent Johnson–Cook law (see
    ``_jc_return``; the uqflow conventions: ε̇* = max(Δεp/(Δt ε̇0), 1))."""
    return _jc_return(sxx, syy, sxy, szz, G, dt, A, B, n, C, m, eps0_dot, eps_p, T_star, -1.0)


@njit(cache=True, fastmath=False)
def jc_radial_return_fixed_rate(sxx, syy, sxy, szz, G, A, B, n, C, m, eps_p, T_star,
                                eps_rate_star):
    """Radial return with ε̇* fixed over the step (seed conventions): σy is a function of εp
    alone, σy = (A + B εp^n)·seed_rate_factor(C, ε̇*)·(1 − T*^m); the same bracketed Newton
    iteration as ``jc_radial_return`` with the rate term's slope 0. Same returns; the
    elastic σy is σy(εp_n, ε̇*, T*)."""
    return _jc_return(sxx, syy, sxy, szz, G, 1.0, A, B, n, C, m, 1.0, eps_p, T_star,
                      eps_rate_star)


@njit(cache=True, fastmath=False)
def _jc_return(sxx, syy, sxy, szz, G, dt, A, B, n, C, m, eps0_dot, eps_p, T_star,
               fixed_rate_star):
    """Radial return of a trial deviator for the rate-dependent Johnson–Cook law.

    Returns (s_xx, s_yy, s_xy, s_zz, Δεp, σy, code): σy is the flow stress the deviator was
    returned to (σy(εp_n, 1, T*) when elastic); Δεp = (σeq* − σy)/(3G) (seed eq. 18).

    The consistency condition g(Δεp) = 3GΔεp + σy(εp_n + Δεp, Δεp/(Δt ε̇0), T*) − σeq* = 0 is
    solved by Newton's method in u = ln Δεp, where g is increasing and convex for every n > 0,
    C ≥ 0, 0 ≤ T* ≤ 1, including the kink of the rate clamp ε̇* ≥ 1 (a convex kink in u) and
    εp_n = 0 with n < 1 (Δεp^n = e^{nu} is smooth in u, its Δεp-slope is infinite at 0). From
    any start the first Newton iterate is ≥ the root and the rest decrease monotonically to it,
    so the sign bracket [lo, hi] never has to be bisected in exact arithmetic; the bisection
    (geometric) is a guard against round-off only. Start: the smaller of the two upper bounds
    of the root, (σeq* − σy0)/(3G) and the strain at which the rate-free hardening alone
    reaches σeq* (this one is what makes a return onto a tiny Δεp ~ 1e-26 take a few steps).
    ERR_OTHER only for dt ≤ 0 or a non-finite residual (non-finite/overflowing inputs); no
    finite physical input fails (docs/mpm_materials.md §3).

    ``fixed_rate_star`` ≥ 0: ε̇* is that value for the whole step (seed conventions; dt and
    eps0_dot unused); < 0: ε̇* = Δεp/(Δt ε̇0), clamped ≥ 1. The fixed rate folds its factor into
    the thermal one (th ← r th), which is what keeps both start bounds above the root.
    """
    fixed = fixed_rate_star >= 0.0
    seq = von_mises(sxx, syy, sxy, szz)
    if fixed:
        sy0 = johnson_cook_flow_stress_seed(A, B, n, C, m, eps_p, fixed_rate_star, T_star)
    else:
        sy0 = johnson_cook_flow_stress(A, B, n, C, m, eps_p, 1.0, T_star)
    if seq <= sy0:
        return sxx, syy, sxy, szz, 0.0, sy0, OK
    if not G > 0.0:                       # no elasticity: only the scaling is defined
        k = sy0 / seq
        return sxx * k, syy * k, sxy * k, szz * k, 0.0, sy0, OK
    if not (fixed or dt * eps0_dot > 0.0):   # the plastic strain rate is undefined
        return sxx, syy, sxy, szz, 0.0, sy0, ERR_OTHER
    g3 = 3.0 * G
    rate_k = 1.0 / (dt * eps0_dot)
    th = thermal_factor(m, T_star)        # T* is frozen over the step
    if fixed:
        th *= seed_rate_factor(C, fixed_rate_star)
    lo, hi = 0.0, (seq - sy0) / g3        # g(lo) < 0 ≤ g(hi): σy grows with Δεp
    x = max(_jc_return_start(seq, A, B, n, eps_p, th, hi), RETURN_TINY)
    converged = False
    for _ in range(RETURN_MAXIT):
        ep = eps_p + x
        epn = ep ** n
        rs = x * rate_k
        r, dr = 1.0, 0.0                  # rate factor and its u-derivative
        if rs > 1.0 and not fixed:
            r += C * math.log(rs)
            dr = C
        h = A + B * epn
        fval = seq - g3 * x - h * r * th  # consistency residual, −g
        if not fval * 0.0 == 0.0:         # NaN/inf: non-finite or overflowing input
            break
        if abs(fval) <= RETURN_RTOL * seq:
            converged = True
            break
        if fval > 0.0:
            lo = x
        else:
            hi = x
        w = x / ep if ep > 0.0 else 1.0   # d ln(εp_n + Δεp)/d ln Δεp
        dg = g3 * x + (n * B * epn * w * r + h * dr) * th       # dg/du, u = ln Δεp
        xn = x * math.exp(fval / dg)      # Newton step in u
        if not (xn > lo and xn < hi):     # round-off guard: geometric bisection
            xn = math.sqrt(lo * hi) if lo > 0.0 else RETURN_SHRINK * hi
        if xn < RETURN_TINY:              # (x ≥ TINY > 0 keeps dg > 0)
            xn = RETURN_TINY
        if xn == x or hi - lo <= 1e-15 * hi:
            converged = True
            break
        x = xn
    if not converged:
        return sxx, syy, sxy, szz, 0.0, sy0, ERR_OTHER
    if x == RETURN_TINY and hi == RETURN_TINY:
        # g(TINY) > 0: the root lies below the smallest normal double (possible only for
        # εp_n = 0, n < 0.045 and σeq*/σy0 − 1 > 1e-13). To double precision Δεp = 0 and
        # σy = σeq* − 3GΔεp = σeq*: the deviator is already on the yield surface.
        return sxx, syy, sxy, szz, 0.0, seq, OK
    if fixed:
        sy = johnson_cook_flow_stress_seed(A, B, n, C, m, eps_p + x, fixed_rate_star, T_star)
    else:
        sy = johnson_cook_flow_stress(A, B, n, C, m, eps_p + x, x * rate_k, T_star)
    k = sy / seq
    return sxx * k, syy * k, sxy * k, szz * k, x, sy, OK


@njit(cache=True, fastmath=False)
def _flow_stress(prm, eps_p, eps_rate_star, T_star):
    """σy under the material's conventions (``seed_conventions``)."""
    if prm[I_SEED] != 0.0:
        return johnson_cook_flow_stress_seed(prm[I_JA], prm[I_JB], prm[I_JN], prm[I_JC],
                                             prm[I_JM], eps_p, eps_rate_star, T_star)
    return johnson_cook_flow_stress(prm[I_JA], prm[I_JB], prm[I_JN], prm[I_JC], prm[I_JM],
                                    eps_p, eps_rate_star, T_star)


@njit(cache=True, fastmath=False)
def init(prm, S, i):
    """Reference state of particle i: ρ0, E = 0, T = T_room, σ = 0, σy = A, C = c_L."""
    code = reset_row(prm, NPRM, S, i)
    if code != OK:
        return code
    rho0 = prm[I_RHO0]
    S[i, RHO] = rho0
    S[i, T] = S[i, T_RETURN] = prm[I_TROOM]
    # at rest: ε̇* = 1 (uqflow: the clamp), the floor (seed conventions)
    S[i, RATE_STAR] = SEED_RATE_STAR_FLOOR if prm[I_SEED] != 0.0 else 1.0
    S[i, SY] = S[i, SY_TOTAL_RATE] = _flow_stress(prm, 0.0, S[i, RATE_STAR], 0.0)
    S[i, COL_C] = math.sqrt(prm[I_C] ** 2 + 4.0 * prm[I_G] / (3.0 * rho0))
    return OK


@njit(cache=True, fastmath=False)
def update(prm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y):
    """The guards (``check_update``), then ``advance``. Returns a code."""
    code = check_update(prm, NPRM, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y)
    if code != OK:
        return code
    return advance(prm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y)


@njit(cache=True, fastmath=False, forceinline=True)
def advance(prm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y):
    """Advance particle i over dt (see module doc; docs/mpm_materials.md §3). Returns a code.

    Unguarded: for callers that have made ``check_update``'s checks cheaper in bulk (the
    solver's loops, step.py)."""
    rho0, G, q, rho_n = prm[I_RHO0], prm[I_G], S[i, Q], S[i, RHO]
    trD, Dxy = Lxx + Lyy, 0.5 * (Lxy + Lyx)
    rho1 = density_update(rho_n, trD, dt)
    if not (rho1 > 0.0 and rho1 < math.inf):          # J = ρ_n/ρ_{n+1} > 0
        return ERR_DENSITY
    # deviator: Jaumann rotation, hypoelastic trial (eq. 13), JC radial return (eq. 14-20)
    sxx, syy, sxy, szz = deviator_of(S, i)
    sxx, syy, sxy = jaumann_rotate(sxx, syy, sxy, dt, 0.5 * (Lxy - Lyx))
    t3, g2dt = trD / 3.0, 2.0 * G * dt
    dxx, dyy = Lxx - t3, Lyy - t3                       # D′ = (dxx, dyy, Dxy, −t3)
    eq_rate = math.sqrt((2.0 / 3.0) * (dxx * dxx + dyy * dyy + 2.0 * Dxy * Dxy + t3 * t3))
    total_rate_star = eq_rate / prm[I_EPS0]
    seed = prm[I_SEED] != 0.0
    T_n = S[i, T]
    Tstar = (T_n - prm[I_TROOM]) / (prm[I_TMELT] - prm[I_TROOM])
    eps_p = S[i, EPS_P]
    if seed:
        rate_star = max(total_rate_star, SEED_RATE_STAR_FLOOR)
        nxx, nyy, nxy, nzz, dep, sy, code = jc_radial_return_fixed_rate(
            sxx + g2dt * dxx, syy + g2dt * dyy, sxy + g2dt * Dxy, szz - g2dt * t3, G,
            prm[I_JA], prm[I_JB], prm[I_JN], prm[I_JC], prm[I_JM], eps_p, Tstar, rate_star)
    else:
        nxx, nyy, nxy, nzz, dep, sy, code = jc_radial_return(
            sxx + g2dt * dxx, syy + g2dt * dyy, sxy + g2dt * Dxy, szz - g2dt * t3,
            G, dt, prm[I_JA], prm[I_JB], prm[I_JN], prm[I_JC], prm[I_JM], prm[I_EPS0], eps_p,
            Tstar)
        rate_star = max(dep * (1.0 / (dt * prm[I_EPS0])), 1.0)   # as the return computed it
    if code != OK:
        return code
    # energy (trapezoidal, implicit in E) and Mie-Gruneisen pressure at ρ_{n+1}
    v_n, v1 = rho0 / rho_n, rho0 / rho1
    w_dev = 0.25 * dt * (v_n + v1) * ((sxx + nxx) * Lxx + (syy + nyy) * Lyy
                                      + 2.0 * (sxy + nxy) * Dxy)
    f, g, dfdmu, code = mg_coefficients(rho0, prm[I_C], prm[I_S1], prm[I_S2], prm[I_S3],
                                        prm[I_G0], prm[I_A], rho1)
    if code != OK:
        return code
    E1, p1, ok = energy_update_linear_eos(S[i, E], S[i, P], q, v1 - v_n, w_dev, f, g)
    if not ok:
        return ERR_OTHER
    wp = sy * dep                                             # plastic work per current volume
    T1 = T_n if seed else T_n + prm[I_TQ] * wp / (rho1 * prm[I_CP])
    # the flow stress at the total rate: the seed's return already uses it
    sy_total = sy if seed else _flow_stress(prm, eps_p + dep, total_rate_star, Tstar)
    c2 = mg_bulk_sound_speed_sq(rho0, prm[I_C], prm[I_A], g, dfdmu, rho1, E1, p1)
    c = math.sqrt(c2 + 4.0 * G / (3.0 * rho1))
    pq = p1 + q
    if not (nxx + nyy + nxy + nzz + E1 + p1 + T1 + c + rho1 + sy + sy_total) * 0.0 == 0.0:
        return ERR_NONFINITE
    S[i, SXX], S[i, SYY], S[i, SXY], S[i, SZZ] = nxx - pq, nyy - pq, nxy, nzz - pq
    S[i, P], S[i, RHO], S[i, E] = p1, rho1, E1
    S[i, EPS_P] += dep
    S[i, EPS_P_RATE] = dep / dt
    S[i, T], S[i, SY], S[i, COL_C] = T1, sy, c
    S[i, PLASTIC_WORK] += wp * v1
    S[i, BURN] = 0.0
    S[i, T_RETURN], S[i, RATE_STAR], S[i, DT] = T_n, rate_star, dt
    S[i, EQ_STRAIN_RATE], S[i, SY_TOTAL_RATE] = eq_rate, sy_total
    return OK


# ------------------------------------------------------------------------------------------
# Analytic parameter derivatives (numpy, vectorised; docs/mpm_materials.md § 10)
# ------------------------------------------------------------------------------------------
# The seed's one-run Taylor method (000, eq. 22–35) differentiates the flow stress with
# respect to DIFFERENTIABLE_PARAMETERS = (A, B, C, n, m) while the particle's state
# (εp, ε̇*, T*) is held fixed. These are the derivatives of the kernels above: the ε̇* ≥ 1
# clamp, T* clipped to [0, 1] and Bεp^n = 0 at εp = 0 (where the printed seed formulas are
# wrong, and the limits kept here: docs/mpm_materials.md § "Constitutive sensitivities").
# States are arrays, parameters scalars or arrays that broadcast against them; value (N,),
# gradient (N, 5), Hessian (N, 5, 5) in DIFFERENTIABLE_PARAMETERS order. The value function
# also accepts complex parameters (the branches depend on the state only).

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
    grad = np.zeros(shape + (len(DIFFERENTIABLE_PARAMETERS),))
    grad[..., 0] = r * t
    grad[..., 1] = P * r * t
    grad[..., 2] = h * Lam * t
    grad[..., 3] = B * PL * r * t
    grad[..., 4] = -h * r * QL

    hess = np.zeros(shape + (len(DIFFERENTIABLE_PARAMETERS),) * 2)
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
    grad = np.zeros(shape + (len(DIFFERENTIABLE_PARAMETERS),))
    hess = np.zeros(shape + (len(DIFFERENTIABLE_PARAMETERS),) * 2)
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
