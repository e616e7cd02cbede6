"""Issue 16: the report's labels and numbers say what they are. Compile time apart from run
time, the variance's standard error only where a method has one, random fields listed as
inputs, units on every statistic, warnings of reduced dims shown, figure names that stay in
their folder, and a levels figure whose title fits and whose axes carry one unit each."""

import re

import numpy as np
import pytest
import xarray as xr

import uqflow
from levels_study import euler_levels_study
from solvers.analytic import AnalyticSolver
from uqflow import report
from uqflow.execute import run_study
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import get_method
from uqflow.realization import evaluate_design
from uqflow.study import load_study

pytestmark = pytest.mark.filterwarnings("error::uqflow.report.FigureWarning")


def normal(name, mean, std):
    return RandomInput.from_spec({"name": name, "distribution": "normal", "mean": mean,
                                  "std": std})


LINEAR = {"model": "linear", "coefficients": [2.0, -1.0], "offset": 1.0}
SPACE = InputSpace([normal("x1", 10.0, 1.0), normal("x2", 5.0, 1.0)])
DECAY_SPACE = InputSpace([normal("alpha", 1.5, 0.2), normal("beta", 0.15, 0.02)])


def analysed(scene, space, kind, seed=0, units=None, **options):
    """(runs, statistics) of a method run in this process on the analytic solver."""
    method = get_method(kind)(**options)
    design = method.plan(space, None, np.random.SeedSequence(seed))
    runs = evaluate_design(AnalyticSolver.from_scene(scene), design)
    if units is not None:
        for out in ("y",):
            runs[out].attrs["units"] = units
    return runs, method.analyze(design, runs)


def tree_of(runs, stats, name="t"):
    return xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": name}), "runs": runs,
                                  "statistics": stats})


def row(table, first):
    for line in table.splitlines():
        cells = re.split(r"\s{2,}", line.strip())
        if cells[0] == first:
            return cells
    raise AssertionError(f"no row '{first}' in:\n{table}")


# --------------------------------------------------------------------------- compile time

def test_numba_compile_time_is_measured_apart_from_the_run():
    numba = pytest.importorskip("numba")

    # defined here, never cached: its first call compiles, the second does not
    @numba.njit(cache=False)
    def doubled(x):
        return 2.0 * x

    class CompilingSolver(AnalyticSolver):
        def run(self, params, fields=None):
            ds = super().run(params, fields)
            ds["y"].values[...] = doubled(float(ds["y"].values))
            return ds

    design = get_method("monte-carlo")(samples=3, rule="random").plan(
        SPACE, None, np.random.SeedSequence(0))
    runs = evaluate_design(CompilingSolver.from_scene(LINEAR), design)
    compile_time, wall = runs["compile_time"].values, runs["wall_time"].values
    assert compile_time[0] > 0 and np.all(compile_time[1:] == 0)
    assert np.all(compile_time <= wall)
    x = design["inputs"].values
    np.testing.assert_array_equal(runs["y"].values, 2.0 * (1.0 + 2.0 * x[:, 0] - x[:, 1]))
    from uqflow.realization import compile_clock

    with compile_clock() as clock:  # nothing compiled in the block: nothing counted
        doubled(1.0)
    assert clock.seconds == 0.0


def test_the_table_prints_compile_time_and_the_per_run_time_without_it():
    runs, stats = analysed(LINEAR, SPACE, "monte-carlo", samples=3, rule="random")
    # the quickstart's case: the first run compiles (4.4 s), the others do not
    runs["wall_time"].values[:] = [5.35, 1.0, 0.9]
    runs["compile_time"].values[:] = [4.4, 0.0, 0.0]
    stats.attrs.update(solver_wall_time=7.25, solver_compile_time=4.4)
    table = report.summary_table(tree_of(runs, stats))
    assert ("compile time (numba, part of the solver wall time above): 4.4 s; per run "
            "without it: median 0.95 s over 3 ok runs") in table
    assert "solver wall time 7.25 s" in table


