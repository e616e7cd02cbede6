"""Reference throughput: a minimal 2-D MLS-MPM step in Taichi on its CPU backend.

The side-by-side figure of ``benchmarks/mpm_throughput.py``: the cheapest explicit MPM step
one can write — MLS-MPM (Hu et al. 2018, "A moving least squares material point method with
displacement discontinuity and two-way rigid body coupling", SIGGRAPH), a weakly compressible
fluid (pressure from J only), quadratic B-splines (3 × 3 stencil), APIC affine transfer,
float64 everywhere. One P2G (atomic scatter), one grid update (gravity, sticky walls), one
G2P per step; no material library, no guards, no bulk viscosity, no MUSL second pass.

Particles: ``n`` on a 2 × 2 lattice per cell over a square block filling the domain (as the
solver's scenes fill theirs), a grid of sqrt(n / 4) cells a side plus 3 cells of padding.

    python benchmarks/taichi_mlsmpm.py --particles 160000 --steps 50 [--threads 2] [--json]

prints one JSON object (``particle_updates_per_s``, the per-repetition times, ...) as its last
line of stdout. Taichi prints a banner on stdout at ``ti.init``; callers take the last line.
"""

from __future__ import annotations

import math
import statistics
import sys
import time


def measure(n_particles: int, steps: int, repeats: int = 5, threads: int = 2) -> dict:
    import taichi as ti

    ti.init(arch=ti.cpu, cpu_max_num_threads=threads, default_fp=ti.f64, default_ip=ti.i32,
            random_seed=0, log_level=ti.WARN)

    ppc = 2                                   # particles per cell, per direction
    cells = max(4, int(round(math.sqrt(n_particles / ppc ** 2))))
    pad = 3
    ng = cells + 2 * pad                      # grid nodes a side
    n = cells * cells * ppc * ppc             # exactly n_particles for square counts
    dx = 1.0 / cells
    inv_dx = 1.0 / dx
    rho = 1.0
    bulk = 400.0                              # "E" of the equation of state p = -K (J - 1)
    c = math.sqrt(bulk / rho)
    dt = 0.2 * dx / c                         # CFL 0.2 on the sound speed
    p_vol = (dx / ppc) ** 2
    p_mass = rho * p_vol
    gravity = -9.8

    x = ti.Vector.field(2, dtype=ti.f64, shape=n)
    v = ti.Vector.field(2, dtype=ti.f64, shape=n)
    C = ti.Matrix.field(2, 2, dtype=ti.f64, shape=n)
    J = ti.field(dtype=ti.f64, shape=n)
    grid_v = ti.Vector.field(2, dtype=ti.f64, shape=(ng, ng))
    grid_m = ti.field(dtype=ti.f64, shape=(ng, ng))

    @ti.kernel
    def seed():
        for p in range(n):
            cell = p // (ppc * ppc)
            sub = p % (ppc * ppc)
            ci = cell % cells
            cj = cell // cells
            si = sub % ppc
            sj = sub // ppc
            x[p] = ti.Vector([(pad + ci + (si + 0.5) / ppc) * dx,
                              (pad + cj + (sj + 0.5) / ppc) * dx])
            v[p] = ti.Vector([0.0, 0.0])
            C[p] = ti.Matrix.zero(ti.f64, 2, 2)
            J[p] = 1.0

    @ti.kernel
    def substep():
        # clear the grid
        for i, j in grid_m:
            grid_v[i, j] = ti.Vector([0.0, 0.0])
            grid_m[i, j] = 0.0
        # P2G: MLS-MPM — the stress term folded into the affine momentum matrix
        for p in x:
            xi = x[p] * inv_dx
            base = ti.cast(xi - 0.5, ti.i32)
            fx = xi - ti.cast(base, ti.f64)
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            # Cauchy stress of the fluid: sigma = -p I, p = K (1 - J); the MLS nodal force
            # -dt V (4/dx^2) sigma (x_i - x_p) folded into the affine momentum matrix
            s = -dt * 4.0 * inv_dx * inv_dx * p_vol * bulk * (J[p] - 1.0)
            affine = ti.Matrix([[s, 0.0], [0.0, s]]) + p_mass * C[p]
            mv = p_mass * v[p]
            for a in ti.static(range(3)):
                for b in ti.static(range(3)):
                    weight = w[a][0] * w[b][1]
                    dpos = (ti.Vector([a, b]).cast(ti.f64) - fx) * dx
                    node = base + ti.Vector([a, b])
                    grid_v[node] += weight * (mv + affine @ dpos)
                    grid_m[node] += weight * p_mass
        # grid update: momentum -> velocity, gravity, sticky walls in the padding band
        for i, j in grid_m:
            m = grid_m[i, j]
            if m > 0.0:
                gv = grid_v[i, j] / m
                gv[1] += dt * gravity
                if i < pad and gv[0] < 0.0:
                    gv[0] = 0.0
                if i > ng - pad - 1 and gv[0] > 0.0:
                    gv[0] = 0.0
                if j < pad and gv[1] < 0.0:
                    gv[1] = 0.0
                if j > ng - pad - 1 and gv[1] > 0.0:
                    gv[1] = 0.0
                grid_v[i, j] = gv
        # G2P: APIC velocity and affine matrix, J from the trace of C, advection
        for p in x:
            xi = x[p] * inv_dx
            base = ti.cast(xi - 0.5, ti.i32)
            fx = xi - ti.cast(base, ti.f64)
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            nv = ti.Vector([0.0, 0.0])
            nC = ti.Matrix.zero(ti.f64, 2, 2)
            for a in ti.static(range(3)):
                for b in ti.static(range(3)):
                    weight = w[a][0] * w[b][1]
                    dpos = ti.Vector([a, b]).cast(ti.f64) - fx     # in cells
                    gv = grid_v[base + ti.Vector([a, b])]
                    nv += weight * gv
                    nC += 4.0 * inv_dx * weight * gv.outer_product(dpos)
            v[p] = nv
            C[p] = nC
            J[p] *= 1.0 + dt * nC.trace()
            x[p] += dt * nv

    seed()
    t0 = time.perf_counter()
    substep()                                  # compile
    ti.sync()
    compile_s = time.perf_counter() - t0
    for _ in range(3):
        substep()
    ti.sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            substep()
        ti.sync()
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    Jn = J.to_numpy()
    xn = x.to_numpy()
    ok = bool((Jn > 0).all() and math.isfinite(float(xn.sum())))
    return {"particles": n, "steps": steps, "repeats": repeats, "threads": threads,
            "grid_nodes": ng * ng, "dt": dt, "compile_s": compile_s, "times_s": times,
            "median_s": med, "step_s": med / steps,
            "particle_updates_per_s": n * steps / med, "finite": ok,
            "taichi_version": ".".join(map(str, ti.__version__)),
            "arch": "cpu", "precision": "f64"}


def main(argv=None) -> int:
    from _minimal_step import command_line      # beside this script, run as one
    return command_line(measure, "Taichi", argv)


if __name__ == "__main__":
    sys.exit(main())
