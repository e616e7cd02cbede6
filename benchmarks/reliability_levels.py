"""Reliability across fidelity levels: uqflow's multifidelity methods against OpenTURNS on
the finest level alone, at exact finest-level answers (issue 18).

Three level families in two standard normals u1, u2, those of
tests/methods/test_multifidelity_reliability.py ("biased") and
tests/methods/test_multilevel_subset_simulation.py ("nested", "narrow"), and one in 100
("linear-100d"). The scene key ``level`` (0 coarse, 1 finest) sets the model; the finest
level of every problem has P[g <= 0] = Phi(-3.5) = 2.326e-4 exactly:

- biased: finest 3.5 - u1, coarse g = 3.5 - u1 + 0.5 (u2^2 - 1) (fails earlier, on a parabola);
- nested: finest 3.5 - u1, coarse g = 3 - u1 (a half-plane holding the finest's failure domain);
- narrow: finest 3.5 - u1, coarse g = 3 - u1 + 3 u2^2 (a thin parabola, most of the finest
  domain outside);
- linear-100d: finest 3.5 - sum(u) / 10, coarse linear with its design point at 3.25 along
  the finest's direction turned 15 degrees: where FORM at the finest level costs hundreds of
  runs (finite differences), the search multifidelity importance sampling moves to the
  coarse level.

uqflow's ``multifidelity-importance-sampling`` and ``multilevel-subset-simulation`` run both
levels, with stated costs: coarse = 1/64 of the finest (``costs = [1, 64]``, reported in
finest-run units). They are driven through their contract exactly as the executor drives
them (plan, extend until None, analyze; the runs in the executor's layout, evaluated in one
vectorized call); ``uqflow.testing.run_in_memory`` does the same but refuses fidelity levels,
so this file has its own 20-line driver, the one of the tests above. OpenTURNS can only run
the finest model: importance sampling centred at its FORM point (its calls counted; in 100
inputs with the finest calls uqflow's rows spent, FORM's included), ``SubsetSampling`` and
plain Monte Carlo.

Each method is repeated with seeds 0, 1, 2, ...; the table gives per method and problem the
mean p_f and its bias, the reported c.o.v. (mean), the measured c.o.v. (spread of p_f over
the repetitions, over the exact p), the finest-level calls and the total cost (finest-run
units), and the figures of merit calls x c.o.v.^2 (measured c.o.v.; lower is better: the
calls a method needs for a c.o.v. of 1, so at equal target accuracy the cost ratio is the
ratio of these), and the equivalent finest-level Monte Carlo cost (1 - p) / (p cov^2) over the
total cost (the speed-up over plain MC at the same accuracy). Only calls and p_f are
measured, never time; one process per part.

    python benchmarks/reliability_levels.py                  # 100 repetitions, BENCHMARKS.md
    python benchmarks/reliability_levels.py --repetitions 50 --part two --save two.json
    python benchmarks/reliability_levels.py --repetitions 50 --part wide --save wide.json
    python benchmarks/reliability_levels.py --report-from two.json wide.json  # BENCHMARKS.md
    python benchmarks/reliability_levels.py --quick          # smoke test: "nested" at toy
                                                             # sizes (20 samples; subset
                                                             # simulation p0 = 0.2, no burn-in),
                                                             # 2 repetitions, no OpenTURNS,
                                                             # writes nothing
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
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
from uqflow.layout import (CONTROL_CORRELATION, PLAIN_PROBABILITY,  # noqa: E402
                           PLAIN_STDERR, FAILURE_COV, FAILURE_COV_UNCORRELATED,
                           FAILURE_FAMILIES, FAILURE_INTERVAL, FAILURE_PROBABILITY,
                           INPUTS, LEVEL,
                           STATUS, STATUS_FAILED, STATUS_OK)
from uqflow.levels import LevelsSpec, resolve_levels  # noqa: E402
from uqflow.limit_states import LimitStates  # noqa: E402
from uqflow.methods.multifidelity_reliability import \
    MultifidelityImportanceSampling  # noqa: E402
from uqflow.methods.multilevel_subset_simulation import \
    MultilevelSubsetSimulation  # noqa: E402
from uqflow.methods.subset_simulation import lognormal_interval  # noqa: E402
from uqflow.realization import empty_runs  # noqa: E402

BETA = 3.5
EXACT = float(sps.norm.sf(BETA))
COSTS = [1.0, 64.0]             # coarse = 1/64 of the finest
LIMIT_STATE = [{"name": "fails", "output": "g", "below": 0.0}]
#: dimension of the many-input problem, its coarse level's offset and rotation
WIDE_DIM, WIDE_COARSE_BETA, WIDE_ROTATION_DEG = 100, 3.25, 15.0


def finest(u):
    """g = 3.5 - a.u, a = (1, ..., 1) / sqrt(d): 3.5 - u1 in two dimensions' problems and
    the equal-weights direction in the wide one (the same P[g <= 0] = Phi(-3.5))."""
    if u.shape[1] == 2:
        return BETA - u[:, 0]
    return BETA - u.sum(axis=1) / math.sqrt(u.shape[1])


def wide_coarse(u):
    """The wide problem's coarse level: linear, its design point 3.25 along the finest's
    direction turned 15 degrees towards (e1 - e2) / sqrt 2 (orthogonal to it): 0.92 from
    the finest's design point, pessimistic (fails at 3.25, not 3.5)."""
    d = u.shape[1]
    turn = math.radians(WIDE_ROTATION_DEG)
    a = np.full(d, 1.0 / math.sqrt(d))
    b = np.zeros(d)
    b[:2] = [1.0 / math.sqrt(2.0), -1.0 / math.sqrt(2.0)]
    return WIDE_COARSE_BETA - u @ (math.cos(turn) * a + math.sin(turn) * b)


