"""The minimal MLS-MPM step of ``benchmarks/taichi_mlsmpm.py``, written in numba.

``benchmarks/mpm_throughput.py`` compares our full-physics MUSL step with Taichi's minimal
MLS-MPM fluid step: two differences at once, the work a step does and the language. This
is the same minimal step, operation for operation (weakly compressible fluid, quadratic
B-splines, APIC, f64, the same lattice, time step, gravity and sticky walls), written in the
style of the solver's kernels (solvers/mpm/step.py): the scatter into one grid buffer per
thread over a contiguous chunk of particles, summed per node afterwards; the gather a
``prange`` over particles. Its rate beside Taichi's, in the same sets, is what the language
and the kernel style give on the same work; our full step beside it is what the seed's
MUSL step and the material models cost.

    python benchmarks/numba_mlsmpm.py --particles 160000 --steps 50 [--threads 2] [--json]

The thread count is set (NUMBA_NUM_THREADS) before numba is imported when run as a script;
imported, ``measure`` uses ``threads`` of the process's numba threads.
"""

from __future__ import annotations

import math
import statistics
import sys
import time

if __name__ == "__main__":
    from _threads import numba_threads_from_argv    # beside this script, run as one
    numba_threads_from_argv(sys.argv[1:])

import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba import njit, prange  # noqa: E402

PPC = 2          # particles per cell, per direction (as taichi_mlsmpm.py)
PAD = 3          # cells of padding
RHO = 1.0
BULK = 400.0     # p = -K (J - 1)
GRAVITY = -9.8


@njit(cache=True, forceinline=True)
def _weights(f):
    return 0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2


@njit(cache=True, forceinline=True)
def _stencil(x, p, inv_dx):
    """(bx, by, fx, fy, wx, wy): the stencil's first node, the particle's offset from it in
    cells, the 1-D weights — as Taichi's ``ti.cast(xi - 0.5, ti.i32)`` truncates."""
    xi = x[p, 0] * inv_dx
    yi = x[p, 1] * inv_dx
    bx = int(xi - 0.5)
    by = int(yi - 0.5)
    fx = xi - bx
    fy = yi - by
    return bx, by, fx, fy, _weights(fx), _weights(fy)


