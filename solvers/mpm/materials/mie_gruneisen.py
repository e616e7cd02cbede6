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

import numpy as np
from numba import njit

from .parameters import ParameterSpec
from .state import ERR_MG_DENOMINATOR, MG_DEN_MIN, OK

# the EOS parameters with analytic derivatives (below), in their gradients' order
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


@njit(cache=True, fastmath=False, forceinline=True)
def mg_denominator(S1, S2, S3, mu):
    """den(μ) = 1 − (S1−1)μ − S2 μ²/(μ+1) − S3 μ³/(μ+1)² of the compression branch."""
    mp1 = mu + 1.0
    return 1.0 - (S1 - 1.0) * mu - S2 * mu * mu / mp1 - S3 * mu * mu * mu / (mp1 * mp1)


@njit(cache=True, fastmath=False, forceinline=True)
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


@njit(cache=True, fastmath=False, forceinline=True)
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


# ------------------------------------------------------------------------------------------
# Analytic parameter derivatives (numpy, vectorised; docs/mpm_materials.md § 10)
# ------------------------------------------------------------------------------------------
# The seed's one-run Taylor method (000, eq. 22–35) differentiates the pressure with respect
# to DIFFERENTIABLE_PARAMETERS = (S1, S2, S3, γ0, a) at a frozen state (μ, E). These are the
# derivatives of the formulas above (the tension branch for μ ≤ 0 included). States are
# arrays, parameters scalars or arrays that broadcast against them; value (N,), gradient
# (N, 5), Hessian (N, 5, 5) in DIFFERENTIABLE_PARAMETERS order. The value function also
# accepts complex parameters (the branch depends on the state only): complex-step
# differentiation applies to it.

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
    grad = np.zeros(shape + (len(DIFFERENTIABLE_PARAMETERS),))
    hess = np.zeros(shape + (len(DIFFERENTIABLE_PARAMETERS),) * 2)
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