#: name: (dimension, coarse level)
PROBLEMS = {
    "biased": (2, lambda u: BETA - u[:, 0] + 0.5 * (u[:, 1] ** 2 - 1.0)),
    "nested": (2, lambda u: 3.0 - u[:, 0]),
    "narrow": (2, lambda u: 3.0 - u[:, 0] + 3.0 * u[:, 1] ** 2),
    f"linear-{WIDE_DIM}d": (WIDE_DIM, wide_coarse),
}


def margin(problem, u, level):
    return np.where(np.asarray(level) == 0, PROBLEMS[problem][1](u), finest(u))


def _solver(u1=0.0, u2=0.0, level=1.0):
    return float(finest(np.array([[u1, u2]]))[0])


LevelsSolver = uqflow.solver_from_function(_solver, outputs="g", units="1",
                                           name="reliability-levels-benchmark")

MFIS = "multifidelity-importance-sampling"
MLSUS = "multilevel-subset-simulation"
MFIS_CROSS_ENTROPY = dict(search="cross-entropy", coarse_samples=500, samples=1000,
                          costs=COSTS)
MLSUS_FULL = dict(samples_per_level=500, costs=COSTS)
#: uqflow's rows of the two-input problems: label: (class, options)
UQFLOW = {MFIS: (MultifidelityImportanceSampling, MFIS_CROSS_ENTROPY),
          f"{MFIS}, search = form": (MultifidelityImportanceSampling,
                                     dict(search="form", samples=1000, costs=COSTS)),
          MLSUS: (MultilevelSubsetSimulation, MLSUS_FULL)}
#: the coarse level as a control variate of the FORM-guided estimate (10 coarse draws per
#: finest draw; its coarse event matched to the finest first-order index, or g_c <= 0)
MFIS_CONTROL = dict(search="form", costs=COSTS, control_variate=True)
CONTROL = ", control variate"
UQFLOW.update({
    f"{MFIS}, search = form{CONTROL}": (MultifidelityImportanceSampling,
                                        dict(MFIS_CONTROL, samples=1000)),
    f"{MFIS}, search = form{CONTROL}, control_event = coarse": (
        MultifidelityImportanceSampling,
        dict(MFIS_CONTROL, samples=1000, control_event="coarse"))})