@njit(cache=True, parallel=True)
def substep(x, v, C, J, buf, grid_m, grid_v, dx, dt, p_vol, p_mass):
    """One P2G (MLS force folded into the affine momentum), grid update, G2P."""
    nt = buf.shape[0]
    n = x.shape[0]
    ng = grid_m.shape[0]
    inv_dx = 1.0 / dx
    stress = -dt * 4.0 * inv_dx * inv_dx * p_vol * BULK
    for t in prange(nt):
        b = buf[t]
        b[:] = 0.0
        for p in range((t * n) // nt, ((t + 1) * n) // nt):
            bx, by, fx, fy, wx, wy = _stencil(x, p, inv_dx)
            s = stress * (J[p] - 1.0)
            a00 = s + p_mass * C[p, 0, 0]
            a01 = p_mass * C[p, 0, 1]
            a10 = p_mass * C[p, 1, 0]
            a11 = s + p_mass * C[p, 1, 1]
            mvx = p_mass * v[p, 0]
            mvy = p_mass * v[p, 1]
            for a in range(3):
                dpx = (a - fx) * dx
                for c in range(3):
                    dpy = (c - fy) * dx
                    w = wx[a] * wy[c]
                    b[bx + a, by + c, 0] += w * (mvx + a00 * dpx + a01 * dpy)
                    b[bx + a, by + c, 1] += w * (mvy + a10 * dpx + a11 * dpy)
                    b[bx + a, by + c, 2] += w * p_mass
    # the threads' buffers folded into the first, node by node, then the grid update
    for i in prange(ng):
        for j in range(ng):
            for t in range(1, nt):
                for q in range(3):
                    buf[0, i, j, q] += buf[t, i, j, q]
            px, py, m = buf[0, i, j, 0], buf[0, i, j, 1], buf[0, i, j, 2]
            grid_m[i, j] = m
            gx = 0.0
            gy = 0.0
            if m > 0.0:
                gx = px / m
                gy = py / m + dt * GRAVITY
                if i < PAD and gx < 0.0:
                    gx = 0.0
                if i > ng - PAD - 1 and gx > 0.0:
                    gx = 0.0
                if j < PAD and gy < 0.0:
                    gy = 0.0
                if j > ng - PAD - 1 and gy > 0.0:
                    gy = 0.0
            grid_v[i, j, 0] = gx
            grid_v[i, j, 1] = gy
    for p in prange(n):
        bx, by, fx, fy, wx, wy = _stencil(x, p, inv_dx)
        nvx = 0.0
        nvy = 0.0
        c00 = 0.0
        c01 = 0.0
        c10 = 0.0
        c11 = 0.0
        for a in range(3):
            dpx = a - fx
            for c in range(3):
                dpy = c - fy
                w = wx[a] * wy[c]
                gx = grid_v[bx + a, by + c, 0]
                gy = grid_v[bx + a, by + c, 1]
                nvx += w * gx
                nvy += w * gy
                k = 4.0 * inv_dx * w
                c00 += k * gx * dpx
                c01 += k * gx * dpy
                c10 += k * gy * dpx
                c11 += k * gy * dpy
        v[p, 0] = nvx
        v[p, 1] = nvy
        C[p, 0, 0] = c00
        C[p, 0, 1] = c01
        C[p, 1, 0] = c10
        C[p, 1, 1] = c11
        J[p] *= 1.0 + dt * (c00 + c11)
        x[p, 0] += dt * nvx
        x[p, 1] += dt * nvy


def lattice(n_particles: int):
    """(x, cells, dx): taichi_mlsmpm.py's lattice — PPC × PPC particles per cell, cell-major,
    over a square block of sqrt(n / PPC²) cells a side inside PAD cells of padding."""
    cells = max(4, int(round(math.sqrt(n_particles / PPC ** 2))))
    dx = 1.0 / cells
    p = np.arange(cells * cells * PPC * PPC)
    cell, sub = p // (PPC * PPC), p % (PPC * PPC)
    x = np.empty((p.size, 2))
    x[:, 0] = (PAD + cell % cells + (sub % PPC + 0.5) / PPC) * dx
    x[:, 1] = (PAD + cell // cells + (sub // PPC + 0.5) / PPC) * dx
    return x, cells, dx


def at_rest(n_particles: int, threads: int):
    """(x, v, C, J, buf, grid_m, grid_v, dx, dt, p_vol, p_mass): ``substep``'s arguments for
    the lattice at rest (v = 0, C = 0, J = 1), with one grid buffer per thread."""
    x, cells, dx = lattice(n_particles)
    n = x.shape[0]
    ng = cells + 2 * PAD
    dt = 0.2 * dx / math.sqrt(BULK / RHO)          # CFL 0.2 on the sound speed
    p_vol = (dx / PPC) ** 2
    return (x, np.zeros((n, 2)), np.zeros((n, 2, 2)), np.ones(n), np.zeros((threads, ng, ng, 3)),
            np.zeros((ng, ng)), np.zeros((ng, ng, 2)), dx, dt, p_vol, RHO * p_vol)


def measure(n_particles: int, steps: int, repeats: int = 5, threads: int = 2) -> dict:
    state = at_rest(n_particles, threads)
    x, J = state[0], state[3]
    n = x.shape[0]
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        t0 = time.perf_counter()
        substep(*state)                            # compile, or load numba's cache
        compile_s = time.perf_counter() - t0
        for _ in range(3):
            substep(*state)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(steps):
                substep(*state)
            times.append(time.perf_counter() - t0)
    finally:
        numba.set_num_threads(before)
    med = statistics.median(times)
    return {"particles": n, "steps": steps, "repeats": repeats, "threads": threads,
            "grid_nodes": state[5].size, "dt": state[8], "compile_s": compile_s, "times_s": times,
            "median_s": med, "step_s": med / steps, "particle_updates_per_s": n * steps / med,
            "finite": bool((J > 0).all() and np.isfinite(x).all()),
            "numba_version": numba.__version__, "precision": "f64"}


def main(argv=None) -> int:
    from _minimal_step import command_line      # beside this script, run as one
    return command_line(measure, "numba", argv)


if __name__ == "__main__":
    sys.exit(main())
