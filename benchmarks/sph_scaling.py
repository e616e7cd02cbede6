"""SPH: time of each phase (neighbour search, assembly, transformation, solve) and peak memory
against particle count, for the four constraint methods and three linear solvers.

A square plate (spacing 1) with a central circular inclusion of a quarter of its side, the
seed's Example 1 materials and eigenstrain, the exact displacement on the whole edge: every
edge particle is a slave, the worst case for plain master-slave. Median of ``--repeats`` runs
per cell; a method and solver are not run at a size where their last median, grown as the
side cubed (a direct solve's n^1.5), would exceed ``--cap`` seconds. Solvers: "direct" (the
default: SuperLU in a nested-dissection order of the particles, or in MMD), "superlu-order"
(SuperLU in its own orders, the direct solver before) and "iterative" (GMRES with an
incomplete LU). Peak memory: the largest resident size sampled during the run above the size
before it (psutil; blank without it). ``--big SIDE`` adds one MS2 direct run of a plate of
that side (450: 202,500 particles).

    python benchmarks/sph_scaling.py            # writes BENCHMARKS.md section "sph-scaling"
    python benchmarks/sph_scaling.py --quick    # a tiny run
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import write_section  # noqa: E402

from solvers.sph.exact import eshelby_displacement  # noqa: E402
from solvers.sph.layouts import Box, Ellipse, regular_layout  # noqa: E402
from solvers.sph.linear import MIXED_PRECISION_ABOVE  # noqa: E402
from solvers.sph.problem import LAGRANGE_FORM_ABOVE, ElasticProblem  # noqa: E402
from solvers.sph.stiffness import Discretisation  # noqa: E402

#: plain MS twice: as the solver chooses (its Lagrange form above LAGRANGE_FORM_ABOVE unknowns)
#: and always reduced (K^ = P^T K P, the solver before)
METHODS = (("master-slave", {}), ("master-slave", {"lagrange_form_above": 10**12}),
           ("master-slave-cutoff", {"cutoff_threshold": 1e-8}),
           ("master-slave-local", {}), ("penalty", {"penalty": 1e4}))
SOLVERS = ("direct", "superlu-order", "iterative", "pardiso")


def label(method, extra) -> str:
    return method + (" (reduced)" if "lagrange_form_above" in extra else "")


def pardiso_available() -> bool:
    return importlib.util.find_spec("pypardiso") is not None


class PeakMemory:
    """The largest resident set size above the starting one, sampled every ``every`` s."""

    def __init__(self, every=0.02):
        try:
            import psutil
        except ImportError:
            psutil = None
        self.process = psutil.Process() if psutil else None
        self.every, self.peak = every, None

    def __enter__(self):
        if self.process is None:
            return self
        self.start = self.peak = self.process.memory_info().rss
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._sample, daemon=True)
        self.thread.start()
        return self

    def _sample(self):
        while not self.stop.wait(self.every):
            self.peak = max(self.peak, self.process.memory_info().rss)

    def __exit__(self, *exc):
        if self.process is not None:
            self.stop.set()
            self.thread.join()
            self.peak = max(self.peak, self.process.memory_info().rss) - self.start

    @property
    def mib(self):
        return None if self.peak is None else self.peak / 2 ** 20


def one_run(side, method, extra, solver):
    with PeakMemory() as memory:
        n, times, t_layout = _solve(side, method, extra, solver)
    times["peak_mib"] = memory.mib
    return n, times, t_layout


def _solve(side, method, extra, solver):
    problem, edge, t_layout = plate_problem(side, method, extra, solver)
    sol = problem.solve(edge)
    factor = problem._system[1]["factor"]
    times = dict(problem.setup_timings, system_nnz=factor.A.nnz, factor_nnz=factor.factor_nnz,
                 dissected=float(factor.ordering == "nested dissection"),
                 single=float(factor.precision == "single, refined"))
    for k, v in sol.timings.items():
        times[k] = times.get(k, 0.0) + v
    times["total"] = sum(times[k] for k in ("neighbours", "assembly", "transformation", "solve"))
    return problem.disc.layout.n, times, t_layout


def plate_problem(side, method, extra, solver):
    """(the ElasticProblem of the plate of this side, its edge displacement, the layout's
    seconds)."""
    t0 = time.perf_counter()
    lay = regular_layout(Box(-side / 2, -side / 2, side / 2, side / 2), 1.0,
                         [Ellipse(0.0, 0.0, side / 4, side / 4)])
    t_layout = time.perf_counter() - t0
    disc = Discretisation(lay, 2.0)
    inside = lay.phase > 0
    eigen = np.zeros((lay.n, 3))
    eigen[inside, :2] = 0.01
    problem = ElasticProblem(disc, np.where(inside, 1000.0, 900.0),
                             np.where(inside, 0.28, 0.33), eigenstrain=eigen, method=method,
                             linear_solver=solver if solver in ("iterative", "pardiso")
                             else "direct",
                             dissection=solver != "superlu-order", **extra)
    edge = eshelby_displacement(lay.x[lay.boundary], side / 4, eigenstrain=0.01,
                                E_inclusion=1000.0, nu_inclusion=0.28, E_matrix=900.0,
                                nu_matrix=0.33)
    return problem, edge, t_layout


def mkl_threads() -> str:
    """MKL's thread count as PARDISO will use it (MKL_NUM_THREADS, else every core)."""
    return os.environ.get("MKL_NUM_THREADS", str(os.cpu_count()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sides", type=int, nargs="*", default=[30, 60, 100, 140, 200])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cap", type=float, default=30.0)
    ap.add_argument("--big", type=int, default=None, help="side of one extra MS2 run per "
                    "--big-solvers")
    ap.add_argument("--big-solvers", nargs="+", default=["direct"], choices=SOLVERS)
    ap.add_argument("--conditions", default="", help="what else ran on the machine")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.sides, args.repeats = [12], 1
    solvers = [s for s in SOLVERS if s != "pardiso" or pardiso_available()]
    cells = [(side, method, extra, solver, args.repeats) for side in args.sides
             for method, extra in METHODS for solver in solvers]
    if args.big:
        cells += [(args.big, "master-slave-local", {}, solver, 1)
                  for solver in args.big_solvers if solver in solvers]
    rows, stopped, undissected, last = [], set(), set(), {}
    for side, method, extra, solver, repeats in cells:
        big = side == args.big and repeats == 1
        method_run, method = method, label(method, extra)
        if not big and (method, solver) in stopped:
            continue
        if not big and (method, solver) in last:
            # a direct solve's cost grows as n^1.5 on 2-D layouts: side^3
            before, seconds = last[method, solver]
            if seconds * (side / before) ** 3 > args.cap:
                stopped.add((method, solver))
                continue
        if solver == "superlu-order" and (side, method) in undissected:
            continue                    # "direct" already used SuperLU's order
        runs = [one_run(side, method_run, extra, solver) for _ in range(repeats)]
        n = runs[0][0]
        med = {k: statistics.median(r[1][k] for r in runs) for k in runs[0][1]
               if runs[0][1][k] is not None}
        rows.append((n, method, solver, med, repeats))
        last[method, solver] = (side, med["total"])
        print(n, method, solver, {k: round(v, 3) for k, v in med.items()}, flush=True)
        if solver == "direct" and not med["dissected"]:
            undissected.add((side, method))
            last[method, "superlu-order"] = (side, med["total"])     # the same solve
    if args.quick:
        return rows
    load = os.getloadavg()[0]
    body = (f"{'Conditions: ' + args.conditions + chr(10) + chr(10) if args.conditions else ''}"
            "Phases of one solve (s, median of %d runs unless the row says; 1-minute load "
            "average %.2f at the end) and the run's peak resident memory above its start "
            "(MiB), the entries of the system solved and of its LU factors. A method and "
            "solver are not run at a size where their last median, grown as the side cubed "
            "(a direct solve's n^1.5), would exceed %g s. Solvers: direct = the default: "
            "SuperLU in a nested-dissection order of the particles (ND) above 60,000 unknowns "
            "where the couplings are local, else in MMD on A^T + A (no superlu-order row "
            "then); superlu-order = SuperLU in its own orders (MMD on A^T + A for the "
            "master-slave systems, COLAMD for the penalty: the direct solver before); "
            "iterative = GMRES with an incomplete LU; pardiso = Intel MKL PARDISO (the "
            "optional extra uqflow[pardiso]: METIS order, %s MKL threads)%s. Factors: "
            "\"single\" = in single precision, each solve refined in double (above %s "
            "unknowns; benchmarks/sph_precision.py compares the two). Plain master-slave "
            "as the solver runs it (its Lagrange form above %s unknowns) and "
            "\"master-slave (reduced)\": always K^ = P^T K P, the solver before.\n\n"
            "| particles | method | solver | factors | neighbours | assembly | transformation "
            "| solve | total | peak MiB | nnz system | nnz L+U |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
            % (args.repeats, load, args.cap, mkl_threads(),
               "" if "pardiso" in solvers else " (not installed: no pardiso rows)",
               f"{MIXED_PRECISION_ABOVE:,}", f"{LAGRANGE_FORM_ABOVE:,}"))
    for n, method, solver, t, repeats in rows:
        runs = "" if repeats == args.repeats else f" ({repeats} run)"
        peak = f"{t['peak_mib']:,.0f}" if "peak_mib" in t else ""
        fill = f"{t['factor_nnz'] / 1e6:.1f}M" if "factor_nnz" in t else ""
        if solver == "direct":
            solver = "direct (ND)" if t["dissected"] else "direct (MMD)"
        factors = "" if solver == "iterative" else "single" if t["single"] else "double"
        body += (f"| {n:,}{runs} | {method} | {solver} | {factors} | {t['neighbours']:.3f} "
                 f"| {t['assembly']:.2f} | {t['transformation']:.2f} | {t['solve']:.2f} "
                 f"| {t['total']:.2f} | {peak} | {t['system_nnz'] / 1e6:.1f}M | {fill} |\n")
    skipped = ", ".join(f"{m} ({s})" for m, s in sorted(stopped))
    if skipped:
        body += f"\nStopped by the cap: {skipped}.\n"
    write_section("sph-scaling", "SPH: time of each phase against particle count", body)
    return rows


if __name__ == "__main__":
    main()