def test_an_unfinished_result_says_how_much_of_its_time_was_compiling():
    runs, _ = analysed(LINEAR, SPACE, "monte-carlo", samples=3, rule="random")
    runs["wall_time"].values[:] = [5.5, 1.0, 1.0]
    runs["compile_time"].values[:] = [4.5, 0.0, 0.0]
    tree = xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "t"}), "runs": runs})
    assert "solver wall time so far 7.5 s (numba compiling 4.5 s of it)" in \
        report.summary_table(tree)


def test_statistics_carry_the_summed_compile_time():
    runs, stats = analysed(LINEAR, SPACE, "monte-carlo", samples=4, rule="random")
    assert stats.attrs["solver_compile_time"] == float(np.sum(runs["compile_time"].values))


# --------------------------------------------------------------------------- variance error

def test_variance_column_has_its_stderr_where_the_method_gives_one():
    """Control variate on i.i.d. samples: the delta-method stderr of the variance."""
    runs, stats = analysed(LINEAR, SPACE, "monte-carlo", samples=16, rule="random",
                           control="taylor-local", units="Pa")
    table = report.summary_table(tree_of(runs, stats))
    header = row(table, "output")
    assert "variance ± stderr [u^2]" in header
    cell = row(table, "y")[header.index("variance ± stderr [u^2]")]
    value, error = cell.split(" ± ")
    assert float(value) == pytest.approx(float(stats["y"].sel(statistic="variance")),
                                         rel=5e-6)  # 6 significant digits shown
    assert float(error) == pytest.approx(float(stats["y_variance_stderr"]), rel=5e-6)  # same
    assert stats["y_variance_stderr"].attrs["units"] == "(Pa)^2"


@pytest.mark.parametrize("scene, space", [
    (LINEAR, SPACE),
    # alpha fixed (std 0): y(t = 0) = alpha is the same in every run
    ({"model": "exponential_decay"}, InputSpace([normal("alpha", 1.5, 0.0),
                                                 normal("beta", 0.15, 0.02)]))])
def test_no_variance_stderr_is_written_or_shown_where_the_method_has_none(scene, space):
    """Randomized QMC with replicates of one sample (the quickstart's design) has no
    within-replicate variance: no all-NaN variable (nor one of zeros where the output is
    constant), no '±' and no 'n/a'."""
    runs, stats = analysed(scene, space, "monte-carlo", samples=8, rule="sobol",
                           control="taylor-local")
    assert stats.attrs["replicates"] == 8
    assert "y_variance_stderr" not in stats
    table = report.summary_table(tree_of(runs, stats))
    assert "variance [u^2]" in row(table, "output")
    assert "±" not in table and "n/a" not in table.split("cost:")[0]


# --------------------------------------------------------------------------- units

def test_every_statistic_column_says_its_unit():
    runs, stats = analysed({"model": "exponential_decay"}, DECAY_SPACE, "monte-carlo",
                           samples=16, rule="random", units="mm")
    table = report.summary_table(tree_of(runs, stats))
    header = row(table, "output")
    assert header == ["output", "unit u", "at", "mean [u]", "std [u]", "variance [u^2]",
                      "95 % CI of the mean [u]"]
    assert row(table, "y")[1] == "mm"
    mean = stats["y"].sel(statistic="mean")
    assert f"the mean ranges over {report.number(mean.min())} .. {report.number(mean.max())} mm" \
        in table


# --------------------------------------------------------------------------- fields as inputs

BAR = """\
name = "bar"
solver = "analytic"
scene = { model = "random_E_bar", points = 20, force = 2.0e4, area = 1.0e-4, length = 0.1 }

[[fields]]
name = "E"
parameters = ["bar.E"]
correlation_length = 0.02
modes = 4
divisor = 10

[method]
kind = "kl-weibull"
realizations = 4

[execution]
workers = 0
seed = 9

[output]
path = "bar.nc"
figures = false
"""


@pytest.mark.parametrize("method", ['kind = "kl-weibull"\nrealizations = 4',
                                    'kind = "nominal"'])
