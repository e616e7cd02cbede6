"""uqflow's reliability methods against OpenTURNS on problems with exact answers (issue 18).

Each problem of ``reliability_problems.py`` becomes a uqflow study (its margin as a solver by
``uqflow.solver_from_function``, its inputs and copula as ``[[inputs]]`` and
``[correlation]``, one ``[[limit_states]]`` "g below 0"), and the same event in OpenTURNS (``ThresholdEvent`` of a ``PythonFunction``). uqflow's repetitions run in memory
(``uqflow.testing.run_in_memory``: the study's method driven through its contract as the
executor drives it, the problem's vectorized margin in place of the solver, no result file),
and seed 0 of each method and problem also as a study through the executor, whose figures
the in-memory run must equal bit for bit (asserted: the run stops otherwise). Both
sides run the same budgets in the same run: the samples of Monte Carlo and importance
sampling, the samples per level and level probability of subset simulation. A sampling
method is repeated with seeds 0, 1, 2, ...: the mean p_f, its bias against the reference
(``reliability_references.json``), the c.o.v. it reports (mean over repetitions), its
empirical c.o.v. (the spread of p_f over the repetitions over the reference), the coverage
of its reported 95 % interval, and the solver calls (mean). Only p_f, c.o.v. and calls are
measured, never time: other processes on the machine change no figure here.

    python benchmarks/reliability.py                   # every problem, 200 repetitions each;
                                                       # BENCHMARKS.md "reliability"
    python benchmarks/reliability.py --case-seconds 120   # stop a uqflow method's
                                                       # repetitions after 2 minutes (stated)
    python benchmarks/reliability.py --problems r_minus_s --repetitions 50
    python benchmarks/reliability.py --quick           # smoke test: R - S at a toy size,
                                                       # MC and FORM, no OpenTURNS, writes
                                                       # nothing
    python benchmarks/reliability.py --problems linear_100 --methods form --save a.json
    python benchmarks/reliability.py --report-from a.json b.json   # merge, write again

A run writes BENCHMARKS.md's section "reliability" and the summary table of
docs/reliability.md's benchmark section (between ``<!-- begin reliability-summary -->`` and
``<!-- end reliability-summary -->``), each with the command, commit and machine.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from scipy import stats as sps

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import ROOT, command, machine, write_section  # noqa: E402
from reliability_problems import PROBLEMS  # noqa: E402

import uqflow  # noqa: E402
from uqflow import testing  # noqa: E402
from uqflow.errors import StudyError  # noqa: E402
from uqflow.layout import (BOUND, BOUND_HIGH, BOUND_LOW, FAILURE_COV,  # noqa: E402
                           FAILURE_INTERVAL, FAILURE_PROBABILITY, SOLVER_RUNS, WARNINGS)

REFERENCES = json.loads((Path(__file__).resolve().parent /
                         "reliability_references.json").read_text())
CONFIDENCE = 0.95
LEVEL_PROBABILITY = 0.1

#: calls of Monte Carlo and importance sampling, and subset simulation's samples per level
BUDGETS = {
    "r_minus_s": dict(samples=1000, per_level=500),
    "four_branch_6": dict(samples=2000, per_level=500),
    "four_branch_7": dict(samples=2000, per_level=500),
    # 1500 a level: the issue's "p_f ~ 1e-6 with a c.o.v. <= 0.4 in at most 10^4 calls"
    # (six or seven levels, 8250 or 9600 runs); at 1000 the spread is about 0.49
    "linear_100": dict(samples=2000, per_level=1500),
    "two_design_points": dict(samples=2000, per_level=500),
    "correlated_lognormals": dict(samples=2000, per_level=500),
}
QUICK_BUDGET = dict(samples=100, per_level=100)
QUICK_METHODS = ["monte-carlo", "form"]

#: uqflow's methods: kind, options from the budget, whether repeated (sampling)
UQFLOW_METHODS = {
    "monte-carlo": (lambda b: {"samples": b["samples"]}, True),
    "form": (lambda b: {}, False),
    "sorm": (lambda b: {}, False),
    "importance-sampling": (lambda b: {"samples": b["samples"]}, True),
    # its rounds and final draws each take `samples`: two or three of them make the budget
    "cross-entropy": (lambda b: {"samples": b["samples"] // 2}, True),
    "subset-simulation": (lambda b: {"samples_per_level": b["per_level"],
                                     "level_probability": LEVEL_PROBABILITY}, True),
}
OT_METHODS = ("FORM", "SORM", "MC", "IS at FORM point", "SubsetSampling")


def available_methods() -> list[str]:
    """uqflow's methods of the table that this checkout registers (the rare-event ones land
    one by one)."""
    found = []
    for kind in UQFLOW_METHODS:
        try:
            uqflow.get_method(kind)
        except StudyError:
            continue
        found.append(kind)
    return found


# ------------------------------------------------------------------------------- uqflow

def _toml(value) -> str:
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(float(value)) if isinstance(value, (float, np.floating)) else repr(value)


def register(problem) -> str:
    """Register the problem's margin as a solver ``bench-<name>``, output g (units 1)."""
    names = problem.names
    margin = problem.margin

    def run(**params):
        return {"g": float(margin(np.array([[params[n] for n in names]]))[0])}

    run.__name__ = f"margin_{problem.name}"
    solver = uqflow.solver_from_function(run, outputs="g", units="1",
                                         parameters={n: 0.0 for n in names},
                                         long_names={"g": "limit-state margin"},
                                         name=f"bench-{problem.name}")
    uqflow.register_solver(f"bench-{problem.name}")(solver)
    return f"bench-{problem.name}"


