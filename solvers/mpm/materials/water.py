"""Water: Mie–Grüneisen EOS (seed eq. 10, LS-DYNA UNDEX set), no strength, cavitation cut-off.

p* = max(p_MG(ρ, E), p_cav), p_cav = ``cavitation_pressure`` (default −0.1 MPa). When the
cut-off is active the energy update uses p_cav as the end-of-step pressure (the work actually
done), so E is no longer on the EOS surface there — that is what a cut-off means.
σ = −(p* + q)·I; the deviator is zero.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .mie_gruneisen import eos_parameters, mg_bulk_sound_speed_sq, mg_coefficients
from .parameters import ParameterSpec, defaults
from .state import (C as COL_C, E, ERR_DENSITY, ERR_NONFINITE, ERR_OTHER, OK, P, Q, RHO, SXX, SXY,
                    SYY, SZZ, check_update, density_update, energy_update_linear_eos,
                    pack_parameters, require, reset_row)

NAME = "mie_gruneisen_fluid"
HAS_STRENGTH = False
#: ``advance`` writes no non-finite value: it returns ERR_NONFINITE instead, the core's Q
#: included, so the water loop skips the core's whole-row state check (step.py, issue 19)
ADVANCE_CHECKS_ITS_WRITES = True

PARAMETER_SPECS = (
    *eos_parameters(C=1480.0, S1=2.56, S2=-1.986, S3=0.2268, gamma0=0.4934, a=1.3937),
    ParameterSpec("rho0", 1000.0, "kg m-3", "reference density"),
    ParameterSpec("cavitation_pressure", -0.1e6, "Pa", "pressure cut-off (cavitation)"),
)
PARAMETERS = defaults(PARAMETER_SPECS)
NPRM = len(PARAMETERS)
I_C, I_S1, I_S2, I_S3, I_G0, I_A, I_RHO0, I_PCAV = range(NPRM)


def pack(values: dict | None = None) -> np.ndarray:
    """Parameter vector in PARAMETERS order (missing names take the water defaults)."""
    prm = pack_parameters(PARAMETERS, values, NAME)
    check(prm)
    return prm


def check(prm: np.ndarray) -> None:
    require(NAME, prm, list(PARAMETERS),
            [("eos.C", lambda v: v > 0, "> 0"), ("rho0", lambda v: v > 0, "> 0"),
             ("cavitation_pressure", lambda v: v <= 0, "<= 0")])


@njit(cache=True, fastmath=False)
def init(prm, S, i):
    """Reference state: ρ0, E = 0, p = 0, C = eos.C."""
    code = reset_row(prm, NPRM, S, i)
    if code != OK:
        return code
    S[i, RHO] = prm[I_RHO0]
    S[i, COL_C] = prm[I_C]
    return OK


@njit(cache=True, fastmath=False)
def update(prm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y):
    """The guards (``check_update``), then ``advance``. Returns a code."""
    code = check_update(prm, NPRM, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y)
    if code != OK:
        return code
    return advance(prm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y)


@njit(cache=True, fastmath=False, inline="always")
def advance(prm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y):
    """Continuity, energy-consistent MG pressure with cut-off, σ = −(p + q) I.

    Unguarded: for callers that have made ``check_update``'s checks cheaper in bulk (the
    solver's loops, step.py). Every value it writes is checked finite first, q among them
    (``ADVANCE_CHECKS_ITS_WRITES``)."""
    rho0, q, rho_n = prm[I_RHO0], S[i, Q], S[i, RHO]
    rho1 = density_update(rho_n, Lxx + Lyy, dt)
    if not (rho1 > 0.0 and rho1 < math.inf):          # J = ρ_n/ρ_{n+1} > 0
        return ERR_DENSITY
    f, g, dfdmu, code = mg_coefficients(rho0, prm[I_C], prm[I_S1], prm[I_S2], prm[I_S3],
                                        prm[I_G0], prm[I_A], rho1)
    if code != OK:
        return code
    dv = rho0 / rho1 - rho0 / rho_n
    E1, p1, ok = energy_update_linear_eos(S[i, E], S[i, P], q, dv, 0.0, f, g)
    if not ok:
        return ERR_OTHER
    pcav = prm[I_PCAV]
    if p1 < pcav:                                  # cavitation cut-off
        p1 = pcav
        E1 = S[i, E] - (0.5 * (S[i, P] + p1) + q) * dv
    c = math.sqrt(mg_bulk_sound_speed_sq(rho0, prm[I_C], prm[I_A], g, dfdmu, rho1, E1, p1))
    if not (E1 + p1 + c + rho1 + q) * 0.0 == 0.0:
        return ERR_NONFINITE
    pq = p1 + q
    S[i, SXX], S[i, SYY], S[i, SXY], S[i, SZZ] = -pq, -pq, 0.0, -pq
    S[i, P], S[i, RHO], S[i, E], S[i, COL_C] = p1, rho1, E1, c
    return OK
