"""Numba kernels of one explicit MUSL step (docs/mpm.md, "Algorithm").

Per step, in this order (``solver._Run.step``):

1. ``max_speed``         max_p (c_p + |v_p|) for the CFL time step (first step only: later
                         steps take it from the material loops of the step before);
2. ``p2g``               mass, momentum and internal + body force to the grid;
3. ``grid_solve``        symmetry fold, v^L = (p + f·dt)/m, boundary conditions, Δv, unfold;
4. ``g2p_velocity_remap`` particle velocity (FLIP/PIC blend), new positions (kept aside) and
                         the MUSL remap of the new momentum at the old positions (one pass);
5. ``grid_solve``        v^{n+1} = p/m with the boundary conditions;
6. ``g2p_gradient``      velocity gradient L_p from v^{n+1}; positions moved; grid guard;
7. material loops        per material, over its particle index list (``loop_for``): the bulk
                         viscosity q from div v (column Q), ``advance`` (``update`` when a
                         guard fails), the row checked finite (the state guard) and
                         max (c + |v|) kept for the next step's CFL time step (the
                         strength kernel also records what its return used: state.py);
                         energies at output times (``energies``).

The cached kernels below inline the material modules' code; their cache is stamped with the
source of every module of the package they import (``kernel_cache.py``), so a change to a
material or to ``state.py`` recompiles them.

Doing q, the state check and the CFL reduction in the material loop, where the particle's
state row is in cache anyway, saves three passes over the state array per step (docs/mpm.md,
"Performance").

Scatter without races: ``p2g`` and the remap split the particles into one contiguous chunk per
thread and each thread scatters into its own grid buffer (``buf[t]``, node-major); a second
parallel loop over grid columns sums the buffers. Gathers and material updates are race-free
per particle.

Runs on one thread call the serial twins of the parallel kernels (``SERIAL``, ``kernels``):
the same functions compiled without parfors, which costs a one-thread run nothing and
shortens the first run's compile (issue 19).

The small helpers here, in ``shapes.py`` and ``materials/`` are ``forceinline``: LLVM inlines
them into the loops, where their loads and guards join the loop's (numba's IR-level
``inline="always"`` and plain calls both ran the step slower). A call that takes an array
(a material's ``advance(prm, S, ...)``) makes numba count references around it, atomic and
opaque to LLVM, at every particle: the serial twins of the loops go without reference
counting altogether (``_serial_twin(nrt=False)``), and the water's ``advance``, the bulk of
every seed scene, is inlined at numba's IR level, so no call is left in its parfors loop.
The other materials' ``advance`` stay ``forceinline``: inlining them at numba's IR level
made the material loops compile about a third longer, for loops over a few per cent of the
particles (docs/mpm.md, "Performance"; issue 19).

Every kernel that indexes the grid first checks the particle's stencil is on the grid and
skips (and flags) it otherwise, so a bad particle can never write out of bounds.
"""

from __future__ import annotations

import math
import types

import numpy as np
from numba import njit, prange

from solvers.mpm.materials.state import (C, PLASTIC_WORK, Q, RHO, SXX, SXY, SYY, E, N_STATE,
                                          bulk_guards_pass, bulk_viscosity, finite_args,
                                          row_finite)
from solvers.mpm.shapes import shape1d, stencil_base

# core error codes (the materials' codes are 1..5, see materials/state.py)
ERR_LEFT_GRID = 101        # the particle's stencil leaves the padded grid
ERR_CORE_NONFINITE = 102   # non-finite position or velocity after the grid-to-particle gather
CORE_ERROR_TEXT = {
    ERR_LEFT_GRID: "particle left the padded grid",
    ERR_CORE_NONFINITE: "non-finite particle velocity or position",
}


@njit(cache=True, parallel=True)
def max_speed(vx, vy, S):
    """max over particles of c + |v| (NaN-free input assumed; see ``check_state``)."""
    m = 0.0
    for p in prange(vx.size):
        s = S[p, C] + math.sqrt(vx[p] * vx[p] + vy[p] * vy[p])
        m = max(m, s)
    return m


@njit(cache=True, forceinline=True)
def _on_grid(bx, by, nnx, nny):
    return bx >= 0 and by >= 0 and bx + 2 < nnx and by + 2 < nny


