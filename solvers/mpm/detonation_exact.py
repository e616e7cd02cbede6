"""Exact solutions of a planar detonation in JWL products, computed with scipy from the
material constants alone (no solver code): the Chapman–Jouguet point, the self-similar Taylor
wave behind a CJ front started at a rigid wall, the centred fan behind one started at a free
end, and, for polytropic products (JWL with
A = B = 0, γ = 1 + ω), the closed-form Taylor wave and the impulse a slab detonated at a
rigid wall gives the wall (docs/mpm_verification.md, "Detonation").

JWL, E per unit reference volume, V = ρ0/ρ:
    p(V, E) = A (1 − ω/(R1 V)) e^{−R1 V} + B (1 − ω/(R2 V)) e^{−R2 V} + ω E / V.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

# CJ tangency by brentq on a central-difference derivative: the step balances truncation
# (h² p''') against round-off (eps p / h), both ≈ 1e-11 relative at h = 1e-6
_DERIVATIVE_STEP = 1e-6
# isentrope/Riemann-invariant quadrature: solve_ivp's local tolerance, far below the
# percent-level truncation error of any MPM run it is compared with
_ODE_RTOL = 1e-10


@dataclass(frozen=True)
class JWL:
    """JWL products with their unreacted density ρ0 and chemical energy E0 (J/m³)."""
    rho0: float
    A: float
    B: float
    R1: float
    R2: float
    omega: float
    E0: float

    @classmethod
    def from_parameters(cls, prm: dict) -> "JWL":
        """From the solver's parameter names (``rho0``, ``eos.A``, ..., ``eos.E0``)."""
        return cls(prm["rho0"], prm["eos.A"], prm["eos.B"], prm["eos.R1"], prm["eos.R2"],
                   prm["eos.omega"], prm["eos.E0"])

    def cold(self, V):
        """p at E = 0: the A and B terms."""
        A, B, R1, R2, w = self.A, self.B, self.R1, self.R2, self.omega
        return (A * (1 - w / (R1 * V)) * math.exp(-R1 * V)
                + B * (1 - w / (R2 * V)) * math.exp(-R2 * V))

    def cold_slope(self, V):
        """d(cold)/dV."""
        A, B, R1, R2, w = self.A, self.B, self.R1, self.R2, self.omega
        return (A * math.exp(-R1 * V) * (w / (R1 * V * V) - R1 + w / V)
                + B * math.exp(-R2 * V) * (w / (R2 * V * V) - R2 + w / V))

    def pressure(self, V, E):
        return self.cold(V) + self.omega * E / V

    def hugoniot_pressure(self, V):
        """Products Hugoniot centred on the unreacted state (V = 1, p = 0, E = E0):
        E = E0 + ½ p (1 − V), solved for p (p is linear in E)."""
        g = self.omega / V
        return (self.cold(V) + g * self.E0) / (1 - 0.5 * g * (1 - V))

    def isentrope_slope(self, V, E):
        """dp/dV along an isentrope (dE = −p dV)."""
        p = self.pressure(V, E)
        return self.cold_slope(V) - self.omega * E / V**2 - self.omega / V * p

    def sound_speed(self, V, E):
        return math.sqrt(-V * V / self.rho0 * self.isentrope_slope(V, E))


@dataclass(frozen=True)
class CJPoint:
    V: float          # relative volume ρ0/ρ
    D: float          # detonation speed of the tangent Rayleigh line
    p: float
    rho: float
    u: float          # particle velocity D (1 − V)
    c: float          # sound speed (= D − u at the CJ point)
    E: float          # E0 + ½ p (1 − V)


def cj_point(eos: JWL) -> CJPoint:
    """The CJ point: where the Rayleigh line from (V = 1, p = 0) is tangent to the products
    Hugoniot, i.e. the root of p_H'(V) (1 − V) + p_H(V) = 0 (D² = p_H / (ρ0 (1 − V)) minimal)."""
    h = _DERIVATIVE_STEP

    def tangency(V):
        slope = (eos.hugoniot_pressure(V + h) - eos.hugoniot_pressure(V - h)) / (2 * h)
        return slope * (1 - V) + eos.hugoniot_pressure(V)

    # Root to ~eps·V: far below the central difference's own error (h² ~ 1e-12), so the CJ
    # point is limited by the derivative, not by the root finder.
    V = brentq(tangency, 0.3, 0.95, xtol=1e-14, rtol=4 * np.finfo(float).eps)
    p = eos.hugoniot_pressure(V)
    D = math.sqrt(p / (eos.rho0 * (1 - V)))
    E = eos.E0 + 0.5 * p * (1 - V)
    return CJPoint(V=V, D=D, p=p, rho=eos.rho0 / V, u=D * (1 - V), c=eos.sound_speed(V, E),
                   E=E)


