"""The SPH benchmarks in their --quick mode, so they cannot rot (no timing is asserted)."""

import pytest


@pytest.mark.parametrize("name", ["sph_scaling", "sph_example3_timing", "sph_factor_floor",
                                  "sph_study"])
def test_benchmark_runs_in_quick_mode(name, monkeypatch, benchmark_module):
    module = benchmark_module(name)
    monkeypatch.setattr(module, "write_section", lambda *a: pytest.fail("quick mode wrote"))
    assert module.main(["--quick"])
