"""Mie–Grüneisen equation of state, seed eq. (10) = LS-DYNA *EOS_GRUNEISEN (E per unit
reference volume). Helpers only; the materials are ``johnson_cook`` (steel) and ``water``.

μ = ρ/ρ0 − 1, and p* = f(μ) + g(μ)·E with g = γ0 + a μ in both branches:

* compression (μ > 0):  f = ρ0 C² μ [1 + (1 − γ0/2) μ − (a/2) μ²] / den²,
  den = 1 − (S1 − 1) μ − S2 μ²/(μ + 1) − S3 μ³/(μ + 1)²;
* tension (μ ≤ 0):      f = ρ0 C² μ.

Both give p* = γ0 E at μ = 0 (continuous). With S2 = S3 = 0 the compression branch reproduces
the linear U_s = C + S1 u_p Hugoniot exactly when E is the Hugoniot energy ½ p (1 − ρ0/ρ).
"""

from __future__ import annotations

from numba import njit

from .parameters import ParameterSpec
from .state import ERR_MG_DENOMINATOR, MG_DEN_MIN, OK

# the EOS parameters with a one-run Taylor derivative (sensitivities.py), in its order
DIFFERENTIABLE_PARAMETERS = ("eos.S1", "eos.S2", "eos.S3", "eos.gamma0", "eos.a")


def eos_parameters(C, S1, S2, S3, gamma0, a):
    """The EOS's parameter specs, first in the packed vector of every material that uses it,
    with that material's defaults."""
    return (ParameterSpec("eos.C", C, "m s-1", "bulk sound speed (U_s = C + S1 u_p)"),
            ParameterSpec("eos.S1", S1, "", "linear Hugoniot slope S1"),
            ParameterSpec("eos.S2", S2, "", "quadratic Hugoniot coefficient S2"),
            ParameterSpec("eos.S3", S3, "", "cubic Hugoniot coefficient S3"),
            ParameterSpec("eos.gamma0", gamma0, "", "Grüneisen coefficient γ0"),
            ParameterSpec("eos.a", a, "", "first-order volume correction a of γ"))


@njit(cache=True, fastmath=False)
def mg_denominator(S1, S2, S3, mu):
    """den(μ) = 1 − (S1−1)μ − S2 μ²/(μ+1) − S3 μ³/(μ+1)² of the compression branch."""
    mp1 = mu + 1.0
    return 1.0 - (S1 - 1.0) * mu - S2 * mu * mu / mp1 - S3 * mu * mu * mu / (mp1 * mp1)


@njit(cache=True, fastmath=False)
def mg_coefficients(rho0, C, S1, S2, S3, gamma0, a, rho):
    """(f, g, df/dμ, code) with p* = f + g E at density ρ (code ERR_MG_DENOMINATOR when the
    compression denominator is ≤ MG_DEN_MIN, i.e. near or past the pole of the Hugoniot)."""
    mu = rho / rho0 - 1.0
    k = rho0 * C * C
    g = gamma0 + a * mu
    if mu <= 0.0:
        return k * mu, g, k, OK
    mp1 = mu + 1.0
    den = mg_denominator(S1, S2, S3, mu)
    if not den > MG_DEN_MIN:
        return 0.0, g, 0.0, ERR_MG_DENOMINATOR
    num = 1.0 + (1.0 - 0.5 * gamma0) * mu - 0.5 * a * mu * mu
    dnum = (1.0 - 0.5 * gamma0) - a * mu
    dden = (-(S1 - 1.0) - S2 * mu * (mu + 2.0) / (mp1 * mp1)
            - S3 * mu * mu * (mu + 3.0) / (mp1 * mp1 * mp1))
    d2 = den * den
    f = k * mu * num / d2
    dfdmu = k * ((num + mu * dnum) / d2 - 2.0 * mu * num * dden / (d2 * den))
    return f, g, dfdmu, OK


@njit(cache=True, fastmath=False)
def mie_gruneisen_pressure(rho0, C, S1, S2, S3, gamma0, a, rho, E):
    """(p*, code): seed eq. (10) pressure at density ρ and energy E (J per m³ of reference
    volume)."""
    f, g, _, code = mg_coefficients(rho0, C, S1, S2, S3, gamma0, a, rho)
    return f + g * E, code


@njit(cache=True, fastmath=False)
def mg_bulk_sound_speed_sq(rho0, C, a, g, dfdmu, rho, E, p):
    """Isentropic bulk sound speed squared, c² = dp/dρ|_s:

    c² = (df/dμ + a E)/ρ0 + g ρ0 p/ρ²   (de = p dρ/ρ² along an isentrope, E = ρ0 e, g = γ0 + aμ),

    floored at 1e-4 C² (deep tension can make c² ≤ 0; the value only feeds the CFL step).
    """
    c2 = (dfdmu + a * E) / rho0 + g * rho0 * p / (rho * rho)
    floor = 1e-4 * C * C
    if not c2 > floor:
        c2 = floor
    return c2
