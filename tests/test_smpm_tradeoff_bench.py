"""benchmarks/smpm_tradeoff.py's machinery at a toy size (resolution 0.125, a handful of
runs), so the benchmark does not rot between its runs. The figures it records are benchmark
figures of its own command; here only what must hold at any size is asserted."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import smpm_tradeoff as bench  # noqa: E402


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tradeoff")
    return folder, bench.benchmark(folder, bench.TOY, reuse=False, record=False)


def _synthetic_runs():
    """Two realizations, 4 times, 2 probes, 2 parameters; realization 0 has derivatives."""
    y = np.array([[[0.0, 1.0], [3.0, -5.0], [2.0, 4.0], [1.0, 0.5]],
                  [[0.0, 2.0], [1.0, -1.0], [6.0, 7.0], [0.5, 0.0]]])
    grad = np.arange(4 * 2 * 2, dtype=float).reshape(1, 4, 2, 2) + 1.0
    hess = np.arange(4 * 2 * 2 * 2, dtype=float).reshape(1, 4, 2, 2, 2) + 1.0
    runs = xr.Dataset(
        {"flow_stress": (("realization", "time", "probe"), y),
         "flow_stress__gradient": (("sensitivity_run", "time", "probe", "parameter"), grad),
         "flow_stress__hessian": (("sensitivity_run", "time", "probe", "parameter",
                                   "parameter_j"), hess),
         "status": ("realization", np.array(["ok", "ok"], dtype=object))},
        coords={"realization": [0, 1], "time": [0.0, 1e-6, 2e-6, 3e-6], "probe": ["H", "I"],
                "parameter": ["a", "b"], "parameter_j": ["a", "b"],
                "sensitivity_realization": ("sensitivity_run", [0])})
    for out in ("S11", "S22"):
        runs[out] = runs["flow_stress"]
    return runs


def test_peak_takes_the_derivative_at_the_argmax_with_its_sign():
    runs = _synthetic_runs()
    reduced = bench.peak(runs)
    assert reduced["flow_stress"].values.tolist() == [[3.0, 5.0], [6.0, 7.0]]
    grad = runs["flow_stress__gradient"].values[0]
    # probe H peaks at time 1 (+3), probe I at time 1 (-5: sign flips the derivative)
    np.testing.assert_array_equal(reduced["flow_stress__gradient"].values[0, 0], grad[1, 0])
    np.testing.assert_array_equal(reduced["flow_stress__gradient"].values[0, 1], -grad[1, 1])
    hess = runs["flow_stress__hessian"].values[0]
    np.testing.assert_array_equal(reduced["flow_stress__hessian"].values[0, 1], -hess[1, 1])
    assert "time" not in reduced.dims


def test_pool_prefixes_are_the_plain_designs(toy):
    """The reference's sample rows are plain Monte Carlo's Sobol' design with the same seed
    (nested prefixes are then plain Sobol' MC), and pce's germ reproduces their inputs."""
    import uqflow
    from uqflow.methods.base import get_method
    folder, _ = toy
    study = uqflow.load_study(folder / "ref.toml")
    seed = np.random.SeedSequence(study.spec.execution.seed)
    design = study.method.plan(study.space, None, seed)
    samples, _ = bench.plain_part(design, design, 2 * bench.TOY.replicates)
    plain = get_method("monte-carlo")(rule="sobol", samples=bench.TOY.ref_samples,
                                      replicates=bench.TOY.replicates).plan(
        study.space, None, np.random.SeedSequence(study.spec.execution.seed))
    np.testing.assert_array_equal(samples["inputs"].values,
                                  plain["inputs"].values[:2 * bench.TOY.replicates])
    germ = bench.pce_design(samples, 2)
    x = samples["input_mean"].values + samples["input_std"].values * germ["standard_normal"].values
    # mu + sigma (x - mu)/sigma: a few roundings of numbers of x's size
    np.testing.assert_allclose(x, samples["inputs"].values, rtol=1e-14)


def test_the_sweep_uses_the_same_normal_draws_at_every_cv(toy):
    import uqflow
    folder, _ = toy
    draws = []
    for cv in bench.TOY.sweep_cvs:
        study = uqflow.load_study(folder / f"sweep_cv{cv:g}_ref.toml")
        design = study.method.plan(study.space, None,
                                   np.random.SeedSequence(study.spec.execution.seed))
        x, mu = design["inputs"].values, design["input_mean"].values
        draws.append((x / mu - 1.0) / cv)
    # z recovered through x = mu (1 + cv z): rounding of x relative to cv z, below 1e-12
    np.testing.assert_allclose(draws[0], draws[-1], rtol=0, atol=1e-12)


def test_the_checks_and_tables_come_out(toy):
    _, out = toy
    checks = "\n".join(out["checks"])
    for label in ("(a) 100 µs", "(b) 100 µs", "(c) cost", "(d) taylor-local"):
        assert label in checks
    main = out["main"]
    ref = main.ref.stats["100 µs"]
    for label, ests in main.curves.items():
        for est in ests:
            mean_err, var_err = bench.errors(est.stats["100 µs"], ref, "flow_stress", "H")
            assert np.isfinite(mean_err) and np.isfinite(var_err), label
    # the largest control-variate prefix is below the reference's size: a non-zero error
    assert main.curves["MC control variate"][-1].runs < main.ref.runs
    for table in (bench.error_table(main, bench.TOY), bench.worst_table(main),
                  bench.sweep_table(out["points"]), bench.leave_table(out["points"]),
                  bench.warning_table(out["points"])):
        assert table.count("\n") >= 2


def test_the_figures_are_drawn(toy, tmp_path):
    _, out = toy
    bench.draw_tradeoff(out["main"], "peak", tmp_path / "peak.png")
    bench.draw_sweep(out["points"], "100 µs", tmp_path / "sweep.png")
    for name in ("peak.png", "sweep.png"):
        # the docs keep figures small (< 150 kB each)
        assert 0 < (tmp_path / name).stat().st_size < 150_000


def test_a_failed_realization_is_recorded_and_the_studies_go_on(toy):
    _, out = toy
    assert len(out["failures"]) == 2
    for line in out["failures"]:
        failed = int(line.split(": ", 1)[1].split(" of ")[0])
        assert failed > 0 and "complete = 1" in line and "(no failure warning)" not in line


def test_the_taylor_warning_fires_at_the_largest_cv(toy):
    _, out = toy
    table = bench.warning_table(out["points"])
    top = [row for row in table.splitlines() if row.startswith(f"| {bench.TOY.sweep_cvs[-1]:g} | taylor |")]
    assert top and "C.V. too large for Taylor" in top[0]
