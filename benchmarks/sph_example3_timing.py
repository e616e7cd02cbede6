"""SPH: the seed's Example 3 (Table 3) — 40 load steps of the 100 µm plate with 9 ellipses and
debonding, time of each phase for MS, MS1, MS2 and PF, at about the seed's 4,664 particles.

The seed's claim: MS2 costs about what PF costs, plain MS far more. Each method runs twice a
repeat: with the low-rank factor updates after breaks (the solver's default) and with a
factorisation per break (the solver's ``update_factors = False``, the solver before). Median of
``--repeats`` runs; ratios within the same repeat.

    python benchmarks/sph_example3_timing.py
    python benchmarks/sph_example3_timing.py --quick   (tests/solvers/sph/test_benchmarks_smoke.py)
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import write_section  # noqa: E402

from solvers.sph import SPHSolver  # noqa: E402

METHODS = (("master-slave", {}), ("master-slave-cutoff", {"cutoff_threshold": 1e-8}),
           ("master-slave-local", {}), ("penalty", {"penalty": 1e4}))
PHASES = ("neighbours", "assembly", "transformation", "solve")


def scene(spacing, steps, method, extra):
    return dict(layout="random", width=100e-6, height=100e-6, spacing=spacing,
                random=dict(count=9, semi_axes_min=[6e-6, 3e-6], semi_axes_max=[10e-6, 6e-6],
                            layout_seed=3),
                matrix=dict(E=1e6, nu=0.4), inclusion=dict(E=150e6, nu=0.3),
                interface_strength=0.04e6, loading="tension", step=0.05e-6, steps=steps,
                constraints=method, **extra)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacing", type=float, default=100e-6 / 64)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.spacing, args.steps, args.repeats = 3.125e-6, 3, 1
    results = {m: [] for m, _ in METHODS}
    particles = None
    for _ in range(args.repeats):
        for method, extra in METHODS:
            t = {}
            for update in (True, False):
                t0 = time.perf_counter()
                solver = SPHSolver.from_scene(scene(args.spacing, args.steps, method, extra))
                solver.update_factors = update
                ds = solver.run({})
                wall = time.perf_counter() - t0
                particles = int(ds.particles.item())
                if update:
                    t = {p: float(ds[f"time_{p}"]) for p in PHASES}
                    t["wall"] = wall
                    t["intact"] = int(ds.intact_pairs.values[-1])
                else:
                    t["refactorised_solve"] = float(ds["time_solve"])
                    t["refactorised_wall"] = wall
                    # the updates change the solves' rounding only, never which pairs break
                    assert t["intact"] == int(ds.intact_pairs.values[-1])
            results[method].append(t)
            print(method, {k: round(v, 2) for k, v in t.items()}, flush=True)
    if args.quick:
        return results

    def within_repeats(f):
        return {m: statistics.median(f(m, i) for i in range(args.repeats)) for m in results}

    med = {m: {k: statistics.median(r[k] for r in rs) for k in rs[0]} for m, rs in results.items()}
    ratio = within_repeats(lambda m, i: results[m][i]["wall"] / results["penalty"][i]["wall"])
    gain = within_repeats(lambda m, i: results[m][i]["refactorised_wall"] / results[m][i]["wall"])
    body = (f"{particles:,} particles, {args.steps} steps of 0.05 µm (seed Table 3: 40 steps). "
            f"Seconds, median of {args.repeats} runs; 1-minute load average "
            f"{os.getloadavg()[0]:.2f} at the end. Each method ran with the factor updates "
            "after breaks (the phases) and with a factorisation per break (the solver before: "
            "its solve phase and wall time); the ratios are of the same repeat.\n\n"
            "| method | neighbours | assembly | transformation | solve | wall | wall / PF "
            "| refactorised: solve | refactorised: wall | refactorised / updated wall "
            "| intact pairs at the end |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|\n")
    for m, t in med.items():
        body += (f"| {m} | {t['neighbours']:.3f} | {t['assembly']:.2f} | {t['transformation']:.2f} "
                 f"| {t['solve']:.2f} | {t['wall']:.1f} | {ratio[m]:.2f} "
                 f"| {t['refactorised_solve']:.2f} | {t['refactorised_wall']:.1f} | {gain[m]:.2f} "
                 f"| {t['intact']:.0f} |\n")
    write_section("sph-example3", "SPH: Example 3, 40 steps with debonding (seed Table 3)", body)
    return results


if __name__ == "__main__":
    main()
