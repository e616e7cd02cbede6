"""SPH: what bounds one MS2 solve of benchmarks/sph_scaling.py's plate (docs/sph.md § 11).

Issue 19 asks MS2 at 40,709 particles (side 200) to solve 8 x faster than the 40.6 s it took
before, in at most 5.08 s. This splits one solve into what the factorisation alone costs —
PARDISO's analysis (METIS's order and the symbolic factorisation) and its numerical
factorisation, SuperLU's order (the coupling graph and nested dissection) and its
factorisation, each timed on the very system the solve built — and what the solve does
around it (neighbour search, assembly, transformation, the singularity check and the refined
solve). Each repeat alternates the whole solve with either solver and the factorisations
alone; medians of ``--repeats``. The factors are in single precision, as the solver makes
them at this size (docs/sph.md § 5).

    python benchmarks/sph_factor_floor.py            # writes BENCHMARKS.md "sph-factor-floor"
    python benchmarks/sph_factor_floor.py --quick    # a tiny run, nothing written
"""

from __future__ import annotations

import argparse
import inspect
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import load1, log, write_section  # noqa: E402
from sph_scaling import _solve, mkl_threads, pardiso_available  # noqa: E402

from solvers.sph import linear  # noqa: E402
from solvers.sph.pardiso import PardisoLU  # noqa: E402  (MKL is loaded at its first use)

BEFORE_S = 40.6                 # MS2 direct at 40,709 particles before issue 19 (docs/sph.md)
SPEED_UP = 8.0                  # the target


def system_of(side):
    """MS2's reduced system at this side, and the points of its unknowns."""
    captured = {}
    original = linear.Factor.__init__

    def capture(self, *args, **kwargs):
        captured.update(inspect.signature(original).bind(self, *args, **kwargs).arguments)
        original(self, *args, **kwargs)

    linear.Factor.__init__ = capture
    try:
        _solve(side, "master-slave-local", {}, "direct")
    finally:
        linear.Factor.__init__ = original
    return sp.csr_matrix(captured["A"]), np.asarray(captured["points"])


def pardiso_phases(A):
    """(analysis, factorisation) seconds of PARDISO on A, in single precision."""
    seconds = PardisoLU(A, np.float32).seconds
    return seconds["analysis"], seconds["factorisation"]


def superlu_phases(A, points):
    """(order, factorisation) seconds of SuperLU on A in single precision, in the solver's
    nested-dissection order."""
    A = sp.csc_matrix(A)
    t0 = time.perf_counter()
    graph = linear.coupling_graph(A)
    perm = linear.nested_dissection(A, points, graph=graph)
    t1 = time.perf_counter()
    linear._factorise(A, True, perm, np.float32)
    return t1 - t0, time.perf_counter() - t1


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--side", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.side, args.repeats = 20, 1
    solvers = ["direct"] + (["pardiso"] if pardiso_available() else [])
    A, points = system_of(args.side)
    runs = {s: [] for s in solvers}
    alone = {s: [] for s in solvers}
    for _ in range(args.repeats):
        for solver in solvers:
            n, phases, _ = _solve(args.side, "master-slave-local", {}, solver)
            runs[solver].append(phases)
            log(solver, {k: round(v, 3) for k, v in phases.items()})
            alone[solver].append(pardiso_phases(A) if solver == "pardiso"
                                 else superlu_phases(A, points))
    med = {s: {k: statistics.median(r[k] for r in runs[s])
               for k in ("neighbours", "assembly", "transformation", "solve", "total")}
           for s in solvers}
    part = {s: [statistics.median(r[i] for r in alone[s]) for i in range(2)] for s in solvers}
    result = dict(particles=n, unknowns=A.shape[0], system_nnz=int(A.nnz), runs=med,
                  alone=part)
    if args.quick:
        return result
    budget = BEFORE_S / SPEED_UP
    rows = []
    for s in solvers:
        m, first, factorisation = med[s], part[s][0], part[s][1]
        around = m["neighbours"] + m["assembly"] + m["transformation"]
        floor = first + factorisation
        what = "analysis" if s == "pardiso" else "order"
        rows.append(f"| {s} | {m['total']:.2f} | {around:.2f} | {m['solve']:.2f} "
                    f"| {floor:.2f} ({what} {first:.2f} + factorisation {factorisation:.2f}) "
                    f"| {m['solve'] - floor:.2f} | {around + floor:.2f} | {budget:.2f} |")
    body = (
        "MS2 on benchmarks/sph_scaling.py's plate at side %d: %s particles, %s unknowns, %s "
        "entries in the reduced system. Seconds, median of %d repeats, each alternating the "
        "whole solve with each solver (its phases as sph_scaling.py reports them) and the "
        "factorisation alone on the same system (factors in single precision, as the solver "
        "makes them at this size). \"around\": neighbour search, assembly and "
        "transformation; \"solve\": the factorisation with everything the solver does around "
        "it (the singularity check's two refined solves, the refined solve); \"factorisation "
        "alone\": PARDISO's analysis and numerical factorisation, or SuperLU's order and "
        "factorisation; \"budget\": the issue's target, %.1f s / %g. direct = SuperLU, "
        "pardiso = Intel MKL PARDISO (%s MKL threads); 1-minute load average %.2f at the "
        "end.\n\n"
        "| solver | whole solve | around | solve | factorisation alone | solve beyond it "
        "| around + factorisation alone | budget |\n|---|---|---|---|---|---|---|---|\n"
        % (args.side, f"{n:,}", f"{A.shape[0]:,}", f"{A.nnz:,}", args.repeats, BEFORE_S,
           SPEED_UP, mkl_threads(), load1())) + "\n".join(rows) + "\n"
    write_section("sph-factor-floor", "SPH: what bounds one MS2 solve", body)
    return result


if __name__ == "__main__":
    main()