def write_study(folder: Path, problem, kind: str, options: dict, seed: int) -> Path:
    lines = [f'name = "{problem.name}-{kind}"', f'solver = "{register(problem)}"',
             "scene = {}", 'outputs = ["g"]', ""]
    for table in problem.inputs:
        lines += ["[[inputs]]", *(f"{k} = {_toml(v)}" for k, v in table.items()), ""]
    if problem.correlation is not None:
        lines += ["[correlation]", f"inputs = {_toml(problem.names)}",
                  f"matrix = {_toml(problem.correlation.tolist())}", ""]
    lines += ["[[limit_states]]", 'name = "fails"', 'output = "g"', "below = 0.0", "",
              "[method]", f'kind = "{kind}"', *(f"{k} = {_toml(v)}" for k, v in options.items()),
              "", "[execution]", "workers = 0", f"seed = {seed}", "",
              "[output]", f'path = "{problem.name}-{kind}.nc"', "figures = false", ""]
    path = folder / f"{problem.name}-{kind}.toml"
    path.write_text("\n".join(lines))
    return path


def run_uqflow(folder: Path, problem, kind: str, options: dict, seed: int) -> dict:
    """One repetition as a whole study through the executor (result file, checkpoints)."""
    study = uqflow.load_study(write_study(folder, problem, kind, options, seed))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # the method's own warnings are in the result
        outcome = uqflow.run_study(study, show_progress=False, force=True)
    return _figures(outcome.statistics)


def run_in_memory(study, problem, seed: int) -> dict:
    """One repetition in memory (``uqflow.testing.run_in_memory``): a copy of the study's
    method as loaded, driven through its contract as the executor drives it, the
    problem's vectorized margin in place of the solver, no result file. The same figures
    as ``run_uqflow`` for the same seed, bit for bit (``run_problem`` asserts it once per
    method and problem)."""
    method = copy.deepcopy(study.method)        # as loaded: nothing run yet
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, stats = testing.run_in_memory(
            method, study.space, study.limit_states, lambda x: {"g": problem.margin(x)},
            seed, outputs=study.solver.outputs()[study.outputs])
    return _figures(stats)


def _figures(stats) -> dict:
    got = {"p": float(stats[FAILURE_PROBABILITY].values[0]),
           "calls": int(stats.attrs[SOLVER_RUNS]), "low": math.nan, "high": math.nan,
           "cov": math.nan, "warnings": stats.attrs.get(WARNINGS, "")}
    if FAILURE_INTERVAL in stats:
        bounds = stats[FAILURE_INTERVAL].isel({stats[FAILURE_INTERVAL].dims[0]: 0})
        got["low"] = float(bounds.sel({BOUND: BOUND_LOW}))
        got["high"] = float(bounds.sel({BOUND: BOUND_HIGH}))
    if FAILURE_COV in stats:
        got["cov"] = float(stats[FAILURE_COV].values[0])
    return got


# ---------------------------------------------------------------------------- OpenTURNS