@dataclass(frozen=True)
class TaylorWave:
    """The self-similar flow behind a CJ front that started at a rigid wall at x = 0, t = 0:
    a centred simple wave, tabulated on the products' isentrope through the CJ point from
    the front (ξ = x/t = D) to the point where u = 0, then a state at rest out to the wall.

    Along the C− characteristics, which all come from the front, u − ∫ c dρ/ρ is the CJ
    value; the C+ characteristics are the rays ξ = u + c."""
    cj: CJPoint
    xi: np.ndarray        # increasing, from the wall state's edge ξ_w = c_w to D
    p: np.ndarray
    rho: np.ndarray
    u: np.ndarray

    @property
    def wall_pressure(self):
        return float(self.p[0])

    @property
    def wall_edge(self):
        """ξ where the fan meets the state at rest (= the sound speed there)."""
        return float(self.xi[0])

    def at(self, xi):
        """(p, ρ, u) at ξ = x/t; the state at rest for ξ below the fan, NaN ahead of the front."""
        xi = np.asarray(xi, float)
        out = [np.interp(xi, self.xi, q) for q in (self.p, self.rho, self.u)]
        ahead = xi > self.cj.D
        for q in out:
            q[ahead] = np.nan
        return tuple(out)


def _isentrope_from_cj(eos: JWL, cj: CJPoint, V_end: float, stop=None):
    """E(V) (dE/dV = −p) and the Riemann invariant w(V) = ∫_{V_CJ}^{V} c/V dV along the
    isentrope through the CJ point, from V_CJ to V_end or to the terminal event ``stop``."""
    def rhs(V, y):
        E = y[0]
        return [-eos.pressure(V, E), eos.sound_speed(V, E) / V]

    return solve_ivp(rhs, (cj.V, V_end), [cj.E, 0.0], events=stop, rtol=_ODE_RTOL,
                     atol=[_ODE_RTOL * cj.E, _ODE_RTOL * cj.u], dense_output=True)


def _isentrope_states(eos: JWL, cj: CJPoint, sol, V):
    """p, c and u = u_CJ − w on the isentrope at the volumes V."""
    E, w = sol.sol(V)
    p = np.array([eos.pressure(v, e) for v, e in zip(V, E)])
    c = np.array([eos.sound_speed(v, e) for v, e in zip(V, E)])
    return p, c, cj.u - w


def taylor_wave(eos: JWL, points: int = 2001) -> TaylorWave:
    """Integrate E(V) and the Riemann invariant from the CJ point until u = 0."""
    cj = cj_point(eos)

    def at_rest(V, y):
        return cj.u - y[1]
    at_rest.terminal = True

    sol = _isentrope_from_cj(eos, cj, 20 * cj.V, stop=at_rest)
    if sol.status != 1:
        raise RuntimeError("the isentrope from the CJ point never brings the products to rest")
    V = np.linspace(cj.V, sol.t_events[0][0], points)
    p, c, u = _isentrope_states(eos, cj, sol, V)
    order = np.argsort(u + c)
    return TaylorWave(cj=cj, xi=(u + c)[order], p=p[order], rho=eos.rho0 / V[order],
                      u=u[order])


@dataclass(frozen=True)
class FreeEndFan:
    """The self-similar flow behind a CJ front that started at a free end (vacuum behind it)
    at x = 0, t = 0: one centred simple wave from the front (ξ = D) to the vacuum, on the
    isentrope through the CJ point — the Taylor wave continued below u = 0, the products
    streaming backwards. Tabulated down to ``rho_floor`` ρ0 (the vacuum edge itself, ρ → 0,
    lies further back and is not tabulated)."""
    cj: CJPoint
    V: np.ndarray         # increasing relative volume, V_CJ ... ρ0/ρ_floor
    p: np.ndarray         # on the isentrope
    u: np.ndarray         # u_CJ − ∫_{V_CJ}^{V} c/V dV
    xi: np.ndarray        # u + c, decreasing with V

    def isentrope_pressure(self, V):
        """p on the isentrope through the CJ point at relative volume V (NaN off the table)."""
        V = np.asarray(V, float)
        p = np.interp(V, self.V, self.p)
        return np.where((V < self.V[0]) | (V > self.V[-1]), np.nan, p)

    def at(self, xi):
        """(p, ρ, u) at ξ = x/t; NaN ahead of the front and behind the tabulated edge."""
        xi = np.asarray(xi, float)
        order = slice(None, None, -1)             # ξ increasing
        out = [np.interp(xi, self.xi[order], q[order])
               for q in (self.p, self.cj.rho * self.cj.V / self.V, self.u)]
        off = (xi > self.cj.D) | (xi < self.xi[-1])
        for q in out:
            q[off] = np.nan
        return tuple(out)


