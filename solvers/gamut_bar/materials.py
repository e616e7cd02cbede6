"""Materials of seed 002 (sec. 4.2), Ramberg–Osgood, the modulus of softness R (eq. 17/18) and
the calibration of the slip (critical) strains of the bond families.

Everything here is a property of the *equivalent-isotropic material*; the bar's curve is never
evaluated from these formulas — they only set the bonds' parameters (docs/gamut_bar.md §4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Seed sec. 4.2 (SI). eps_y = sigma_y/E + K_ro is derived, nu is unused in 1-D.
MATERIALS = {
    "M1": {"E": 71.6e9, "sigma_f": 665.8e6, "eps_f": 0.115, "sigma_y": 538.6e6,
           "n_ro": 17.8702, "K_ro": 0.002, "rho": 2810.0, "nu": 0.33},
    "M2": {"E": 115.7e9, "sigma_f": 933e6, "eps_f": 0.516, "sigma_y": 867e6,
           "n_ro": 47.61, "K_ro": 0.002, "rho": 4430.0, "nu": 0.31},
}


def ro_strain(sigma, E, sigma_y, n_ro, K_ro):
    """Ramberg–Osgood: ε = σ/E + K_ro (σ/σ_y)^n_ro (odd in σ)."""
    s = np.asarray(sigma, dtype=float)
    return s / E + np.sign(s) * K_ro * (np.abs(s) / sigma_y) ** n_ro


def ro_stress(eps, E, sigma_y, n_ro, K_ro):
    """Inverse of ``ro_strain`` for one strain ε ≥ 0, by bisection to machine precision (used
    for the calibration, figures and tests — never for the bar's curve)."""
    eps = float(eps)
    if eps <= 0.0:
        return 0.0
    lo, hi = 0.0, min(E * eps, sigma_y * (eps / K_ro) ** (1.0 / n_ro))
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if ro_strain(mid, E, sigma_y, n_ro, K_ro) > eps:
            hi = mid
        else:
            lo = mid
        if hi - lo <= 1e-15 * hi:
            break
    return 0.5 * (lo + hi)


def ro_tangent_ratio(sigma, E, sigma_y, n_ro, K_ro):
    """E_t/E of Ramberg–Osgood at stress σ ≥ 0: 1 / (1 + E K n/σ_y (σ/σ_y)^(n−1))."""
    return 1.0 / (1.0 + E * K_ro * n_ro / sigma_y * (sigma / sigma_y) ** (n_ro - 1.0))


def modulus_of_softness(E, sigma_f, eps_f, sigma_y, n_ro, K_ro):
    """R = U_S/(U_S + U_T) of seed eq. 17/18 (Material 1: 0.8514)."""
    brittle = 0.5 * E * eps_f**2
    u_s = (brittle - sigma_f * eps_f + sigma_f**2 / (2.0 * E)
           + K_ro * sigma_y / (n_ro + 1.0) * (sigma_f / sigma_y) ** (n_ro + 1.0))
    return u_s / brittle


def material_problem(p):
    """First inconsistency of a property set as (key, reason), or None; and R of eq. 17."""
    for key in ("E", "sigma_y", "sigma_f", "eps_f", "K_ro", "rho", "area", "length"):
        if not p[key] > 0:
            return (key, f"must be > 0, got {p[key]!r}"), None
    if not p["n_ro"] > 1:
        return ("n_ro", f"must be > 1, got {p['n_ro']!r}"), None
    if p["sigma_f"] < p["sigma_y"]:
        return ("sigma_f", f"failure stress {p['sigma_f']:g} Pa is below the yield stress "
                           f"{p['sigma_y']:g} Pa"), None
    eps_y = p["sigma_y"] / p["E"] + p["K_ro"]
    if p["eps_f"] < eps_y:
        return ("eps_f", f"failure strain {p['eps_f']:g} is below the yield strain "
                         f"sigma_y/E + K_ro = {eps_y:g}"), None
    try:
        R = modulus_of_softness(p["E"], p["sigma_f"], p["eps_f"], p["sigma_y"], p["n_ro"],
                                p["K_ro"])
    except OverflowError:
        return overflow_problem(p), None
    if not 0.0 < R < 1.0:
        return ("eps_f", f"modulus of softness R (eq. 17) = {R:.4g} is not in (0, 1): the "
                         f"properties do not describe a hardening, ductile material"), None
    return None, R


def overflow_problem(p):
    """(key, reason) for properties whose energies overflow float64 (a Python float power
    raises): the Ramberg–Osgood term (sigma_f/sigma_y)^(n_ro + 1) if that is what overflows,
    else the largest property."""
    if (p["n_ro"] + 1.0) * math.log(p["sigma_f"] / p["sigma_y"]) > 700.0:
        return ("n_ro", f"(sigma_f/sigma_y)^(n_ro + 1) overflows a float64 with n_ro = "
                        f"{p['n_ro']:g}")
    key = max(("E", "sigma_y", "sigma_f", "eps_f", "K_ro"), key=lambda k: abs(p[k]))
    return (key, f"the material's strain energies overflow a float64 with {key} = {p[key]:g}")


def family_weights(sigma_stdev, cutoff):
    """Nominal one-sided weights w̄_m of the families m = 2..M on the uniform interior
    (Gaussian eq. 22 in m spacings, normalised to 1 — eq. 13 one-sided)."""
    M = int(math.floor(cutoff * sigma_stdev + 1e-9))
    m = np.arange(2, M + 1, dtype=float)
    y = np.exp(-m * m / (2.0 * sigma_stdev**2))
    return y / y.sum()


@dataclass(frozen=True)
class Calibration:
    """Critical strains of the slip elements of the equivalent-isotropic bar.

    ``eps_local``: the local bond's slipping share; ``eps_family[m-2]``: family m (nonlocal bonds
    of degree m and the local sub-elements standing in for them); the hardening share
    ``hardening`` (a fraction of E) never slips.
    """

    R: float
    hardening: float
    eps_local: float
    eps_family: np.ndarray
    match_strains: np.ndarray      # e_j: where the staircase equals Ramberg–Osgood
    weights: np.ndarray            # w̄_m


def calibrate(E, sigma_y, n_ro, K_ro, eps_f, R, weights) -> Calibration:
    """Critical strains so that the homogeneous bar's staircase equals Ramberg–Osgood.

    Shares in slip order: the local share (1 − R − h), the nonlocal families R·w̄_m by
    decreasing weight, and a hardening share h = E_t(ε_f)/E that never slips. With cumulative
    shares S_j, e_j is the RO strain where E_t/E = 1 − S_j and
    ε_c,j = (σ_RO(e_j)/E − Σ_{k<j} s_k ε_c,k − (1 − S_j) e_j) / s_j (it lies in [e_{j−1}, e_j]):
    the staircase stress equals the RO stress at every e_j, and at e_last = ε_f.
    """
    sig_f = ro_stress(eps_f, E, sigma_y, n_ro, K_ro)
    h = min(ro_tangent_ratio(sig_f, E, sigma_y, n_ro, K_ro), 0.5 * (1.0 - R))
    shares = np.concatenate([[1.0 - R - h], R * np.asarray(weights, dtype=float)])
    S = np.cumsum(shares)
    eps_c = np.empty(shares.size)
    e = np.empty(shares.size)
    acc = 0.0
    for j, s in enumerate(shares):
        t = max(1.0 - S[j], h)                 # unslipped share after slip j
        # RO stress where E_t/E = t:  (σ/σ_y)^(n−1) = (1/t − 1) σ_y / (E K n)
        sig = sigma_y * ((1.0 / t - 1.0) * sigma_y / (E * K_ro * n_ro)) ** (1.0 / (n_ro - 1.0))
        e[j] = float(ro_strain(sig, E, sigma_y, n_ro, K_ro))
        eps_c[j] = (sig / E - acc - t * e[j]) / s
        acc += s * eps_c[j]
    return Calibration(R=R, hardening=h, eps_local=float(eps_c[0]), eps_family=eps_c[1:].copy(),
                       match_strains=e, weights=np.asarray(weights, dtype=float))


def staircase_stress(eps, cal: Calibration, E):
    """Stress of the ideal homogeneous network under monotonic uniform strain (for docs/tests;
    the solver never uses it)."""
    eps = np.asarray(eps, dtype=float)[..., None]
    shares = np.concatenate([[1.0 - cal.R - cal.hardening], cal.R * cal.weights])
    ec = np.concatenate([[cal.eps_local], cal.eps_family])
    return E * (np.sum(shares * np.minimum(eps, ec), axis=-1) + cal.hardening * eps[..., 0])