class OpenTurnsProblem:
    """The problem's event in OpenTURNS, counting the margin's evaluations (its calls)."""

    def __init__(self, problem):
        import openturns as ot

        ot.Log.Show(ot.Log.NONE)
        self.ot, self.problem, self.calls = ot, problem, 0
        marginals = [ot.Normal(t["mean"], t["std"]) if t["distribution"] == "normal" else
                     ot.LogNormal(t["mu"], t["sigma"], 0.0) for t in problem.inputs]
        if problem.correlation is None:
            self.distribution = ot.JointDistribution(marginals)
        else:
            # OpenTURNS' NormalCopula takes the normal scores' correlation, as uqflow's
            # [correlation] does
            self.distribution = ot.JointDistribution(
                marginals, ot.NormalCopula(ot.CorrelationMatrix(problem.correlation.tolist())))

        def margin(x):
            x = np.asarray(x)
            self.calls += x.shape[0]
            return problem.margin(x)[:, None]

        function = ot.PythonFunction(problem.dimension, 1, func_sample=margin)
        output = ot.CompositeRandomVector(function, ot.RandomVector(self.distribution))
        self.event = ot.ThresholdEvent(output, ot.LessOrEqual(), 0.0)

    def _counted(self, work) -> dict:
        self.calls = 0
        got = work()
        got["calls"] = self.calls
        return got

    def _search(self):
        algorithm = self.ot.AbdoRackwitz()
        # from the medians, as uqflow's search starts (u = 0); OpenTURNS takes the starting
        # point in the inputs' physical space
        algorithm.setStartingPoint([self.distribution.getMarginal(k).computeQuantile(0.5)[0]
                                    for k in range(self.problem.dimension)])
        return algorithm

    def form(self, seed: int) -> dict:
        def work():
            algorithm = self.ot.FORM(self._search(), self.event)
            algorithm.run()
            result = algorithm.getResult()
            return {"p": result.getEventProbability(),
                    "design_point": np.array(result.getStandardSpaceDesignPoint())}
        return self._counted(work)

    def sorm(self, seed: int) -> dict:
        def work():
            algorithm = self.ot.SORM(self._search(), self.event)
            algorithm.run()
            return {"p": algorithm.getResult().getEventProbabilityTvedt()}
        return self._counted(work)

    def _simulation(self, algorithm, samples: int) -> dict:
        algorithm.setMaximumOuterSampling(1)
        algorithm.setBlockSize(samples)
        algorithm.setMaximumCoefficientOfVariation(-1.0)    # the whole budget, no early stop
        algorithm.run()
        return _simulation_result(algorithm.getResult())

    def monte_carlo(self, seed: int, samples: int) -> dict:
        self.ot.RandomGenerator.SetSeed(seed)
        return self._counted(lambda: self._simulation(self.ot.ProbabilitySimulationAlgorithm(
            self.event, self.ot.MonteCarloExperiment()), samples))

    def importance_sampling(self, seed: int, samples: int, design_point) -> dict:
        """Unit normal density centred on OpenTURNS' FORM design point (its calls are
        counted with the sampling's)."""
        self.ot.RandomGenerator.SetSeed(seed)
        ot = self.ot
        experiment = ot.ImportanceSamplingExperiment(
            ot.Normal(ot.Point(design_point.tolist()), ot.CovarianceMatrix(len(design_point))))
        return self._simulation(ot.ProbabilitySimulationAlgorithm(ot.StandardEvent(self.event),
                                                                  experiment), samples)

    def subset(self, seed: int, per_level: int) -> dict:
        self.ot.RandomGenerator.SetSeed(seed)

        def work():
            algorithm = self.ot.SubsetSampling(self.event)
            # a level's N samples: outer sampling x block size, one block of N (one call
            # of the vectorized margin per step)
            algorithm.setMaximumOuterSampling(1)
            algorithm.setBlockSize(per_level)
            algorithm.setConditionalProbability(LEVEL_PROBABILITY)
            algorithm.run()
            return _simulation_result(algorithm.getResult())
        return self._counted(work)


def _simulation_result(result) -> dict:
    # OpenTURNS' interval: p -+ z sd, its normal approximation (getConfidenceLength)
    p, sd = result.getProbabilityEstimate(), result.getStandardDeviation()
    half = sps.norm.ppf(0.5 + CONFIDENCE / 2) * sd
    return {"p": p, "cov": result.getCoefficientOfVariation(), "low": p - half,
            "high": p + half}


