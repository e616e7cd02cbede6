"""Reliability across fidelity levels: uqflow's multifidelity methods against OpenTURNS on
the finest level alone, at exact finest-level answers (issue 18).

Three level families in two standard normals u1, u2, those of
tests/methods/test_multifidelity_reliability.py ("biased") and
tests/methods/test_multilevel_subset_simulation.py ("nested", "narrow"). The scene key
``level`` (0 coarse, 1 finest) sets the model; the finest level of all three is exactly
g = 3.5 - u1, P[g <= 0] = Phi(-3.5) = 2.326e-4:

- biased: coarse g = 3.5 - u1 + 0.5 (u2^2 - 1) (fails earlier, on a parabola);
- nested: coarse g = 3 - u1 (a half-plane holding the finest's failure domain);
- narrow: coarse g = 3 - u1 + 3 u2^2 (a thin parabola, most of the finest domain outside).

uqflow's ``multifidelity-importance-sampling`` (cross-entropy search on the coarse level) and
``multilevel-subset-simulation`` run both levels, with stated costs: coarse = 1/64 of the
finest (``costs = [1, 64]``, reported in finest-run units). They are driven through their
contract exactly as the executor drives them (plan, extend until None, analyze; the runs in
the executor's layout, evaluated in one vectorized call); ``uqflow.testing.run_in_memory``
does the same but refuses fidelity levels, so this file has its own 20-line driver, the one
of the tests above. OpenTURNS can only run the finest model: importance sampling centred at
its FORM point (Cobyla FORM, its calls counted), ``SubsetSampling`` and plain Monte Carlo.

Each method is repeated with seeds 0, 1, 2, ...; the table gives per method and problem the
mean p_f and its bias, the reported c.o.v. (mean), the measured c.o.v. (spread of p_f over
the repetitions, over the exact p), the finest-level calls and the total cost (finest-run
units), and the figures of merit calls x c.o.v.^2 (measured c.o.v.; lower is better: the
calls a method needs for a c.o.v. of 1, so at equal target accuracy the cost ratio is the
ratio of these), and the equivalent finest-level Monte Carlo cost (1 - p) / (p cov^2) over the
finest calls (the speed-up over plain MC at the same accuracy). Only calls and p_f are
measured, never time; one process.

    python benchmarks/reliability_levels.py                  # 100 repetitions, BENCHMARKS.md
    python benchmarks/reliability_levels.py --repetitions 200
    python benchmarks/reliability_levels.py --quick          # smoke test: "nested" at toy
                                                             # sizes (20 samples; subset
                                                             # simulation p0 = 0.2, no burn-in),
                                                             # 2 repetitions, no OpenTURNS,
                                                             # writes nothing
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import xarray as xr
from scipy import stats as sps

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import ROOT, write_section  # noqa: E402

import uqflow  # noqa: E402
from uqflow.errors import AccuracyWarning  # noqa: E402
from uqflow.inputs import InputSpace, RandomInput  # noqa: E402
from uqflow.layout import (FAILURE_COV, FAILURE_PROBABILITY, INPUTS, LEVEL,  # noqa: E402
                           STATUS, STATUS_FAILED, STATUS_OK)
from uqflow.levels import LevelsSpec, resolve_levels  # noqa: E402
from uqflow.limit_states import LimitStates  # noqa: E402
from uqflow.methods.multifidelity_reliability import \
    MultifidelityImportanceSampling  # noqa: E402
from uqflow.methods.multilevel_subset_simulation import \
    MultilevelSubsetSimulation  # noqa: E402
from uqflow.realization import empty_runs  # noqa: E402

BETA = 3.5
EXACT = float(sps.norm.sf(BETA))
COSTS = [1.0, 64.0]             # coarse = 1/64 of the finest
LIMIT_STATE = [{"name": "fails", "output": "g", "below": 0.0}]


def finest(u):
    return BETA - u[:, 0]


PROBLEMS = {
    "biased": lambda u: BETA - u[:, 0] + 0.5 * (u[:, 1] ** 2 - 1.0),
    "nested": lambda u: 3.0 - u[:, 0],
    "narrow": lambda u: 3.0 - u[:, 0] + 3.0 * u[:, 1] ** 2,
}


def margin(problem, u, level):
    return np.where(np.asarray(level) == 0, PROBLEMS[problem](u), finest(u))


def _solver(u1=0.0, u2=0.0, level=1.0):
    return float(finest(np.array([[u1, u2]]))[0])


LevelsSolver = uqflow.solver_from_function(_solver, outputs="g", units="1",
                                           name="reliability-levels-benchmark")

#: uqflow's methods: class, options (full size, quick size)
UQFLOW = {
    "multifidelity-importance-sampling": (
        MultifidelityImportanceSampling,
        dict(search="cross-entropy", coarse_samples=500, samples=1000, costs=COSTS),
        dict(search="cross-entropy", coarse_samples=20, samples=20, costs=COSTS)),
    "multilevel-subset-simulation": (
        MultilevelSubsetSimulation,
        dict(samples_per_level=500, costs=COSTS),
        dict(samples_per_level=20, level_probability=0.2, burn_in=0, costs=COSTS)),
}
#: OpenTURNS' budgets on the finest level
OT_BUDGET = dict(is_samples=1000, subset_per_level=500, mc_samples=100_000)


def space():
    return InputSpace([RandomInput.from_spec({"name": n, "distribution": "normal",
                                              "mean": 0.0, "std": 1.0}) for n in ("u1", "u2")])


def configured(cls, options):
    method = cls(**options)
    template = LevelsSolver.from_scene({}).outputs()
    method.check(space(), None)
    method.check_limit_states(LimitStates.from_tables(LIMIT_STATE, template))
    method.check_levels(resolve_levels(LevelsSpec(key="level", values=[0.0, 1.0]), {},
                                       LevelsSolver, ["g"], "scene"))
    return method


def evaluate(design, problem):
    runs = empty_runs(design, LevelsSolver.from_scene({}).outputs())
    g = margin(problem, design[INPUTS].values, design[LEVEL].values)
    runs["g"].values[:] = g
    runs[STATUS].values[:] = np.where(np.isfinite(g), STATUS_OK, STATUS_FAILED)
    runs["wall_time"].values[:] = 0.0
    return runs


def drive(method, problem, seed):
    """plan, extend until None, analyze, as the executor does: (p, reported cov, finest
    calls, total cost in finest-run units)."""
    design = method.plan(space(), None, np.random.SeedSequence(seed))
    runs = evaluate(design, problem)
    glue = dict(dim="realization", data_vars="minimal", coords="minimal", compat="override",
                join="override")
    while (more := method.extend(design, runs)) is not None:
        n = design.sizes["realization"]
        more = more.assign_coords(realization=np.arange(n, n + more.sizes["realization"]))
        runs = xr.concat([runs, evaluate(more, problem)], **glue)
        design = xr.concat([design, more], **glue)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        stats = method.analyze(design, runs)
    level = runs[LEVEL].values
    n_fine = int((level == 1).sum())
    cost = n_fine + int((level == 0).sum()) * COSTS[0] / COSTS[1]
    return (float(np.ravel(stats[FAILURE_PROBABILITY].values)[0]),
            float(np.ravel(stats[FAILURE_COV].values)[0]), n_fine, cost)


# --------------------------------------------------------------- OpenTURNS, finest only

def openturns_runs(method, seed):
    import openturns as ot
    ot.RandomGenerator.SetSeed(seed)
    model = ot.PythonFunction(2, 1, func_sample=lambda x: np.asarray(
        finest(np.asarray(x))).reshape(-1, 1))
    model = ot.MemoizeFunction(model)
    model.disableCache()
    dist = ot.Normal(2)
    vect = ot.RandomVector(dist)
    event = ot.ThresholdEvent(ot.CompositeRandomVector(model, vect), ot.LessOrEqual(), 0.0)
    if method == "ot-importance-at-form":
        solver = ot.Cobyla()
        solver.setStartingPoint(dist.getMean())
        form = ot.FORM(solver, event)
        form.run()
        star = form.getResult().getStandardSpaceDesignPoint()
        std_event = ot.StandardEvent(event)
        experiment = ot.ImportanceSamplingExperiment(ot.Normal(star, ot.CovarianceMatrix(2)))
        algo = ot.ProbabilitySimulationAlgorithm(std_event, experiment)
        algo.setMaximumOuterSampling(OT_BUDGET["is_samples"])
        algo.setMaximumCoefficientOfVariation(0.0)   # all the samples (default: stop at 0.1)
    elif method == "ot-subset-sampling":
        algo = ot.SubsetSampling(event)
        algo.setMaximumOuterSampling(OT_BUDGET["subset_per_level"])
    else:
        algo = ot.ProbabilitySimulationAlgorithm(event, ot.MonteCarloExperiment())
        algo.setBlockSize(1000)
        algo.setMaximumOuterSampling(OT_BUDGET["mc_samples"] // 1000)
        algo.setMaximumCoefficientOfVariation(0.0)
    algo.run()
    result = algo.getResult()
    p = result.getProbabilityEstimate()
    calls = model.getEvaluationCallsNumber()
    return p, result.getCoefficientOfVariation(), calls, float(calls)


OT_METHODS = ["ot-importance-at-form", "ot-subset-sampling", "ot-monte-carlo"]


# --------------------------------------------------------------- the table

def summarize(rows):
    p, cov, fine, cost = (np.array(c, dtype=float) for c in zip(*rows))
    measured = float(np.std(p, ddof=1) / EXACT) if len(p) > 1 else float("nan")
    calls = float(fine.mean())
    merit = calls * measured ** 2
    mc_equivalent = (1 - EXACT) / (EXACT * measured ** 2)
    return dict(mean=float(p.mean()), bias=float(p.mean() / EXACT - 1), reported=float(cov.mean()),
                measured=measured, calls=calls, cost=float(cost.mean()), merit=merit,
                mc_equivalent=mc_equivalent, speedup=mc_equivalent / float(cost.mean()),
                reps=len(p))


def benchmark(repetitions, quick=False):
    results = {}
    for problem in (["nested"] if quick else PROBLEMS):
        for name, (cls, full, small) in UQFLOW.items():
            options = small if quick else full
            rows = [drive(configured(cls, options), problem, seed) for seed in range(repetitions)]
            results[(problem, name)] = summarize(rows)
            print(problem, name, results[(problem, name)], flush=True)
    if not quick:
        for name in OT_METHODS:
            rows = [openturns_runs(name, seed) for seed in range(repetitions)]
            results[("finest only", name)] = summarize(rows)
            print(name, results[("finest only", name)], flush=True)
    return results


def table(results):
    lines = ["| problem | method | reps | mean p_f / exact | reported c.o.v. | measured c.o.v. "
             "| finest calls | total cost (finest units) | finest calls × c.o.v.² "
             "| finest-MC equivalent / total cost |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for (problem, name), r in results.items():
        lines.append(f"| {problem} | {name} | {r['reps']} | {r['mean'] / EXACT:.3f} | "
                     f"{r['reported']:.3f} | {r['measured']:.3f} | {r['calls']:.0f} | "
                     f"{r['cost']:.0f} | {r['merit']:.1f} | {r['speedup']:.0f} |")
    return "\n".join(lines)


def _ot_version():
    import openturns as ot
    return ot.__version__


def section(results, repetitions):
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    return f"""Commit: {commit}. Issue 18's check "side by side with OpenTURNS at equal calls".
The finest level of every problem is g = 3.5 - u1 in two standard normals, exact p_f =
Phi(-3.5) = {EXACT:.4e}; the coarse level is biased ("biased": 3.5 - u1 + 0.5 (u2² - 1);
"nested": 3 - u1; "narrow": 3 - u1 + 3 u2²). uqflow's multifidelity methods run both levels
with stated costs coarse = 1/64 of the finest; OpenTURNS {_ot_version()} runs the
finest model only (importance sampling at its Cobyla FORM point, {OT_BUDGET['is_samples']}
samples, FORM's calls included; SubsetSampling, {OT_BUDGET['subset_per_level']} per level;
Monte Carlo, {OT_BUDGET['mc_samples']} samples), so its rows are one per method. uqflow:
multifidelity importance sampling with 500 coarse cross-entropy draws per round and 1000
finest draws; multilevel subset simulation with 500 samples per level. Seeds 0 to
{repetitions - 1}. Measured c.o.v. = standard deviation of p_f over the repetitions / exact.
"finest calls × c.o.v.²" (measured) is the finest calls needed for a c.o.v. of 1: at equal
target accuracy, finest-level cost goes as this figure (lower is better). The last column is
finest-level Monte Carlo's cost for the same measured c.o.v., (1 - p) / (p c.o.v.²), over the
method's total cost.

{table(results)}
"""


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repetitions", type=int, default=100)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    if args.quick:
        results = benchmark(2, quick=True)
        print(table(results))
        return results
    results = benchmark(args.repetitions)
    text = section(results, args.repetitions)
    print(text)
    write_section("reliability-levels", "Reliability across levels", text)
    return results


if __name__ == "__main__":
    main()