@njit(cache=True, forceinline=True)
def _stencil(kind, x, y, ox, oy, inv_dx, lp):
    """(bx, by, wx, wy, dwx, dwy) of a particle at (x, y): the lower-left node of its 3×3
    stencil, the 1-D weights and their derivatives in physical units (1/m)."""
    bx, wx0, wx1, wx2, dx0, dx1, dx2 = shape1d(kind, (x - ox) * inv_dx, lp)
    by, wy0, wy1, wy2, dy0, dy1, dy2 = shape1d(kind, (y - oy) * inv_dx, lp)
    return (bx, by, (wx0, wx1, wx2), (wy0, wy1, wy2),
            (dx0 * inv_dx, dx1 * inv_dx, dx2 * inv_dx),
            (dy0 * inv_dx, dy1 * inv_dx, dy2 * inv_dx))


@njit(cache=True, parallel=True)
def p2g(xp, yp, vx, vy, mass, S, kind, lp, ox, oy, inv_dx, gravx, gravy, buf,
        gm, gpx, gpy, gfx, gfy):
    """Scatter mass, momentum and internal + body force to the grid. Returns the number of
    particles skipped because their stencil is off the grid (0 in a healthy run)."""
    nt = buf.shape[0]
    n = xp.size
    nnx, nny = gm.shape
    skipped = 0
    for t in prange(nt):
        b = buf[t]
        b[:] = 0.0
        lo = (t * n) // nt
        hi = ((t + 1) * n) // nt
        for p in range(lo, hi):
            bx, by, wx, wy, dwx, dwy = _stencil(kind, xp[p], yp[p], ox, oy, inv_dx, lp)
            if not _on_grid(bx, by, nnx, nny):
                skipped += 1
                continue
            m = mass[p]
            mvx = m * vx[p]
            mvy = m * vy[p]
            vol = m / S[p, RHO]
            sxx = vol * S[p, SXX]
            syy = vol * S[p, SYY]
            sxy = vol * S[p, SXY]
            for a in range(3):
                i = bx + a
                for c in range(3):
                    j = by + c
                    w = wx[a] * wy[c]
                    gx = dwx[a] * wy[c]
                    gy = wx[a] * dwy[c]
                    b[i, j, 0] += w * m
                    b[i, j, 1] += w * mvx
                    b[i, j, 2] += w * mvy
                    b[i, j, 3] += w * m * gravx - (sxx * gx + sxy * gy)
                    b[i, j, 4] += w * m * gravy - (sxy * gx + syy * gy)
    for i in prange(nnx):
        for j in range(nny):
            sm = 0.0
            spx = 0.0
            spy = 0.0
            sfx = 0.0
            sfy = 0.0
            for t in range(nt):
                sm += buf[t, i, j, 0]
                spx += buf[t, i, j, 1]
                spy += buf[t, i, j, 2]
                sfx += buf[t, i, j, 3]
                sfy += buf[t, i, j, 4]
            gm[i, j] = sm
            gpx[i, j] = spx
            gpy[i, j] = spy
            gfx[i, j] = sfx
            gfy[i, j] = sfy
    return skipped


@njit(cache=True)
def _fold(a, k, side, bnode, sign):
    """Add the ghost layer ``k`` of a symmetry side onto its mirror (times ``sign``)."""
    nnx, nny = a.shape
    if side == 0:          # left: ghost column bnode-k -> bnode+k
        g, m = bnode - k, bnode + k
        if g >= 0 and m < nnx:
            for j in range(nny):
                a[m, j] += sign * a[g, j]
    elif side == 1:        # right: ghost bnode+k -> bnode-k
        g, m = bnode + k, bnode - k
        if g < nnx and m >= 0:
            for j in range(nny):
                a[m, j] += sign * a[g, j]
    elif side == 2:        # bottom
        g, m = bnode - k, bnode + k
        if g >= 0 and m < nny:
            for i in range(nnx):
                a[i, m] += sign * a[i, g]
    else:                  # top
        g, m = bnode + k, bnode - k
        if g < nny and m >= 0:
            for i in range(nnx):
                a[i, m] += sign * a[i, g]