def run_openturns(problem, budget: dict, repetitions: int) -> tuple[dict, dict]:
    """The runs of each OpenTURNS algorithm, and the error of each that could not run (its
    FORM search stops where the gradient is zero, as at the four-branch system's origin)."""
    side = OpenTurnsProblem(problem)
    out, errors = {}, {}
    for label, algorithm in (("FORM", side.form), ("SORM", side.sorm)):
        try:
            out[label] = [algorithm(0)]
        except RuntimeError as exc:
            errors[label] = "not run: " + str(exc).splitlines()[0]
    def repeat(label, run):
        out[label], stopped = [], []
        for seed in range(repetitions):
            try:
                out[label].append(run(seed))
            except (RuntimeError, TypeError, ValueError) as exc:   # OpenTURNS' exceptions
                stopped.append(str(exc).splitlines()[0])
        if stopped:
            errors[label] = (f"{len(stopped)} of {repetitions} repetitions stopped with "
                             f"'{stopped[0]}'; the row is the others'")

    repeat("MC", lambda seed: side.monte_carlo(seed, budget["samples"]))
    if "FORM" in out:
        form = out["FORM"][0]

        def importance(seed):
            got = side._counted(lambda: side.importance_sampling(seed, budget["samples"],
                                                                 form["design_point"]))
            got["calls"] += form["calls"]
            return got
        repeat("IS at FORM point", importance)
    else:
        errors["IS at FORM point"] = "not run: no FORM design point to centre on"
    repeat("SubsetSampling", lambda seed: side.subset(seed, budget["per_level"]))
    return out, errors


# -------------------------------------------------------------------------- summaries

def binomial_band(trials: int, level: float = CONFIDENCE) -> tuple[float, float, float]:
    """The central 95 % range of the coverage fraction of ``trials`` intervals whose true
    coverage is ``level``: binomial quantiles 2.5 % and 97.5 %, and the exact probability
    of landing in it."""
    low = sps.binom.ppf(0.025, trials, level)
    high = sps.binom.ppf(0.975, trials, level)
    mass = sps.binom.cdf(high, trials, level) - sps.binom.cdf(low - 1, trials, level)
    return low / trials, high / trials, float(mass)


def summarize(runs: list[dict], reference: float) -> dict:
    p = np.array([r["p"] for r in runs], dtype=float)
    calls = np.array([r["calls"] for r in runs], dtype=float)
    out = {"repetitions": len(runs), "p_mean": float(np.mean(p)),
           "bias": float(np.mean(p) / reference - 1), "calls": float(np.mean(calls))}
    if len(runs) > 1:
        out["cov_empirical"] = float(np.std(p, ddof=1) / reference)
        # the mean's own standard error, to say whether a bias is real
        out["bias_stderr"] = float(np.std(p, ddof=1) / math.sqrt(len(p)) / reference)
    cov = np.array([r.get("cov", math.nan) for r in runs], dtype=float)
    # OpenTURNS reports a c.o.v. of -1 where none is defined (no failure seen)
    cov[cov < 0] = math.nan
    if np.isfinite(cov).any():
        out["cov_reported"] = float(np.mean(cov[np.isfinite(cov)]))
    low = np.array([r.get("low", math.nan) for r in runs], dtype=float)
    high = np.array([r.get("high", math.nan) for r in runs], dtype=float)
    if len(runs) > 1 and np.isfinite(low).all():
        out["covered"] = int(np.sum((low <= reference) & (reference <= high)))
    return out


class NotTheExecutorsFigures(AssertionError):
    """The in-memory path gave other figures than the executor for the same seed."""


def same_as_executor(executor: dict, in_memory: dict, what: str) -> None:
    """The figures of seed 0 through the executor and in memory, bit for bit."""
    differ = [k for k in ("p", "low", "high", "cov", "calls")
              if not (executor[k] == in_memory[k] or (np.isnan(executor[k]) and
                                                      np.isnan(in_memory[k])))]
    if differ:
        raise NotTheExecutorsFigures(
            f"{what}, seed 0: in memory {[in_memory[k] for k in differ]} where the executor "
            f"gave {[executor[k] for k in differ]} ({', '.join(differ)})")


