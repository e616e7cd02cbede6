"""The report: summary table and PNG figures of result files, and ``uqflow report``."""

import math
import re
import struct
import textwrap
import warnings

import numpy as np
import pytest
import xarray as xr

from uqflow import report
from uqflow.cli import main
from uqflow.errors import AccuracyWarning, StudyError
from uqflow.execute import StudyFailed, run_study
from uqflow.study import load_study

# A figure that fails to draw is skipped with a FigureWarning: here that is a test failure.
pytestmark = pytest.mark.filterwarnings("error::uqflow.report.FigureWarning")

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

ISHIGAMI = ('{ model = "ishigami" }', "".join(f"""
[[inputs]]
name = "x{i}"
distribution = "uniform"
lower = -3.141592653589793
upper = 3.141592653589793
""" for i in (1, 2, 3)))

DECAY = ('{ model = "exponential_decay" }', """
[[inputs]]
name = "alpha"
distribution = "normal"
mean = 1.5
std = 0.2

[[inputs]]
name = "beta"
distribution = "uniform"
lower = 0.1
upper = 0.2
""")

FAULTY = ('{ model = "faulty", raise_above = 0.5 }', """
[[inputs]]
name = "x"
distribution = "normal"
mean = 0.0
std = 1.0
units = "mm"
""")

LINEAR_CORRELATED = ('{ model = "linear", coefficients = [2.0, -1.0], offset = 1.0 }', """
[[inputs]]
name = "x1"
distribution = "normal"
mean = 10.0
std = 1.0

[[inputs]]
name = "x2"
distribution = "normal"
mean = 5.0
std = 1.0

[correlation]
inputs = ["x1", "x2"]
matrix = [[1.0, 0.6], [0.6, 1.0]]
""")

MC = 'kind = "monte-carlo"\nsamples = 256'
TAYLOR = 'kind = "taylor"'
SOBOL = 'kind = "sobol"\nsamples = 64\nresamples = 100'


def write_study(folder, name, model, method, execution="workers = 0"):
    scene, inputs = model
    text = textwrap.dedent(f"""\
        name = "{name}"
        solver = "analytic"
        scene = {scene}
        """) + inputs + f"\n[method]\n{method}\n\n[execution]\n{execution}\n" \
        f'\n[output]\npath = "results/{name}.nc"\nfigures = false\n'
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


