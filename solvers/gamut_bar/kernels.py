"""numba kernels: return mapping, banded assembly, banded Cholesky, Newton per load step and
the load-path drivers (no Python loop over elements, points or steps).

Unknowns are the displacements u_1..u_n (u_0 = 0 is pinned); the tangent is stored as a lower
band ``ab[j, d] = K[j + d, j]`` (half-bandwidth = the largest bond degree). Elements are
elastic–perfectly-plastic (Jenkins): force f = k (e − e_p), |f| ≤ f_c. A step is solved by
Newton's method with the consistent tangent (slipping elements contribute nothing) and a
backtracking line search on the step's convex incremental potential; the Cholesky factor is
kept and reused while no element changes between elastic and slipping.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

OK, SINGULAR, NO_CONVERGENCE, RUNAWAY, NONFINITE, STRAIN = 0, 1, 2, 3, 4, 5
STATUS_TEXT = {OK: "converged", SINGULAR: "singular tangent", NO_CONVERGENCE:
               "Newton did not converge", RUNAWAY: "displacements ran away (limit load)",
               NONFINITE: "non-finite residual", STRAIN: "local strain beyond eps_f"}

PIVOT_TOL = 1e-13     # a Cholesky pivot below this fraction of its diagonal: singular
REGULARISE = 1e-4     # slipping elements' stiffness fraction when the exact tangent is singular
ARMIJO = 1e-4


@njit(cache=True)
def trial(u, F, ei, ej, ek, efc, ep_n, ep_t, st_t, r, st_ref):
    """Return mapping of every element from the converged slips ``ep_n`` at ``u``.

    Writes trial slips ``ep_t``, states ``st_t`` (−1/0/+1: slipping in compression / elastic /
    slipping in tension) and the residual r = F_ext − F_int (F at the last point). Returns
    max |r| and the number of elements whose state differs from ``st_ref``.
    """
    nn = u.size - 1
    for a in range(nn):
        r[a] = 0.0
    r[nn - 1] = F
    changed = 0
    for e in range(ek.size):
        i = ei[e]
        j = ej[e]
        k = ek[e]
        d = u[j] - u[i] - ep_n[e]
        f = k * d
        fc = efc[e]
        s = 0
        if f > fc:
            f = fc
            s = 1
        elif f < -fc:
            f = -fc
            s = -1
        if s != 0:
            ep_t[e] = ep_n[e] + (d - f / k)
        else:
            ep_t[e] = ep_n[e]
        st_t[e] = s
        if s != st_ref[e]:
            changed += 1
        if i > 0:
            r[i - 1] += f
        r[j - 1] -= f
    rmax = 0.0
    for a in range(nn):
        v = abs(r[a])
        if not v <= rmax:      # also propagates NaN
            rmax = v
    return rmax, changed


@njit(cache=True)
def _psi(k, fc, d):
    f = k * d
    if abs(f) <= fc:
        return 0.5 * f * d
    return fc * abs(d) - 0.5 * fc * fc / k


@njit(cache=True)
def energy_change(u_old, du, alpha, F, ei, ej, ek, efc, ep_n):
    """Π(u_old + α du) − Π(u_old), Π = Σ ψ_e − F u_n, computed element by element."""
    total = 0.0
    for e in range(ek.size):
        i = ei[e]
        j = ej[e]
        k = ek[e]
        fc = efc[e]
        d0 = u_old[j] - u_old[i] - ep_n[e]
        dd = du[j - 1] - (du[i - 1] if i > 0 else 0.0)
        d1 = d0 + alpha * dd
        if abs(k * d0) <= fc and abs(k * d1) <= fc:
            total += 0.5 * k * (alpha * dd) * (d0 + d1)
        else:
            total += _psi(k, fc, d1) - _psi(k, fc, d0)
    return total - F * alpha * du[du.size - 1]


@njit(cache=True)
def factor(ab, diag, st, ei, ej, ek, eta):
    """Assemble the tangent (slipping elements: eta·k) into the band and factor it in place
    (banded Cholesky). Returns −1, or the unknown whose pivot is not positive."""
    nn = ab.shape[0]
    b = ab.shape[1] - 1
    ab[:, :] = 0.0
    for e in range(ek.size):
        kt = ek[e] if st[e] == 0 else eta * ek[e]
        if kt == 0.0:
            continue
        a = ei[e] - 1
        c = ej[e] - 1
        ab[c, 0] += kt
        if a >= 0:
            ab[a, 0] += kt
            ab[a, c - a] -= kt
    for j in range(nn):
        diag[j] = ab[j, 0]
    for j in range(nn):
        piv = ab[j, 0]
        if not piv > PIVOT_TOL * diag[j]:
            return j
        piv = math.sqrt(piv)
        ab[j, 0] = piv
        m = min(b, nn - 1 - j)
        inv = 1.0 / piv
        for i in range(1, m + 1):
            ab[j, i] *= inv
        for kk in range(1, m + 1):
            lk = ab[j, kk]
            if lk == 0.0:
                continue
            row = j + kk
            for i in range(kk, m + 1):
                ab[row, i - kk] -= ab[j, i] * lk
    return -1


@njit(cache=True)
def solve(ab, r, x):
    """x = K⁻¹ r with the banded Cholesky factor in ``ab``."""
    nn = ab.shape[0]
    b = ab.shape[1] - 1
    for j in range(nn):
        x[j] = r[j]
    for j in range(nn):
        x[j] /= ab[j, 0]
        xj = x[j]
        m = min(b, nn - 1 - j)
        for i in range(1, m + 1):
            x[j + i] -= ab[j, i] * xj
    for j in range(nn - 1, -1, -1):
        s = x[j]
        m = min(b, nn - 1 - j)
        for i in range(1, m + 1):
            s -= ab[j, i] * x[j + i]
        x[j] = s / ab[j, 0]


@njit(cache=True)
def newton_step(F, tol, u, ep_n, ep, st, ei, ej, ek, efc, ab, diag, fst, fmeta, fmeta_f,
                r, du, ep_t, st_t, r_t, u_old, maxit, umax):
    """Equilibrium at external force F from the converged state (u, ep_n).

    On return (status OK) ``u`` is the new equilibrium, ``ep``/``st`` the elements' slips and
    states there (not yet committed to ``ep_n``). ``fst``/``fmeta`` describe the factor held in
    ``ab``: the states it was assembled with, fmeta[0] = 1 if valid. Returns (status, iterations,
    refactorisations).
    """
    nn = u.size - 1
    nref = 0
    if fmeta[1] == 1:
        # r and st still describe (u, ep_n) at the force fmeta_f[0]: only the load changed
        r[nn - 1] += F - fmeta_f[0]
        rmax = 0.0
        for a in range(nn):
            v = abs(r[a])
            if not v <= rmax:
                rmax = v
    else:
        rmax, _ = trial(u, F, ei, ej, ek, efc, ep_n, ep, st, r, st)
    fmeta[1] = 0
    for it in range(maxit):
        if not math.isfinite(rmax):
            return NONFINITE, it, nref
        if rmax <= tol:
            return OK, it, nref
        need = fmeta[0] == 0
        if not need:
            for e in range(ek.size):
                if (st[e] != 0) != (fst[e] != 0):
                    need = True
                    break
        if need:
            nref += 1
            bad = factor(ab, diag, st, ei, ej, ek, 0.0)
            if bad >= 0:
                bad = factor(ab, diag, st, ei, ej, ek, REGULARISE)
            if bad >= 0:
                fmeta[0] = 0
                fmeta[2] = bad + 1
                return SINGULAR, it, nref
            for e in range(ek.size):
                fst[e] = st[e]
            fmeta[0] = 1
        solve(ab, r, du)
        slope = 0.0
        for a in range(nn):
            slope -= r[a] * du[a]
        for a in range(nn + 1):
            u_old[a] = u[a]
        alpha = 1.0
        accepted = False
        rt = 0.0
        for _ls in range(60):
            for a in range(1, nn + 1):
                u[a] = u_old[a] + alpha * du[a - 1]
            rt, changed = trial(u, F, ei, ej, ek, efc, ep_n, ep_t, st_t, r_t, st)
            if rt <= tol or changed == 0:
                accepted = True
                break
            dpi = energy_change(u_old, du, alpha, F, ei, ej, ek, efc, ep_n)
            if dpi <= ARMIJO * alpha * slope:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            for a in range(nn + 1):
                u[a] = u_old[a]
            return NO_CONVERGENCE, it, nref
        for e in range(ek.size):
            ep[e] = ep_t[e]
            st[e] = st_t[e]
        for a in range(nn):
            r[a] = r_t[a]
        rmax = rt
        if abs(u[nn]) > umax:
            return RUNAWAY, it, nref
    return NO_CONVERGENCE, maxit, nref


@njit(cache=True)
def _max_local_strain(u, seg):
    emax = 0.0
    imax = 0
    for i in range(seg.size):
        e = abs(u[i + 1] - u[i]) / seg[i]
        if e > emax:
            emax = e
            imax = i
    return emax, imax


@njit(cache=True)
def run_path(forces, tols, u, ep_n, ep, st, ei, ej, ek, efc, ab, diag, fst, fmeta, fmeta_f,
             work_r, work_du, work_ep, work_st, work_r2, u_old, u_prev, seg, eps_f,
             out_u, maxit, umax, info):
    """Follow the prescribed forces; record the end displacement after every step.

    Stops at the first step that does not converge or takes a local bond beyond ``eps_f``; the
    state is then left at the last converged step. Returns the number of steps done; ``info``
    receives (status, failing bond, its strain, Newton iterations, factorisations).
    """
    iters = 0
    nref = 0
    for s in range(forces.size):
        for a in range(u.size):
            u_prev[a] = u[a]
        status, it, nr = newton_step(forces[s], tols[s], u, ep_n, ep, st, ei, ej, ek, efc, ab,
                                     diag, fst, fmeta, fmeta_f, work_r, work_du, work_ep,
                                     work_st, work_r2, u_old, maxit, umax)
        iters += it
        nref += nr
        if status != OK:
            for a in range(u.size):
                u[a] = u_prev[a]
            info[0] = status
            if status == SINGULAR:
                info[1] = fmeta[2]
                info[2] = np.nan
            else:                       # the point with the largest residual force
                rmax = -1.0
                for a in range(work_r.size):
                    if not abs(work_r[a]) <= rmax:
                        rmax = abs(work_r[a])
                        info[1] = a + 1
                        info[2] = work_r[a]
            info[3] = iters
            info[4] = nref
            return s
        emax, imax = _max_local_strain(u, seg)
        if emax > eps_f:
            for a in range(u.size):
                u[a] = u_prev[a]
            info[0] = STRAIN
            info[1] = imax
            info[2] = emax
            info[3] = iters
            info[4] = nref
            return s
        for e in range(ek.size):
            ep_n[e] = ep[e]
        fmeta[1] = 1
        fmeta_f[0] = forces[s]
        out_u[s] = u[u.size - 1]
    info[0] = OK
    info[1] = -1
    info[2] = 0.0
    info[3] = iters
    info[4] = nref
    return forces.size


@njit(cache=True)
def bisect_failure(f_lo, f_hi, nbis, tol_rel, f_floor, u, ep_n, ep, st, ei, ej, ek, efc, ab,
                   diag, fst, fmeta, fmeta_f, work_r, work_du, work_ep, work_st, work_r2, u_old,
                   u_prev, seg, eps_f, maxit, umax):
    """Bisect the force between the last converged step (state held) and the failing one;
    leaves the state at the largest force found that converges with every local bond within
    ``eps_f``. Returns that force."""
    for _ in range(nbis):
        fm = 0.5 * (f_lo + f_hi)
        for a in range(u.size):
            u_prev[a] = u[a]
        tol = tol_rel * max(abs(fm), f_floor)
        status, it, nr = newton_step(fm, tol, u, ep_n, ep, st, ei, ej, ek, efc, ab, diag, fst,
                                     fmeta, fmeta_f, work_r, work_du, work_ep, work_st,
                                     work_r2, u_old, maxit, umax)
        good = status == OK
        if good:
            emax, imax = _max_local_strain(u, seg)
            good = emax <= eps_f
        if good:
            for e in range(ek.size):
                ep_n[e] = ep[e]
            fmeta[1] = 1
            fmeta_f[0] = fm
            f_lo = fm
        else:
            for a in range(u.size):
                u[a] = u_prev[a]
            f_hi = fm
    return f_lo