def run_problem(name: str, methods: list[str], repetitions: int, case_seconds: float,
                folder: Path, with_openturns: bool, budget: dict) -> dict:
    problem = PROBLEMS[name]
    reference = REFERENCES[name]["p_f"]
    result = {"reference": reference, "uqflow": {}, "openturns": {}, "warnings": {},
              "stopped": {}, "errors": {}}
    for kind in methods:
        options, repeated = UQFLOW_METHODS[kind]
        runs, start = [], time.perf_counter()
        try:
            # seed 0 through the executor, as a study; every repetition (seed 0 again
            # included) in memory, which must give the executor's figures bit for bit
            through_executor = run_uqflow(folder, problem, kind, options(budget), 0)
            study = uqflow.load_study(folder / f"{problem.name}-{kind}.toml")
            for seed in range(repetitions if repeated else 1):
                runs.append(run_in_memory(study, problem, seed))
                if seed == 0:
                    same_as_executor(through_executor, runs[0], f"{name} {kind}")
                if time.perf_counter() - start > case_seconds and seed + 1 < repetitions:
                    result["stopped"][kind] = time.perf_counter() - start
                    break
        except (StudyError, uqflow.SolverError, RuntimeError) as exc:
            # a method that cannot run this problem says so in the table
            result["errors"][kind] = f"{type(exc).__name__}: {exc}".splitlines()[0]
            print(f"{name} uqflow {kind}: {result['errors'][kind]}", flush=True)
            continue
        result["uqflow"][kind] = summarize(runs, reference)
        result["uqflow"][kind]["seconds"] = time.perf_counter() - start
        result["warnings"][kind] = runs[0]["warnings"]
        print(f"{name} uqflow {kind}: {result['uqflow'][kind]} "
              f"({time.perf_counter() - start:.0f} s)", flush=True)
    if with_openturns:
        runs_of, result["openturns_errors"] = run_openturns(problem, budget, repetitions)
        for label, runs in runs_of.items():
            result["openturns"][label] = summarize(runs, reference)
            print(f"{name} OpenTURNS {label}: {result['openturns'][label]}", flush=True)
        for label, error in result["openturns_errors"].items():
            print(f"{name} OpenTURNS {label}: {error}", flush=True)
    return result


# ----------------------------------------------------------------------------- report

def _cell(summary: dict, key: str, fmt: str) -> str:
    value = summary.get(key)
    return "" if value is None or not np.isfinite(value) else format(value, fmt)


def _row(side: str, method: str, s: dict, band) -> str:
    if s.get("cov_reported", 0) < 0:        # figures saved before negative ones were dropped
        s = {k: v for k, v in s.items() if k != "cov_reported"}
    covered = ""
    if "covered" in s:
        fraction = s["covered"] / s["repetitions"]
        low, high, _ = band(s["repetitions"])
        mark = _band_mark(fraction, low, high)
        covered = f"{s['covered']}/{s['repetitions']} = {fraction:.3f}{mark}"
    if "bias_stderr" in s:
        bias = _cell(s, "bias", "+.3f") + f" ± {s['bias_stderr']:.3f}"
    else:                                   # one deterministic answer: its relative error
        bias = _cell(s, "bias", "+.2g")
    return (f"| {side} | {method} | {s['repetitions']} | {s['calls']:.0f} | "
            f"{s['p_mean']:.4g} | {bias} | "
            f"{_cell(s, 'cov_reported', '.3f')} | {_cell(s, 'cov_empirical', '.3f')} | "
            f"{covered} |\n")


TITLE = "Reliability: uqflow against OpenTURNS on exact problems"


