"""The bar through the study path with real random fields (uqflow.fields, kl-weibull)."""

import numpy as np
import pytest

from uqflow.execute import run_study
from uqflow.study import load_study

STUDY = """\
name = "{name}"
solver = "gamut_bar"
scene = {{ material = "M1", local_bonds = 40, grid = "{grid}", curve_points = 50 }}
{fields}
[method]
kind = "{kind}"
{options}

[execution]
workers = 0
seed = 21

[output]
path = "out/{name}.nc"
figures = false
"""

FIELD = """
[[fields]]
name = "{name}"
parameters = ["bar.{name}"]
correlation_length = {length}
germ = {{ kind = "symmetric-weibull", scale = 1.0, shape = {shape} }}
{amplitude}
"""


def study(tmp_path, name, grid="uniform", kind="kl-weibull", options="realizations = 6",
          amplitude="divisor = 10", length=0.01, shape=2.0, names=("E", "R", "w")):
    fields = "".join(FIELD.format(name=n, length=length, shape=shape, amplitude=amplitude)
                     for n in names)
    path = tmp_path / f"{name}.toml"
    path.write_text(STUDY.format(name=name, grid=grid, kind=kind, options=options,
                                 fields=fields))
    return run_study(load_study(path), show_progress=False)


def test_zero_amplitude_fields_reproduce_the_deterministic_bar_exactly(tmp_path):
    nominal = study(tmp_path, "nominal", kind="nominal", options="")
    flat = study(tmp_path, "flat", amplitude="cv = 0.0")
    for out in ("strain", "stress", "failure_strain", "R", "sigma_stdev"):
        reference = nominal.runs[out].values[0]
        for realization in flat.runs[out].values:
            np.testing.assert_array_equal(realization, reference)


def test_fields_make_every_realization_different_and_reproducible(tmp_path):
    first = study(tmp_path, "first")
    again = study(tmp_path, "again")
    fs = first.runs["failure_strain"].values
    assert np.unique(fs).size == fs.size
    np.testing.assert_array_equal(fs, again.runs["failure_strain"].values)
    assert (first.runs["status"].values == "ok").all()


def test_stochastic_grid_is_new_for_every_realization(tmp_path):
    out = study(tmp_path, "grid", grid="stochastic", names=("E",))
    x = out.runs["x"].values
    assert not np.allclose(x[0], x[1])
    assert np.all(np.diff(x, axis=1) > 0)
    # the grid's end is a 500-term cumsum of rescaled spacings: ≤ 500·eps ≈ 1.1e-13
    np.testing.assert_allclose(x[:, -1], 0.1, rtol=1e-12)


def test_large_scatter_is_clipped_never_nan(tmp_path):
    out = study(tmp_path, "wild", amplitude="divisor = 2", shape=0.8,
                options="realizations = 8")
    status = out.runs["status"].values
    assert out.runs["clipped_points"].values.sum() > 0
    ok = status == "ok"
    for name in ("stress", "failure_strain", "R"):
        assert np.isfinite(out.runs[name].values[ok]).all()
    for message in out.runs["message"].values[~ok]:
        assert message.startswith("SolverError")
    assert (out.runs["R"].values[ok] > 0).all() and (out.runs["R"].values[ok] < 1).all()


@pytest.mark.parametrize("length", [1e-5, 10.0])   # 1e-4 L and 100 L
def test_extreme_correlation_lengths(tmp_path, length):
    out = study(tmp_path, f"len{length:g}".replace(".", "_"), length=length, names=("E",),
                options="realizations = 3")
    assert (out.runs["status"].values == "ok").all()
    if length > 1:
        # one mode spans the bar: E is nearly uniform along it, so the bar stays homogeneous
        ratio = out.runs["failure_strain"].values / 0.115
        np.testing.assert_allclose(ratio, 1.0, atol=0.02)
