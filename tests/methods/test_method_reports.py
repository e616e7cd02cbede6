"""Each built-in method's report hook (``PropagationMethod.report``): its columns carry the
numbers of its statistics, its sensitivities are the ones it computed (Taylor's g_k² s_k²,
Sobol' S1/ST with bootstrap half-widths, PCE's indices), its description says the method and
its runs in words; a method without a hook still gets a report; ``compare_results`` gives the
level methods' comparison once."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import uqflow
from levels_study import euler_levels_study
from solvers.analytic import AnalyticSolver
from uqflow.execute import run_study
from uqflow.fields import FieldSpec, RandomField
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import PropagationMethod, compare_results, get_method
from uqflow.methods.level_report import squared
from uqflow.realization import evaluate_design
from uqflow.report import MethodReport, ResultView, number, summary_table
from uqflow.study import load_study


def normal(name, mean, std):
    return RandomInput.from_spec({"name": name, "distribution": "normal", "mean": mean,
                                  "std": std})


SPACE = InputSpace([normal("x1", 10.0, 1.0), normal("x2", 5.0, 1.0)])
# y = 1 + 2 x1 - x2 + 0.1 x1² + 0.2 x2²: at the means dy/dx1 = 2 + 0.2·10 = 4, dy/dx2 = -1 +
# 0.4·5 = 1, so Taylor's contributions g_k² s_k² are exactly 16 and 1 (s = 1)
QUADRATIC = {"model": "quadratic", "coefficients": [2.0, -1.0], "offset": 1.0,
             "quadratic": [[0.1, 0.0], [0.0, 0.2]]}
DECAY = {"model": "exponential_decay", "t": [0.0, 0.5, 1.0]}


def result(kind, scene=QUADRATIC, space=SPACE, fields=None, **options):
    """A result tree of ``kind`` run in this process on the analytic solver (y in m)."""
    method = get_method(kind)(**options)
    design = method.plan(space, fields, np.random.SeedSequence(0))
    runs = evaluate_design(AnalyticSolver.from_scene(scene), design)
    runs["y"].attrs["units"] = "m"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Taylor's C.V. warning: not what is tested here
        stats = method.analyze(design, runs)
    return xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "t",
                                                         "solver": "analytic"}),
                                  "runs": runs, "statistics": stats})


def hook(tree) -> tuple[ResultView, MethodReport]:
    view = ResultView(tree)
    return view, view.method_report


def cells(view, report):
    return [c.cell("y", view.focus("y")) for c in report.columns]


# ----------------------------------------------------------------------------- Monte Carlo

def test_monte_carlo_reports_its_interval_rule_error_and_convergence():
    view, report = hook(result("monte-carlo", samples=16))
    stats = view.stats
    assert report.description == "Monte Carlo, 16 runs (independent random points)"
    assert report.runs_are_draws
    assert [c.header for c in report.columns] == ["95 % CI of the mean [u]"]
    low, high = (stats["y"].sel(statistic=s).item() for s in ("ci_low", "ci_high"))
    assert cells(view, report) == [f"{number(low)} .. {number(high)}"]
    assert report.cost_details == ["rule random"]
    assert report.notes == ["standard error and interval of the mean: i.i.d. formula "
                            "s/sqrt(n), Student t with 15 degrees of freedom"]
    assert report.sensitivities is None
    [figure] = report.figures
    fig = figure.draw(view, "y")
    mean = stats["y_trace"].sel(trace_statistic="mean").values
    line = fig.axes[0].get_lines()[0]  # the running mean, as the trace stores it
    assert np.array_equal(line.get_ydata(), mean)
    assert "Monte Carlo convergence" in fig.axes[0].get_title()


def test_a_control_variate_says_what_it_bought_and_is_in_the_description():
    # y = x³ is no quadratic: the surrogate leaves an error for the control to reduce
    view, report = hook(result("monte-carlo", scene={"model": "power", "p": 3.0},
                               space=InputSpace([normal("x", 1.0, 0.1)]), samples=16,
                               control="taylor"))
    stats = view.stats
    assert report.description == ("Monte Carlo, 16 runs (independent random points), Taylor "
                                  "from 3 finite-difference runs as control variate")
    rho, gain, count = (stats[f"y_{v}"].item() for v in
                        ("correlation", "variance_reduction", "equivalent_samples"))
    assert report.notes[1] == ("control variate taylor (3 control run(s)): correlation rho "
                               "with the surrogate, variance reduction 1/(1 - rho^2), "
                               "equivalent plain samples n/(1 - rho^2)")
    assert report.notes[2] == (f"  y: rho {rho:.6g}, reduction {gain:.3g}x, equivalent to "
                               f"{count:.3g} plain samples")
    # the control runs are not draws: the samples the report shows are the 16 others
    assert view.sample_values("y").shape == (16,)
    _, local = hook(result("monte-carlo", samples=16, rule="sobol", replicates=4,
                           control="taylor-local"))
    assert local.description == ("Monte Carlo, 16 runs (scrambled Sobol' points), one-run "
                                 "Taylor as control variate")


def test_kl_weibull_runs_are_draws_of_its_fields():
    field = RandomField(FieldSpec(name="E", parameters=["x1"], correlation_length=0.5),
                        np.linspace(0.0, 1.0, 5))
    view, report = hook(result("kl-weibull", space=SPACE, fields=[field], realizations=6))
    assert report.description == "Monte Carlo over the random field E (KL expansion), 6 runs"
    assert report.runs_are_draws and not report.columns
    assert report.notes[0].startswith("standard error and interval of the mean: i.i.d.")
    assert [f.kind for f in report.figures] == ["convergence"]


# ----------------------------------------------------------------------------- expansions

@pytest.mark.parametrize("kind, description", [
    ("taylor", "Taylor expansion, order 2, 9 runs"),
    ("taylor-local", "Taylor expansion from the solver's local derivatives, order 2, 1 run")])
def test_taylor_contributions_are_g_squared_s_squared(kind, description):
    view, report = hook(result(kind))
    stats = view.stats
    assert report.description == description
    assert int(stats.attrs["solver_runs"]) == int(description.split(", ")[-1].split()[0])
    assert not report.runs_are_draws
    sensitivity = report.sensitivities("y")
    assert sensitivity.values.dims == ("parameter", "index")
    g, s = stats["y_gradient"].values, stats["input_std"].values
    assert np.array_equal(sensitivity.values.values[:, 0], (g * s) ** 2)
    # central differences of a quadratic are exact up to the rounding of y ~ 40 over the
    # steps h = 0.1 s: ~1e3 eps |y| / (h |g|), below 1e-10 of g² s² even for g = 1
    assert sensitivity.values.values[:, 0] == pytest.approx(
        [16.0, 1.0], rel=1e-9)  # rounding of y over h: ~1e3 eps |y| / (h |g|) < 1e-10
    assert sensitivity.quantity == "variance [(m)²]" and sensitivity.note == ""
    assert report.sensitivities("not an output") is None


def test_taylor_column_and_the_note_of_what_the_bars_leave_out():
    view, report = hook(result("taylor", variance="second-order"))
    assert cells(view, report) == ["Taylor order 2, second-order variance"]
    assert report.description.endswith(", second-order variance")
    assert report.sensitivities("y").note == ("second-order variance: the curvature terms "
                                              "apart")


def test_sobol_indices_carry_their_bootstrap_half_widths():
    view, report = hook(result("sobol", samples=16, resamples=50))
    stats = view.stats
    assert report.description == "Sobol' indices (Saltelli's design), 16 base samples, 64 runs"
    assert not report.runs_are_draws
    assert report.cost_details == ["16 base samples, 16 kept"]
    sensitivity = report.sensitivities("y")
    si = stats["y_sobol"]
    assert list(sensitivity.values["index"].values) == ["first order S1", "total ST"]
    for k, (index, conf) in enumerate((("S1", "S1_conf"), ("ST", "ST_conf"))):
        assert np.array_equal(sensitivity.values.values[:, k], si.sel(sobol_index=index))
        assert np.array_equal(sensitivity.errors.values[:, k],
                              np.abs(si.sel(sobol_index=conf).values))
    assert sensitivity.error_label == "95 % bootstrap half-width"
    s1, st = si.sel(sobol_index="S1").values, si.sel(sobol_index="ST").values
    assert cells(view, report) == [f"x1 {s1[0]:.2f}/{st[0]:.2f}, x2 {s1[1]:.2f}/{st[1]:.2f}"]


def test_sobol_indices_of_a_field_output_keep_its_dim():
    view, report = hook(result("sobol", scene=DECAY, space=InputSpace(
        [normal("alpha", 1.5, 0.2), normal("beta", 0.15, 0.02)]), samples=8, resamples=20))
    sensitivity = report.sensitivities("y")
    assert sensitivity.values.dims == ("parameter", "index", "t")


def test_pce_reports_its_fit_and_the_indices_of_its_coefficients():
    view, report = hook(result("pce", order=2))
    stats = view.stats
    assert report.description == ("Polynomial chaos expansion, order 2, 12 runs (scrambled "
                                  "Sobol' points)")
    assert report.runs_are_draws
    loo = stats["y_loo_error"].item()
    assert cells(view, report) == [f"order 2, {int(stats['y_terms'])} terms, LOO error "
                                   f"{loo:.2g}"]
    sensitivity = report.sensitivities("y")
    assert sensitivity.errors is None
    assert np.array_equal(sensitivity.values.values, stats["y_sobol"].values.T)
    _, loo_report = hook(result("pce", order="loo", max_order=2))
    assert "order chosen by leave-one-out up to 2" in loo_report.description


def test_nominal_is_one_run_and_no_draw():
    _, report = hook(result("nominal"))
    assert report.description == "Nominal run: one run with the inputs at their means"
    assert not report.runs_are_draws and not report.columns and report.sensitivities is None


# ----------------------------------------------------------------------------- levels

@pytest.fixture(scope="module")
def level_results(tmp_path_factory) -> dict[str, xr.DataTree]:
    folder = tmp_path_factory.mktemp("levels")
    trees = {}
    for kind in ("multilevel", "multifidelity"):
        (folder / f"{kind}.toml").write_text(
            euler_levels_study(f"{kind}-study", kind=kind, output=f"{kind}.nc"))
        out = run_study(load_study(folder / f"{kind}.toml"), show_progress=False)
        trees[kind] = uqflow.open_result(out.path)
    return trees


def test_multilevel_says_how_sure_what_it_saved_and_its_levels(level_results, tmp_path):
    view, report = hook(level_results["multilevel"])
    at = view.stats["y"]
    runs, levels = int(view.stats.attrs["solver_runs"]), view.stats.sizes["level"]
    assert report.description == f"Multilevel Monte Carlo, {levels} levels, {runs} runs"
    assert [c.header for c in report.columns] == ["how sure [u], what it saved"]
    g = {s: f"{at.sel(statistic=s).item():.4g}" for s in ("stderr", "bias", "rmse")}
    ratio = f"{view.stats['y_cost_ratio'].item():.4g}"
    assert cells(view, report) == [f"stderr {g['stderr']}, bias ~{g['bias']}, rmse "
                                   f"{g['rmse']}, {ratio}x cheaper than plain MC at the "
                                   f"finest level"]
    assert report.notes[0] == "" and report.notes[1].startswith("levels (cost per run in "
                                                                "stated units;")
    n = view.stats["level_samples"].values
    for level in range(levels):
        row = next(line.split() for line in report.notes if line.split()[:1] == [str(level)])
        assert int(row[2]) == n[level]
    [figure] = report.figures
    fig = figure.draw(view, "y")
    assert "log2 V_l [-]" in [a.get_ylabel() for a in fig.axes]  # y has no units here
    assert "multilevel-study: y" in fig._suptitle.get_text()


def test_multifidelity_gives_its_model_table_and_no_levels_figure(level_results):
    view, report = hook(level_results["multifidelity"])
    models = view.stats.sizes["model"]
    assert report.description.startswith(f"Multifidelity Monte Carlo, {models} models, ")
    assert "bias" not in cells(view, report)[0]
    assert report.notes[1].startswith("models (0 = high fidelity;")
    rho = view.stats["y_correlation"].values
    rows = [line.split() for line in report.notes[4:4 + models]]  # after header and rule
    assert [r[0] for r in rows] == [str(m) for m in range(models)]
    assert [float(r[4]) for r in rows] == pytest.approx(rho, abs=5e-7)  # printed to 6 places
    assert report.figures == []


def test_compare_results_gives_the_level_comparison_once(level_results, tmp_path):
    trees = [level_results["multilevel"], level_results["multifidelity"],
             level_results["multilevel"]]
    text, paths = compare_results(trees, tmp_path, figures=True)
    assert text.count("error against cost") == 1
    assert [p.name for p in paths] == ["y_error_vs_cost.png"] and paths[0].exists()
    # results without a level method compare nothing
    plain = result("monte-carlo", samples=8)
    assert compare_results([plain, plain], tmp_path, figures=False) == ("", [])


def test_error_against_cost_leaves_the_compile_time_out(level_results):
    plain = result("monte-carlo", scene={"model": "euler_decay", "steps": 16},
                   space=InputSpace([RandomInput.from_spec(
                       {"name": "k", "distribution": "uniform", "lower": 0.5,
                        "upper": 1.5})]), samples=8, rule="random")
    # 10 s of wall time of which 8 s compiling: the 8 runs cost 2 s
    plain["statistics"].attrs.update(solver_wall_time=10.0, solver_compile_time=8.0)
    plain.attrs["study_name"] = "plain"
    text, _ = compare_results([plain, level_results["multilevel"]], ".", figures=False)
    row = next(line.split() for line in text.splitlines() if line.split()[0] == "plain")
    assert row[3] == "2" and row[5] == "2"  # 8 runs at 0.25 s: exact in binary


@pytest.mark.parametrize("unit, expected", [("Pa", "Pa^2"), ("m s-1", "(m s-1)^2"),
                                            ("-", "-"), ("", "-"), ("1", "-")])
def test_a_dimensionless_variance_stays_dimensionless(unit, expected):
    assert squared(unit) == expected


# ----------------------------------------------------------------------------- third party

class MirroredPairs(PropagationMethod):
    """A third-party method with no report hook (not registered: the report must not need
    it installed either)."""

    def plan(self, space, fields, seed):
        raise AssertionError("reporting a stored result never plans")

    def analyze(self, design, runs):
        raise AssertionError("reporting a stored result never analyzes")


def test_a_method_without_a_hook_still_reports():
    assert MirroredPairs.report(None) is None
    assert MirroredPairs.compare([], ".") == ("", [])
    tree = result("monte-carlo", samples=8)
    # a name no test registers (the docs' antithetic method is registered by another test)
    tree["statistics"].attrs["method"] = "mirrored-pairs-not-installed"
    view, report = hook(tree)
    assert report == MethodReport()
    table = summary_table(tree)
    assert "cost: 8 solver runs" in table and "method mirrored-pairs-not-installed" in table
    assert compare_results([tree, tree], ".", figures=False) == ("", [])


def test_no_method_module_spells_the_report_layer_private_names():
    source = Path(uqflow.__file__).parent / "methods"
    for path in source.glob("*.py"):
        text = path.read_text()
        assert "report.summary" not in text and "report_levels" not in text, path.name
        assert "from uqflow.report." not in text, path.name  # only the package's public names