def report(results: dict, repetitions: int, case_seconds: float, checkout: str = "") -> str:
    low, high, mass = binomial_band(repetitions)
    body = (
        "Each problem is a uqflow study (a `solver_from_function` margin, `[[inputs]]`, "
        "`[correlation]`, one `[[limit_states]]` g below 0) and the same event in "
        "OpenTURNS "
        f"{_openturns_version()}, at the same budgets in the same run (samples of MC and "
        "IS; samples per level and p0 = 0.1 of subset simulation). Sampling methods run "
        f"with seeds 0 … R − 1 (R = {repetitions}, or the fewer its column R says). uqflow's "
        "repetitions run in memory (`uqflow.testing.run_in_memory`: the study's method "
        "driven through plan, extend, stop points and analyze as the executor drives it, the "
        "vectorized margin in place of the solver, no result file); seed 0 of every uqflow "
        "row also ran as a study through the executor (workers = 0) and gave the same p_f, "
        "interval, c.o.v. and calls bit for bit (asserted by the run). 'calls' is "
        "the mean number of margin evaluations (OpenTURNS' IS includes its FORM search), "
        "'p_f' the mean estimate, 'bias' mean / reference − 1 ± its standard error, "
        "'c.o.v. rep.' the mean reported c.o.v., 'c.o.v. emp.' the spread of p_f over the "
        "repetitions / reference, 'coverage' how many reported 95 % intervals hold the "
        "reference (uqflow's Monte Carlo: Clopper–Pearson, conservative by construction; "
        "OpenTURNS: p ± 1.96 sd). "
        f"Coverage band: for R = {repetitions} intervals of true coverage 0.95 the count "
        f"lies in [{low:.3f}, {high:.3f}] with probability {mass:.3f} (binomial quantiles "
        "2.5 % and 97.5 %); rows with fewer repetitions are judged against their own R. "
        "Only p_f, c.o.v. and calls are figures here, no time: other load on the machine "
        "changes none of them. References: `benchmarks/reliability_references.json` "
        "(exact formulas or quadrature; 10⁸-sample numpy Monte Carlo checks beside them). "
        f"Measured with {checkout or _checkout()}.\n")
    if any(r["stopped"] for r in results.values()):
        full = sum(s["seconds"] / s["repetitions"] * repetitions
                   for r in results.values() for kind, s in r["uqflow"].items()
                   if kind in r["stopped"])
        body += (f"\nA uqflow method's repetitions stop after {case_seconds:.0f} s "
                 "(`--case-seconds`); those rows say how many ran. All "
                 f"{repetitions} of the stopped rows would take about {full / 60:.0f} min "
                 "here: `python benchmarks/reliability.py`.\n")
    for name, res in results.items():
        budget = BUDGETS[name]
        body += (f"\n### {PROBLEMS[name].title}\n\nReference p_f = {res['reference']:.6g} "
                 f"({REFERENCES[name]['how']}). Budget: {budget['samples']} samples, "
                 f"{budget['per_level']} per subset level.\n\n"
                 "| | method | R | calls | p_f | bias | c.o.v. rep. | c.o.v. emp. | coverage |\n"
                 "|---|---|---|---|---|---|---|---|---|\n")
        for kind, s in res["uqflow"].items():
            body += _row("uqflow", kind, s, binomial_band)
        for label, s in res["openturns"].items():
            body += _row("OpenTURNS", label, s, binomial_band)
        for label, error in res.get("openturns_errors", {}).items():
            if not error.startswith("not run"):     # figures saved before the prefix
                error = error if " repetitions stopped " in error else "not run: " + error
            if error.startswith("not run"):
                body += f"| OpenTURNS | {label} | | | {error} | | | | |\n"
        stopped = {k: e for k, e in res.get("openturns_errors", {}).items()
                   if " repetitions stopped " in e}
        if stopped:
            body += "\nOpenTURNS: " + " / ".join(f"{k}: {e}" for k, e in stopped.items()) + "\n"
        for kind, error in res["errors"].items():
            body += f"| uqflow | {kind} | | | not run: {error} | | | | |\n"
        notes = [f"{k}: {w.splitlines()[0]}" for k, w in res["warnings"].items() if w]
        if notes:
            body += "\nuqflow warnings (first repetition): " + " / ".join(notes) + "\n"
    return body


#: OpenTURNS' counterpart of each uqflow method in the summary
COUNTERPART = {"monte-carlo": "MC", "form": "FORM", "sorm": "SORM",
               "importance-sampling": "IS at FORM point", "subset-simulation": "SubsetSampling"}
DOCS = ROOT / "docs" / "reliability.md"
SUMMARY = "reliability-summary"


def _headline(s: dict | None, error: str | None = None) -> str:
    """calls | p_f / exact | c.o.v. reported / measured | coverage (against its band)."""
    if s is None:
        return f"{error or '—'} | | | " if error else "— | | | "
    ratio = s["p_mean"] / s["reference"]
    cov = ""
    if "cov_empirical" in s:
        cov = (f"{s['cov_reported']:.3f} / " if "cov_reported" in s else "— / ") + \
            f"{s['cov_empirical']:.3f}"
    covered = ""
    if "covered" in s:
        low, high, _ = binomial_band(s["repetitions"])
        fraction = s["covered"] / s["repetitions"]
        covered = f"{s['covered']}/{s['repetitions']}" + _band_mark(fraction, low, high)
    shown = "no p_f" if not np.isfinite(ratio) else f"{ratio:.3g}"
    return f"{s['calls']:.0f} | {shown} | {cov} | {covered}"