@njit(cache=True)
def _unfold(a, k, side, bnode, sign):
    """Set the ghost layer ``k`` of a symmetry side to ``sign`` × its mirror."""
    nnx, nny = a.shape
    if side == 0:
        g, m = bnode - k, bnode + k
        if g >= 0 and m < nnx:
            for j in range(nny):
                a[g, j] = sign * a[m, j]
    elif side == 1:
        g, m = bnode + k, bnode - k
        if g < nnx and m >= 0:
            for j in range(nny):
                a[g, j] = sign * a[m, j]
    elif side == 2:
        g, m = bnode - k, bnode + k
        if g >= 0 and m < nny:
            for i in range(nnx):
                a[i, g] = sign * a[i, m]
    else:
        g, m = bnode + k, bnode - k
        if g < nny and m >= 0:
            for i in range(nnx):
                a[i, g] = sign * a[i, m]


@njit(cache=True, forceinline=True)
def _mirror_signs(kind, side):
    """Signs of (v_x, v_y) of a ghost node relative to its mirror: a fixed wall is the odd
    image (both components flip); a roller/symmetry plane flips the normal component only."""
    if kind == 1:
        return -1.0, -1.0
    if side < 2:
        return -1.0, 1.0
    return 1.0, -1.0


@njit(cache=True, parallel=True)
def grid_solve(gm, gpx, gpy, gfx, gfy, dt, forces, fold_mass, fixx, fixy, etax, etay, sides,
               bnodes, pad, mtiny, gvx, gvy, gdx, gdy):
    """Grid velocities with boundary conditions.

    ``forces``: v^L = (p + f·dt)/m and Δv = v^L − p/m (both with the boundary conditions);
    otherwise v = p/m (MUSL remap). Absorbing sides: nodes with dashpots (``etax``, ``etay``
    > 0) take v^L = (p + f·dt)/(m + η·dt) (implicit dashpot, grid.py). Fixed, roller and
    symmetry sides (``sides[s] != 0``: the folded codes, grid.folded_side_codes) fold
    the ghost layers onto their mirrors first (x sides, then y sides; the mass only when
    ``fold_mass``) and mirror the velocities back onto the ghosts last (y sides, then x
    sides): the contribution of image particles (odd image for a fixed wall, even tangential /
    odd normal for a roller or symmetry plane).
    """
    nnx, nny = gm.shape
    for s in range(4):
        if sides[s] != 0:
            nx_sign, ny_sign = _mirror_signs(sides[s], s)
            # k = 0 is the node on the plane, its own image: mass doubled, reversed
            # components cancelled (exactly what the image particles would add)
            for k in range(0, pad + 1):
                if fold_mass:
                    _fold(gm, k, s, bnodes[s], 1.0)
                _fold(gpx, k, s, bnodes[s], nx_sign)
                _fold(gpy, k, s, bnodes[s], ny_sign)
                if forces:
                    _fold(gfx, k, s, bnodes[s], nx_sign)
                    _fold(gfy, k, s, bnodes[s], ny_sign)
    for i in prange(nnx):
        for j in range(nny):
            m = gm[i, j]
            if m > mtiny:
                vx = gpx[i, j] / m
                vy = gpy[i, j] / m
                if forces:
                    nvx = vx + dt * gfx[i, j] / m
                    nvy = vy + dt * gfy[i, j] / m
                    if etax[i, j] > 0.0:
                        nvx = (gpx[i, j] + dt * gfx[i, j]) / (m + dt * etax[i, j])
                    if etay[i, j] > 0.0:
                        nvy = (gpy[i, j] + dt * gfy[i, j]) / (m + dt * etay[i, j])
                else:
                    nvx = vx
                    nvy = vy
            else:
                vx = 0.0
                vy = 0.0
                nvx = 0.0
                nvy = 0.0
            if fixx[i, j]:
                nvx = 0.0
            if fixy[i, j]:
                nvy = 0.0
            gvx[i, j] = nvx
            gvy[i, j] = nvy
            if forces:
                gdx[i, j] = nvx - vx
                gdy[i, j] = nvy - vy
    for s in (3, 2, 1, 0):
        if sides[s] != 0:
            nx_sign, ny_sign = _mirror_signs(sides[s], s)
            for k in range(1, pad + 1):
                _unfold(gvx, k, s, bnodes[s], nx_sign)
                _unfold(gvy, k, s, bnodes[s], ny_sign)
                if forces:
                    _unfold(gdx, k, s, bnodes[s], nx_sign)
                    _unfold(gdy, k, s, bnodes[s], ny_sign)


