"""benchmarks/multilevel_gain.py in its --quick mode (the analytic Euler model), so it cannot
rot; no timing is asserted, only that the three studies agree on the mean they estimate."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_multilevel_gain_runs_in_quick_mode(monkeypatch):
    spec = importlib.util.spec_from_file_location("multilevel_gain",
                                                  ROOT / "benchmarks" / "multilevel_gain.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "write_section", lambda *a: pytest.fail("quick mode wrote"))
    results = module.main(["--quick"])
    row = results["euler"]["rows"][0]
    for method in ("multilevel", "multifidelity", "multifidelity+taylor-local"):
        # the same finest-level mean: within 4 combined standard errors
        assert abs(row[method]["z"]) < 4
        assert row[method]["cost"] > 0 and row[method]["plain_cost"] > 0
