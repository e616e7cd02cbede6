"""benchmarks/sph_precision.py in its --quick mode, so it cannot rot (no timing is
asserted): every case runs both ways, and the refined solves end where they should."""

import pytest

from solvers.sph import linear


def test_the_precision_benchmark_runs_in_quick_mode(monkeypatch, benchmark_module):
    module = benchmark_module("sph_precision")
    monkeypatch.setattr(module, "write_section", lambda *a: pytest.fail("quick mode wrote"))
    # --quick refines at its tiny size by lowering the limit: the test puts it back
    monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", linear.MIXED_PRECISION_ABOVE)
    rows = module.main(["--quick"])
    assert {(r["method"], r["weight"]) for r in rows} == {
        ("master-slave-local", None), ("master-slave-cutoff", None), ("penalty", 1e4),
        ("penalty", 1e6)}
    for r in rows:
        # a penalty 1e6 times the stiffness is too ill-conditioned for single precision
        # (cond x 6e-8 > 1): refinement stalls and the solve ends in double
        stiff = r["weight"] == 1e6
        assert r["precision"] == ("double" if stiff else "single, refined")
        assert (r["steps"] == 0) if stiff else (r["steps"] >= 1)