#: and of the wide one: the coarse search by FORM (2 d + 1 coarse runs an iteration) and its
#: refinement at the finest level (the default: d + 1 finest runs) with 300, 1000 and 2000
#: finest draws, without the refinement (the coarse design point), with three defensive
#: weights, by cross-entropy, and multilevel subset simulation
#: the finest draws of the wide problem's FORM-guided rows; OpenTURNS runs at each's calls
WIDE_BUDGETS = (1000, 300, 2000)


def form_guided(**options):
    """A FORM-guided multifidelity row: 1000 finest draws unless ``options`` say otherwise."""
    return MultifidelityImportanceSampling, {"search": "form", "samples": 1000,
                                             "costs": COSTS, **options}


UQFLOW_WIDE = {
    f"{MFIS}, search = form": form_guided(),
    f"{MFIS}, search = form, 300 finest draws": form_guided(samples=300),
    f"{MFIS}, search = form, 2000 finest draws": form_guided(samples=2000),
    f"{MFIS}, search = form, finest_search_rounds = 0": form_guided(finest_search_rounds=0),
    f"{MFIS}, search = form, finest_search_rounds = 0, 300 finest draws": form_guided(
        samples=300, finest_search_rounds=0),
    f"{MFIS}, search = form, w = 0.3": form_guided(defensive_weight=0.3),
    f"{MFIS}, search = form, w = 0.02": form_guided(defensive_weight=0.02),
    f"{MFIS}, search = cross-entropy": (MultifidelityImportanceSampling, MFIS_CROSS_ENTROPY),
    # the cross-entropy search before it became the single-level method's (improved rule,
    # von Mises-Fisher-Nakagami from 20 inputs): one Gaussian on the quantile rule's elites
    f"{MFIS}, search = cross-entropy, rule = quantile, family = gaussian": (
        MultifidelityImportanceSampling,
        dict(MFIS_CROSS_ENTROPY, rule="quantile", family="gaussian")),
    MLSUS: (MultilevelSubsetSimulation, MLSUS_FULL),
    **{f"{MFIS}, search = form" + ("" if draws == 1000 else f", {draws} finest draws")
       + CONTROL: (MultifidelityImportanceSampling, dict(MFIS_CONTROL, samples=draws))
       for draws in WIDE_BUDGETS},
    f"{MFIS}, search = form{CONTROL}, control_event = coarse": (
        MultifidelityImportanceSampling,
        dict(MFIS_CONTROL, samples=1000, control_event="coarse")),
}
#: --quick: every two-input row at toy sizes, so none can rot
TOY_SIZES = dict(coarse_samples=20, samples=20, samples_per_level=20)
UQFLOW_QUICK = {label: (cls, {**options, **{key: size for key, size in TOY_SIZES.items()
                                            if key in options}})
                for label, (cls, options) in UQFLOW.items()}
UQFLOW_QUICK[MLSUS][1].update(level_probability=0.2, burn_in=0)
#: OpenTURNS' budgets on the finest level; in the wide problem its importance sampling gets
#: what FORM left of uqflow's finest calls (equal finest calls)
OT_BUDGET = dict(is_samples=1000, subset_per_level=500, mc_samples=100_000)


def space(dim=2):
    return InputSpace([RandomInput.from_spec({"name": f"u{i + 1}", "distribution": "normal",
                                              "mean": 0.0, "std": 1.0})
                       for i in range(dim)])


