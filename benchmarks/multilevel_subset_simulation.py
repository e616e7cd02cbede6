"""Multilevel subset simulation on the level families of its tests, over repetitions: the
bias and spread against the burn-in on the narrow coarse level, and the finest-level runs
against single-level subset simulation on the nested one (docs/rare_events_across_levels.md
quotes this table).

    python -m benchmarks.multilevel_subset_simulation [repetitions]

The families: two standard normals, the finest level g = 3.5 - u1 (P = Phi(-3.5)); the coarse
level g = 3 - u1 + 3 u2^2 (narrow) or 3 - u1 (nested). The method is driven as the executor
drives it (plan, extend until None, analyze) on runs evaluated in one vectorized call.
"""

from __future__ import annotations

import math
import sys
import warnings

import numpy as np
import xarray as xr
from scipy import integrate
from scipy import stats as sps

import uqflow
from uqflow.errors import AccuracyWarning
from uqflow.inputs import InputSpace, RandomInput
from uqflow.layout import (FAILURE_COV, FAILURE_COV_CORRELATED, FAILURE_PROBABILITY,
                           FIDELITY_RUNS, INPUTS, LEVEL, SOLVER_RUNS, STATUS, STATUS_OK,
                           SUBSET_CORRECTION)
from uqflow.levels import LevelsSpec, resolve_levels
from uqflow.limit_states import LimitStates
from uqflow.methods.multilevel_subset_simulation import MultilevelSubsetSimulation
from uqflow.methods.subset_simulation import SubsetSimulation
from uqflow.realization import empty_runs

EXACT = float(sps.norm.sf(3.5))
N = 500


def narrow_correction() -> float:
    """P[coarse failure | finest failure] on the narrow family, the correction its level
    change estimates (the finest subset is the finest failure domain there):
    P[u1 >= max(3.5, 3 + 3 u2^2)] / Phi(-3.5), by quadrature (split where the two meet)."""
    knot = 1.0 / math.sqrt(6.0)

    def integrand(v):
        return sps.norm.pdf(v) * sps.norm.sf(max(3.5, 3.0 + 3.0 * v * v))
    both = sum(integrate.quad(integrand, a, b, epsabs=0, epsrel=1e-12)[0]
               for a, b in ((-np.inf, -knot), (-knot, knot), (knot, np.inf)))
    return both / EXACT


def nested(u, level):
    return np.where(level == 0, 3.0 - u[:, 0], 3.5 - u[:, 0])


def narrow(u, level):
    return np.where(level == 0, 3.0 - u[:, 0] + 3.0 * u[:, 1] ** 2, 3.5 - u[:, 0])


def _margin(u1=0.0, u2=0.0, level=1.0):
    return 0.0


Solver = uqflow.solver_from_function(_margin, outputs="g", units="1", name="mlsus-benchmark")


def method(cls, **options):
    m = cls(samples_per_level=N, **options)
    template = Solver.from_scene({}).outputs()
    m.check_limit_states(LimitStates.from_tables(
        [{"name": "fails", "output": "g", "below": 0.0}], template))
    if cls is MultilevelSubsetSimulation:
        m.check_levels(resolve_levels(LevelsSpec(key="level", values=[0.0, 1.0]), {}, Solver,
                                      ["g"], "scene"))
    return m


def evaluate(design, problem, level):
    runs = empty_runs(design, Solver.from_scene({}).outputs())
    levels = design[LEVEL].values if level is None else np.full(design.sizes["realization"],
                                                                 level)
    runs["g"].values[:] = problem(design[INPUTS].values, levels)
    runs[STATUS].values[:] = STATUS_OK
    runs["wall_time"].values[:] = 0.0
    return runs


def drive(m, problem, seed, level=None):
    space = InputSpace([RandomInput.from_spec({"name": n, "distribution": "normal",
                                               "mean": 0.0, "std": 1.0})
                        for n in ("u1", "u2")])
    design = m.plan(space, None, np.random.SeedSequence(seed))
    runs = evaluate(design, problem, level)
    glue = dict(dim="realization", data_vars="minimal", coords="minimal", compat="override",
                join="override")
    while (more := m.extend(design, runs)) is not None:
        n = design.sizes["realization"]
        more = more.assign_coords(realization=np.arange(n, n + more.sizes["realization"]))
        runs = xr.concat([runs, evaluate(more, problem, level)], **glue)
        design = xr.concat([design, more], **glue)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        return m.analyze(design, runs)


def row(label, stats, correction=None):
    p = np.array([float(s[FAILURE_PROBABILITY].values[0]) for s in stats])
    k = p.size
    finest = np.mean([s[FIDELITY_RUNS].values[-1] if FIDELITY_RUNS in s else
                      s.attrs[SOLVER_RUNS] for s in stats])
    ratio = "—"
    if correction is not None:
        c = np.array([float(s[SUBSET_CORRECTION].values[-1]) for s in stats]) / correction
        ratio = f"{c.mean():.3f} ± {c.std(ddof=1) / np.sqrt(k):.3f}"
    print(f"| {label} | {p.mean() / EXACT:.2f} ± {p.std(ddof=1) / EXACT / np.sqrt(k):.2f} | "
          f"{ratio} | {p.std(ddof=1) / p.mean():.2f} | "
          f"{np.mean([float(s[FAILURE_COV].values[0]) for s in stats]):.2f} | "
          f"{np.mean([float(s[FAILURE_COV_CORRELATED].values[0]) for s in stats]):.2f} | "
          f"{finest:.0f} |", flush=True)


def main(repetitions: int = 40) -> None:
    print(f"N = {N}, p0 = 0.1, {repetitions} repetitions (seeds 100 ...), P = Phi(-3.5)")
    correction = narrow_correction()
    print(f"narrow family: exact correction P[coarse failure | finest failure] = "
          f"{correction:.4f}")
    print("| case | p_f / exact (mean ± s.e.) | correction / exact | spread c.o.v. | "
          "reported c.o.v. | fully correlated | finest runs |")
    print("|---|---|---|---|---|---|---|")
    seeds = range(100, 100 + repetitions)
    for burn_in in (0, 10, 20, 40, 80):
        row(f"narrow, burn_in = {burn_in}",
            [drive(method(MultilevelSubsetSimulation, burn_in=burn_in, costs=[1.0, 10.0]),
                   narrow, s) for s in seeds], correction)
    row("nested, burn_in = 0", [drive(method(MultilevelSubsetSimulation, burn_in=0,
                                             costs=[1.0, 10.0]), nested, s) for s in seeds])
    row("single-level subset simulation at the finest",
        [drive(method(SubsetSimulation), nested, s, level=1) for s in seeds])


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
