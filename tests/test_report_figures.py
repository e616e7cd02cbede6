"""Issue 17: the framework's figures and HTML report, for every method and solver: the scatter
band (quantiles of the runs where they are draws, ± 1.96 std otherwise), display units, the
exceedance curve and its band, sensitivities from a method's hook, the HTML report, and a
report layer that names no method."""

import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from scipy import stats as sps

from uqflow import report
from uqflow.layout import STUDY_TEXT
from uqflow.report import Column, FigureSpec, MethodReport, ResultView, Sensitivity
from uqflow.report import framework_figures

pytestmark = pytest.mark.filterwarnings("error::uqflow.report.FigureWarning")

ROOT = Path(__file__).resolve().parents[1]


def field_result(n=40, seed=1, method="not-installed"):
    """A small result built by hand: a stress over (t, probe) in Pa, two probes with their
    positions, n runs; its statistics are the runs' moments."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1e-4, 6)
    base = 2.0e9 * (1 + t / 1e-4)[:, None] * np.array([1.0, 0.5])[None, :]
    y = base[None] * (1 + 0.1 * rng.standard_normal((n, 1, 2)))
    status = np.array(["ok"] * (n - 1) + ["failed"])
    runs = xr.Dataset({"s_xx": (("realization", "t", "probe"), y,
                                {"units": "Pa", "long_name": "deviatoric stress s_xx"}),
                       "status": ("realization", status)},
                      coords={"t": ("t", t, {"units": "s"}), "probe": ["H", "I"],
                              "probe_x": ("probe", [0.12, 0.2], {"units": "m",
                                                                  "long_name": "x"}),
                              "probe_y": ("probe", [0.01, 0.01], {"units": "m",
                                                                   "long_name": "y"})})
    ok = y[:-1]
    moments = np.stack([ok.mean(0), ok.std(0, ddof=1), ok.std(0, ddof=1) / np.sqrt(n - 1),
                        ok.var(0, ddof=1)])
    stats = xr.Dataset({"s_xx": (("statistic", "t", "probe"), moments,
                                 {"units": "Pa", "long_name": "deviatoric stress s_xx"})},
                       coords={"statistic": ["mean", "std", "stderr", "variance"],
                               "t": runs["t"], "probe": runs["probe"],
                               "probe_x": runs["probe_x"], "probe_y": runs["probe_y"]},
                       attrs={"method": method, "solver_runs": n, "failed_runs": 1})
    return xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "hand"}),
                                  "runs": runs, "statistics": stats})


def scalar_result(n=30, seed=2):
    rng = np.random.default_rng(seed)
    y = 1e-3 * (2 + rng.standard_normal(n))
    runs = xr.Dataset({"tip": ("realization", y, {"units": "m", "long_name": "tip deflection"}),
                       "status": ("realization", np.array(["ok"] * n))})
    stats = xr.Dataset({"tip": ("statistic", [y.mean(), y.std(ddof=1)], {"units": "m"})},
                       coords={"statistic": ["mean", "std"]},
                       attrs={"method": "not-installed", "solver_runs": n, "failed_runs": 0})
    return xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "beam"}),
                                  "runs": runs, "statistics": stats})


@pytest.fixture
def hook(monkeypatch):
    """Make every result's method report the one given (as a method's ``report`` would)."""
    def use(contribution: MethodReport):
        monkeypatch.setattr(ResultView, "method_report", property(lambda self: contribution))
    return use


# --------------------------------------------------------------------------- display units

@pytest.mark.parametrize("values, units, scale, label", [
    ([2.3e9], "Pa", 1e-9, "GPa"), ([-4.0e5, 1.0], "Pa", 1e-3, "kPa"),
    ([0.12, 0.01], "m", 1e3, "mm"), ([3e-6], "m", 1e6, "µm"), ([1e-4], "s", 1e6, "µs"),
    ([2e-3], "s", 1e3, "ms"),
    ([5e3], "s", 1.0, "s"),  # no kiloseconds
    ([2.0e6], "J", 1e-6, "MJ"), ([7.0], "N", 1.0, "N"), ([1e9], "W", 1e-9, "GW"),
    ([2.3e9], "furlong", 1.0, "furlong"), ([2.3e9], "Pa^2", 1.0, "Pa^2"), ([1.0], "", 1.0, ""),
])
def test_display_units_pick_the_si_prefix_by_magnitude(values, units, scale, label):
    got_scale, got_label = report.display_units(np.array(values), units)
    assert got_label == label
    assert got_scale == pytest.approx(scale, rel=1e-15)  # a power of ten, to rounding


def test_display_units_show_2_3e9_pa_as_2_3_gpa():
    scale, label = report.display_units([2.3e9], "Pa")
    # 2.3e9, 1e-9, their product and 2.3 are each rounded once: under 4 x 2^-53 apart
    assert (label, 2.3e9 * scale) == ("GPa", pytest.approx(2.3, rel=1e-15))


@pytest.mark.parametrize("values", [[], [0.0], [np.nan], [np.inf, -np.inf], [0.0, np.nan]])
def test_display_units_leave_values_without_a_magnitude_alone(values):
    assert report.display_units(np.array(values), "Pa") == (1.0, "Pa")


def test_display_units_use_the_largest_finite_magnitude():
    assert report.display_units([np.nan, -3e9, np.inf, 2.0], "Pa") == (1e-9, "GPa")


def test_a_probe_reads_with_its_position_in_display_units():
    stats = field_result()["statistics"].to_dataset()
    assert report.where(stats, {"probe": 0}) == "probe H (x = 120, y = 10 mm)"
    assert report.where(stats, {"t": 1, "probe": 1}) == \
        "t = 2e-05 s, probe I (x = 200, y = 10 mm)"
    unplaced = stats.drop_vars(["probe_x", "probe_y"])
    assert report.where(unplaced, {"probe": 0}) == "probe = H"


# --------------------------------------------------------------------------- the scatter band

def band_polygons(fig):
    """(label, lower, upper) of every filled band of the first value panel."""
    ax = fig.axes[0]
    found = []
    for coll in ax.collections:
        vertices = coll.get_paths()[0].vertices
        half = (len(vertices) - 1) // 2  # fill_between: along the upper edge, back the lower
        ys = vertices[:, 1]
        found.append((coll.get_label(), ys[1:half], ys[half + 1:-1]))
    return found


def test_scatter_band_is_the_runs_quantiles_where_they_are_draws(hook):
    hook(MethodReport(description="test draws", runs_are_draws=True))
    tree = field_result()
    view = ResultView(tree)
    band = framework_figures.scatter_band(view, "s_xx")
    ok = tree["runs"]["s_xx"].values[:-1]  # the failed run is not a draw
    assert band.from_runs
    # nanquantile and quantile interpolate the same two order statistics: a few ulp apart
    np.testing.assert_allclose(band.lower.values, np.quantile(ok, 0.025, axis=0), rtol=1e-14)
    np.testing.assert_allclose(band.upper.values, np.quantile(ok, 0.975, axis=0), rtol=1e-14)
    assert "2.5-97.5 % quantiles of 39 runs" in band.label
    fig = framework_figures.scatter_figure(view, "s_xx")
    label, *edges = band_polygons(fig)[0]
    assert fig.legends[0].get_texts()[0].get_text() == band.label
    assert label == band.label
    shown = np.sort(np.concatenate(edges))
    expected = 1e-9 * np.sort(np.concatenate([band.lower.values[:, 0],
                                              band.upper.values[:, 0]]))
    np.testing.assert_allclose(shown, expected, rtol=1e-12)  # one scaling: a few ulp
    assert fig.axes[0].get_ylabel() == "deviatoric stress s_xx [GPa]"
    assert fig.axes[0].get_title() == "probe H (x = 120, y = 10 mm)"
    assert "test draws" in fig.get_suptitle()


def test_scatter_band_is_mean_plus_minus_1_96_std_without_draws(hook):
    hook(MethodReport(description="moments only", runs_are_draws=False))
    view = ResultView(field_result())
    band = framework_figures.scatter_band(view, "s_xx")
    mean, std = (view.statistic("s_xx", s).values for s in ("mean", "std"))
    assert not band.from_runs and "mean ± 1.96 std" in band.label
    # 1.959963984540054 = Phi^-1(0.975); the rest is one multiply-add: a few ulp of the mean
    np.testing.assert_allclose(band.lower.values, mean - 1.959963984540054 * std, rtol=1e-14)
    np.testing.assert_allclose(band.upper.values, mean + 1.959963984540054 * std, rtol=1e-14)
    fig = framework_figures.scatter_figure(view, "s_xx")
    labels = [c.get_label() for c in fig.axes[0].collections]
    assert labels == [band.label, "95 % interval of the mean (± 1.96 standard errors)"]
    _, low, high = band_polygons(fig)[1]
    stderr = view.statistic("s_xx", "stderr").values[:, 0]
    half = 1.959963984540054 * stderr  # ± 1.96 standard errors (Phi^-1(0.975))
    np.testing.assert_allclose(np.sort(np.concatenate([low, high])), 1e-9 * np.sort(
        np.concatenate([mean[:, 0] - half, mean[:, 0] + half])),
        rtol=1e-12)  # the figure scales each edge once more: a few ulp
    std_axis = fig.axes[2]  # value panels first row, std panels second (2 probes: 2 columns)
    assert std_axis.get_ylabel() == "std [GPa]"
    np.testing.assert_allclose(std_axis.lines[0].get_ydata(), 1e-9 * std[:, 0], rtol=1e-12)


def test_scatter_shows_at_most_eight_panels(hook):
    hook(MethodReport(runs_are_draws=True))
    tree = field_result()
    stats = tree["statistics"].to_dataset()
    wide = stats.isel(probe=[0] * 20).assign_coords(probe=[f"P{i}" for i in range(20)])
    tree = xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "w"}),
                                  "statistics": wide})
    fig = framework_figures.scatter_figure(ResultView(tree), "s_xx")
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible() and ax.get_title()]
    assert len(titles) == framework_figures.MAX_PANELS == 8
    assert "8 of 20 probe labels" in fig.get_suptitle()


# --------------------------------------------------------------------------- exceedance

def test_exceedance_band_contains_the_curve_and_is_clopper_pearson():
    y = np.array([3.0, 1.0, 2.0, 2.0, 5.0, np.nan, 4.0, 0.5])
    curve = report.exceedance_curve(y)
    assert curve.count == 7
    np.testing.assert_array_equal(curve.levels, [0.5, 1.0, 2.0, 3.0, 4.0, 5.0])
    np.testing.assert_array_equal(curve.probability * 7, [6, 5, 3, 2, 1, 0])
    assert np.all(curve.lower <= curve.probability) and np.all(curve.probability <= curve.upper)
    for k, low, high in zip([6, 5, 3, 2, 1, 0], curve.lower, curve.upper):
        exact = sps.binomtest(k, 7).proportion_ci(0.95, method="exact")
        # scipy finds the same limits by brentq on the binomial tail (xtol 2e-12, rtol 4 eps):
        # its root is within ~3e-12 of the beta quantile, so 1e-10 bounds it 30 times over
        assert (low, high) == (pytest.approx(exact.low, abs=1e-10),
                               pytest.approx(exact.high, abs=1e-10))


def test_exceedance_of_too_few_runs_is_none():
    assert report.exceedance_curve([1.0, np.nan]) is None


def test_scalar_output_gets_histogram_and_exceedance_only_from_draws(hook, tmp_path):
    tree = scalar_result()
    hook(MethodReport(runs_are_draws=False))
    assert [p.name for p in report.write_figures(tree, tmp_path / "a")] == []
    hook(MethodReport(description="plain draws", runs_are_draws=True))
    paths = report.write_figures(tree, tmp_path / "b")
    assert [p.name for p in paths] == ["tip_histogram.png", "tip_exceedance.png"]
    fig = framework_figures.exceedance_figure(ResultView(tree), "tip")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "y: tip deflection [mm]"
    assert "Clopper-Pearson" in ax.collections[0].get_label()
    assert "plain draws" in ax.get_title()


# --------------------------------------------------------------------------- method hooks

def sensitivity_of(view, output):
    values = xr.DataArray([[0.6, 0.7], [0.3, 0.35]], dims=("parameter", "index"),
                          coords={"parameter": ["a", "b"], "index": ["first", "total"]})
    return Sensitivity("made-up indices", values, "fraction of the variance",
                       errors=0.05 + 0 * values, error_label="95 % half-width")


def test_a_method_report_adds_columns_notes_cost_sensitivities_and_figures(hook, tmp_path):
    def extra(view, output):
        fig, ax = report.new_figure()
        ax.plot([0, 1], [0, 1])
        return fig

    hook(MethodReport(description="a made-up method, 30 runs", runs_are_draws=True,
                      columns=[Column("made-up [u]", lambda out, focus: f"cell of {out}")],
                      notes=["a note of the method"], cost_details=["rule made-up"],
                      sensitivities=lambda out: sensitivity_of(None, out),
                      figures=[FigureSpec("extra", extra), FigureSpec("whole", extra, False)]))
    tree = scalar_result()
    table = report.summary_table(tree)
    assert "method: a made-up method, 30 runs" in table
    assert re.search(r"^tip .* cell of tip$", table, re.M)
    assert "a note of the method" in table
    assert re.search(r"method not-installed \(rule made-up\)$", table, re.M)
    assert "made-up indices: tip (fraction of the variance; ± 95 % half-width)" in table
    assert re.search(r"^a\s+0\.6 ± 0\.05\s+0\.7 ± 0\.05$", table, re.M)
    names = [p.name for p in report.write_figures(tree, tmp_path)]
    assert names == ["tip_histogram.png", "tip_exceedance.png", "tip_sensitivities.png",
                     "tip_extra.png", "whole.png"]


def test_a_result_of_a_method_not_installed_gets_the_framework_report(tmp_path):
    tree = field_result()
    table = report.summary_table(tree)
    assert "method not-installed" in table and "at" in table
    assert [p.name for p in report.write_figures(tree, tmp_path)] == ["s_xx_scatter.png"]


# --------------------------------------------------------------------------- the HTML report

class Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tables, self.images, self.urls, self.pre = 0, [], [], []
        self._in_pre = False

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.tables += tag == "table"
        self._in_pre = tag == "pre"
        if tag == "img":
            self.images.append(attrs)
        for key in ("href", "src"):
            if key in attrs and not attrs[key].startswith("data:"):
                self.urls.append(attrs[key])

    def handle_endtag(self, tag):
        self._in_pre = self._in_pre and tag != "pre"

    def handle_data(self, data):
        if self._in_pre:
            self.pre.append(data)


def test_the_html_report_embeds_every_table_and_figure(hook, tmp_path):
    import base64

    hook(MethodReport(description="draws", runs_are_draws=True,
                      sensitivities=lambda out: sensitivity_of(None, out)))
    tree = scalar_result()
    tree.attrs[STUDY_TEXT] = "name = \"beam\" # the study file <&>"
    folder = tmp_path / "figs"
    figures = report.write_figures(tree, folder)
    solver_png = report.write_figures(field_result(), tmp_path / "solver")
    path = report.write_html(tree, tmp_path / "r.html", solver_text="the solver's words",
                             solver_figures=solver_png, figures=figures)
    page = Page()
    page.feed(path.read_text(encoding="utf-8"))
    blocks = report.summary.summary_blocks(tree)
    assert page.tables == sum(isinstance(b, report.Table) for b in blocks) == 2  # outputs, S
    embedded = {img["data-file"]: base64.b64decode(img["src"].split(",", 1)[1])
                for img in page.images}
    for png in [*figures, *solver_png]:
        assert embedded[png.name] == png.read_bytes()
    assert len(page.images) == len(figures) + len(solver_png) == 5
    assert page.urls == []  # nothing outside the file: it opens offline
    text = "".join(page.pre)
    assert "the solver's words" in text and "the study file <&>" in text
    assert "cost: 30 solver runs" in text


def test_the_html_report_draws_the_figures_itself_when_given_none(hook, tmp_path):
    hook(MethodReport(runs_are_draws=True))
    page = Page()
    page.feed(report.write_html(scalar_result(), tmp_path / "r.html").read_text())
    assert sorted(img["data-file"] for img in page.images) == ["tip_exceedance.png",
                                                              "tip_histogram.png"]


# --------------------------------------------------------------------------- no method names

def test_the_report_layer_names_no_method_or_solver():
    from uqflow.methods import method_registry
    from uqflow.solver import solver_registry

    method_registry._load_entry_points()
    solver_registry._load_entry_points()
    names = set(method_registry._classes) | set(solver_registry._classes)
    names |= {"Monte Carlo", "Taylor", "Sobol'", "polynomial chaos", "multilevel", "gamut"}
    assert len(names) > 8
    for source in (ROOT / "uqflow" / "report").glob("*.py"):
        text = source.read_text(encoding="utf-8").lower()
        for name in names:
            assert not re.search(rf"(?<![\w-]){re.escape(name.lower())}(?![\w-])", text), \
                f"{source.name} names {name!r}"


def test_an_output_over_labels_only_gets_a_bar_per_label(hook):
    """No line drawn between probes: the band at each label is a vertical bar."""
    hook(MethodReport(runs_are_draws=False))
    tree = field_result()
    stats = tree["statistics"].to_dataset().isel(t=-1, drop=True)
    view = ResultView(xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "p"}),
                                             "statistics": stats}))
    fig = framework_figures.scatter_figure(view, "s_xx")
    band = framework_figures.scatter_band(view, "s_xx")
    bars = fig.axes[0].collections[0]
    assert bars.get_label() == band.label
    ends = np.array([segment[:, 1] for segment in bars.get_segments()])
    np.testing.assert_allclose(ends, 1e-9 * np.stack([band.lower.values, band.upper.values],
                                                     axis=1), rtol=1e-12)  # one scaling
    assert [t.get_text() for t in fig.axes[1].get_xticklabels()] == ["H", "I"]