@njit(cache=True, parallel=True)
def g2p_velocity_remap(xp, yp, vx, vy, mass, kind, lp, ox, oy, inv_dx, gvx, gvy, gdx, gdy, dt,
                       flip, xn, yn, buf, gpx, gpy, err):
    """Particle velocity v ← flip·(v + Σ N Δv) + (1 − flip)·Σ N v^L and new positions
    x_new = x + dt·Σ N v^L (into ``xn``, ``yn``), and at once the MUSL remap: the new momentum
    m v scattered with the same (old-position) weights into ``gpx``, ``gpy`` — one pass, the
    stencil evaluated once. Returns the number of flagged particles."""
    nt = buf.shape[0]
    n = xp.size
    nnx, nny = gvx.shape
    nbad = 0
    for t in prange(nt):
        b = buf[t]
        lo = (t * n) // nt
        hi = ((t + 1) * n) // nt
        for i in range(b.shape[0]):
            for j in range(b.shape[1]):
                b[i, j, 1] = 0.0
                b[i, j, 2] = 0.0
        for p in range(lo, hi):
            bx, by, wx, wy, dwx, dwy = _stencil(kind, xp[p], yp[p], ox, oy, inv_dx, lp)
            if not _on_grid(bx, by, nnx, nny):
                err[p] = ERR_LEFT_GRID
                nbad += 1
                continue
            vlx = 0.0
            vly = 0.0
            dvx = 0.0
            dvy = 0.0
            for a in range(3):
                i = bx + a
                for c in range(3):
                    j = by + c
                    w = wx[a] * wy[c]
                    vlx += w * gvx[i, j]
                    vly += w * gvy[i, j]
                    dvx += w * gdx[i, j]
                    dvy += w * gdy[i, j]
            nvx = flip * (vx[p] + dvx) + (1.0 - flip) * vlx
            nvy = flip * (vy[p] + dvy) + (1.0 - flip) * vly
            x1 = xp[p] + dt * vlx
            y1 = yp[p] + dt * vly
            vx[p] = nvx
            vy[p] = nvy
            xn[p] = x1
            yn[p] = y1
            if (nvx * 0.0 + nvy * 0.0 + x1 * 0.0 + y1 * 0.0) != 0.0:
                err[p] = ERR_CORE_NONFINITE
                nbad += 1
                continue
            mvx = mass[p] * nvx
            mvy = mass[p] * nvy
            for a in range(3):
                i = bx + a
                for c in range(3):
                    w = wx[a] * wy[c]
                    b[i, by + c, 1] += w * mvx
                    b[i, by + c, 2] += w * mvy
    for i in prange(nnx):
        for j in range(nny):
            spx = 0.0
            spy = 0.0
            for t in range(nt):
                spx += buf[t, i, j, 1]
                spy += buf[t, i, j, 2]
            gpx[i, j] = spx
            gpy[i, j] = spy
    return nbad


@njit(cache=True, parallel=True)
def g2p_gradient(xp, yp, kind, lp, ox, oy, inv_dx, gvx, gvy, xn, yn, Lg, err):
    """Velocity gradient L_p = Σ v_i ⊗ ∇N_i(x_p) (columns Lxx, Lxy, Lyx, Lyy with
    L_ab = ∂v_a/∂x_b), then x_p ← x_new; flags particles whose new stencil is off the grid.
    Returns the number of flagged particles."""
    nnx, nny = gvx.shape
    nbad = 0
    for p in prange(xp.size):
        bx, by, wx, wy, dwx, dwy = _stencil(kind, xp[p], yp[p], ox, oy, inv_dx, lp)
        if not _on_grid(bx, by, nnx, nny):
            err[p] = ERR_LEFT_GRID
            nbad += 1
            continue
        lxx = 0.0
        lxy = 0.0
        lyx = 0.0
        lyy = 0.0
        for a in range(3):
            i = bx + a
            for c in range(3):
                j = by + c
                gx = dwx[a] * wy[c]
                gy = wx[a] * dwy[c]
                lxx += gvx[i, j] * gx
                lxy += gvx[i, j] * gy
                lyx += gvy[i, j] * gx
                lyy += gvy[i, j] * gy
        Lg[p, 0] = lxx
        Lg[p, 1] = lxy
        Lg[p, 2] = lyx
        Lg[p, 3] = lyy
        xp[p] = xn[p]
        yp[p] = yn[p]
        # only the new stencil's first node is needed: the weights' code (three kinds,
        # inlined) would multiply this kernel's compile time for nothing
        if not _on_grid(stencil_base((xn[p] - ox) * inv_dx),
                        stencil_base((yn[p] - oy) * inv_dx), nnx, nny):
            err[p] = ERR_LEFT_GRID
            nbad += 1
    return nbad


