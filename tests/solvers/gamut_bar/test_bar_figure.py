"""The bar with its field realizations (solvers/gamut_bar/bar_figure.py), written with every
gamut-bar result: its artists hold the stored field values, their mean and 2.5–97.5 % band."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import uqflow
from solvers.gamut_bar import GamutBarSolver
from solvers.gamut_bar import bar_figure
from solvers.gamut_bar.report import identify
from uqflow.execute import run_study
from uqflow.fields import field_value_variable
from uqflow.layout import FIELD_PREFIX
from uqflow.report import figure_folder, solver_report
from uqflow.study import load_study

from ._common import EPS, field_table

def _study(folder: Path, name: str, fields: str, method: str) -> Path:
    path = folder / f"{name}.toml"
    path.write_text(f'name = "{name}"\nsolver = "gamut_bar"\n'
                    f'scene = {{ material = "M1", local_bonds = 16 }}\n{fields}\n'
                    f'[method]\n{method}\n[execution]\nseed = 3\nworkers = 0\n'
                    f'[output]\npath = "out/{name}.nc"\n')
    return path


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A tiny study with fields (E and rho stored, w from its germs) and one without, run and
    reported as ``uqflow run`` does (the solver's hook writing into the figures folder; the
    framework's own figures, which take most of a run's time, are left out): (result, figure)
    of each."""
    folder = tmp_path_factory.mktemp("bar_fields")
    fields = "".join(field_table(name, parameters, correlation_length=0.02,
                                 captured_variance=0.9, store_values=store)
                     for name, parameters, store in (("E", '["bar.E", "bar.rho"]', True),
                                                     ("w", '["bar.w"]', False)))
    out = {}
    for name, f, method in (("fields", fields, 'kind = "kl-weibull"\nrealizations = 12'),
                            ("nominal", "", 'kind = "nominal"')):
        result = run_study(load_study(_study(folder, name, f, method)), workers=0,
                           show_progress=False).path
        _, pngs = solver_report([uqflow.open_result(result)], figure_folder(result))
        out[name] = (result, pngs[0])
    return out


def _figure(result: Path):
    res = identify(uqflow.open_result(result))
    bar = GamutBarSolver.from_scene(res.scene)
    realizations = bar_figure.field_realizations(bar, res.field_tables, res.runs)
    return res, bar, realizations, bar_figure.draw(bar, realizations, "test")


def _by_gid(ax, gid, kind="lines"):
    return [a for a in getattr(ax, kind) if a.get_gid() == gid]


def test_every_result_gets_the_figure(written):
    for result, png in written.values():
        assert png == figure_folder(result) / "bar_fields.png"
        assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_panels_hold_the_stored_values_their_mean_and_band(written):
    res, bar, realizations, fig = _figure(written["fields"][0])
    assert [r.parameter for r in realizations] == ["bar.E", "bar.rho", "bar.w"]
    axes = fig.axes
    assert len(axes) == 4
    for ax, field in zip(axes[1:], realizations):
        words, unit, scale = bar_figure.FIELD_LABELS[field.parameter]
        assert ax.get_ylabel() == f"{words} [{unit}]"
        name = field_value_variable(field.parameter)
        if field.parameter != "bar.w":
            assert name.startswith(FIELD_PREFIX) and field.source == "stored values"
            stored = np.asarray(res.runs[name].values, float)
        else:
            assert name not in res.runs and field.source == "rebuilt from the germs"
            stored = field.values
        assert stored.shape == (12, field.x.size)
        x = np.asarray(bar.field_points(field.parameter))[:, 0] * 1e3
        # the realizations drawn: the first five, as stored, in display units
        lines = _by_gid(ax, "realization")
        assert len(lines) == 5
        for k, line in enumerate(lines):
            np.testing.assert_array_equal(line.get_xdata(), x)
            np.testing.assert_array_equal(line.get_ydata(), stored[k] / scale)
        # mean: the same sum in the same order, one division by the scale apart
        (mean,) = _by_gid(ax, "mean")
        np.testing.assert_allclose(mean.get_ydata(), stored.mean(axis=0) / scale,
                                   rtol=4 * EPS)
        # the band's edges at each point: numpy's quantiles of the stored values
        (band,) = _by_gid(ax, "band", "collections")
        lo, hi = np.quantile(stored, [0.025, 0.975], axis=0) / scale
        vertices = band.get_paths()[0].vertices
        for i, xi in enumerate(x):
            ys = vertices[vertices[:, 0] == xi, 1]
            np.testing.assert_allclose([ys.min(), ys.max()], [lo[i], hi[i]], rtol=4 * EPS)
        assert hi.max() > lo.min()      # a band, not a line
        (nominal,) = _by_gid(ax, "nominal")
        assert nominal.get_ydata()[0] == field.nominal / scale


def test_values_rebuilt_from_the_germs_are_the_stored_ones(written):
    """The germ path rebuilds what the solver evaluated: same KL modes, germs and points (a
    uniform grid), same code; so exactly the stored values."""
    res, bar, _, _ = _figure(written["fields"][0])
    fields = bar_figure._fields(bar, res.field_tables)
    for parameter in ("bar.E", "bar.rho"):
        x = np.asarray(bar.field_points(parameter))[:, 0]
        rebuilt = bar_figure._rebuilt(bar, fields, res.runs, parameter, x)
        np.testing.assert_array_equal(
            rebuilt, np.asarray(res.runs[field_value_variable(parameter)].values, float))


def test_without_random_fields_the_bar_with_its_nominal_properties(written):
    res, bar, realizations, fig = _figure(written["nominal"][0])
    assert realizations == [] and len(fig.axes) == 1
    ax = fig.axes[0]
    (rect,) = _by_gid(ax, "bar", "patches")
    assert rect.get_x() == 0 and rect.get_width() == pytest.approx(100.0)   # 0.1 m, in mm
    texts = " ".join(t.get_text() for t in ax.texts)
    assert "E = 71.6 GPa" in texts and "yield stress 538.6 MPa" in texts
    assert "monotonic tension" in texts
    assert len([t for t in ax.texts if t.get_gid() == "load"]) == 1