def _band_mark(fraction: float, low: float, high: float) -> str:
    """Below the band: intervals too narrow; above it: conservative ones (Clopper-Pearson)."""
    if fraction < low:
        return " **(below the band)**"
    return " (above the band)" if fraction > high else ""


def summary(results: dict, checkout: str) -> str:
    """docs/reliability.md's table: per problem and uqflow method, its headline and
    OpenTURNS' counterpart's, with the command, commit and machine."""
    repetitions = max((s["repetitions"] for r in results.values()
                       for s in r["uqflow"].values()), default=0)
    low, high, _ = binomial_band(max(repetitions, 2))
    lines = [
        f"<!-- begin {SUMMARY} -->",
        f"Benchmark figures of `{command()}` ({checkout or _checkout()}; OpenTURNS "
        f"{_openturns_version()}; {machine()}), written by it; the whole table, with the bias "
        "and its standard error, is BENCHMARKS.md's section \"Reliability\". Per cell: solver "
        "calls (mean), mean p_f / exact, reported c.o.v. (mean) / measured c.o.v. (spread of "
        f"p_f over the repetitions / exact), and how many of the R = {repetitions} reported "
        f"95 % intervals hold the exact p_f, against the binomial band "
        f"[{low:.3f}, {high:.3f}] of a true 95 % (judged at the row's own R): below it the "
        "intervals are too narrow, above it conservative. 'no p_f': the method gave none "
        "(FORM's search stopped at a zero gradient).",
        "",
        "| problem | uqflow method | calls | p_f / exact | c.o.v. rep. / meas. | coverage | "
        "OpenTURNS | calls | p_f / exact | c.o.v. rep. / meas. | coverage |",
        "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, res in results.items():
        for kind in UQFLOW_METHODS:
            mine = res["uqflow"].get(kind)
            if mine is None and kind not in res.get("errors", {}):
                continue
            mine = dict(mine, reference=res["reference"]) if mine else None
            label = COUNTERPART.get(kind)
            theirs = res["openturns"].get(label) if label else None
            theirs = dict(theirs, reference=res["reference"]) if theirs else None
            error = res.get("openturns_errors", {}).get(label, "") if label else ""
            lines.append(
                f"| `{name}` | {kind} | "
                f"{_headline(mine, 'not run' if kind in res.get('errors', {}) else None)} | "
                f"{label or '—'} | "
                f"{_headline(theirs, 'not run' if error.startswith('not run') else None)} |")
    lines.append(f"<!-- end {SUMMARY} -->")
    return "\n".join(lines)


def write_summary(text: str) -> None:
    """Replace the summary between its markers in docs/reliability.md (they must be there:
    the page's prose around it is written by hand)."""
    import re

    page = DOCS.read_text()
    pattern = re.compile(rf"<!-- begin {SUMMARY} -->.*?<!-- end {SUMMARY} -->", re.S)
    if not pattern.search(page):
        raise SystemExit(f"{DOCS} has no <!-- begin {SUMMARY} --> ... <!-- end {SUMMARY} -->")
    DOCS.write_text(pattern.sub(lambda _: text, page))


def _checkout() -> str:
    """The commit the figures were measured at, and uqflow's files changed since (a method
    being written while the benchmark ran)."""
    import subprocess

    from _record import ROOT

    def git(*args):
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=False).stdout.strip()
    head = git("rev-parse", "--short", "HEAD") or "unknown"
    changed = [line.split()[-1] for line in
               git("status", "--porcelain", "--", "uqflow").splitlines()]
    return f"uqflow at commit {head}" + (
        f" with uncommitted changes in {', '.join(changed)}" if changed else "")


def _openturns_version() -> str:
    try:
        import openturns as ot
    except ImportError:
        return "(not installed)"
    return ot.__version__