@njit(cache=True, parallel=True)
def check_state(S, err):
    """Flag (ERR_CORE_NONFINITE) particles whose state row holds a NaN or inf."""
    nbad = 0
    for p in prange(S.shape[0]):
        acc = 0.0
        for k in range(N_STATE):
            acc += S[p, k] * 0.0
        if acc != 0.0:
            err[p] = ERR_CORE_NONFINITE
            nbad += 1
    return nbad


@njit(cache=True, parallel=True)
def energies(vx, vy, mass, vol0, S):
    """(kinetic, internal, plastic work, momentum x, momentum y) of all particles, per metre
    of thickness (J/m, kg/s)."""
    ke = 0.0
    ie = 0.0
    pw = 0.0
    mx = 0.0
    my = 0.0
    for p in prange(vx.size):
        ke += 0.5 * mass[p] * (vx[p] * vx[p] + vy[p] * vy[p])
        ie += S[p, E] * vol0[p]
        pw += S[p, PLASTIC_WORK] * vol0[p]
        mx += mass[p] * vx[p]
        my += mass[p] * vy[p]
    return ke, ie, pw, mx, my


def grid_buffers(nthreads, nnx, nny):
    """Per-thread scatter buffers, node-major (the 5 quantities of a node share a cache line):
    mass, momentum x, y, force x, y."""
    return np.zeros((nthreads, nnx, nny, 5))


# ------------------------------------------------------------------------------------------
# Material dispatch
# ------------------------------------------------------------------------------------------
# One cached loop per material module: a loop over that material's particle index list
# calling the module's ``update``. Numba cannot cache a kernel that takes the update function
# as an argument or closes over it (measured: it recompiles in every process), so the loops
# of the library's modules are written out here; a module not listed falls back to the
# generic loop ``_loop_any`` (compiled once per process, not cached).
from solvers.mpm.materials import elastic as _elastic          # noqa: E402
from solvers.mpm.materials import johnson_cook as _johnson_cook  # noqa: E402
from solvers.mpm.materials import jwl as _jwl                  # noqa: E402
from solvers.mpm.materials import water as _water              # noqa: E402


@njit(cache=True, forceinline=True)
def _prepare(S, i, Lg, q1, q2, length, dt, time, xp, yp):
    """Write the bulk viscosity of row i's step (column Q, before the material update) and
    tell whether the row may skip the per-row guards of ``update``: finite arguments and
    ρ > 0 (the row itself was checked finite after the previous update, by ``_settle``)."""
    S[i, Q] = bulk_viscosity(S[i, RHO], length, S[i, C], Lg[i, 0] + Lg[i, 3], q1, q2)
    return (S[i, RHO] > 0.0
            and finite_args(Lg[i, 0], Lg[i, 1], Lg[i, 2], Lg[i, 3], dt, time, xp[i], yp[i]))


@njit(cache=True, forceinline=True)
def _settle(S, i, code, vx, vy, err, check_row=True):
    """(failed, c + |v|) of row i after its update: the code, or the core's state check (a
    non-finite row is ERR_CORE_NONFINITE; skipped, ``check_row`` False, for a material whose
    ``advance`` checks every value it writes), flagged in ``err``; the particle's signal
    speed for the next CFL step."""
    if check_row and code == 0 and not row_finite(S, i):
        code = ERR_CORE_NONFINITE
    if code != 0:
        err[i] = code
        return 1, 0.0
    return 0, S[i, C] + math.sqrt(vx[i] * vx[i] + vy[i] * vy[i])


