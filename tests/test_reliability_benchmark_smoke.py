"""benchmarks/reliability.py in its --quick mode (R - S, Monte Carlo twice at 100 samples and
FORM, no OpenTURNS), so the benchmark cannot rot; its figures are benchmark figures of its own
command, and here only what holds at any size is asserted."""

from __future__ import annotations

import copy
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from scipy import stats as sps

import uqflow
import uqflow.inputs
from uqflow.layout import (COMPILE_TIME, FAILED_RUNS, MESSAGE, STATUS, STATUS_FAILED,
                           STOPPED_EARLY, UNITS, WALL_TIME)
from uqflow.testing import run_in_memory

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import reliability as bench  # noqa: E402


def test_reliability_benchmark_runs_in_quick_mode(monkeypatch):
    monkeypatch.setattr(bench, "write_section", lambda *a: pytest.fail("quick mode wrote"))
    repetitions = []                    # each in-memory repetition's figures, as it ran
    in_memory = bench.run_in_memory

    def recorded(study, problem, seed):
        repetitions.append((study.method.name, seed, in_memory(study, problem, seed)))
        return repetitions[-1][2]
    monkeypatch.setattr(bench, "run_in_memory", recorded)
    results = bench.main(["--quick"])["r_minus_s"]
    reference = sps.norm.cdf(-math.sqrt(2))
    # the stored formula's value against scipy's: a few ulp of the normal tail (abs=0:
    # approx's default 1e-12 is 1e-11 of this p)
    assert results["reference"] == pytest.approx(reference, rel=1e-12, abs=0)
    assert results["openturns"] == {}
    form = results["uqflow"]["form"]
    # R - S is linear in normals: FORM is exact up to the differences' rounding (1e-13)
    assert form["p_mean"] == pytest.approx(reference, rel=1e-9)
    assert form["repetitions"] == 1 and form["calls"] > 0
    assert [(kind, seed) for kind, seed, _ in repetitions] == [
        ("monte-carlo", 0), ("monte-carlo", 1), ("form", 0)]
    mc = results["uqflow"]["monte-carlo"]
    assert mc["repetitions"] == 2 and mc["calls"] == 100
    # two means of 100 draws at p = 0.079: stderr sqrt(p (1 - p) / 200) = 0.019; 4 of them
    assert abs(mc["p_mean"] - reference) < 4 * math.sqrt(reference * (1 - reference) / 200)
    # each repetition's failure count k of 100, recomputed: its Clopper-Pearson interval
    # holds the exact p_f when neither tail of binomial(100, p_f) beyond k is below 2.5 %
    # (3 <= k <= 13), so the coverage is a count known without the intervals
    counts = [round(figures["p"] * 100) for kind, _, figures in repetitions
              if kind == "monte-carlo"]
    assert [f["p"] for kind, _, f in repetitions if kind == "monte-carlo"] == [
        k / 100 for k in counts]
    assert mc["covered"] == sum(sps.binom.sf(k - 1, 100, reference) > 0.025 and
                                sps.binom.cdf(k, 100, reference) > 0.025 for k in counts)
    # the reported c.o.v.: the binomial sqrt((1 - p) / (n p)), averaged over the two; each
    # side a few correctly rounded operations (no libm): 1e-14 is 45 eps (abs=0: approx's
    # default 1e-12 would hide a relative error of 3e-12 here)
    assert mc["cov_reported"] == pytest.approx(
        # bound: the same formula, a few roundings per term: 1e-14
        np.mean([math.sqrt((1 - k / 100) / k) for k in counts]), rel=1e-14, abs=0)
    text = bench.report({"r_minus_s": results}, 2, math.inf)
    assert "| uqflow | form | 1 |" in text and "| uqflow | monte-carlo | 2 | 100 |" in text
    # the docs' summary: FORM exact (p_f / exact rounds to 1), Monte Carlo's 100 calls
    table = bench.summary({"r_minus_s": results}, "uqflow at commit x")
    assert f"| `r_minus_s` | form | {form['calls']:.0f} | 1 |" in table
    assert f"| `r_minus_s` | monte-carlo | 100 | {mc['p_mean'] / reference:.3g} |" in table
    assert table.startswith("<!-- begin reliability-summary -->")


