"""Linear isotropic hypoelastic material with the Jaumann rate (verification problems:
vibrating bar, colliding disks), plane strain.

σ^∇ = λ tr(D) I + 2G D, split as  s^∇ = 2G D'  and  ṗ = −K tr(D)  (K = λ + 2G/3),
G = E/(2(1+ν)), K = E/(3(1−2ν)). The deviator is rotated by the Hughes–Winget form of the
Jaumann spin, then incremented; p_{n+1} = p_n − K tr(D) Δt. E (per reference volume) gets the
trapezoidal stress work ½(σ_n + σ_{n+1}):D Δt (with −q tr D), so from a stress-free start it
is the stored strain energy plus the viscous dissipation.

Defaults: small-strain constants consistent with the 4340 data (K = ρ0 C² = 163.5 GPa,
G = 81.8 GPa → E = 210 GPa, ν = 0.286); verification scenes set their own.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .parameters import ParameterSpec, defaults
from .state import (C as COL_C, E as COL_E, ERR_DENSITY, ERR_NONFINITE, OK, P, Q, RHO, SXX, SXY,
                    SYY, SZZ, check_update, density_update, deviator_of, jaumann_rotate,
                    pack_parameters, require, reset_row)

NAME = "hypoelastic"
HAS_STRENGTH = True          # it carries a deviator (but never yields)

PARAMETER_SPECS = (
    ParameterSpec("rho0", 7830.0, "kg m-3", "reference density"),
    ParameterSpec("E", 210e9, "Pa", "Young's modulus"),
    ParameterSpec("nu", 0.286, "", "Poisson's ratio"),
)
PARAMETERS = defaults(PARAMETER_SPECS)
NPRM = len(PARAMETERS)
I_RHO0, I_E, I_NU = range(NPRM)


def pack(values: dict | None = None) -> np.ndarray:
    """Parameter vector in PARAMETERS order."""
    prm = pack_parameters(PARAMETERS, values, NAME)
    check(prm)
    return prm


def check(prm: np.ndarray) -> None:
    require(NAME, prm, list(PARAMETERS),
            [("rho0", lambda v: v > 0, "> 0"), ("E", lambda v: v > 0, "> 0"),
             ("nu", lambda v: -1.0 < v < 0.5, "in (-1, 0.5)")])


@njit(cache=True, fastmath=False)
def moduli(Y, nu):
    """(G, K) from Young's modulus and Poisson's ratio."""
    return Y / (2.0 * (1.0 + nu)), Y / (3.0 * (1.0 - 2.0 * nu))


@njit(cache=True, fastmath=False)
def init(prm, S, i):
    """Stress-free reference state; C = longitudinal (P-wave) speed."""
    code = reset_row(prm, NPRM, S, i)
    if code != OK:
        return code
    G, K = moduli(prm[I_E], prm[I_NU])
    S[i, RHO] = prm[I_RHO0]
    S[i, COL_C] = math.sqrt((K + 4.0 * G / 3.0) / prm[I_RHO0])
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
    """Jaumann-rate hypoelastic update of particle i; returns a code.

    Unguarded: for callers that have made ``check_update``'s checks cheaper in bulk (the
    solver's loops, step.py)."""
    rho0, q, rho_n = prm[I_RHO0], S[i, Q], S[i, RHO]
    G, K = moduli(prm[I_E], prm[I_NU])
    trD, Dxy = Lxx + Lyy, 0.5 * (Lxy + Lyx)
    rho1 = density_update(rho_n, trD, dt)
    if not (rho1 > 0.0 and rho1 < math.inf):          # J = ρ_n/ρ_{n+1} > 0
        return ERR_DENSITY
    sxx, syy, sxy, szz = deviator_of(S, i)
    sxx, syy, sxy = jaumann_rotate(sxx, syy, sxy, dt, 0.5 * (Lxy - Lyx))
    t3, g2dt = trD / 3.0, 2.0 * G * dt
    nxx, nyy, nxy, nzz = (sxx + g2dt * (Lxx - t3), syy + g2dt * (Lyy - t3), sxy + g2dt * Dxy,
                          szz - g2dt * t3)
    p_n = S[i, P]
    p1 = p_n - K * trD * dt
    v_n, v1 = rho0 / rho_n, rho0 / rho1
    w_dev = 0.25 * dt * (v_n + v1) * ((sxx + nxx) * Lxx + (syy + nyy) * Lyy
                                      + 2.0 * (sxy + nxy) * Dxy)
    E1 = S[i, COL_E] + w_dev - (0.5 * (p_n + p1) + q) * (v1 - v_n)
    c = math.sqrt((K + 4.0 * G / 3.0) / rho1)
    if not (nxx + nyy + nxy + nzz + p1 + E1 + c + rho1) * 0.0 == 0.0:
        return ERR_NONFINITE
    pq = p1 + q
    S[i, SXX], S[i, SYY], S[i, SXY], S[i, SZZ] = nxx - pq, nyy - pq, nxy, nzz - pq
    S[i, P], S[i, RHO], S[i, COL_E], S[i, COL_C] = p1, rho1, E1, c
    return OK