def run(folder, name, model, method, **kw):
    """Run a study in this process; returns the result path (relative to the study file)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)  # taylor: large input C.V.
        out = run_study(load_study(write_study(folder, name, model, method, **kw)),
                        show_progress=False)
    assert out.path == folder / "results" / f"{name}.nc"
    return out.path


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    """Result files, each study run once for the whole module."""
    folder = tmp_path_factory.mktemp("studies")
    cache = {}

    def get(name, model, method):
        if name not in cache:
            cache[name] = run(folder, name, model, method)
        return cache[name]

    return get


def assert_png(path):
    assert path.exists(), path
    data = path.read_bytes()
    assert len(data) > 1000
    assert data[:8] == PNG_SIGNATURE
    assert data[12:16] == b"IHDR"
    width, height = struct.unpack(">II", data[16:24])
    assert width > 200 and height > 200


def table_row(table, first):
    """The cells of the table row whose first cell is ``first`` (split on 2+ spaces)."""
    for line in table.splitlines():
        cells = re.split(r"\s{2,}", line.strip())
        if cells[0] == first:
            return cells
    raise AssertionError(f"no row '{first}' in:\n{table}")


def close(text, value):
    """``text`` is ``value`` to the digits it shows (6 significant: relative 5e-6)."""
    # Rounding to 6 significant digits moves a number by at most half a unit in the 6th
    # digit: 5e-6 of it. abs_tol only lets a value that underflows the format ("0") match.
    return math.isclose(float(text), float(value), rel_tol=5e-6, abs_tol=1e-300)


# --------------------------------------------------------------------------- the table

def test_monte_carlo_table_shows_the_statistics(studies):
    tree = report.open_result(studies("mc", ISHIGAMI, MC))
    stats = tree["statistics"].to_dataset()
    table = report.summary_table(tree)
    assert "study 'mc' (monte-carlo, complete)" in table
    header = table_row(table, "output")
    # plain Monte Carlo gives no standard error of the variance: no '±' in its column;
    # the interval column is the method's (its report hook), after the framework's columns
    assert header == ["output", "unit u", "mean [u]", "std [u]", "variance [u^2]",
                      "95 % CI of the mean [u]"]
    name, units, mean, std, variance, ci = table_row(table, "y")
    assert units == "-"
    y = stats["y"]
    assert close(mean, y.sel(statistic="mean"))
    assert close(std, y.sel(statistic="std"))
    assert close(variance, y.sel(statistic="variance"))
    lo, hi = ci.split(" .. ")
    assert close(lo, y.sel(statistic="ci_low")) and close(hi, y.sel(statistic="ci_high"))
    assert float(lo) < float(mean) < float(hi)
    assert re.search(r"cost: 256 solver runs, 0 failed, solver wall time [\d.e+-]+ m?s, "
                     r"elapsed [\d.e+-]+ m?s, method monte-carlo", table)
    # zero-mean inputs: the C.V. is undefined rather than printed as inf
    assert table_row(table, "x2") == ["x2", "-", "0", "1.8138", "n/a (mean 0)", "0"]


def test_field_output_gets_one_row_at_its_largest_std(studies):
    tree = report.open_result(studies("mc_decay", DECAY, MC))
    stats = tree["statistics"].to_dataset()
    table = report.summary_table(tree)
    std = stats["y"].sel(statistic="std")
    k = int(np.argmax(std.values))
    cells = table_row(table, "y")
    assert cells[2] == f"t = {stats['t'].values[k]:.4g} s"
    assert close(cells[3], stats["y"].sel(statistic="mean")[k])
    assert close(cells[4], std[k])
    assert close(cells[5], stats["y"].sel(statistic="variance")[k])
    assert "y is a field of 21 points (t): its row is at the point of largest std" in table
    mean = stats["y"].sel(statistic="mean")
    lo, hi = re.search(r"the mean ranges over (\S+) \.\. (\S+)", table).groups()
    assert close(lo, mean.min()) and close(hi, mean.max())
    cv = stats["input_cv"].sel(parameter="beta")
    assert table_row(table, "beta")[4] == f"{float(cv):.3g}"


def test_taylor_table_shows_the_methods_column_and_contributions(studies):
    tree = report.open_result(studies("taylor", ISHIGAMI, TAYLOR))
    stats = tree["statistics"].to_dataset()
    table = report.summary_table(tree)
    contribution = report.ResultView(tree).method_report
    cells = table_row(table, "y")
    assert close(cells[2], stats["y"].sel(statistic="mean"))
    assert cells[-1] == contribution.columns[-1].cell("y", {})
    assert f"method: {contribution.description}" in table
    assert "method taylor" in table
    # the method's sensitivities as a table: one row per input, one column per kind of index
    sens = contribution.sensitivities("y")
    for p in ("x1", "x2", "x3"):
        shown = table_row(table, p)[1:1 + sens.values.sizes["index"]]
        assert all(close(c, v) for c, v in zip(shown, sens.values.sel(parameter=p).values))


def test_sobol_table_lists_indices_by_total_index(studies):
    tree = report.open_result(studies("sobol", ISHIGAMI, SOBOL))
    si = tree["statistics"]["y_sobol"]
    table = report.summary_table(tree)
    assert "Sobol' indices: y (fraction of the variance; ± 95 % bootstrap half-width)" in table
    cells = table_row(table, "y")
    entries = cells[-1].split(", ")
    assert len(entries) == 3
    st = [float(e.split()[1].split("/")[1]) for e in entries]
    assert st == sorted(st, reverse=True)
    for entry in entries:
        p, pair = entry.split()
        s1, st_ = pair.split("/")
        assert s1 == f"{float(si.sel(sobol_index='S1', parameter=p)):.2f}"
        assert st_ == f"{float(si.sel(sobol_index='ST', parameter=p)):.2f}"


def test_study_stopped_by_failures_shows_status_and_first_failure(tmp_path, capsys):
    with pytest.raises(StudyFailed):
        run(tmp_path, "faulty", FAULTY, 'kind = "monte-carlo"\nsamples = 200')
    path = tmp_path / "results" / "faulty.nc"
    tree = report.open_result(path)
    assert "statistics" not in tree.children
    table = report.summary_table(tree)
    status = tree["runs"]["status"].values.astype(str)
    counts = {s: int((status == s).sum()) for s in ("ok", "failed", "pending")}
    assert counts["failed"] > 0
    assert (f"runs: 200 planned: {counts['ok']} ok, {counts['failed']} failed, "
            f"{counts['pending']} pending") in table
    first = int(np.flatnonzero(status == "failed")[0])
    assert (f"first failure, realization {first}: SolverError: diverged"
            in table)
    assert report.write_figures(tree, tmp_path / "figs") == []
    assert main(["report", str(path)]) == 0
    assert "no statistics" in capsys.readouterr().out


def test_failed_runs_in_a_complete_study_are_reported(tmp_path):
    path = run(tmp_path, "tolerant", FAULTY, 'kind = "monte-carlo"\nsamples = 100',
               execution="workers = 0\nmax_failure_fraction = 0.6")
    tree = report.open_result(path)
    failed = tree["statistics"].attrs["failed_runs"]
    table = report.summary_table(tree)
    assert failed > 0
    assert f"100 solver runs, {failed} failed" in table
    assert "first failure, realization" in table
    assert table_row(table, "x")[1] == "mm"
    assert "1 warning recorded" in table


def test_a_file_without_uqflow_groups_is_a_study_error(tmp_path):
    path = tmp_path / "plain.nc"
    xr.Dataset({"a": ("x", [1.0, 2.0])}).to_netcdf(path, engine="netcdf4")
    with pytest.raises(StudyError, match="not a uqflow result"):
        report.summary_table(report.open_result(path))


# --------------------------------------------------------------------------- figures

def test_monte_carlo_scalar_figures(studies, tmp_path):
    import matplotlib.pyplot as plt

    tree = report.open_result(studies("mc", ISHIGAMI, MC))
    before = plt.get_fignums()
    paths = report.write_figures(tree, tmp_path / "figs")
    assert [p.name for p in paths] == ["y_histogram.png", "y_exceedance.png",
                                       "y_convergence.png"]
    for p in paths:
        assert p.parent == tmp_path / "figs"
        assert_png(p)
    assert plt.get_fignums() == before  # nothing left open in pyplot


def test_monte_carlo_time_series_figures(studies, tmp_path):
    tree = report.open_result(studies("mc_decay", DECAY, MC))
    paths = report.write_figures(tree, tmp_path)
    assert [p.name for p in paths] == ["y_scatter.png", "y_convergence.png"]
    for p in paths:
        assert_png(p)


@pytest.mark.parametrize("name, model, expected", [
    ("taylor", ISHIGAMI, ["y_sensitivities.png"]),
    ("taylor_decay", DECAY, ["y_scatter.png", "y_sensitivities.png"]),
    ("taylor_correlated", LINEAR_CORRELATED, ["y_sensitivities.png"]),  # with cross terms
])
def test_taylor_figures(studies, tmp_path, name, model, expected):
    tree = report.open_result(studies(name, model, TAYLOR))
    paths = report.write_figures(tree, tmp_path)
    assert [p.name for p in paths] == expected
    for p in paths:
        assert_png(p)


@pytest.mark.parametrize("name, model, expected", [
    ("sobol", ISHIGAMI, ["y_sensitivities.png"]),
    ("sobol_decay", DECAY, ["y_scatter.png", "y_sensitivities.png"]),
])
def test_sobol_figures(studies, tmp_path, name, model, expected):
    tree = report.open_result(studies(name, model, SOBOL))
    paths = report.write_figures(tree, tmp_path)
    assert [p.name for p in paths] == expected
    for p in paths:
        assert_png(p)


def test_two_dimensional_field_is_summarised_without_failing(studies, tmp_path):
    """An output over (t, k): a table row, the scatter over t (one panel per k) and the
    convergence trace."""
    tree = report.open_result(studies("mc_decay", DECAY, MC))
    runs = tree["runs"].to_dataset()
    stats = tree["statistics"].to_dataset()
    scale = xr.DataArray([1.0, 3.0], dims="k")
    runs["z"] = runs["y"] * scale
    for v in ("y", "y_trace"):
        stats[v.replace("y", "z")] = stats[v] * scale
    stats["z"].loc[dict(statistic="variance")] = stats["y"].sel(statistic="variance") * scale**2
    runs, stats = runs.drop_vars("y"), stats.drop_vars(["y", "y_trace"])
    tree2 = xr.DataTree.from_dict({"/": xr.Dataset(attrs=tree.attrs), "runs": runs,
                                   "statistics": stats})
    table = report.summary_table(tree2)
    assert table_row(table, "z")[2] == "t = 0 s, k[1]"
    names = [p.name for p in report.write_figures(tree2, tmp_path)]
    assert names == ["z_scatter.png", "z_convergence.png"]


# --------------------------------------------------------------------------- the CLI

def test_cli_report_prints_table_and_writes_figures(studies, capsys):
    path = studies("mc", ISHIGAMI, MC)
    assert report.figure_folder(path) == path.parent / "mc_figures"
    assert main(["report", str(path)]) == 0
    out = capsys.readouterr().out
    assert "study 'mc' (monte-carlo, complete)" in out
    for name in ("y_histogram.png", "y_exceedance.png", "y_convergence.png"):
        assert f"figure: {path.parent / 'mc_figures' / name}" in out
        assert_png(path.parent / "mc_figures" / name)


def test_cli_report_no_figures(studies, tmp_path, capsys):
    path = studies("mc", ISHIGAMI, MC)
    assert main(["report", str(path), "--no-figures",
                 "--figures", str(tmp_path / "elsewhere")]) == 0
    assert "figure:" not in capsys.readouterr().out
    assert not (tmp_path / "elsewhere").exists()


def test_cli_report_time_on_a_solver_without_a_comparison_is_one_line_and_exit_2(studies,
                                                                                   capsys):
    path = studies("mc", ISHIGAMI, MC)
    assert main(["report", str(path), "--no-figures", "--time", "1e-6"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--time: the 'analytic' solver's report takes no such option" in \
        err[0]


def test_cli_report_on_a_missing_file_is_one_line_and_exit_2(tmp_path, capsys):
    missing = tmp_path / "nope.nc"
    assert main(["report", str(missing)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert lines == [f"uqflow: error: {missing}: no such result file"]
    assert not report.figure_folder(missing).exists()


def test_the_documented_ishigami_table_is_what_uqflow_prints(tmp_path):
    """docs/results.md shows the table of studies/ishigami_mc.toml: every line but the times
    on the cost line must be the one uqflow prints."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    doc = (root / "docs" / "results.md").read_text()
    section = doc[doc.index("## `uqflow report RESULT`: the table"):]
    shown = section.split("```\n")[1].splitlines()
    study = load_study(root / "studies" / "ishigami_mc.toml")
    out = run_study(study, workers=0, show_progress=False, output=tmp_path / "q.nc")
    printed = report.summary_table(report.open_result(out.path)).splitlines()
    times = re.compile(r"solver wall time [0-9.]+ s, elapsed [0-9.]+ s|median [0-9.e+-]+ s")
    for line in shown:
        if line == "...":
            break
        assert times.sub("TIMES", line) in [times.sub("TIMES", p) for p in printed], line
    assert len([line for line in shown if line.startswith("y ")]) == 1