def test_the_coverage_band_is_the_binomial_one():
    low, high, mass = bench.binomial_band(200)
    # 200 intervals at 0.95: 184 to 196 of them (0.92 to 0.98), binomial mass 0.967
    assert (low, high) == (184 / 200, 196 / 200)
    assert mass == pytest.approx(0.96715, abs=1e-5)


# ------------------------------------------------ uqflow.testing.run_in_memory, the fast path

def _study(tmp_path, kind, options, seed=3):
    problem = bench.PROBLEMS["r_minus_s"]
    return uqflow.load_study(bench.write_study(tmp_path, problem, kind, options, seed)), problem


def _without_timing(ds):
    # the executor's wall and compile times are measured, run_in_memory's 0
    return ds.drop_vars([WALL_TIME, COMPILE_TIME], errors="ignore")


@pytest.mark.parametrize("kind, options", [
    # planned draws stopped early by enough at a stop point (target_cov reached)
    ("monte-carlo", {"samples": 400, "target_cov": 0.3}),
    # FORM's search rounds through extend
    ("form", {}),
    # subset simulation: a round per chain step, levels through extend
    ("subset-simulation", {"samples_per_level": 60, "level_probability": 0.1}),
])
def test_in_memory_runs_are_the_executors_bit_for_bit(tmp_path, kind, options):
    study, problem = _study(tmp_path, kind, options)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        outcome = uqflow.run_study(study, show_progress=False, force=True)
        runs, stats = run_in_memory(copy.deepcopy(uqflow.load_study(study.path).method),
                                    study.space, study.limit_states,
                                    lambda x: {"g": problem.margin(x)}, 3,
                                    outputs=study.solver.outputs()[study.outputs])
    # the same rows, values, dtypes, coordinates and attributes; the statistics too (but
    # for the solver's time, which the executor measured)
    xr.testing.assert_identical(_without_timing(runs), _without_timing(outcome.runs))
    assert np.all(runs[WALL_TIME].values == 0)
    timed = [k for k in stats.attrs if "time" in k]
    xr.testing.assert_identical(stats.drop_attrs(deep=False).assign_attrs(
        {k: v for k, v in stats.attrs.items() if k not in timed}),
        outcome.statistics.drop_attrs(deep=False).assign_attrs(
        {k: v for k, v in outcome.statistics.attrs.items() if k not in timed}))
    if kind == "monte-carlo":
        assert STOPPED_EARLY in outcome.attrs and runs.sizes["realization"] < 400


def test_in_memory_failed_rows_and_defaults():
    # no outputs given: the limit-state tables' outputs, units "1"; a NaN output fails its
    # row with the executor's message and is left out of the estimate
    space = uqflow.inputs.InputSpace([uqflow.inputs.RandomInput.from_spec(
        {"name": "x", "distribution": "normal", "mean": 0.0, "std": 1.0})])
    method = uqflow.get_method("monte-carlo")(samples=50)

    def g(x):
        return np.where(x[:, 0] > 1.0, np.nan, 2.0 - x[:, 0])
    runs, stats = run_in_memory(method, space, [{"name": "f", "output": "g", "below": 0.0}],
                                g, 5)
    failed = runs[STATUS].values == STATUS_FAILED
    assert failed.any() and np.all(runs["g"].values[failed] != runs["g"].values[failed])
    assert set(runs[MESSAGE].values[failed]) == {"non-finite output 'g'"}
    assert runs["g"].attrs[UNITS] == "1"
    assert stats.attrs[FAILED_RUNS] == failed.sum()