def test_random_fields_are_listed_as_uncertain_inputs(tmp_path, method):
    (tmp_path / "bar.toml").write_text(BAR.replace('kind = "kl-weibull"\nrealizations = 4',
                                                   method))
    out = run_study(load_study(tmp_path / "bar.toml"), show_progress=False)
    table = report.summary_table(uqflow.open_result(out.path))
    assert "none uncertain" not in table
    cells = row(table, "E")
    assert cells[:4] == ["E", "bar.E", "exponential", "0.02"]
    assert cells[4].startswith("4 (")
    # divisor 10: amplitude 1/10, printed to 6 significant digits
    assert "symmetric-weibull" in cells[5] and float(cells[6]) == pytest.approx(0.1, rel=5e-6)


# --------------------------------------------------------------------------- reduced dims

def test_the_report_shows_which_dims_a_method_reduced():
    from tests.methods.test_base_outputs import TimeAverage

    method = TimeAverage()
    design = method.plan(DECAY_SPACE, None, np.random.SeedSequence(1))
    runs = evaluate_design(AnalyticSolver.from_scene({"model": "exponential_decay"}), design)
    table = report.summary_table(tree_of(runs, method.analyze(design, runs)))
    assert "1 warning recorded with the statistics" in table
    assert re.search(r"  - the statistics of 'y' have no dim 't' of its runs: the method "
                     r"reduced them", table)


# --------------------------------------------------------------------------- figure names

@pytest.mark.parametrize("name, expected", [
    ("../../../escaped", "_._.._.._escaped"), ("G/K", "G_K"), (".hidden", "_hidden"),
    ("sigma_y at H", "sigma_y_at_H"), ("C:\\x", "C__x"), ("", "_")])
def test_safe_file_names(name, expected):
    assert report.safe_file_name(name) == expected


def test_figure_paths_from_path_like_names_stay_in_their_folder(tmp_path):
    folder = tmp_path / "a" / "figs"
    for parts, name in ((("../../../escaped", "histogram"), "_._.._.._escaped_histogram.png"),
                        (("G/K", "band"), "G_K_band.png"), (("..", ""), "_._.png")):
        path = report.figure_path(folder, *parts)
        assert path == folder / name


def test_figures_of_outputs_with_odd_names_stay_in_their_folder(tmp_path):
    """A DataTree refuses '/' in a variable name; '..', a leading dot, spaces and
    backslashes reach write_figures."""
    runs, stats = analysed(LINEAR, SPACE, "monte-carlo", samples=16, rule="random")
    runs = runs.rename({"y": ".."})
    stats = stats.rename({"y": "..", "y_trace": ".._trace"})
    runs["G\\K at H"] = runs[".."]
    stats["G\\K at H"], stats["G\\K at H_trace"] = stats[".."], stats[".._trace"]
    folder = tmp_path / "a" / "figs"
    written = report.write_figures(tree_of(runs, stats), folder)
    assert sorted(p.name for p in written) == sorted(
        ["_._histogram.png", "_._exceedance.png", "_._convergence.png",
         "G_K_at_H_histogram.png", "G_K_at_H_exceedance.png", "G_K_at_H_convergence.png"])
    assert all(p.parent == folder and p.exists() for p in written)
    assert {p for p in tmp_path.rglob("*") if p.is_file()} == set(written)


def test_a_figure_path_is_refused_outside_its_folder(tmp_path):
    (tmp_path / "figs").mkdir()
    (tmp_path / "figs" / "y_band.png").symlink_to(tmp_path / "outside.png")
    with pytest.raises(uqflow.StudyError, match="leaves the figures folder"):
        report.figure_path(tmp_path / "figs", "y", "band")


# --------------------------------------------------------------------------- levels

LEVELS = euler_levels_study("a-study-name-long-enough-to-clip-the-levels-figure-title-mlmc",
                            output="ml.nc")