def _checkouts(saved: list[dict]) -> str:
    """The checkout each saved file's uqflow rows ran at (methods measured at different
    commits say which)."""
    order = list(UQFLOW_METHODS)
    kinds: dict[str, set] = {}
    for part in saved:
        kinds.setdefault(part["checkout"], set()).update(
            k for r in part["results"].values() for k in r["uqflow"])
    if len(kinds) == 1:
        return next(iter(kinds))
    return "; ".join(f"{', '.join(sorted(k, key=order.index))} with {c}"
                     for c, k in kinds.items())


def merged(parts) -> dict:
    """The results of several ``--save`` files as one: a problem's rows from every file
    that ran it (methods split among processes), uqflow's in the table's order."""
    results: dict = {}
    for part in parts:
        for name, result in part.items():
            into = results.setdefault(name, {"reference": result["reference"]})
            for key, value in result.items():
                if isinstance(value, dict):
                    into.setdefault(key, {}).update(value)
                else:
                    into[key] = value
    results = {name: results[name] for name in PROBLEMS if name in results}
    for result in results.values():
        result["uqflow"] = {k: result["uqflow"][k] for k in UQFLOW_METHODS
                            if k in result.get("uqflow", {})}
        for key in ("uqflow", "openturns", "warnings", "stopped", "errors"):
            result.setdefault(key, {})
    return results


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", nargs="*", default=list(PROBLEMS))
    ap.add_argument("--methods", nargs="*", default=None,
                    help="uqflow methods (default: every one of the table registered)")
    ap.add_argument("--repetitions", type=int, default=200)
    ap.add_argument("--case-seconds", type=float, default=math.inf,
                    help="stop a uqflow method's repetitions after this many seconds")
    ap.add_argument("--no-openturns", action="store_true")
    ap.add_argument("--save", type=Path, help="also write the raw figures to this JSON file")
    ap.add_argument("--report-from", type=Path, nargs="*",
                    help="write BENCHMARKS.md from --save files (no run; several: problems "
                         "run by separate processes, in the order given), with the command "
                         "of the first")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    methods = args.methods or (QUICK_METHODS if args.quick else available_methods())
    problems = ["r_minus_s"] if args.quick else args.problems
    repetitions = 2 if args.quick else args.repetitions
    with_openturns = not (args.quick or args.no_openturns)
    if args.report_from:
        saved = [json.loads(path.read_text()) for path in args.report_from]
        results = merged(part["results"] for part in saved)
        first = saved[0]
        sys.argv = first["argv"]            # the section names the command that measured it
        if len(saved) > 1:                  # one command for all: drop the split's --problems
            sys.argv = [a for a in first["argv"] if a not in PROBLEMS and a not in (
                "--problems", "--methods", "--no-openturns") and a not in UQFLOW_METHODS]
            sys.argv = [a for i, a in enumerate(sys.argv) if not (
                a.endswith(".json") or (i and sys.argv[i - 1] == "--save") or a == "--save")]
        checkout = _checkouts(saved)
        body = report(results, first["repetitions"], first["case_seconds"], checkout)
        if len(saved) > 1:
            body += (f"\nRun as {len(saved)} processes, the problems split among them by "
                     "`--problems` and the methods by `--methods` (each with `--save`), merged "
                     "by `--report-from`: every row's figures are its own, the same as from "
                     "the one command. The commands and the commit each ran at: "
                     + "; ".join(f"`{' '.join(['python', *part['argv']])}` at "
                                 f"{part['checkout'].removeprefix('uqflow at ')}"
                                 for part in saved) + ".\n")
        write_section("reliability", TITLE, body)
        write_summary(summary(results, checkout))
        return results
    results = {}
    checkout = "" if args.quick else _checkout()    # the code that runs: as it starts
    with tempfile.TemporaryDirectory() as tmp:
        for name in problems:
            results[name] = run_problem(name, methods, repetitions, args.case_seconds,
                                        Path(tmp), with_openturns,
                                        QUICK_BUDGET if args.quick else BUDGETS[name])
            if args.save:       # after each problem: a run stopped early keeps what it did
                args.save.write_text(json.dumps(
                    {"argv": sys.argv, "results": results, "repetitions": repetitions,
                     "case_seconds": args.case_seconds, "checkout": checkout}, indent=1))
    if not args.quick:
        write_section("reliability", TITLE, report(results, repetitions, args.case_seconds,
                                                   checkout))
        write_summary(summary(results, checkout))
    return results


if __name__ == "__main__":
    main()