def html_images(path):
    """The data-file names of the images embedded in an HTML report, and any outside URL."""
    from html.parser import HTMLParser

    class Images(HTMLParser):
        def __init__(self):
            super().__init__()
            self.names, self.urls = [], []

        def handle_starttag(self, tag, attrs):
            attrs = dict(attrs)
            if tag == "img":
                self.names.append(attrs["data-file"])
            self.urls += [v for k, v in attrs.items()
                          if k in ("src", "href") and not v.startswith("data:")]

    page = Images()
    page.feed(path.read_text(encoding="utf-8"))
    return sorted(page.names), page.urls


def test_cli_report_html_embeds_every_figure_it_wrote(studies, tmp_path, capsys):
    path = studies("mc_decay", DECAY, MC)
    folder = tmp_path / "f"
    assert main(["report", str(path), "--html", "--figures", str(folder)]) == 0
    out = capsys.readouterr().out
    html = folder / "mc_decay_report.html"
    assert f"report: {html}" in out
    assert html_images(html) == (sorted(p.name for p in folder.glob("*.png")), [])
    assert len(list(folder.glob("*.png"))) == 2  # the scatter and the method's convergence
    # without --figures: beside the result, figures drawn for the report alone
    assert main(["report", str(path), "--html", "--no-figures"]) == 0
    names, _ = html_images(path.with_name("mc_decay_report.html"))
    assert names == ["y_convergence.png", "y_scatter.png"]