@pytest.fixture(scope="module")
def multilevel_tree(tmp_path_factory):
    folder = tmp_path_factory.mktemp("levels")
    (folder / "ml.toml").write_text(LEVELS)
    out = run_study(load_study(folder / "ml.toml"), show_progress=False)
    tree = uqflow.open_result(out.path)
    tree["runs"]["y"].attrs["units"] = "Pa"
    tree["statistics"]["y"].attrs["units"] = "Pa"
    return tree


def test_levels_figure_title_fits_and_each_axis_has_one_unit(multilevel_tree, tmp_path):
    view = report.ResultView(multilevel_tree)
    spec = next(s for s in view.method_report.figures if s.kind == "levels")
    fig = spec.draw(view, "y")
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = fig.bbox
    texts = [fig._suptitle] + [a.title for a in fig.axes]
    assert multilevel_tree.attrs["study_name"] in fig._suptitle.get_text().replace("\n", "")
    for text in texts:
        extent = text.get_window_extent(renderer)
        # whole pixels: the renderer rounds text extents to them
        assert extent.x0 >= box.x0 - 1 and extent.x1 <= box.x1 + 1, text.get_text()
        assert extent.y0 >= box.y0 - 1 and extent.y1 <= box.y1 + 1, text.get_text()
    labels = [a.get_ylabel() for a in fig.axes]
    assert "log2 V_l [Pa^2]" in labels and "log2 |E_l| [Pa]" in labels
    for label in labels:  # one unit per axis
        assert len(re.findall(r"\[[^]]*\]", label)) == 1, label
    paths = report.write_figures(multilevel_tree, tmp_path)
    assert [p.name for p in paths] == ["y_levels.png"]


def test_level_table_columns_say_which_cost_they_are(multilevel_tree):
    stats = multilevel_tree["statistics"].to_dataset()
    table = report.summary_table(multilevel_tree)
    header = row(table, "level")
    assert header[4:7] == ["run cost c_l [stated units]", "sample cost C_l [stated units]",
                           "level cost N_l C_l [stated units]"]
    assert header[7:] == ["E_l y [Pa]", "V_l y [Pa^2]"]
    for level in range(stats.sizes["level"]):
        cells = row(table, str(level))
        n = int(stats["level_samples"].values[level])
        run, sample = (float(stats[v].values[level]) for v in ("level_run_cost",
                                                                 "level_sample_cost"))
        # costs = [1, 2, 4]: a pair costs c_l + c_l-1, exact in binary
        assert sample == run + (float(stats["level_run_cost"].values[level - 1])
                                if level else 0.0)
        assert [float(c) for c in cells[4:7]] == [run, sample, n * sample]
    assert "how sure [u], what it saved" in row(table, "output")



def test_error_against_cost_leaves_the_compile_time_out(multilevel_tree):
    from uqflow.methods import compare_results as cost_comparison

    k = RandomInput.from_spec({"name": "k", "distribution": "uniform", "lower": 0.5,
                               "upper": 1.5})
    runs, stats = analysed({"model": "euler_decay", "steps": 16}, InputSpace([k]),
                           "monte-carlo", samples=8, rule="random")
    # 10 s of wall time of which 8 s compiling: the 8 runs cost 2 s
    stats.attrs.update(solver_wall_time=10.0, solver_compile_time=8.0)
    plain = xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "plain",
                                                          "solver": "analytic"}),
                                   "runs": runs, "statistics": stats})
    text, _ = cost_comparison([plain, multilevel_tree], ".", figures=False)
    cells = next(line.split() for line in text.splitlines() if line.strip().startswith("plain"))
    assert cells[3] == "2" and cells[5] == "2"  # 8 runs at 0.25 s: exact in binary
    assert "solver time without compile (s)" in text


@pytest.mark.parametrize("unit, expected", [("Pa", "Pa^2"), ("m s-1", "(m s-1)^2"), ("-", "-"),
                                            ("", "-"), ("1", "-")])
def test_a_dimensionless_variance_stays_dimensionless(unit, expected):
    from uqflow.methods.level_report import squared

    assert squared(unit) == expected