@njit(cache=True, parallel=True)
def _loop_elastic(prm, S, idx, Lg, q1, q2, length, dt, time, xp, yp, vx, vy, err):
    bulk_ok = bulk_guards_pass(prm, _elastic.NPRM, S, dt, time)
    nbad = 0
    vmax = 0.0
    for k in prange(idx.size):
        i = idx[k]
        L = (Lg[i, 0], Lg[i, 1], Lg[i, 2], Lg[i, 3])
        if _prepare(S, i, Lg, q1, q2, length, dt, time, xp, yp) and bulk_ok:
            e = _elastic.advance(prm, S, i, L[0], L[1], L[2], L[3], dt, time, xp[i], yp[i])
        else:
            e = _elastic.update(prm, S, i, L[0], L[1], L[2], L[3], dt, time, xp[i], yp[i])
        bad, speed = _settle(S, i, e, vx, vy, err)
        nbad += bad
        vmax = max(vmax, speed)
    return nbad, vmax


@njit(cache=True, parallel=True)
def _loop_johnson_cook(prm, S, idx, Lg, q1, q2, length, dt, time, xp, yp, vx, vy, err):
    bulk_ok = bulk_guards_pass(prm, _johnson_cook.NPRM, S, dt, time)
    nbad = 0
    vmax = 0.0
    for k in prange(idx.size):
        i = idx[k]
        L = (Lg[i, 0], Lg[i, 1], Lg[i, 2], Lg[i, 3])
        if _prepare(S, i, Lg, q1, q2, length, dt, time, xp, yp) and bulk_ok:
            e = _johnson_cook.advance(prm, S, i, L[0], L[1], L[2], L[3], dt, time, xp[i], yp[i])
        else:
            e = _johnson_cook.update(prm, S, i, L[0], L[1], L[2], L[3], dt, time, xp[i], yp[i])
        bad, speed = _settle(S, i, e, vx, vy, err)
        nbad += bad
        vmax = max(vmax, speed)
    return nbad, vmax


@njit(cache=True, parallel=True)
def _loop_jwl(prm, S, idx, Lg, q1, q2, length, dt, time, xp, yp, vx, vy, err):
    bulk_ok = bulk_guards_pass(prm, _jwl.NPRM, S, dt, time)
    nbad = 0
    vmax = 0.0
    for k in prange(idx.size):
        i = idx[k]
        L = (Lg[i, 0], Lg[i, 1], Lg[i, 2], Lg[i, 3])
        if _prepare(S, i, Lg, q1, q2, length, dt, time, xp, yp) and bulk_ok:
            e = _jwl.advance(prm, S, i, L[0], L[1], L[2], L[3], dt, time, xp[i], yp[i])
        else:
            e = _jwl.update(prm, S, i, L[0], L[1], L[2], L[3], dt, time, xp[i], yp[i])
        bad, speed = _settle(S, i, e, vx, vy, err)
        nbad += bad
        vmax = max(vmax, speed)
    return nbad, vmax


@njit(cache=True, parallel=True)
def _loop_water(prm, S, idx, Lg, q1, q2, length, dt, time, xp, yp, vx, vy, err):
    bulk_ok = bulk_guards_pass(prm, _water.NPRM, S, dt, time)
    nbad = 0
    vmax = 0.0
    for k in prange(idx.size):
        i = idx[k]
        L = (Lg[i, 0], Lg[i, 1], Lg[i, 2], Lg[i, 3])
        if _prepare(S, i, Lg, q1, q2, length, dt, time, xp, yp) and bulk_ok:
            e = _water.advance(prm, S, i, L[0], L[1], L[2], L[3], dt, time, xp[i], yp[i])
        else:
            e = _water.update(prm, S, i, L[0], L[1], L[2], L[3], dt, time, xp[i], yp[i])
        bad, speed = _settle(S, i, e, vx, vy, err, not _water.ADVANCE_CHECKS_ITS_WRITES)
        nbad += bad
        vmax = max(vmax, speed)
    return nbad, vmax


@njit(cache=True)
def _init_elastic(prm, S, idx, err):
    nbad = 0
    for k in range(idx.size):
        e = _elastic.init(prm, S, idx[k])
        if e != 0:
            err[idx[k]] = e
            nbad += 1
    return nbad


@njit(cache=True)
def _init_johnson_cook(prm, S, idx, err):
    nbad = 0
    for k in range(idx.size):
        e = _johnson_cook.init(prm, S, idx[k])
        if e != 0:
            err[idx[k]] = e
            nbad += 1
    return nbad


@njit(cache=True)
def _init_jwl(prm, S, idx, err):
    nbad = 0
    for k in range(idx.size):
        e = _jwl.init(prm, S, idx[k])
        if e != 0:
            err[idx[k]] = e
            nbad += 1
    return nbad


