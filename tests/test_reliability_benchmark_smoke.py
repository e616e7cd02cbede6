"""benchmarks/reliability.py in its --quick mode (R - S, Monte Carlo twice at 100 samples and
FORM, no OpenTURNS), so the benchmark cannot rot; its figures are benchmark figures of its own
command, and here only what holds at any size is asserted."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
from scipy import stats as sps

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import reliability as bench  # noqa: E402


def test_reliability_benchmark_runs_in_quick_mode(monkeypatch):
    monkeypatch.setattr(bench, "write_section", lambda *a: pytest.fail("quick mode wrote"))
    results = bench.main(["--quick"])["r_minus_s"]
    reference = sps.norm.cdf(-math.sqrt(2))
    # the stored formula's value against scipy's: a few ulp of the normal tail
    assert results["reference"] == pytest.approx(reference, rel=1e-12)
    assert results["openturns"] == {}
    form = results["uqflow"]["form"]
    # R - S is linear in normals: FORM is exact up to the differences' rounding (1e-13)
    assert form["p_mean"] == pytest.approx(reference, rel=1e-9)
    assert form["repetitions"] == 1 and form["calls"] > 0
    mc = results["uqflow"]["monte-carlo"]
    assert mc["repetitions"] == 2 and mc["calls"] == 100
    # two means of 100 draws at p = 0.079: stderr sqrt(p (1 - p) / 200) = 0.019; 4 of them
    assert abs(mc["p_mean"] - reference) < 4 * math.sqrt(reference * (1 - reference) / 200)
    assert 0 <= mc["covered"] <= 2 and mc["cov_reported"] > 0
    text = bench.report({"r_minus_s": results}, 2, math.inf)
    assert "| uqflow | form | 1 |" in text and "| uqflow | monte-carlo | 2 | 100 |" in text


def test_the_coverage_band_is_the_binomial_one():
    low, high, mass = bench.binomial_band(200)
    # 200 intervals at 0.95: 184 to 196 of them (0.92 to 0.98), binomial mass 0.967
    assert (low, high) == (184 / 200, 196 / 200)
    assert mass == pytest.approx(0.96715, abs=1e-5)