def test_cli_run_writes_the_html_report_beside_the_figures(tmp_path, capsys):
    study = write_study(tmp_path, "decay", DECAY, 'kind = "monte-carlo"\nsamples = 16')
    study.write_text(study.read_text().replace("figures = false", "figures = true"))
    assert main(["run", str(study), "--quiet"]) == 0
    html = tmp_path / "results" / "decay_report.html"
    assert f"report: {html}" in capsys.readouterr().out
    figures = sorted(p.name for p in (tmp_path / "results" / "decay_figures").glob("*.png"))
    assert html_images(html) == (figures, []) and figures
    assert main(["run", str(study), "--quiet", "--force", "--no-figures"]) == 0
    assert "report:" not in capsys.readouterr().out


# ------------------------------------------------------------------- the scene a result ran

def _decay_result(folder, scene, overrides=None):
    """A nominal run of the decay model with ``scene`` (a TOML value: inline table or file
    name) and ``--set`` overrides; the result's attributes."""
    path = write_study(folder, "decay", (scene, DECAY[1]), 'kind = "nominal"')
    out = run_study(load_study(path, overrides=overrides), show_progress=False)
    return dict(report.open_result(out.path).attrs)


def test_the_scene_ran_is_the_inline_table_with_the_recorded_overrides(tmp_path):
    attrs = _decay_result(tmp_path, '{ model = "exponential_decay", t = [2.0] }',
                          {"scene.t": [3.0]})
    assert report.scene_ran(attrs) == ({"model": "exponential_decay", "t": [3.0]},
                                       "the study's inline scene table")


