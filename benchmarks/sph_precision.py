"""SPH: direct solves with single-precision factors refined in double, against double factors,
in the same run (docs/sph.md § 5, § 11).

benchmarks/sph_scaling.py's plate (a central inclusion, the exact edge displacement) solved
with each direct solver twice per repeat, alternating: factors in double precision
(``linear.MIXED_PRECISION_ABOVE`` raised past the system) and the solver's own choice (single
precision refined, above that many unknowns). Median of ``--repeats`` pairs; the displacement
difference is the largest over the repeats, against the double solve's largest displacement.
A case and solver are not run at a size where their last pair, grown as the side cubed (a
direct solve's n^1.5), would exceed ``--cap`` seconds. The refined runs try single precision
on the stiff penalty too, which the solver itself does not (problem.SINGLE_PRECISION_MAX_PENALTY):
those rows show why.

    python benchmarks/sph_precision.py            # writes BENCHMARKS.md section "sph-precision"
    python benchmarks/sph_precision.py --quick    # a tiny run
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import load1, log, write_section  # noqa: E402
from sph_scaling import mkl_threads, pardiso_available, plate_problem  # noqa: E402

from solvers.sph import linear  # noqa: E402
from solvers.sph import problem as problem_module  # noqa: E402

CASES = (("master-slave-local", {}), ("master-slave-cutoff", {"cutoff_threshold": 1e-8}),
         ("penalty", {"penalty": 1e4}), ("penalty", {"penalty": 1e6}))


def one_solve(side, method, extra, solver, mixed):
    """(particles, unknowns, seconds of the whole solve, of its factorisation and solves,
    the factors' precision, refinement steps, displacements)."""
    limit, stiffest = linear.MIXED_PRECISION_ABOVE, problem_module.SINGLE_PRECISION_MAX_PENALTY
    if mixed:
        problem_module.SINGLE_PRECISION_MAX_PENALTY = np.inf
    else:
        linear.MIXED_PRECISION_ABOVE = np.iinfo(np.int64).max
    try:
        problem, edge, _ = plate_problem(side, method, extra, solver)
        t0 = time.perf_counter()
        sol = problem.solve(edge)
        total = time.perf_counter() - t0 + sum(problem.setup_timings.values())
    finally:
        linear.MIXED_PRECISION_ABOVE = limit
        problem_module.SINGLE_PRECISION_MAX_PENALTY = stiffest
    factor = problem._system[1]["factor"]
    return (problem.disc.layout.n, factor.A.shape[0], total, sol.timings["solve"],
            factor.precision, sol.solve_info.iterations, sol.displacement)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sides", type=int, nargs="*", default=[100, 200])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cap", type=float, default=60.0)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.sides, args.repeats = [30], 1
        linear.MIXED_PRECISION_ABOVE = 0
    solvers = ["direct"] + (["pardiso"] if pardiso_available() else [])
    rows, last, capped = [], {}, []
    for side in args.sides:
        for method, extra in CASES:
            for solver in solvers:
                case = (method, extra.get("penalty"), solver)
                if case in last and last[case][1] * (side / last[case][0]) ** 3 > args.cap:
                    capped.append((side, case))
                    continue
                runs = {False: [], True: []}
                for _ in range(args.repeats):
                    for mixed in (False, True):
                        runs[mixed].append(one_solve(side, method, extra, solver, mixed))
                double, single = runs[False], runs[True]
                scale = max(float(np.abs(r[6]).max()) for r in double)
                worst = max(float(np.abs(s[6] - d[6]).max()) for s, d in zip(single, double))
                row = dict(n=double[0][0], unknowns=double[0][1], method=method,
                           weight=extra.get("penalty"), solver=solver,
                           solve_double=statistics.median(r[3] for r in double),
                           solve_mixed=statistics.median(r[3] for r in single),
                           total_double=statistics.median(r[2] for r in double),
                           total_mixed=statistics.median(r[2] for r in single),
                           precision=single[-1][4], steps=max(r[5] for r in single),
                           difference=worst / scale)
                rows.append(row)
                last[case] = (side, row["total_double"] + row["total_mixed"])
                log(row)
    if args.quick:
        return rows
    body = ("Seconds (median of %d alternated pairs; 1-minute load average %.2f at the end) "
            "of the factorisation and solves (\"solve\") and of the whole solve with its "
            "neighbour search, assembly and transformation (\"total\"), with factors in "
            "double precision and as the solver chooses: single precision refined in double "
            "above %s unknowns, falling back to double where refinement stalls (\"precision\" "
            "says what the run ended with; \"steps\": the most refinement steps of a solve). "
            "The stiff penalty (10^6) is tried in single precision here, though the solver "
            "itself factorises it in double (above 10^5): its rows show why. "
            "\"difference\": the largest |u_refined - u_double| over the repeats, against the "
            "largest |u_double|. direct = SuperLU (the default), pardiso = Intel MKL PARDISO "
            "(%s MKL threads).\n\n"
            "| particles | unknowns | method | solver | solve double | solve refined "
            "| ratio | total double | total refined | ratio | precision | steps | difference |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
            % (args.repeats, load1(), f"{linear.MIXED_PRECISION_ABOVE:,}", mkl_threads()))
    for r in rows:
        method = r["method"] + (f" ({r['weight']:g})" if r["weight"] else "")
        body += (f"| {r['n']:,} | {r['unknowns']:,} | {method} | {r['solver']} "
                 f"| {r['solve_double']:.2f} | {r['solve_mixed']:.2f} "
                 f"| {r['solve_double'] / r['solve_mixed']:.2f} | {r['total_double']:.2f} "
                 f"| {r['total_mixed']:.2f} | {r['total_double'] / r['total_mixed']:.2f} "
                 f"| {r['precision']} | {r['steps']} | {r['difference']:.1e} |\n")
    if capped:
        body += "\nNot run (the cap of %g s a pair): %s.\n" % (args.cap, ", ".join(
            f"{method}{f' ({weight:g})' if weight else ''} {solver} at side {side}"
            for side, (method, weight, solver) in capped))
    write_section("sph-precision", "SPH: single-precision factors refined, against double",
                  body)
    return rows


if __name__ == "__main__":
    main()
