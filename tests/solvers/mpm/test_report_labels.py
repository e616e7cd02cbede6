"""The MPM report's words (issue 17, point 3): outputs by their long names, probes by their
position in mm, times in µs, methods as their report hooks say them; seed 000 named only
where its numbers are printed, with the one line that says what it is."""

from __future__ import annotations

import pytest

from solvers.mpm import report as mpm_report

from .test_report import PROBES, trees, write

XY = [(0.045, 0.0), (0.045, 0.03), (0.05, 0.0), (0.055, 0.0)]     # seed Table 4: H, I, G, K
WORDS = {"S11": "deviatoric stress s_xx", "flow_stress": "flow stress"}


def _words(fig) -> dict:
    """Every text of a figure, by where it stands (saving the figure clears it)."""
    axes = fig.axes
    return {"suptitle": fig.get_suptitle(), "titles": [ax.get_title() for ax in axes],
            "ylabels": [ax.get_ylabel() for ax in axes],
            "xlabels": [ax.get_xlabel() for ax in axes],
            "legends": [[t.get_text() for t in ax.get_legend().get_texts()]
                        if ax.get_legend() else [] for ax in axes],
            "texts": [t.get_text() for t in fig.texts]}


@pytest.fixture
def figures(monkeypatch):
    """The words of the figures the report draws, by file name (they are still written)."""
    drawn = {}
    save = mpm_report.save_figure

    def keep(fig, path, **kw):
        drawn[path.name] = _words(fig)
        return save(fig, path, **kw)

    monkeypatch.setattr(mpm_report, "save_figure", keep)
    return drawn


def _two_results(tmp_path, **kw):
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7, outputs=("S11",),
               probe_xy=XY, long_names=WORDS, **kw)
    local = write(tmp_path / "local.nc", method="taylor-local", mean=1.01e9, outputs=("S11",),
                  probe_xy=XY, long_names=WORDS, **kw)
    return trees(mc, local)


def test_figure_labels_are_in_words_with_the_probe_in_mm(tmp_path, figures):
    mpm_report.report(_two_results(tmp_path), tmp_path / "figs")
    words = figures["mpm_S11_G.png"]
    assert words["suptitle"] == ("deviatoric stress s_xx at probe G (x = 50, y = 0 mm): mean "
                                 "and variance over time, by method")
    assert words["ylabels"] == ["mean deviatoric stress s_xx [GPa]",
                                "variance of deviatoric stress s_xx [GPa²]"]
    assert words["xlabels"] == ["time [µs]", "time [µs]"]
    assert words["titles"] == ["mean, input C.V. 0.1", "variance, input C.V. 0.1"]
    legend = words["legends"][0]
    assert "reference ± 2 standard errors of its mean" in legend
    assert any(t.endswith("(mc.nc), reference") for t in legend)


def test_no_figure_names_the_seed(tmp_path, figures):
    # the figures compare our results with each other, not with the seed's numbers
    mpm_report.report(_two_results(tmp_path), tmp_path / "figs")
    assert sorted(figures) == sorted(f"mpm_S11_{p}.png" for p in PROBES)
    for name, words in figures.items():
        every = [words["suptitle"], *words["titles"], *words["ylabels"], *words["xlabels"],
                 *sum(words["legends"], []), *words["texts"]]
        assert not any("seed" in w.lower() or "Fig." in w for w in every), (name, every)


def test_a_probe_without_coordinates_is_named_alone(tmp_path, figures):
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7)
    mpm_report.report(trees(mc), tmp_path / "figs")
    suptitle = figures["mpm_flow_stress_H.png"]["suptitle"]
    assert suptitle.startswith("flow stress at probe H: ")     # the solver's label


def test_the_seed_is_named_where_its_rows_are_printed_with_what_it_is(tmp_path):
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=0.005e9,
               outputs=("flow_stress", "pressure"))
    text, _ = mpm_report.report(trees(mc), tmp_path, figures=False)
    lines = text.splitlines()
    assert lines[0] == ("MPM comparison: each result's probe statistics against the "
                        "reference, and the cost")
    flow = next(line for line in lines if line.startswith("flow stress (flow_stress) at"))
    assert flow.endswith("; rows 'seed': seed 000's Table 6")
    pressure = next(line for line in lines if line.startswith("pressure (pressure) at"))
    assert "seed" not in pressure                 # no seed table of the pressure
    assert mpm_report.SEED_LINE in lines
    assert mpm_report.SEED_LINE == ("seed 000: stochastic MPM of contact explosions, Taylor vs "
                                    "Monte Carlo")
    cost = next(line for line in lines if line.startswith("Cost, beside"))
    assert f"seed 000's Tables 3 and 9 ({mpm_report.SEED_LINE})" in cost


def test_without_seed_rows_the_seed_line_is_only_at_the_cost(tmp_path):
    other = write(tmp_path / "mc.nc", method="monte-carlo", stderr=0.005e9,
                  parameters=["steel.eos.S1"], cv=0.01)
    text, _ = mpm_report.report(trees(other), tmp_path, figures=False)
    assert text.count(mpm_report.SEED_LINE) == 1


@pytest.mark.parametrize("parameters, family", [
    (["steel.jc.A", "steel.jc.n"], "jc"), (["steel.eos.S1"], "eos"),
    (["steel.jc.A", "steel.eos.S1"], None), ([], None), (["steel.shear_modulus"], None)])
def test_the_seed_example_of_the_inputs_is_read_in_one_place(parameters, family):
    assert mpm_report.input_family(parameters) == family


def test_numbers_are_printed_as_before(tmp_path):
    # the words around them changed (issue 17); a table's numbers did not
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=0.005e9)
    text, _ = mpm_report.report(trees(mc), tmp_path, figures=False)
    row = next(line for line in text.splitlines() if line.startswith("H ") and "(ref)" in line)
    assert row.split()[-6:] == ["1", "±", "0.005", "-", "0.005", "-"]
