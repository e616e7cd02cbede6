"""The sobol method against exact indices of the Ishigami and Sobol g functions."""

import numpy as np
import pytest

from solvers.analytic import AnalyticSolver
from uqflow.errors import StudyError
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import get_method
from uqflow.realization import evaluate_design

TOL = 0.05


def uniform(name, lower, upper):
    return RandomInput.from_spec({"name": name, "distribution": "uniform",
                                  "lower": lower, "upper": upper})


def constant(name, value):
    return RandomInput.from_spec({"name": name, "distribution": "normal",
                                  "mean": value, "std": 0.0})


def ishigami_space():
    return InputSpace([uniform(f"x{i}", -np.pi, np.pi) for i in (1, 2, 3)])


def study(model, space, seed=1, scene=None, **options):
    """Plan, run in-process and analyze; returns (design, runs, stats)."""
    method = get_method("sobol")(**options)
    solver = AnalyticSolver.from_scene({"model": model, **(scene or {})})
    design = method.plan(space, None, np.random.SeedSequence(seed))
    runs = evaluate_design(solver, design)
    return design, runs, method.analyze(design, runs)


@pytest.fixture(scope="module")
def ishigami():
    # One second-order design serves S1, ST and S2: its A, AB and B rows are the first-order
    # design of the same seed.
    return study("ishigami", ishigami_space(), samples=1024, second_order=True)


def test_registered_with_options():
    cls = get_method("sobol")
    assert cls.name == "sobol"
    opts = cls().options
    assert (opts.samples, opts.second_order, opts.resamples, opts.confidence) == \
        (1024, False, 1000, 0.95)
    with pytest.raises(ValueError):
        cls(samples=1)


def test_ishigami_first_and_total(ishigami, reference):
    _, _, stats = ishigami
    s = stats["y_sobol"]
    assert s.dims == ("sobol_index", "parameter")
    assert list(s["sobol_index"].values) == ["S1", "S1_conf", "ST", "ST_conf"]
    np.testing.assert_allclose(s.sel(sobol_index="S1"), reference["ishigami"]["S"], atol=TOL)
    np.testing.assert_allclose(s.sel(sobol_index="ST"), reference["ishigami"]["ST"], atol=TOL)
    assert stats.attrs["warnings"] == ""


def test_ishigami_second_order(ishigami, reference):
    _, _, stats = ishigami
    s2 = stats["y_sobol2"]
    assert s2.dims == ("sobol2_index", "parameter", "parameter_j")
    assert s2.sel(sobol2_index="S2", parameter="x1", parameter_j="x3") == \
        pytest.approx(reference["ishigami"]["S13"], abs=TOL)
    # x1-x2 and x2-x3 do not interact; SALib leaves the diagonal and lower triangle NaN.
    assert abs(s2.sel(sobol2_index="S2", parameter="x1", parameter_j="x2")) < TOL
    assert abs(s2.sel(sobol2_index="S2", parameter="x2", parameter_j="x3")) < TOL
    values = s2.sel(sobol2_index="S2").values
    assert np.all(np.isnan(values[np.tril_indices(3)]))
    assert np.all(np.isfinite(values[np.triu_indices(3, k=1)]))


def test_ishigami_moments(ishigami, reference):
    _, _, stats = ishigami
    y = stats["y"]
    assert list(y["statistic"].values) == ["mean", "variance", "std"]
    ref = reference["ishigami"]
    assert y.sel(statistic="mean") == pytest.approx(ref["mean"], abs=0.1)
    assert y.sel(statistic="variance") == pytest.approx(ref["variance"], rel=0.05)
    assert y.sel(statistic="std") == pytest.approx(np.sqrt(y.sel(statistic="variance")))


def test_bootstrap_interval_covers_exact(ishigami, reference):
    _, _, stats = ishigami
    s = stats["y_sobol"]
    for key, exact in (("S1", "S"), ("ST", "ST")):
        err = np.abs(s.sel(sobol_index=key).values - reference["ishigami"][exact])
        half = s.sel(sobol_index=f"{key}_conf").values
        assert np.all(half > 0)
        assert np.all(err <= half + 0.01), (key, err, half)  # "or nearly": 0.01 of slack


def test_sobol_g(reference):
    ref = reference["sobol_g"]
    space = InputSpace([uniform(f"x{i + 1}", 0.0, 1.0) for i in range(8)])
    _, _, stats = study("sobol_g", space, seed=3, scene={"a": ref["a"]}, samples=1024)
    s = stats["y_sobol"].isel(parameter=slice(0, 4))
    np.testing.assert_allclose(s.sel(sobol_index="S1"), ref["S"], atol=TOL)
    np.testing.assert_allclose(s.sel(sobol_index="ST"), ref["ST"], atol=TOL)


@pytest.mark.parametrize("second_order", [False, True])
def test_run_count(second_order):
    space = InputSpace([uniform(f"x{i + 1}", 0.0, 1.0) for i in range(5)])
    method = get_method("sobol")(samples=64, second_order=second_order)
    design = method.plan(space, None, np.random.SeedSequence(0))
    d = len(space)
    assert design.sizes["realization"] == 64 * ((2 * d + 2) if second_order else (d + 2))
    assert design["inputs"].dims == ("realization", "parameter")
    assert np.all((design["inputs"].values > 0) & (design["inputs"].values < 1))


def test_same_seed_same_design():
    method = get_method("sobol")(samples=32)
    plan = lambda seed: method.plan(ishigami_space(), None, np.random.SeedSequence(seed))
    a, b, c = plan(7), plan(7), plan(8)
    np.testing.assert_array_equal(a["inputs"].values, b["inputs"].values)
    assert a.attrs == b.attrs
    assert not np.array_equal(a["inputs"].values, c["inputs"].values)


