"""The quickstart answers what README.md says it answers: the scatter of the thin plate's
stresses, how sure (the control variate's correlation and reduction) and what it cost."""

from pathlib import Path

import numpy as np
import pytest

from uqflow import report
from uqflow.execute import run_study
from uqflow.study import load_study

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def quickstart(tmp_path_factory):
    study = load_study(ROOT / "studies" / "quickstart.toml")
    out = run_study(study, workers=0, show_progress=False,
                    output=tmp_path_factory.mktemp("quickstart") / "quickstart.nc")
    return report.open_result(out.path)


def _at_largest_std(stats, name):
    """The (time, probe) point the summary table reports: the output's largest std."""
    std = stats[name].sel(statistic="std")
    return np.unravel_index(int(np.nanargmax(std.values)), std.shape)


@pytest.mark.slow
def test_the_control_run_and_the_samples_all_succeed(quickstart):
    stats = quickstart["statistics"].to_dataset()
    assert (stats.attrs["solver_runs"], stats.attrs["failed_runs"]) == (9, 0)


@pytest.mark.slow
def test_the_flow_stress_follows_its_taylor_polynomial(quickstart):
    """README: "For the flow stress rho > 0.99"; S11 and S22 follow it less."""
    stats = quickstart["statistics"].to_dataset()
    rho = {o: float(stats[f"{o}_correlation"].values[_at_largest_std(stats, o)])
           for o in ("flow_stress", "S11", "S22")}
    assert rho["flow_stress"] > 0.99, rho
    assert max(abs(rho["S11"]), abs(rho["S22"])) < rho["flow_stress"], rho


@pytest.mark.slow
def test_the_table_says_what_the_answer_cost_and_how_sure_it_is(quickstart):
    text = report.summary_table(quickstart)
    assert "95 % CI of the mean" in text
    assert "control variate taylor-local" in text and "equivalent to" in text
    assert "cost: 9 solver runs, 0 failed" in text
    comparison, _ = report.solver_report([quickstart], Path("."), figures=False)
    assert "rows 'seed': seed 000's Table 6" in comparison and "speed-up" in comparison
    # the one-run answer beside the corrected one, for every probe of every output
    assert comparison.count("its control: taylor-local surrogate") == 3 * 4


@pytest.mark.slow
def test_the_figures_show_the_scatter_in_gpa_the_probes_where_they_are_and_a_scene_map(
        quickstart, tmp_path):
    """Issue 17: the quickstart's figures read for a mechanics engineer, and its HTML report
    holds every table and figure."""
    from html.parser import HTMLParser

    from uqflow.report.framework_figures import scatter_figure

    view = report.ResultView(quickstart)
    fig = scatter_figure(view, "flow_stress")
    labels = [ax.get_ylabel() for ax in fig.axes]
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    # the flow stress is ~1 GPa: shown in GPa, the std below it in GPa too
    assert "flow stress [GPa]" in labels and "std [GPa]" in labels, labels
    assert "probe H (x = 45, y = 0 mm)" in titles, titles   # the scene's probe H at (45, 0) mm
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("quantiles of 8 runs" in t for t in legend), legend
    assert any("interval of the mean" in t for t in legend), legend

    written = report.write_figures(quickstart, tmp_path)
    text, solver_figures = report.solver_report([quickstart], tmp_path, figures=True)
    names = {p.name for p in [*written, *solver_figures]}
    assert {"flow_stress_scatter.png", "S11_scatter.png", "S22_scatter.png",
            "scene_map.png"} <= names, names
    page = report.write_html(quickstart, tmp_path / "quickstart_report.html",
                             solver_text=text, solver_figures=solver_figures,
                             figures=written)

    class Images(HTMLParser):
        def __init__(self):
            super().__init__()
            self.images, self.tables = [], 0

        def handle_starttag(self, tag, attrs):
            attrs = dict(attrs)
            if tag == "img":
                self.images.append(attrs.get("src", ""))
            self.tables += tag == "table"

    parsed = Images()
    parsed.feed(page.read_text(encoding="utf-8"))
    assert len(parsed.images) == len(written) + len(solver_figures)
    assert all(src.startswith("data:image/png;base64,") for src in parsed.images)
    assert parsed.tables >= 2   # the outputs and the inputs
