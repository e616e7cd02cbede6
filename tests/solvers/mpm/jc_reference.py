"""The tests' one reference of the Johnson–Cook flow stress (docs/mpm_materials.md § 3, § 10):

    σy = h·r·t,   h = A + B εp^n,   r = 1 + C ln max(ε̇*, floor),   t = 1 − T*^m,

with the limits the material states: B εp^n = 0 for εp ≤ 0, T*^m = 0 for T* ≤ 0, t = 0 for
T* ≥ 1 (melt); floor = 1 is the uqflow clamp ε̇* ≥ 1, the seed conventions pass their floor.

Written out here in plain numpy, apart from solvers/mpm (it is the oracle the kernels are
checked against, so it must not share their code): the value, which also takes complex
parameters (complex-step differentiation), each factor's parameter derivatives, and the
flow stress's gradient and Hessian in the order θ = (A, B, C, n, m) by the product rule.
A change of the law is made here and in solvers/mpm/materials/johnson_cook.py, nowhere else
in the tests.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

PARAMETERS = ("A", "B", "C", "n", "m")


def _as_array(x):
    return np.asarray(x, dtype=float)


def _masked_log(x, inside):
    """ln x where ``inside``, 0 elsewhere (so no NaN or −∞ reaches a product)."""
    return np.log(np.where(inside, x, 1.0))


def hardening_increase(B, n, eps_p):
    """B εp^n, 0 for εp ≤ 0 (the limit, also for complex n)."""
    eps_p = _as_array(eps_p)
    strained = eps_p > 0.0
    return B * np.where(strained, np.power(np.where(strained, eps_p, 1.0), n), 0.0)


def strain_for_hardening_increase(B, n, increase):
    """The εp > 0 at which B εp^n equals ``increase`` (> 0): the inverse of the above."""
    return (_as_array(increase) / B) ** (1.0 / n)


def hardening(A, B, n, eps_p):
    """h = A + B εp^n."""
    return A + hardening_increase(B, n, eps_p)


def rate_log(eps_rate_star, floor=1.0):
    """Λ = ln max(ε̇*, floor): 0 below the uqflow clamp (floor 1)."""
    return np.log(np.maximum(_as_array(eps_rate_star), floor))


def rate_factor(C, eps_rate_star, floor=1.0):
    """r = 1 + C Λ."""
    return 1.0 + C * rate_log(eps_rate_star, floor)


def thermal_power(m, T_star):
    """T*^m on 0 < T* < 1, 0 elsewhere (also for complex m)."""
    T_star = _as_array(T_star)
    warm = (T_star > 0.0) & (T_star < 1.0)
    return np.where(warm, np.power(np.where(warm, T_star, 1.0), m), 0.0)


def thermal_factor(m, T_star):
    """t = 1 − T*^m, 1 at T* ≤ 0, 0 at and above melt (T* ≥ 1)."""
    melted = _as_array(T_star) >= 1.0
    return np.where(melted, 0.0, 1.0 - thermal_power(m, T_star))


def flow_stress(A, B, C, n, m, eps_p, eps_rate_star, T_star, floor=1.0):
    """σy = h·r·t for arrays of states; the parameters may be complex."""
    return (hardening(A, B, n, eps_p) * rate_factor(C, eps_rate_star, floor)
            * thermal_factor(m, T_star))


class Factors(NamedTuple):
    """h, r, t and their nonzero parameter derivatives (subscripts name the parameters)."""
    h: np.ndarray
    h_A: np.ndarray
    h_B: np.ndarray
    h_n: np.ndarray
    h_Bn: np.ndarray
    h_nn: np.ndarray
    r: np.ndarray
    r_C: np.ndarray
    t: np.ndarray
    t_m: np.ndarray
    t_mm: np.ndarray


def factors(A, B, C, n, m, eps_p, eps_rate_star, T_star, floor=1.0):
    """Each factor and its derivatives: h_B = εp^n, h_n = B εp^n ln εp, h_Bn = εp^n ln εp,
    h_nn = B εp^n ln² εp (all 0 at εp ≤ 0); r_C = Λ; t_m = −T*^m ln T*, t_mm = −T*^m ln² T*
    (0 outside 0 < T* < 1: t is constant there)."""
    eps_p, T_star = _as_array(eps_p), _as_array(T_star)
    power_eps = hardening_increase(1.0, n, eps_p)
    log_eps = _masked_log(eps_p, eps_p > 0.0)
    power_T = thermal_power(m, T_star)
    log_T = _masked_log(T_star, (T_star > 0.0) & (T_star < 1.0))
    one = np.ones(np.broadcast(eps_p, eps_rate_star, T_star).shape)
    return Factors(
        h=A + B * power_eps, h_A=one, h_B=power_eps * one, h_n=B * power_eps * log_eps,
        h_Bn=power_eps * log_eps * one, h_nn=B * power_eps * log_eps ** 2,
        r=rate_factor(C, eps_rate_star, floor) * one, r_C=rate_log(eps_rate_star, floor) * one,
        t=thermal_factor(m, T_star) * one, t_m=-power_T * log_T * one,
        t_mm=-power_T * log_T ** 2 * one)


def flow_stress_derivatives(A, B, C, n, m, eps_p, eps_rate_star, T_star, floor=1.0):
    """(∂σy/∂θ (..., 5), ∂²σy/∂θ² (..., 5, 5)), θ = (A, B, C, n, m), by the product rule on
    ``factors``: h depends on A, B, n; r on C; t on m."""
    f = factors(A, B, C, n, m, eps_p, eps_rate_star, T_star, floor)
    iA, iB, iC, i_n, im = range(5)
    shape = f.h.shape
    grad = np.zeros(shape + (5,))
    grad[..., iA] = f.h_A * f.r * f.t
    grad[..., iB] = f.h_B * f.r * f.t
    grad[..., iC] = f.h * f.r_C * f.t
    grad[..., i_n] = f.h_n * f.r * f.t
    grad[..., im] = f.h * f.r * f.t_m
    hess = np.zeros(shape + (5, 5))
    entries = {
        (iB, i_n): f.h_Bn * f.r * f.t,
        (i_n, i_n): f.h_nn * f.r * f.t,
        (im, im): f.h * f.r * f.t_mm,
    }
    for i, h_i in ((iA, f.h_A), (iB, f.h_B), (i_n, f.h_n)):
        entries[(i, iC)] = h_i * f.r_C * f.t
        entries[(i, im)] = h_i * f.r * f.t_m
    entries[(iC, im)] = f.h * f.r_C * f.t_m
    for (i, j), value in entries.items():
        hess[..., i, j] = hess[..., j, i] = value
    return grad, hess