def test_same_runs_same_intervals():
    # The bootstrap seed travels with the design, so a re-analysis repeats the intervals.
    design, runs, first = study("ishigami", ishigami_space(), samples=64, resamples=100)
    again = get_method("sobol")(samples=64, resamples=100).analyze(design, runs)
    np.testing.assert_array_equal(first["y_sobol"].values, again["y_sobol"].values)


def test_field_output():
    space = InputSpace([
        RandomInput.from_spec({"name": "alpha", "distribution": "normal",
                               "mean": 1.5, "std": 0.2}),
        uniform("beta", 0.1, 0.2),
    ])
    _, _, stats = study("exponential_decay", space, samples=256)
    s = stats["y_sobol"]
    assert s.dims == ("sobol_index", "parameter", "t")
    assert stats["y"].dims == ("statistic", "t")
    assert s.sizes["t"] == 21 and np.all(np.isfinite(s.values))
    var = stats["y"].sel(statistic="variance").values
    assert np.all(var > 0)
    s1, st = s.sel(sobol_index="S1"), s.sel(sobol_index="ST")
    # Estimator noise may push a sum a hair above 1 or ST a hair below S1.
    assert np.all(s1.sum("parameter").values <= 1 + 0.01)
    assert np.all(st.values >= s1.values - 0.01)
    # y(0) = alpha: all of the variance is alpha's; later beta takes a growing share.
    assert s1.sel(parameter="alpha", t=0.0) == pytest.approx(1.0, abs=0.02)
    assert s1.sel(parameter="beta", t=10.0) > s1.sel(parameter="beta", t=1.0)
    assert stats["t"].attrs["units"] == "s"


def test_constant_input_has_zero_indices():
    space = InputSpace([uniform("x1", -np.pi, np.pi), uniform("x2", -np.pi, np.pi),
                        constant("x3", 0.0)])
    design, _, stats = study("ishigami", space, samples=256)
    assert np.all(design["inputs"].sel(parameter="x3").values == 0.0)
    s = stats["y_sobol"].sel(parameter="x3").values
    # x3's resampled matrix A_B^(3) is A itself: every difference in the estimators is 0.0
    np.testing.assert_array_equal(s, 0.0)
    assert np.all(np.isfinite(stats["y_sobol"].values))


def test_all_inputs_constant_gives_nan_and_warning():
    space = InputSpace([constant(f"x{i}", 1.0) for i in (1, 2, 3)])
    _, _, stats = study("ishigami", space, samples=16)
    assert np.all(np.isnan(stats["y_sobol"].values))
    assert stats["y"].sel(statistic="variance") == 0.0
    assert "zero variance" in stats.attrs["warnings"]


def test_solver_failures_drop_blocks():
    # faulty: y = x, failing above 0.8; each base sample is a block of 3 runs (A, AB, B).
    space = InputSpace([uniform("x", 0.0, 1.0)])
    design, runs, stats = study("faulty", space, samples=256, scene={"raise_above": 0.8})
    failed = runs["status"].values.reshape(256, 3) != "ok"
    dropped = int(failed.any(axis=1).sum())
    assert 0 < dropped < 256
    assert stats.attrs["samples_kept"] == 256 - dropped
    assert f"{dropped} of 256 base samples dropped" in stats.attrs["warnings"]
    assert stats.attrs["failed_runs"] == int(failed.sum())
    s = stats["y_sobol"].sel(parameter="x")
    assert np.all(np.isfinite(s.values))
    assert s.sel(sobol_index="S1") == pytest.approx(1.0, abs=0.05)


def test_hand_made_failures(ishigami, reference):
    design, runs, _ = ishigami
    runs = runs.copy(deep=True)
    step = 2 * 3 + 2
    rng = np.random.default_rng(0)
    bad = rng.choice(runs.sizes["realization"], size=100, replace=False)
    runs["status"].values[bad] = "failed"
    runs["y"].values[bad] = np.nan
    # A run marked ok with a NaN output is treated as failed too.
    runs["y"].values[3 * step + 1] = np.nan
    stats = get_method("sobol")(second_order=True).analyze(design, runs)
    dropped = len(set(bad // step) | {3})
    assert stats.attrs["samples_kept"] == 1024 - dropped
    assert f"{dropped} of 1024 base samples dropped" in stats.attrs["warnings"]
    s = stats["y_sobol"]
    assert np.all(np.isfinite(s.values))
    np.testing.assert_allclose(s.sel(sobol_index="S1"), reference["ishigami"]["S"], atol=TOL)
    np.testing.assert_allclose(s.sel(sobol_index="ST"), reference["ishigami"]["ST"], atol=TOL)


def test_too_few_blocks_gives_nan():
    space = InputSpace([uniform("x", 0.0, 1.0)])
    _, _, stats = study("faulty", space, samples=16, scene={"raise_above": 0.05})
    assert stats.attrs["samples_kept"] < 2
    assert np.all(np.isnan(stats["y_sobol"].values))
    assert "sobol indices are NaN" in stats.attrs["warnings"]


def test_correlated_inputs_refused():
    space = InputSpace([uniform("x1", 0, 1), uniform("x2", 0, 1)],
                       correlation=np.array([[1.0, 0.5], [0.5, 1.0]]))
    with pytest.raises(StudyError, match="assume independent inputs") as err:
        get_method("sobol")().plan(space, None, np.random.SeedSequence(0))
    assert err.value.key == "method.kind"
