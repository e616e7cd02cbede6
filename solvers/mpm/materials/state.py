"""Per-particle material state of the MPM solver: column layout, error codes, shared helpers.

The state of particle ``i`` is the row ``S[i]`` of a float64 array of shape
``(n_particles, N_STATE)``. Stresses are Cauchy stresses (Pa, tension positive) and *include*
the pressure and the artificial viscosity: σ = s − (P + Q)·I. The deviator is recovered as
σ − tr(σ)/3·I (it is kept traceless), so nothing depends on the Q of the previous step.

Contract with the core (docs/mpm_materials.md §1):

* the core writes ``Q`` (bulk viscosity of this step, Pa, ≥ 0) *before* calling a material's
  ``update``; the kernel uses it in the energy equation and in σ, and never changes it;
* a kernel leaves ``S[i]`` untouched when it returns a nonzero code (transactional), so the
  core can report the state before the failing step;
* ``E`` is internal energy per unit *reference* volume (J/m³, LS-DYNA *EOS_GRUNEISEN);
  ``PLASTIC_WORK`` likewise; ``C`` is the wave speed the CFL step must use (longitudinal
  speed for solids, detonation speed for unburnt explosive).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from uqflow.errors import SceneError, SolverError

# --- columns -------------------------------------------------------------------------------
SXX, SYY, SXY, SZZ = 0, 1, 2, 3   # Cauchy stress incl. −(P+Q)·I, Pa, tension positive
P = 4                             # EOS pressure p* (compression positive), excludes Q
Q = 5                             # artificial bulk viscosity (written by the core), Pa
RHO = 6                           # current density, kg/m³
E = 7                             # internal energy per unit reference volume, J/m³
EPS_P = 8                         # equivalent plastic strain
EPS_P_RATE = 9                    # equivalent plastic strain rate of the last step, 1/s
T = 10                            # temperature, K (0 for materials without temperature)
BURN = 11                         # burn fraction 0..1 (explosives), else 0
SY = 12                           # current flow stress σy, Pa (0 for materials without strength)
C = 13                            # wave speed for the CFL step, m/s
PLASTIC_WORK = 14                 # plastic work per unit reference volume, J/m³
# what the last return mapping used (strength materials; 0 elsewhere), so that constitutive
# derivatives can be evaluated at the state the return actually saw (probe_sensitivities.py)
T_RETURN = 15                     # temperature the return used (T before this step's heating), K
RATE_STAR = 16                    # ε̇* the return used (after the clamp or floor), 1
DT = 17                           # the last step's Δt, s (Δεp = EPS_P_RATE · DT)
EQ_STRAIN_RATE = 18               # total equivalent deviatoric strain rate √(2/3 D':D'), 1/s
SY_TOTAL_RATE = 19                # σy(εp, ε̇* of EQ_STRAIN_RATE, T_RETURN), Pa: no elastic jump
N_STATE = 20

COLUMNS = ("SXX", "SYY", "SXY", "SZZ", "P", "Q", "RHO", "E", "EPS_P", "EPS_P_RATE", "T",
           "BURN", "SY", "C", "PLASTIC_WORK", "T_RETURN", "RATE_STAR", "DT", "EQ_STRAIN_RATE",
           "SY_TOTAL_RATE")

# --- error codes returned by every kernel ----------------------------------------------------
OK = 0
ERR_NONFINITE = 1        # NaN/inf in the input row, L, dt, time, x, y, parameters or the result
ERR_DENSITY = 2          # ρ ≤ 0 or J ≤ 0 (before or after the step)
ERR_MG_DENOMINATOR = 3   # Mie–Grüneisen compression denominator ≤ MG_DEN_MIN
ERR_OTHER = 4            # dt ≤ 0, or a return mapping that failed to converge
ERR_SHAPE = 5            # index outside S, S with < N_STATE columns, or short parameter vector

ERROR_TEXT = {
    OK: "ok",
    ERR_NONFINITE: "non-finite value (NaN or inf) in the particle state, velocity gradient, "
                   "time step, position or material parameters",
    ERR_DENSITY: "non-positive density or volume ratio J",
    ERR_MG_DENOMINATOR: "Mie-Gruneisen compression denominator near zero (compression beyond "
                        "the Hugoniot pole)",
    ERR_OTHER: "non-positive time step or failed return mapping",
    ERR_SHAPE: "particle index outside the state array, or a state/parameter array too short",
}

MG_DEN_MIN = 1e-6        # Mie–Grüneisen denominator guard


def error_text(code: int) -> str:
    """One-line description of a kernel return code."""
    return ERROR_TEXT.get(int(code), f"unknown error code {int(code)}")


def solver_error(code: int, *, step: int, particle: int, material: str,
                 row: np.ndarray | None = None) -> SolverError:
    """A ``SolverError`` for a nonzero kernel code, naming step, particle, material and the
    state the particle had before the failing step (``row``, optional)."""
    msg = (f"step {step}: particle {particle} ({material}): {error_text(code)} "
           f"[code {int(code)}]")
    if row is not None:
        r = np.asarray(row, dtype=float)
        msg += (f"; before the step rho = {r[RHO]:.6g}, p = {r[P]:.6g}, q = {r[Q]:.6g}, "
                f"E = {r[E]:.6g}, sxx = {r[SXX]:.6g}, syy = {r[SYY]:.6g}")
    return SolverError(msg)


def new_state(n: int) -> np.ndarray:
    """A zeroed state array for ``n`` particles (use each material's ``init`` to fill rows)."""
    return np.zeros((int(n), N_STATE))


def deviatoric(S: np.ndarray) -> np.ndarray:
    """Deviatoric stress (n, 4) = [s_xx, s_yy, s_xy, s_zz] of state rows (the seed's S11, S22)."""
    S = np.atleast_2d(S)
    mean = (S[:, SXX] + S[:, SYY] + S[:, SZZ]) / 3.0
    return np.stack([S[:, SXX] - mean, S[:, SYY] - mean, S[:, SXY], S[:, SZZ] - mean], axis=1)


def pack_parameters(parameters: dict, values: dict | None, material: str) -> np.ndarray:
    """Parameter vector in ``parameters`` order; names missing from ``values`` take their
    defaults. Unknown names raise ``SceneError`` (key = the name); non-finite values raise
    ``SolverError`` (a sampled realization, not the study, is at fault)."""
    values = dict(values or {})
    unknown = sorted(set(values) - set(parameters))
    if unknown:
        raise SceneError(f"material '{material}' has no parameter '{unknown[0]}' "
                         f"(takes {', '.join(parameters)})", key=unknown[0])
    out = np.empty(len(parameters))
    for k, (name, default) in enumerate(parameters.items()):
        v = values.get(name, default)
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise SceneError(f"must be a number, got {v!r}", key=name) from None
        if not math.isfinite(v):
            raise SolverError(f"material '{material}': parameter {name} = {v!r} is not finite")
        out[k] = v
    return out


class ParameterError(SolverError):
    """A material parameter outside its range: ``parameter`` names it and ``reason`` says
    why, so a scene constant can be refused at load under its own key (scene.py)."""

    def __init__(self, material: str, parameter: str, reason: str):
        super().__init__(f"material '{material}': parameter {parameter} = {reason}")
        self.parameter, self.reason = parameter, reason


def require(material: str, prm: np.ndarray, names, rules) -> None:
    """Raise ``ParameterError`` (a ``SolverError``) for the first parameter breaking its rule.

    ``rules``: iterable of (name, predicate, text), e.g. ("rho0", lambda v: v > 0, "> 0").
    """
    idx = {n: k for k, n in enumerate(names)}
    for name, ok, text in rules:
        v = float(prm[idx[name]])
        if not ok(v):
            raise ParameterError(material, name, f"{v:g} must be {text}")


# --- numba helpers shared by the kernels -----------------------------------------------------
@njit(cache=True, fastmath=False)
def finite_values(a, k0, k1):
    """True when a[k0:k1] (1-D) is finite. Each test is independent (no chain of dependent
    floating-point adds: this runs for every particle and step)."""
    ok = True
    for k in range(k0, k1):
        ok &= a[k] * 0.0 == 0.0
    return ok


@njit(cache=True, fastmath=False, forceinline=True)
def row_finite(S, i):
    """True when the state row i is finite."""
    ok = True
    for k in range(N_STATE):
        ok &= S[i, k] * 0.0 == 0.0
    return ok


@njit(cache=True, fastmath=False)
def check_call(prm, nprm, S, i):
    """Shape guard and finiteness of the parameters and of the row. Returns an error code."""
    if i < 0 or i >= S.shape[0] or S.shape[1] < N_STATE or prm.shape[0] < nprm:
        return ERR_SHAPE
    if not (finite_values(prm, 0, nprm) and row_finite(S, i)):
        return ERR_NONFINITE
    return OK


@njit(cache=True, fastmath=False)
def bulk_guards_pass(prm, nprm, S, dt, time):
    """The per-call part of ``check_update`` for a loop over many rows of ``S``: shapes,
    finite parameters, dt > 0, finite time. A loop that passes it may call a material's
    unguarded ``advance`` for a row that is finite with ρ > 0 and finite arguments."""
    return (S.shape[1] >= N_STATE and prm.shape[0] >= nprm and finite_values(prm, 0, nprm)
            and dt > 0.0 and dt * 0.0 == 0.0 and time * 0.0 == 0.0)


@njit(cache=True, fastmath=False, forceinline=True)
def finite_args(Lxx, Lxy, Lyx, Lyy, dt, time, x, y):
    """True when every scalar argument of ``update`` is finite."""
    return (Lxx * 0.0 + Lxy * 0.0 + Lyx * 0.0 + Lyy * 0.0 + dt * 0.0 + time * 0.0
            + x * 0.0 + y * 0.0) == 0.0


@njit(cache=True, fastmath=False)
def reset_row(prm, nprm, S, i):
    """The start of every ``init``: the call guards, then a zeroed state row. Returns a code."""
    code = check_call(prm, nprm, S, i)
    if code != OK:
        return code
    for k in range(N_STATE):
        S[i, k] = 0.0
    return OK


@njit(cache=True, fastmath=False)
def check_update(prm, nprm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y):
    """The guards every ``update`` starts with: shapes and finite row and parameters, finite
    arguments, dt > 0, ρ > 0. Returns a code; OK means the update may proceed."""
    code = check_call(prm, nprm, S, i)
    if code != OK:
        return code
    if not finite_args(Lxx, Lxy, Lyx, Lyy, dt, time, x, y):
        return ERR_NONFINITE
    if not dt > 0.0:
        return ERR_OTHER
    if not S[i, RHO] > 0.0:
        return ERR_DENSITY
    return OK


@njit(cache=True, fastmath=False)
def jaumann_rotate(sxx, syy, sxy, dt, w):
    """Rotate the in-plane deviator by the spin w = ½(Lxy − Lyx) over dt (Jaumann rate,
    ṡ = W s − s W with W = [[0, w], [−w, 0]]).

    Exact for a spin constant over the step: s ← R s Rᵀ with R = exp(WΔt) =
    [[cos θ, sin θ], [−sin θ, cos θ]], θ = wΔt, so the invariants are preserved to round-off
    and the rotation angle is exact (the Hughes–Winget form would lag by θ³/12 per step).
    s_zz is not rotated (the spin axis is z).
    """
    th = w * dt
    c = math.cos(th)
    s = math.sin(th)
    # R s Rᵀ
    cc, ss, cs = c * c, s * s, c * s
    rxx = cc * sxx + 2.0 * cs * sxy + ss * syy
    ryy = ss * sxx - 2.0 * cs * sxy + cc * syy
    rxy = cs * (syy - sxx) + (cc - ss) * sxy
    return rxx, ryy, rxy


@njit(cache=True, fastmath=False)
def deviator_of(S, i):
    """(s_xx, s_yy, s_xy, s_zz) of row i: σ − tr(σ)/3 (the 4 plane-strain components)."""
    m = (S[i, SXX] + S[i, SYY] + S[i, SZZ]) / 3.0
    return S[i, SXX] - m, S[i, SYY] - m, S[i, SXY], S[i, SZZ] - m


@njit(cache=True, fastmath=False, forceinline=True)
def density_update(rho, trD, dt):
    """ρ_{n+1} = ρ_n exp(−tr(D) Δt) (continuity, exact for constant D over the step).

    J = ρ_n/ρ_{n+1} underflows to 0 (ρ_{n+1} = inf) for absurd compressions: the kernels treat
    that as ERR_DENSITY."""
    return rho * math.exp(-trD * dt)


@njit(cache=True, fastmath=False, forceinline=True)
def bulk_viscosity(rho, length, c, div_v, Q1, Q2):
    """Artificial bulk viscosity q = ρ l (Q1 l ε̇v² − Q2 c ε̇v) for ε̇v = div v < 0, else 0
    (docs/design/mpm.md: Q1 = 1.5, Q2 = 0.06). Provided for the core; kernels only read Q."""
    if div_v >= 0.0:
        return 0.0
    return rho * length * (Q1 * length * div_v * div_v - Q2 * c * div_v)


@njit(cache=True, fastmath=False, forceinline=True)
def energy_update_linear_eos(E_n, p_n, q, dv, w_dev, f, g):
    """Energy-consistent (trapezoidal, implicit in E) update for an EOS linear in E.

    With p = f(ρ) + g(ρ)·E at the new density and dv = ρ0(1/ρ_{n+1} − 1/ρ_n) the change of the
    volume per unit reference volume,

        E_{n+1} = E_n + w_dev − (½(p_n + p_{n+1}) + q)·dv

    is solved exactly for E_{n+1} (no iteration): E_{n+1} = (E_n + w_dev − (½p_n + q)dv −
    ½ f dv)/(1 + ½ g dv). ``w_dev`` is the deviatoric work of the step per reference volume.
    For a single step from rest this is the Rankine–Hugoniot energy jump ½ (p + p_0)(V_0 − V).
    Returns (E_{n+1}, p_{n+1}, ok) with ok False when 1 + ½ g dv ≤ 0.
    """
    den = 1.0 + 0.5 * g * dv
    if not den > 0.0:
        return E_n, p_n, False
    E1 = (E_n + w_dev - (0.5 * p_n + q) * dv - 0.5 * f * dv) / den
    return E1, f + g * E1, True
