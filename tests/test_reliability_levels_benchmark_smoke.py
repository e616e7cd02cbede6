"""benchmarks/reliability_levels.py in its --quick mode ("nested" at tiny sizes, two
repetitions of each uqflow multifidelity method, no OpenTURNS), so the benchmark cannot rot;
its figures are benchmark figures of its own command, and here only what holds at any size
is asserted: the level families' finest level is exact, the cost bookkeeping adds up."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as sps

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location(
        "reliability_levels", ROOT / "benchmarks" / "reliability_levels.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_reliability_levels_benchmark_runs_in_quick_mode(monkeypatch):
    bench = _bench()
    monkeypatch.setattr(bench, "write_section", lambda *a: pytest.fail("quick mode wrote"))
    # every family's finest level is g = 3.5 - u1 itself: the exact p_f is Phi(-3.5)
    u = np.random.default_rng(0).standard_normal((100, 2))
    for problem in bench.PROBLEMS:
        assert np.array_equal(bench.margin(problem, u, np.ones(100)), 3.5 - u[:, 0])
        assert not np.array_equal(bench.margin(problem, u, np.zeros(100)), 3.5 - u[:, 0])
    assert bench.EXACT == sps.norm.sf(3.5)
    results = bench.main(["--quick"])
    assert {name for _, name in results} == set(bench.UQFLOW)
    for (problem, name), row in results.items():
        assert row["reps"] == 2 and row["mean"] > 0
        # total cost = finest runs + coarse runs / 64: at least the finest runs
        assert row["cost"] >= row["calls"] > 0
        assert row["merit"] == pytest.approx(row["calls"] * row["measured"] ** 2)