def test_the_scene_ran_is_the_scene_file_while_it_holds_what_the_study_read(tmp_path):
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text('model = "exponential_decay"\nt = [2.0]\n')
    attrs = _decay_result(tmp_path, '"scene.toml"', {"scene.t": [3.0]})
    assert report.scene_ran(attrs) == ({"model": "exponential_decay", "t": [3.0]},
                                       f"the scene file {scene_file}")
    scene_file.write_text('model = "exponential_decay"\nt = [2.5]\n')
    assert report.scene_ran(attrs) == (None, f"the scene file {scene_file} changed after "
                                             f"the run (sha256 differs)")
    scene_file.unlink()
    assert report.scene_ran(attrs) == (None, f"the scene file {scene_file} cannot be read "
                                             f"from here")


def test_a_recorded_override_applies_as_set_applied_it(tmp_path):
    # an array of tables is entered by index, as --set enters it (uqflow.overrides.set_key)
    attrs = {"study": 'scene = { bodies = [{ x = 1 }, { x = 2 }] }',
             "study_overrides": "scene.bodies.1.x = 5\n"}
    assert report.scene_ran(attrs)[0] == {"bodies": [{"x": 1}, {"x": 5}]}
    attrs["study_overrides"] = "scene.bodies.0.x.y = 5\n"
    scene, why = report.scene_ran(attrs)
    assert scene is None and why.startswith("the recorded override cannot be applied: ")
    assert report.scene_ran({"study": 'name = "s"'}) == \
        (None, "the result names no scene file and stores no scene table")


def test_a_report_hook_that_raises_costs_only_the_methods_part(studies, monkeypatch, tmp_path):
    """A broken hook (a third party's method) warns naming the method; the table and the
    inputs are still reported, and drawing the figures raises nothing."""
    from uqflow.methods.monte_carlo import MonteCarlo

    def broken(cls, view):
        raise KeyError("no such statistic")

    tree = report.open_result(studies("mc", ISHIGAMI, MC))
    monkeypatch.setattr(MonteCarlo, "report", classmethod(broken))
    with pytest.warns(report.ReportHookWarning, match="method 'monte-carlo' failed"):
        text = report.summary_table(tree)
    assert "cost:" in text and "95 % CI of the mean" not in text  # the method's column went
    assert "x1" in text.split("cost:")[1]                           # the inputs table stays
    with pytest.warns(report.ReportHookWarning):
        written = report.write_figures(tree, tmp_path)   # without the hook: no draws claimed,
    assert all(p.exists() for p in written)              # so no histogram, but no error


def test_a_field_without_a_std_gets_one_number_a_cell_at_its_point_of_largest_difference():
    # FORM's statistics of an output are its values at the medians and at the design point,
    # importance sampling's a weighted mean alone: a cell must still be one number, and the
    # row where they tell most (the largest difference, or the largest magnitude).
    t = np.linspace(0.0, 2.0, 5)
    two = xr.Dataset({"y": (("statistic", "t"), [[1.0, 2.0, 3.0, 4.0, 5.0],
                                                 [1.0, 2.5, 3.0, 4.0, 5.1]])},
                     coords={"statistic": ["at_medians", "at_design_point"], "t": t})
    assert report.focus_point(two, "y") == {"t": 1}
    one = xr.Dataset({"y": (("statistic", "t"), [[1.0, -7.0, 3.0, 4.0, 5.0]])},
                     coords={"statistic": ["mean"], "t": t})
    assert report.focus_point(one, "y") == {"t": 1}
    scalar = xr.Dataset({"y": (("statistic",), [1.0, 2.0])},
                        coords={"statistic": ["at_medians", "at_design_point"]})
    assert report.focus_point(scalar, "y") == {}
