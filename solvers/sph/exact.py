"""Closed forms the SPH solver is checked against (docs/sph.md § 8, "Exact references").

1. A circular inclusion of radius R with a uniform dilatational eigenstrain eps* in an
   infinite matrix (seed Example 1). The Lamé solution u_r = C r inside and C R²/r outside
   (both equilibrated: u_r = A r + B/r is the general radially symmetric field, bounded at the
   centre and at infinity), with C fixed by the continuity of sigma_rr at R:
   inside  sigma_rr = 2 (lam_i + mu_i) C - s*,  s* the eigen-stress of the variant;
   outside sigma_rr = -2 mu_m C.
   - plane strain, in-plane eigenstrain eps*·I2:  s* = 2 (lam_i + mu_i) eps*
         C = (lam_i + mu_i) eps* / (lam_i + mu_i + mu_m)
   - plane strain, 3-D dilatation (eps*_zz = eps* too):  s* = (3 lam_i + 2 mu_i) eps*
         C = 3 K_i eps* / (2 (lam_i + mu_i + mu_m)),  K_i = lam_i + 2 mu_i / 3
   - plane stress:  in-plane (lam*, mu) with lam* = 2 lam mu / (lam + 2 mu), s* = 2 K_i eps*
         C = K_i eps* / (K_i + mu_m),  K_i = lam*_i + mu_i = E_i / (2 (1 - nu_i))
2. Hashin–Shtrikman bounds of a two-phase isotropic 2-D composite in Walpole's form
   (Walpole 1966; Torquato, Random Heterogeneous Materials, 2002, eq. 21.x for d = 2):
   kappa_± = [sum_i f_i / (kappa_i + mu_ref)]^-1 - mu_ref, mu_ref = max / min mu_i;
   mu_± = [sum_i f_i / (mu_i + z)]^-1 - z, z = mu k / (k + 2 mu) at (max k, max mu) / (min, min);
   and the in-plane Young's modulus E_2D = 4 kappa mu / (kappa + mu), monotone in both.
   They bound the *effective* modulus of a statistically isotropic composite, not the apparent
   modulus of one finite window (docs/sph.md § 8).
3. Voigt–Reuss bounds of one window's apparent modulus under the solver's tension test (u_y
   prescribed on top and bottom, no shear traction there, free sides):
   E_Reuss = 1 / <S_yy>,  S_yy = C11 / (C11² - C12²)  (plane strain: (1 - nu²)/E),
   E_Voigt = <C11> - <C12>² / <C11>,  C11 = lam + 2 mu, C12 = lam (in-plane Lamé constants),
   <.> the area average. The uniform uniaxial stress is statically admissible (complementary
   energy: Reuss below), the uniform strain (eps_xx chosen best) kinematically admissible
   (potential energy: Voigt above), for every arrangement of the phases.
"""

from __future__ import annotations

import numpy as np

from solvers.sph.stiffness import lame

VARIANTS = ("plane_strain", "plane_strain_3d", "plane_stress")


def eshelby_constant(eigenstrain, E_inclusion, nu_inclusion, E_matrix, nu_matrix,
                     variant="plane_strain") -> float:
    """C of u_r = C r inside (C R²/r outside)."""
    state = "plane_stress" if variant == "plane_stress" else "plane_strain"
    lam_i, mu_i = lame(E_inclusion, nu_inclusion, state)
    _, mu_m = lame(E_matrix, nu_matrix, state)
    if variant == "plane_strain":
        return float((lam_i + mu_i) * eigenstrain / (lam_i + mu_i + mu_m))
    if variant == "plane_strain_3d":
        K3 = lam_i + 2.0 * mu_i / 3.0
        return float(3.0 * K3 * eigenstrain / (2.0 * (lam_i + mu_i + mu_m)))
    if variant == "plane_stress":
        K2 = lam_i + mu_i
        return float(K2 * eigenstrain / (K2 + mu_m))
    raise ValueError(f"unknown variant {variant!r} (known: {', '.join(VARIANTS)})")


def eshelby_radial(r, radius, C):
    """u_r, eps_rr, eps_tt at radii ``r`` (inside: C, C, C; outside: C R²/r, -C R²/r², C R²/r²)."""
    r = np.asarray(r, dtype=float)
    inside = r <= radius
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(inside, 1.0, radius * radius / np.where(r > 0, r * r, 1.0))
    return C * r * ratio, np.where(inside, C, -C * ratio), C * ratio


def eshelby_displacement(points, radius, centre=(0.0, 0.0), *, eigenstrain, E_inclusion,
                         nu_inclusion, E_matrix, nu_matrix, variant="plane_strain"):
    """Cartesian displacement (n, 2) of the exact solution at ``points``."""
    C = eshelby_constant(eigenstrain, E_inclusion, nu_inclusion, E_matrix, nu_matrix, variant)
    p = np.asarray(points, dtype=float).reshape(-1, 2) - np.asarray(centre, dtype=float)
    r = np.hypot(p[:, 0], p[:, 1])
    ur = eshelby_radial(r, radius, C)[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(r > 0, ur / np.where(r > 0, r, 1.0), 0.0)
    return p * scale[:, None]


def bulk_2d(E, nu, state="plane_strain"):
    """The 2-D bulk modulus kappa = lam + mu of the in-plane law (plane stress: E/(2(1-nu)))."""
    lam, mu = lame(E, nu, state)
    return lam + mu, mu


def hashin_shtrikman_2d(fraction, E_inclusion, nu_inclusion, E_matrix, nu_matrix,
                        state="plane_strain"):
    """(lower, upper) bounds of kappa, mu and E_2D for inclusion area ``fraction``."""
    f = np.asarray(fraction, dtype=float)
    k_i, m_i = bulk_2d(E_inclusion, nu_inclusion, state)
    k_m, m_m = bulk_2d(E_matrix, nu_matrix, state)
    k, m, w = np.array([k_m, k_i]), np.array([m_m, m_i]), np.stack([1.0 - f, f])

    def kappa(ref):
        return 1.0 / (w[0] / (k[0] + ref) + w[1] / (k[1] + ref)) - ref

    def shear(kr, mr):
        z = mr * kr / (kr + 2.0 * mr)
        return 1.0 / (w[0] / (m[0] + z) + w[1] / (m[1] + z)) - z
    k_lo, k_hi = kappa(m.min()), kappa(m.max())
    m_lo, m_hi = shear(k.min(), m.min()), shear(k.max(), m.max())
    young = lambda kk, mm: 4.0 * kk * mm / (kk + mm)  # noqa: E731
    return {"kappa": (k_lo, k_hi), "mu": (m_lo, m_hi),
            "E_2D": (young(k_lo, m_lo), young(k_hi, m_hi))}


def voigt_reuss_2d(volume, E, nu, state="plane_strain"):
    """(Reuss, Voigt) bounds of the apparent in-plane Young's modulus sigma_yy/eps_yy of a
    window under the tension test, for per-particle moduli ``E``, ``nu`` weighted by the
    particle ``volume`` (each phase's particles share its exact area)."""
    w = np.asarray(volume, dtype=float)
    w = w / w.sum()
    lam, mu = lame(E, nu, state)
    c11, c12 = lam + 2.0 * mu, lam
    compliance = c11 / ((c11 - c12) * (c11 + c12))
    mean11, mean12 = float(np.dot(w, c11)), float(np.dot(w, c12))
    return 1.0 / float(np.dot(w, compliance)), mean11 - mean12 * mean12 / mean11
