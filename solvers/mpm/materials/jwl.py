"""High explosive: JWL products EOS with programmed burn (TNT, Dobratz & Crawford 1985).

JWL (E per unit reference volume, V = ρ0/ρ):

    p_JWL = A (1 − ω/(R1 V)) e^{−R1 V} + B (1 − ω/(R2 V)) e^{−R2 V} + ω E / V.

Programmed burn (Wilkins ramp): lighting time t_l = |x − x_det| / D with the detonation point
("det_x", "det_y", set by the core from the scene) and

    F = clamp((t − t_l) D / w, 0, 1),   w = "burn_width" (the core should set w = β Δx, β ≈ 1.5;
                                         w ≤ 0 gives a step at t_l),

evaluated at the END of the step (t = time + dt), never decreasing (F = max(F_n, F)).
p = F · p_JWL(ρ, E); E starts at E0 (chemical energy) and follows the same trapezoidal,
implicit-in-E update as the Mie–Grüneisen materials. No strength: σ = −(p + q) I.
Wave speed for the CFL step: D while F < 1 (docs/design/mpm.md), the JWL isentropic sound
speed once fully burnt.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .parameters import ParameterSpec, defaults
from .state import (BURN, C as COL_C, E, ERR_DENSITY, ERR_NONFINITE, ERR_OTHER, OK, P, Q, RHO,
                    SXX, SXY, SYY, SZZ, check_update, density_update, energy_update_linear_eos,
                    pack_parameters, require, reset_row)

NAME = "jwl_programmed_burn"
HAS_STRENGTH = False
# parameter holding the chemical energy per unit reference volume: the core reports
# Σ BURN · E0 · V0 as the energy the burn has released (probes.py, "explosive_release")
CHEMICAL_ENERGY = "eos.E0"

PARAMETER_SPECS = (
    ParameterSpec("rho0", 1630.0, "kg m-3", "reference density"),
    ParameterSpec("D", 6930.0, "m s-1", "detonation speed"),
    ParameterSpec("eos.A", 371.2e9, "Pa", "JWL coefficient A"),
    ParameterSpec("eos.B", 3.231e9, "Pa", "JWL coefficient B"),
    ParameterSpec("eos.R1", 4.15, "", "JWL exponent R1"),
    ParameterSpec("eos.R2", 0.95, "", "JWL exponent R2"),
    ParameterSpec("eos.omega", 0.30, "", "JWL Grüneisen coefficient ω"),
    ParameterSpec("eos.E0", 7.0e9, "J m-3", "chemical energy per unit reference volume"),
    ParameterSpec("det_x", 0.0, "m", "detonation point x (set by the core from the scene)"),
    ParameterSpec("det_y", 0.0, "m", "detonation point y (set by the core from the scene)"),
    ParameterSpec("burn_width", 0.0075, "m",
                  "programmed-burn ramp width β Δx (β = 1.5, Δx = 5 mm; the core sets it)"),
)
PARAMETERS = defaults(PARAMETER_SPECS)
NPRM = len(PARAMETERS)
I_RHO0, I_D, I_A, I_B, I_R1, I_R2, I_OM, I_E0, I_DETX, I_DETY, I_W = range(NPRM)


def pack(values: dict | None = None) -> np.ndarray:
    """Parameter vector in PARAMETERS order (missing names take the TNT defaults)."""
    prm = pack_parameters(PARAMETERS, values, NAME)
    check(prm)
    return prm


def check(prm: np.ndarray) -> None:
    pos = (lambda v: v > 0, "> 0")
    require(NAME, prm, list(PARAMETERS),
            [(k, *pos) for k in ("rho0", "D", "eos.R1", "eos.R2", "eos.omega")]
            + [(k, lambda v: v >= 0, ">= 0") for k in ("eos.A", "eos.B", "eos.E0")])


@njit(cache=True, fastmath=False)
def jwl_coefficients(A, B, R1, R2, omega, V):
    """(f, g, df/dV) with p_JWL = f(V) + g(V) E, g = ω/V."""
    e1, e2 = math.exp(-R1 * V), math.exp(-R2 * V)
    f = A * (1.0 - omega / (R1 * V)) * e1 + B * (1.0 - omega / (R2 * V)) * e2
    dfdV = (A * e1 * (omega / (R1 * V * V) - R1 + omega / V)
            + B * e2 * (omega / (R2 * V * V) - R2 + omega / V))
    return f, omega / V, dfdV


@njit(cache=True, fastmath=False)
def jwl_pressure(A, B, R1, R2, omega, V, E):
    """Fully burnt JWL pressure at relative volume V = ρ0/ρ and E (J/m³ of reference volume)."""
    f, g, _ = jwl_coefficients(A, B, R1, R2, omega, V)
    return f + g * E


@njit(cache=True, fastmath=False)
def jwl_sound_speed_sq(A, B, R1, R2, omega, V, E, rho):
    """c² = dp/dρ|_s of the products: with dE = −p dV on an isentrope and dV/dρ = −V/ρ,
    c² = (V/ρ)(g p − f'(V) + ω E / V²), floored at 0."""
    f, g, dfdV = jwl_coefficients(A, B, R1, R2, omega, V)
    p = f + g * E
    c2 = (V / rho) * (g * p - dfdV + omega * E / (V * V))
    return c2 if c2 > 0.0 else 0.0


@njit(cache=True, fastmath=False)
def burn_fraction(D, det_x, det_y, width, t, x, y):
    """Programmed-burn fraction at time t and position (x, y) (Wilkins ramp, step if w ≤ 0)."""
    dx, dy = x - det_x, y - det_y
    tl = math.sqrt(dx * dx + dy * dy) / D
    if width > 0.0:
        F = (t - tl) * D / width
    else:
        F = 1.0 if t >= tl else 0.0
    if F < 0.0:
        return 0.0
    if F > 1.0:
        return 1.0
    return F


@njit(cache=True, fastmath=False)
def init(prm, S, i):
    """Unburnt explosive: ρ0, E = E0, F = 0, p = 0, C = D."""
    code = reset_row(prm, NPRM, S, i)
    if code != OK:
        return code
    S[i, RHO] = prm[I_RHO0]
    S[i, E] = prm[I_E0]
    S[i, COL_C] = prm[I_D]
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
    """Burn fraction at time + dt, continuity, p = F p_JWL with the trapezoidal energy update.

    Unguarded: for callers that have made ``check_update``'s checks cheaper in bulk (the
    solver's loops, step.py)."""
    rho0, D, q, rho_n = prm[I_RHO0], prm[I_D], S[i, Q], S[i, RHO]
    F = burn_fraction(D, prm[I_DETX], prm[I_DETY], prm[I_W], time + dt, x, y)
    if S[i, BURN] > F:
        F = S[i, BURN]
    rho1 = density_update(rho_n, Lxx + Lyy, dt)
    if not (rho1 > 0.0 and rho1 < math.inf):          # J = ρ_n/ρ_{n+1} > 0
        return ERR_DENSITY
    V1 = rho0 / rho1
    A, B, R1, R2, om = prm[I_A], prm[I_B], prm[I_R1], prm[I_R2], prm[I_OM]
    f, g, _ = jwl_coefficients(A, B, R1, R2, om, V1)
    E1, p1, ok = energy_update_linear_eos(S[i, E], S[i, P], q, V1 - rho0 / rho_n, 0.0,
                                          F * f, F * g)
    if not ok:
        return ERR_OTHER
    c = D
    if F >= 1.0:
        c = math.sqrt(jwl_sound_speed_sq(A, B, R1, R2, om, V1, E1, rho1))
    if not (E1 + p1 + c + rho1) * 0.0 == 0.0:
        return ERR_NONFINITE
    pq = p1 + q
    S[i, SXX], S[i, SYY], S[i, SXY], S[i, SZZ] = -pq, -pq, 0.0, -pq
    S[i, P], S[i, RHO], S[i, E], S[i, BURN], S[i, COL_C] = p1, rho1, E1, F, c
    return OK
