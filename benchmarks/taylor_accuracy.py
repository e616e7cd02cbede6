"""Accuracy of the Taylor method on Y = X^p, X lognormal, against the exact moments.

E[X^r] = mu^r (1 + v^2)^(r (r - 1) / 2) for a lognormal X with mean mu and C.V. v, so the
error of the order-2 mean and of both variance forms is known exactly at every C.V.
Run from the repository root: ``python benchmarks/taylor_accuracy.py``; it rewrites the
``taylor-accuracy`` section of BENCHMARKS.md.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._record import write_section  # noqa: E402
from solvers.analytic.models import AnalyticSolver  # noqa: E402
from uqflow.errors import AccuracyWarning  # noqa: E402
from uqflow.inputs import InputSpace, RandomInput  # noqa: E402
from uqflow.methods.taylor import Taylor  # noqa: E402
from uqflow.realization import evaluate_design  # noqa: E402

POWERS = (2.0, 3.0, -1.0)
CVS = (0.01, 0.05, 0.15, 0.3)
MEAN = 2.0


def exact_moment(r, cv):
    return MEAN**r * (1 + cv**2) ** (r * (r - 1) / 2)


def measure(p, cv, variance):
    space = InputSpace([RandomInput.from_spec({"name": "x", "distribution": "lognormal",
                                               "mean": MEAN, "cv": cv})])
    method = Taylor(order=2, variance=variance)
    design = method.plan(space, None, np.random.SeedSequence(0))
    runs = evaluate_design(AnalyticSolver.from_scene({"model": "power", "p": p}), design)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)  # the C.V. 0.3 rows warn, by design
        stats = method.analyze(design, runs)
    mean = exact_moment(p, cv)
    std = np.sqrt(exact_moment(2 * p, cv) - mean**2)
    return (float(stats["y"].sel(statistic="mean")) / mean - 1,
            float(stats["y"].sel(statistic="std")) / std - 1,
            stats.attrs["solver_runs"])


def slope(cvs, errors):
    """Exponent of |error| ~ C.V.^k from the two smallest C.V.s."""
    return np.log(abs(errors[1] / errors[0])) / np.log(cvs[1] / cvs[0])


def main():
    rows = ["| p | C.V. | runs | mean error | std error, first-order var. "
            "| std error, second-order var. |",
            "|---:|---:|---:|---:|---:|---:|"]
    found = {}
    for p in POWERS:
        for cv in CVS:
            m1, s1, runs = measure(p, cv, "first-order")
            m2, s2, runs2 = measure(p, cv, "second-order")
            assert m1 == m2 and runs == runs2  # the variance form changes neither
            found[p, cv] = (m1, s1, s2)
            rows.append(f"| {p:g} | {cv:g} | {runs} | {m1:+.1e} | {s1:+.1e} | {s2:+.1e} |")
    table = "\n".join(rows)
    print(table)

    mean3 = [found[3.0, cv][0] for cv in CVS]
    first = np.mean([slope(CVS, [found[p, cv][1] for cv in CVS]) for p in POWERS])
    worst_mean_other = max(abs(found[p, cv][0]) for p in (2.0, -1.0) for cv in CVS)
    at_03 = {p: found[p, 0.3] for p in POWERS}

    def change(p):
        s1, s2 = abs(at_03[p][1]), abs(at_03[p][2])
        return (f"{'cuts' if s2 < s1 else 'raises'} it to {s2:.0%} for p = {p:g}")

    summary = (
        f"Signed relative errors against the exact lognormal moments (mean {MEAN:g}; order 2, "
        f"step 0.1 std, step check on). "
        f"The order-2 mean is exact for p = 2 and p = -1, where E[X^p] is linear in v^2 (the "
        f"largest error, {worst_mean_other:.1e}, is finite-difference error), and for p = 3 "
        f"it grows like C.V.^{slope(CVS, mean3):.1f} (the dropped 3 v^4 term) to "
        f"{abs(mean3[-1]):.1%} at C.V. 0.3; the std from the first-order variance (seed eq. "
        f"24) errs like C.V.^{first:.1f}, by "
        + ", ".join(f"{abs(at_03[p][1]):.0%}" for p in POWERS)
        + f" for p = {', '.join(f'{p:g}' for p in POWERS)} at C.V. 0.3; the second-order "
        f"variance makes p = 2 exact, {change(3.0)} but {change(-1.0)}, so it is no "
        f"reliable fix: above C.V. 0.15 prefer monte-carlo for the spread.")
    print(summary)
    write_section("taylor-accuracy", "Taylor method accuracy (lognormal power law)",
                  f"{table}\n\n{summary}\n")


if __name__ == "__main__":
    main()