@njit(cache=True)
def _init_water(prm, S, idx, err):
    nbad = 0
    for k in range(idx.size):
        e = _water.init(prm, S, idx[k])
        if e != 0:
            err[idx[k]] = e
            nbad += 1
    return nbad


_LOOPS = {_elastic: (_loop_elastic, _init_elastic),
          _johnson_cook: (_loop_johnson_cook, _init_johnson_cook),
          _jwl: (_loop_jwl, _init_jwl),
          _water: (_loop_water, _init_water)}


@njit(parallel=True)
def _loop_any(update, prm, S, idx, Lg, q1, q2, length, dt, time, xp, yp, vx, vy, err):
    nbad = 0
    vmax = 0.0
    for k in prange(idx.size):
        i = idx[k]
        _prepare(S, i, Lg, q1, q2, length, dt, time, xp, yp)
        e = update(prm, S, i, Lg[i, 0], Lg[i, 1], Lg[i, 2], Lg[i, 3], dt, time, xp[i], yp[i])
        bad, speed = _settle(S, i, e, vx, vy, err)
        nbad += bad
        vmax = max(vmax, speed)
    return nbad, vmax


@njit
def _init_any(init, prm, S, idx, err):
    nbad = 0
    for k in range(idx.size):
        e = init(prm, S, idx[k])
        if e != 0:
            err[idx[k]] = e
            nbad += 1
    return nbad


def loop_for(module, parallel=True):
    """(update_loop, init_loop) for a material module: the cached loops of the library's
    modules, else the generic (uncached) ones bound to the module's kernels; ``parallel``
    False: the update loop's serial twin (``kernels``)."""
    if module in _LOOPS:
        update, init = _LOOPS[module]
        return (update if parallel else _SERIAL_LOOPS[module]), init
    upd, ini = module.update, module.init
    loop = _loop_any if parallel else _loop_any_serial

    def update_loop(prm, S, idx, Lg, q1, q2, length, dt, time, xp, yp, vx, vy, err):
        return loop(upd, prm, S, idx, Lg, q1, q2, length, dt, time, xp, yp, vx, vy, err)

    def init_loop(prm, S, idx, err):
        return _init_any(ini, prm, S, idx, err)

    return update_loop, init_loop


# ------------------------------------------------------------------------------------------
# Serial twins: the kernels for runs on one thread
# ------------------------------------------------------------------------------------------
def _serial_twin(kernel, cache=True, nrt=True):
    """``kernel``'s Python function compiled without parfors. A run on one thread (the scenes'
    default, and every run below SERIAL_BELOW particles) gains nothing from parfors and pays
    for it at compile time: parfors' analysis and a gufunc per ``prange`` loop make the
    parallel kernels of the quickstart compile in 27 s against 17.5 s serial (issue 19).
    Numba keys its cache on the function's qualified name and bytecode, not on ``parallel``,
    so the twin is the same code under its own name: neither loads the other's machine code.
    """
    f = kernel.py_func
    twin = types.FunctionType(f.__code__, f.__globals__, f.__name__, f.__defaults__,
                              f.__closure__)
    twin.__qualname__ = f"{f.__qualname__}_serial"
    twin.__doc__ = f.__doc__
    return njit(cache=cache, _nrt=nrt)(twin)


_PARALLEL_KERNELS = (max_speed, p2g, grid_solve, g2p_velocity_remap, g2p_gradient, check_state,
                     energies)
PARALLEL = types.SimpleNamespace(**{k.py_func.__name__: k for k in _PARALLEL_KERNELS})
SERIAL = types.SimpleNamespace(**{k.py_func.__name__: _serial_twin(k)
                                  for k in _PARALLEL_KERNELS})
# without numba's reference counting: the loops allocate nothing, and the counts numba adds
# around each call that takes an array (atomic, opaque to LLVM) cost the water loop a fifth of
# its time; the parfors kernels need it for their reductions, and prune those counts anyway
_SERIAL_LOOPS = {module: _serial_twin(update, nrt=False)
                 for module, (update, _init) in _LOOPS.items()}
_loop_any_serial = _serial_twin(_loop_any, cache=False)


def kernels(parallel: bool):
    """The grid and particle kernels of a run: the parfors ones, or their serial twins."""
    return PARALLEL if parallel else SERIAL
