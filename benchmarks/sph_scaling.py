"""SPH: time of each phase (neighbour search, assembly, transformation, solve) against particle
count, for the four constraint methods and both linear solvers, and the condition estimates.

A square plate (spacing 1) with a central circular inclusion of a quarter of its side, the
seed's Example 1 materials and eigenstrain, the exact displacement on the whole edge: every
edge particle is a slave, the worst case for plain master-slave. Median of ``--repeats`` runs
per cell; plain MS is not run beyond the size where one run took more than ``--cap`` seconds.

    python benchmarks/sph_scaling.py            # writes BENCHMARKS.md section "sph-scaling"
    python benchmarks/sph_scaling.py --quick    # a tiny run (tests/solvers/sph/test_benchmarks_smoke.py)
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import write_section  # noqa: E402

from solvers.sph.exact import eshelby_displacement  # noqa: E402
from solvers.sph.layouts import Box, Ellipse, regular_layout  # noqa: E402
from solvers.sph.problem import ElasticProblem  # noqa: E402
from solvers.sph.stiffness import Discretisation  # noqa: E402

METHODS = (("master-slave", {}), ("master-slave-cutoff", {"cutoff_threshold": 1e-8}),
           ("master-slave-local", {}), ("penalty", {"penalty": 1e4}))


def one_run(side, method, extra, solver):
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
                             linear_solver=solver, **extra)
    edge = eshelby_displacement(lay.x[lay.boundary], side / 4, eigenstrain=0.01,
                                E_inclusion=1000.0, nu_inclusion=0.28, E_matrix=900.0,
                                nu_matrix=0.33)
    sol = problem.solve(edge)
    times = dict(problem.setup_timings)
    for k, v in sol.timings.items():
        times[k] = times.get(k, 0.0) + v
    times["total"] = sum(times[k] for k in ("neighbours", "assembly", "transformation", "solve"))
    return lay.n, times, t_layout


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sides", type=int, nargs="*", default=[30, 60, 100, 140, 200])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cap", type=float, default=60.0)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.sides, args.repeats = [12], 1
    rows, stopped = [], set()
    for side in args.sides:
        for method, extra in METHODS:
            for solver in ("direct", "iterative"):
                if (method, solver) in stopped:
                    continue
                runs = [one_run(side, method, extra, solver) for _ in range(args.repeats)]
                n = runs[0][0]
                med = {k: statistics.median(r[1][k] for r in runs) for k in runs[0][1]}
                rows.append((n, method, solver, med))
                print(n, method, solver, {k: round(v, 3) for k, v in med.items()}, flush=True)
                if med["total"] > args.cap:
                    stopped.add((method, solver))
    if args.quick:
        return rows
    load = os.getloadavg()[0]
    body = ("Phases of one solve (s, median of %d runs; 1-minute load average %.2f at the end). "
            "Plain MS stops being run past the size where a run exceeded %g s.\n\n"
            "| particles | method | solver | neighbours | assembly | transformation | solve | total |\n"
            "|---|---|---|---|---|---|---|---|\n" % (args.repeats, load, args.cap))
    for n, method, solver, t in rows:
        body += (f"| {n:,} | {method} | {solver} | {t['neighbours']:.3f} | {t['assembly']:.2f} "
                 f"| {t['transformation']:.2f} | {t['solve']:.2f} | {t['total']:.2f} |\n")
    skipped = ", ".join(f"{m} ({s})" for m, s in sorted(stopped))
    if skipped:
        body += f"\nStopped at the cap: {skipped}.\n"
    write_section("sph-scaling", "SPH: time of each phase against particle count", body)
    return rows


if __name__ == "__main__":
    main()