def configured(cls, options, dim=2):
    method = cls(**options)
    template = LevelsSolver.from_scene({}).outputs()
    method.check(space(dim), None)
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
    calls, total cost in finest-run units, whether the reported interval holds the exact
    p, and for a genealogical c.o.v. a dict of what is stored beside it: Au & Beck's
    uncorrelated c.o.v. and whether its lognormal 95 % interval holds p, the effective
    families and the c.o.v. without their k / (k - 1))."""
    design = method.plan(space(PROBLEMS[problem][0]), None, np.random.SeedSequence(seed))
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
    low, high = np.ravel(stats[FAILURE_INTERVAL].values)[:2]
    p, cov = (float(np.ravel(stats[name].values)[0]) for name in (FAILURE_PROBABILITY,
                                                                   FAILURE_COV))
    beside = {}
    if FAILURE_FAMILIES in stats:
        uncorrelated, k = (float(np.ravel(stats[name].values)[0]) for name in (
            FAILURE_COV_UNCORRELATED, FAILURE_FAMILIES))
        a_low, a_high = lognormal_interval(p, uncorrelated, 0.95)
        beside = dict(reported_uncorrelated=uncorrelated, families=k,
                      covered_uncorrelated=bool(a_low <= EXACT <= a_high),
                      reported_without_families_factor=cov * math.sqrt((k - 1) / k)
                      if k > 1 else math.inf)
    if CONTROL_CORRELATION in stats:
        # the control variate's correlation of the two levels' weighted indicators, and
        # the c.o.v. of its plain estimate from the same finest runs
        beside = dict(correlation=float(np.ravel(stats[CONTROL_CORRELATION].values)[0]),
                      reported_plain=float(np.ravel(stats[PLAIN_STDERR].values)[0])
                      / float(np.ravel(stats[PLAIN_PROBABILITY].values)[0]))
    return p, cov, n_fine, cost, bool(low <= EXACT <= high), beside


# --------------------------------------------------------------- OpenTURNS, finest only

def openturns_runs(method, seed, dim=2, finest_calls=None):
    """One OpenTURNS run on the finest model in ``dim`` inputs. Importance sampling at the
    FORM point: Cobyla in two dimensions, 1000 samples besides FORM's calls; in more
    (Cobyla does not converge in 100 within its call limit), Abdo-Rackwitz with OpenTURNS'
    finite-difference gradient, and what is left of ``finest_calls`` after FORM as samples."""
    import openturns as ot
    ot.RandomGenerator.SetSeed(seed)
    model = ot.PythonFunction(dim, 1, func_sample=lambda x: np.asarray(
        finest(np.asarray(x))).reshape(-1, 1))
    model = ot.MemoizeFunction(model)
    model.disableCache()
    dist = ot.Normal(dim)
    vect = ot.RandomVector(dist)
    event = ot.ThresholdEvent(ot.CompositeRandomVector(model, vect), ot.LessOrEqual(), 0.0)
    if method == "ot-importance-at-form":
        solver = ot.Cobyla() if dim == 2 else ot.AbdoRackwitz()
        solver.setStartingPoint(dist.getMean())
        form = ot.FORM(solver, event)
        form.run()
        star = form.getResult().getStandardSpaceDesignPoint()
        std_event = ot.StandardEvent(event)
        experiment = ot.ImportanceSamplingExperiment(ot.Normal(star,
                                                               ot.CovarianceMatrix(dim)))
        algo = ot.ProbabilitySimulationAlgorithm(std_event, experiment)
        samples = OT_BUDGET["is_samples"] if finest_calls is None else \
            max(2, finest_calls - model.getEvaluationCallsNumber())
        algo.setMaximumOuterSampling(samples)
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
#: in the wide problem: importance sampling at equal finest calls with uqflow's, subset
#: sampling (plain Monte Carlo's figures do not depend on the dimension)
OT_WIDE = ["ot-importance-at-form", "ot-subset-sampling"]


# --------------------------------------------------------------- the table

def summarize(rows):
    """The row's figures; ``covered``: how many reported intervals held the exact p (uqflow's
    rows, which carry a fifth column; None for OpenTURNS')."""
    columns = list(zip(*rows))
    p, cov, fine, cost = (np.array(c, dtype=float) for c in columns[:4])
    covered = int(sum(columns[4])) if len(columns) > 4 else None
    beside = {}
    for key in (columns[5][0] if len(columns) > 5 else {}):
        values = [row[key] for row in columns[5]]
        beside[key] = int(sum(values)) if key.startswith("covered") else float(np.mean(values))
    measured = float(np.std(p, ddof=1) / EXACT) if len(p) > 1 else float("nan")
    calls = float(fine.mean())
    merit = calls * measured ** 2
    mc_equivalent = (1 - EXACT) / (EXACT * measured ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        # in ln p: the spread, the reported c.o.v.'s lognormal s = sqrt(ln(1 + cov^2)) (its
        # quadratic mean) and the largest p / exact, for estimates with a heavy right tail
        spread_log = float(np.std(np.log(p / EXACT), ddof=1)) if len(p) > 1 else math.nan
        reported_log = float(np.sqrt(np.mean(np.log1p(cov**2))))
    return dict(spread_log=spread_log, reported_log=reported_log,
                largest=float(p.max() / EXACT),
                mean=float(p.mean()), bias=float(p.mean() / EXACT - 1), reported=float(cov.mean()),
                measured=measured, calls=calls, cost=float(cost.mean()), merit=merit,
                mc_equivalent=mc_equivalent, speedup=mc_equivalent / float(cost.mean()),
                reps=len(p), covered=covered, **beside)


def benchmark(repetitions, quick=False, part="all", methods=None, openturns=False):
    """The rows: ``part`` "two" (the two-input problems and OpenTURNS on them), "wide" (the
    many-input problem and OpenTURNS on it) or "all"; ``methods``: only the uqflow rows whose
    label is one of these (and no OpenTURNS row unless ``openturns``)."""
    results = {}
    wide = f"linear-{WIDE_DIM}d"
    for problem, (dim, _) in PROBLEMS.items():
        if (quick and problem != "nested") or part == ("wide" if dim == 2 else "two"):
            continue
        rows_of = UQFLOW_QUICK if quick else UQFLOW if dim == 2 else UQFLOW_WIDE
        for name, (cls, options) in rows_of.items():
            if methods is not None and name not in methods:
                continue
            rows = [drive(configured(cls, options, dim), problem, seed)
                    for seed in range(repetitions)]
            results[(problem, name)] = summarize(rows)
            print(problem, name, results[(problem, name)], flush=True)
    if quick or (methods is not None and not openturns):
        return results
    if part != "wide":
        for name in OT_METHODS:
            rows = [openturns_runs(name, seed) for seed in range(repetitions)]
            results[("finest only", name)] = summarize(rows)
            print(name, results[("finest only", name)], flush=True)
    if part != "two":
        # importance sampling at equal finest calls with each FORM-guided budget (the
        # refinement's stencil runs included: they are level-1 calls), subset sampling once
        for draws in WIDE_BUDGETS:
            label = f"{MFIS}, search = form" + ("" if draws == 1000 else
                                                 f", {draws} finest draws")
            if (wide, label) not in results:    # the control variate's row: the same calls
                label += CONTROL
            if (wide, label) not in results:    # a --methods run without that row
                continue
            equal = round(results[(wide, label)]["calls"])
            for name in OT_WIDE if draws == 1000 else OT_WIDE[:1]:
                rows = [openturns_runs(name, seed, WIDE_DIM, equal)
                        for seed in range(repetitions)]
                key = name if name != OT_WIDE[0] else f"{name}, {equal} finest calls asked"
                results[(f"{wide}, finest only", key)] = summarize(rows)
                print(key, results[(f"{wide}, finest only", key)], flush=True)
    return results


def table(results):
    lines = ["| problem | method | reps | mean p_f / exact | reported c.o.v. | measured c.o.v. "
             "| 95 % intervals holding p_f | finest calls | total cost (finest units) "
             "| finest calls × c.o.v.² | finest-MC equivalent / total cost |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for (problem, name), r in results.items():
        covered = "—" if r.get("covered") is None else f"{r['covered']}"
        lines.append(f"| {problem} | {name} | {r['reps']} | {r['mean'] / EXACT:.3f} | "
                     f"{r['reported']:.3f} | {r['measured']:.3f} | {covered} | "
                     f"{r['calls']:.0f} | "
                     f"{r['cost']:.0f} | {r['merit']:.1f} | {r['speedup']:.0f} |")
    return "\n".join(lines)


def _ot_version():
    import openturns as ot
    return ot.__version__


def _commit():
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                          capture_output=True, text=True).stdout.strip()


def made_by(repetitions, saved=None) -> str:
    """How the table was made: one run, or the saved runs --report-from merged (each with
    the command that saved it where the save records it)."""
    if not saved:
        return (f"Made by `python benchmarks/reliability_levels.py --repetitions "
                f"{repetitions}`.")
    runs = "\n".join(f"- at {part.get('commit', '?')}: " +
                     (f"`{part['command']}`" if "command" in part else
                      f"part {part['part']}, {part['repetitions']} repetitions")
                     for part in saved)
    return ("Made by these runs (the reps column says how many repetitions each row had), "
            "merged by `--report-from` in this order, a later run's row replacing an "
            f"earlier one's:\n\n{runs}\n")


def section(results, repetitions, commits, saved=None):
    wide = f"linear-{WIDE_DIM}d"
    turn = math.radians(WIDE_ROTATION_DEG)
    distance = math.hypot(BETA - WIDE_COARSE_BETA * math.cos(turn),
                          WIDE_COARSE_BETA * math.sin(turn))
    return f"""Commit: {", ".join(commits)}. Issue 18's check "side by side with OpenTURNS at equal
calls: the multifidelity variants clearly better in finest-level cost". {made_by(repetitions, saved)}
Every problem's finest level has the exact p_f = Phi(-3.5) = {EXACT:.4e}; its coarse level
costs 1/64 of a finest run (stated costs; total cost in finest-run units). Why each problem
is here:

- "biased", "nested", "narrow" (two standard normals, finest g = 3.5 - u1): coarse levels
  that are wrong in three ways, the families of the methods' tests. "biased": 3.5 - u1 +
  0.5 (u2² - 1), a parabola failing about three times as often; "nested": 3 - u1, a
  half-plane holding the finest failure domain (multilevel subset simulation's best case:
  its correction is exactly 1); "narrow": 3 - u1 + 3 u2², a thin parabola with most of the
  finest failure domain outside it (its worst case: the correction 0.38 must be sampled on
  the finest level). In two inputs FORM costs OpenTURNS a few dozen finest runs, so
  importance sampling at its FORM point is the finest-only method to beat.
- "{wide}" ({WIDE_DIM} standard normals, finest g = 3.5 - sum(u) / {WIDE_DIM ** 0.5:g}): where the
  search for the biasing density is expensive at the finest level: FORM with
  finite-difference gradients costs about {2 * WIDE_DIM} finest runs an iteration. Its coarse
  level is linear, its design point {WIDE_COARSE_BETA} along the finest's direction turned
  {WIDE_ROTATION_DEG:g} degrees ({distance:.2f} from the finest design point): biased in
  offset and direction, chosen before any run as a moderate error, not fitted to a result.
  OpenTURNS runs FORM (Abdo-Rackwitz, its finite-difference gradient; Cobyla does not
  converge in {WIDE_DIM} inputs) and importance sampling at its design point with the rest of
  the finest calls uqflow's FORM-guided rows spent (equal finest calls, at each of their
  budgets; where FORM alone costs OpenTURNS more than the calls asked, its importance
  sampling still gets 2 samples, and its row says how many calls it took). uqflow's FORM
  search runs on the coarse level, then (the default, finest_search_rounds = 1) one HL-RF
  step on the finest level from the coarse design point: its forward-difference stencil,
  {WIDE_DIM + 1} finest calls, counted in the row's finest calls. The refinement (and its
  absence, finest_search_rounds = 0), the defensive weight w (default 0.1), the finest
  budget and the coarse search (FORM or cross-entropy, 500 draws a round) are varied there.

OpenTURNS {_ot_version()} runs the finest model only: importance sampling at its FORM point
({OT_BUDGET['is_samples']} samples besides FORM's calls in two inputs), SubsetSampling
({OT_BUDGET['subset_per_level']} per level), Monte Carlo ({OT_BUDGET['mc_samples']} samples).
uqflow: multifidelity importance sampling with 1000 finest draws (cross-entropy search with
500 coarse draws a round unless the row says otherwise; search = form with its default
refinement, d + 1 finest calls more); multilevel subset simulation with
500 samples per level, p0 = 0.1, burn-in 40. Seeds 0 to {repetitions - 1}. Measured c.o.v. =
standard deviation of p_f over the repetitions / exact; "95 % intervals holding p_f": of
the repetitions, how many reported intervals held the exact p_f (uqflow's rows; — where the
saved row predates the count). "finest calls × c.o.v.²" (measured)
is the finest calls needed for a c.o.v. of 1: at equal target accuracy finest-level cost goes
as this figure (lower is better). The last column is finest-level Monte Carlo's cost for the
same measured c.o.v., (1 - p) / (p c.o.v.²), over the method's total cost.

{table(results)}
"""


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repetitions", type=int, default=100)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--part", choices=["all", "two", "wide"], default="all",
                        help="run only the two-input problems or only the wide one")
    parser.add_argument("--methods", nargs="+", help="run only the uqflow rows with these "
                        "labels (e.g. multilevel-subset-simulation), no OpenTURNS rows")
    parser.add_argument("--openturns", action="store_true", help="with --methods, run "
                        "OpenTURNS' rows of the part too (in the wide part they need the "
                        "FORM-guided multifidelity rows among the methods)")
    parser.add_argument("--save", type=Path, help="write the rows as JSON (no BENCHMARKS.md)")
    parser.add_argument("--report-from", type=Path, nargs="+",
                        help="write BENCHMARKS.md's section from saved parts")
    args = parser.parse_args(argv)
    if args.quick:
        results = benchmark(2, quick=True)
        print(table(results))
        return results
    if args.report_from:
        saved = [json.loads(path.read_text()) for path in args.report_from]
        order = list(PROBLEMS) + ["finest only", f"linear-{WIDE_DIM}d, finest only"]
        rows = {tuple(key.split(" | ")): value for part in saved
                for key, value in part["rows"].items()}
        results = dict(sorted(rows.items(), key=lambda kv: order.index(kv[0][0])))
        repetitions = saved[0]["repetitions"]
        commits = sorted({part["commit"] for part in saved})
    else:
        commits = [_commit()]       # the checkout the run starts from, not where it ends
        results = benchmark(args.repetitions, part=args.part, methods=args.methods,
                            openturns=args.openturns)
        repetitions = args.repetitions
    if args.save:
        args.save.write_text(json.dumps({
            "repetitions": repetitions, "commit": commits[0], "part": args.part,
            "command": "python benchmarks/reliability_levels.py " + " ".join(
                shlex.quote(arg) for arg in (argv if argv is not None else sys.argv[1:])),
            "rows": {" | ".join(key): value for key, value in results.items()}}, indent=1))
        return results
    text = section(results, repetitions, commits, saved if args.report_from else None)
    print(text)
    write_section("reliability-levels", "Reliability across levels", text)
    return results


if __name__ == "__main__":
    main()