def free_end_fan(eos: JWL, rho_floor: float = 0.05, points: int = 4001) -> FreeEndFan:
    """Integrate E(V) and the Riemann invariant from the CJ point to V = 1/rho_floor."""
    cj = cj_point(eos)
    V_end = 1 / rho_floor
    sol = _isentrope_from_cj(eos, cj, V_end)
    if sol.status != 0:
        raise RuntimeError(f"the isentrope from the CJ point stopped before V = {V_end}")
    V = np.geomspace(cj.V, V_end, points)
    p, c, u = _isentrope_states(eos, cj, sol, V)
    return FreeEndFan(cj=cj, V=V, p=p, u=u, xi=u + c)


# -- polytropic products: closed forms -------------------------------------------------------

def polytropic_gamma(rho0, D, p_cj):
    """γ of the polytropic gas with the same ρ0, D and P_CJ: P_CJ = ρ0 D² / (γ + 1)."""
    return rho0 * D * D / p_cj - 1


def polytropic_taylor_pressure(xi, rho0, D, gamma):
    """Taylor's closed form: with u − 2c/(γ−1) fixed at its CJ value and ξ = u + c,
    c(ξ) = ((γ − 1) ξ + 2 c_CJ − (γ − 1) u_CJ)/(γ + 1) and p = P_CJ (c/c_CJ)^{2γ/(γ−1)};
    at rest (c = c_CJ − (γ − 1) u_CJ / 2) for ξ below that sound speed."""
    u_cj, c_cj = D / (gamma + 1), gamma * D / (gamma + 1)
    p_cj = rho0 * D * D / (gamma + 1)
    xi = np.asarray(xi, float)
    c_rest = c_cj - 0.5 * (gamma - 1) * u_cj
    c = np.maximum(((gamma - 1) * xi + 2 * c_cj - (gamma - 1) * u_cj) / (gamma + 1), c_rest)
    p = p_cj * (c / c_cj) ** (2 * gamma / (gamma - 1))
    return np.where(xi > D, np.nan, p)


def gamma3_wall_momentum(rho0, D, length, t):
    """Momentum (per unit area) a γ = 3 slab of thickness ``length``, detonated at a rigid
    wall at t = 0 (CJ, p0 = 0), has given the wall by time t; the free far end expands into
    vacuum. Until t_d = length/D the wall feels the state at rest, p_w = 2/27 ρ0 D².

    For γ = 3 the Riemann invariants u ± c are constant along straight characteristics, and
    the gas moves like free particles spread uniformly in velocity over [u − c, u + c] (a
    "water bag", phase density ρ/(2c) fixed by p ∝ ρ³); the wall reflects them. At
    t_d = length/D the state is Taylor's: at rest (c = D/2, ρ = 8ρ0/9) for ξ < D/2, and in
    the fan velocities uniform on [−D/2, ξ] with ρ = 8ρ0 (ξ + D/2)/(9D). A particle with
    velocity v < 0 at x has reached the wall by t if x < |v| (t − t_d), and then carries +|v|
    instead of −|v|: the momentum the wall has given by t is the final Σ |v| m
    = 8/27 ρ0 D length (t → ∞, Kennedy's/Stanyukovich's γ = 3 result) less 2 Σ |v| m over
    the particles not yet reflected (at t = t_d it is the wall pressure 2/27 ρ0 D² times t_d)."""
    t_d = length / D
    tau = t - t_d
    if tau <= 0:                       # Taylor's state at rest on the wall: p_w = 2/27 ρ0 D²
        return 2 / 27 * rho0 * D * D * t
    # phase density ρ/(2c) = 8ρ0/(9D), the same at rest and in the fan (Liouville: it is
    # carried along the particle paths); every point holds velocities down to −D/2
    phase = 8 * rho0 / (9 * D)
    final = 8 / 27 * rho0 * D * length     # Σ |v| m: every v < 0 reflected once

    def unreflected_momentum(x):
        """∫ |v| f dv over the v < 0 at x (t_d) that have not reached the wall: |v| τ < x."""
        cap = min(D / 2, x / tau)
        return phase * cap * cap / 2

    deficit, _ = quad(unreflected_momentum, 0.0, length, limit=200)
    return final - 2 * deficit
