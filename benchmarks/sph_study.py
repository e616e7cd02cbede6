"""SPH: the realizations of a study on one layout, each handed the last one's order or
PARDISO analysis (solvers/sph/symbolic.py, docs/sph.md § 11).

Issue 19 asks MS2 at 40,709 particles to solve 8 x faster than the 40.6 s it took before.
A study solves that plate once per realization with other moduli; from the second on, the
solver reuses what depends on the pattern alone. This runs a Monte Carlo study's
realizations through ``SPHSolver.run`` — the scene of benchmarks/sph_scaling.py's plate at
side 200 (a central circular inclusion, the exact edge displacement, MS2, Example 1's
materials), both moduli drawn normal with a C.V. of 0.1 — on two solvers of the same scene
alternated realization by realization: one keeping its symbolic store, one without (both
build the layout's geometry once: ``Discretisation.memo``). Medians of the realizations after
the first, per linear solver.

    python benchmarks/sph_study.py             # writes BENCHMARKS.md "sph-study"
    python benchmarks/sph_study.py --quick     # a tiny run, nothing written
"""

from __future__ import annotations

import argparse
import gc
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import load1, log, write_section  # noqa: E402
from sph_scaling import mkl_threads, pardiso_available  # noqa: E402

from solvers.sph import SPHSolver  # noqa: E402

BEFORE_S = 40.6                 # MS2 direct at 40,709 particles before issue 19 (docs/sph.md)
SPEED_UP = 8.0                  # the target
CV = 0.1


def scene(side: int, solver: str) -> dict:
    """benchmarks/sph_scaling.py's plate as a scene: side ``side``, spacing 1, MS2."""
    return dict(layout="regular", width=float(side), height=float(side), spacing=1.0,
                inclusions=[dict(centre=[0.0, 0.0], semi_axes=[side / 4, side / 4])],
                matrix=dict(E=900.0, nu=0.33), inclusion=dict(E=1000.0, nu=0.28),
                loading="eigenstrain", eigenstrain=0.01, edge="exact",
                constraints="master-slave-local", linear_solver=solver)


def realizations(count: int, seed: int = 19):
    rng = np.random.default_rng(seed)
    return [{"matrix.E": 900.0 * (1.0 + CV * rng.standard_normal()),
             "inclusion.E": 1000.0 * (1.0 + CV * rng.standard_normal())} for _ in range(count)]


def resident_mib():
    """This process's resident memory (MiB), or NaN without psutil."""
    try:
        import psutil
    except ImportError:
        return float("nan")
    return psutil.Process().memory_info().rss / 2 ** 20


def timed_run(solver, params):
    t0 = time.perf_counter()
    ds = solver.run(params)
    return time.perf_counter() - t0, ds


def study(side: int, linear_solver: str, count: int) -> dict:
    reusing = SPHSolver.from_scene(scene(side, linear_solver))
    alone = SPHSolver.from_scene(scene(side, linear_solver))
    alone.symbolic = None
    seconds = {"reusing": [], "alone": []}
    displacement = {}
    for k, params in enumerate(realizations(count)):
        # alternate which goes first, so that neither always runs on the other's freed memory
        order = [("reusing", reusing), ("alone", alone)][::1 if k % 2 == 0 else -1]
        for name, solver in order:
            t, ds = timed_run(solver, params)
            seconds[name].append(t)
            displacement[name] = ds.displacement.values
        log(linear_solver, k, {name: round(s[-1], 3) for name, s in seconds.items()})
    # the last realization's displacements by the two solvers (each solve refined)
    a, b = displacement["reusing"], displacement["alone"]
    hits = reusing.symbolic.hits
    # what the store holds between realizations: the memory its release gives back
    gc.collect()
    before = resident_mib()
    reusing.symbolic.clear()
    gc.collect()
    return dict(kept_mib=before - resident_mib(), particles=reusing.layout.x.shape[0],
                first=seconds["reusing"][0],
                reusing=statistics.median(seconds["reusing"][1:]),
                alone=statistics.median(seconds["alone"][1:]),
                ratios=statistics.median(r / a for r, a in zip(seconds["reusing"][1:],
                                                                 seconds["alone"][1:])),
                hits=hits, difference=float(np.abs(a - b).max() / np.abs(b).max()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="side 40, 3 realizations, no record")
    ap.add_argument("--side", type=int, default=200)
    ap.add_argument("--realizations", type=int, default=6)
    args = ap.parse_args(argv)
    side, count = (40, 3) if args.quick else (args.side, args.realizations)
    solvers = (["pardiso"] if pardiso_available() else []) + ["direct"]
    for solver in solvers:
        # the process's first call of each solver (MKL's loading, say) is not a realization's
        SPHSolver.from_scene(scene(40, solver)).run({})
    results = {s: study(side, s, count) for s in solvers}
    if args.quick:
        return results
    budget = BEFORE_S / SPEED_UP
    rows = [f"| {s} | {r['first']:.2f} | {r['reusing']:.2f} | {r['alone']:.2f} "
            f"| {r['ratios']:.2f} | {BEFORE_S / r['reusing']:.1f} | {r['hits']} "
            f"| {r['difference']:.1e} | {r['kept_mib']:.0f} |" for s, r in results.items()]
    n = next(iter(results.values()))["particles"]
    body = (
        "A Monte Carlo study of MS2 on benchmarks/sph_scaling.py's plate at side %d (%s "
        "particles) through `SPHSolver.run`, both moduli drawn normal (C.V. %.1f), %d "
        "realizations, on two solvers of one scene alternated realization by realization: "
        "one keeping its symbolic store (solvers/sph/symbolic.py), one without (both build "
        "the layout's geometry once), after one "
        "small solve by each linear solver (the process's first call). Seconds per "
        "realization (the whole run: assembly, transformation, factorisation, solves, "
        "outputs): the first, then medians of the later ones and of their ratios in the same "
        "pairs. \"x before\": %.1f s (MS2 direct before issue 19) over the median with the "
        "store; the target is %g x (%.2f s). \"hits\": realizations that found an order or "
        "analysis kept (a PARDISO analysis whose pattern does not cover the matrix is "
        "found, then redone on the union); \"difference\": the two solvers' displacements "
        "of one realization, relative to the largest (PARDISO's factors differ in rounding "
        "with the analysis and with MKL's threads; SuperLU's are the same); \"kept\": the "
        "resident memory the store held after the study (what releasing it gave back, MiB). "
        "direct = SuperLU, pardiso = Intel MKL PARDISO (%s MKL threads); 1-minute load "
        "average %.2f at the end.\n\n"
        "| solver | first realization | later, with the store | later, without | ratio "
        "| x before | hits | difference | kept |\n|---|---|---|---|---|---|---|---|---|\n"
        % (side, f"{n:,}", CV, count, BEFORE_S, SPEED_UP, budget,
           mkl_threads(), load1())) + "\n".join(rows) + "\n"
    write_section("sph-study", "SPH: a study's realizations on one layout", body)
    return results


if __name__ == "__main__":
    main()
