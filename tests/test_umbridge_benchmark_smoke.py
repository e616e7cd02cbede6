"""benchmarks/umbridge_overhead.py in its --quick mode, so it cannot rot (no timing is
asserted)."""

import pytest

pytest.importorskip("umbridge")


def test_the_umbridge_benchmark_runs_in_quick_mode(monkeypatch, benchmark_module):
    module = benchmark_module("umbridge_overhead")
    monkeypatch.setattr(module, "write_section", lambda *a: pytest.fail("quick mode wrote"))
    figures = module.main(["--quick"])
    assert figures["trivial"]["http"] > 0 and set(figures["throughput"]) == {1, 2, 4}
