"""Random fields through the whole study path: validation, germs, determinism, nominal runs."""

import numpy as np
import pytest
import xarray as xr

import uqflow
from uqflow.execute import run_study
from uqflow.study import load_study

BAR = """\
name = "{name}"
solver = "analytic"
scene = {{ model = "random_E_bar", points = 50, force = 2.0e4, area = 1.0e-4, length = 0.1 }}
{inputs}
[[fields]]
name = "E"
parameters = ["bar.E"]
correlation_length = 0.02
{amplitude}

[method]
kind = "{kind}"
{options}

[execution]
workers = {workers}
seed = 9

[output]
path = "out/{name}.nc"
figures = false
"""


def bar_study(tmp_path, name="bar", kind="kl-weibull", options="realizations = 12",
              amplitude="divisor = 10", workers=0, inputs=""):
    path = tmp_path / f"{name}.toml"
    path.write_text(BAR.format(name=name, kind=kind, options=options, amplitude=amplitude,
                               workers=workers, inputs=inputs))
    return path


def test_nominal_run_of_a_field_study_is_the_deterministic_bar(tmp_path):
    out = run_study(load_study(bar_study(tmp_path, kind="nominal", options="")),
                    show_progress=False)
    exact = 2.0e4 * 0.1 / (1.0e-4 * 200.0e9)     # F L / (A E)
    # the solver sums 50 segments' dx/E: ≤ 50·eps ≈ 1.1e-14, plus a few roundings
    assert float(out.statistics["end_displacement"].sel(statistic="mean")) == \
        pytest.approx(exact, rel=1e-12)
    assert float(out.statistics["end_displacement"].sel(statistic="std")) == 0.0


def test_zero_amplitude_field_reproduces_the_deterministic_result_exactly(tmp_path):
    out = run_study(load_study(bar_study(tmp_path, amplitude="cv = 0.0")), show_progress=False)
    y = out.runs["end_displacement"].values
    exact = 2.0e4 * 0.1 / (1.0e-4 * 200.0e9)
    assert np.all(y == y[0])
    # a 50-term sum of dx/E and F/A: ≤ (50 + 4)·eps ≈ 1.2e-14 (1e-14 was tighter than that)
    assert y[0] == pytest.approx(exact, rel=(50 + 4) * np.finfo(float).eps)
    assert (np.abs(out.runs["germ_E"].values) > 0).any()   # germs drawn, amplitude zero


def test_a_scalar_input_sets_the_mean_the_field_perturbs(tmp_path):
    inputs = '\n[[inputs]]\nname = "bar.E"\ndistribution = "normal"\nmean = 100.0e9\ncv = 0.05\n'
    out = run_study(load_study(bar_study(tmp_path, inputs=inputs, amplitude="cv = 0.0")),
                    show_progress=False)
    e = out.runs["inputs"].sel(parameter="bar.E").values
    np.testing.assert_allclose(out.runs["end_displacement"].values,
                               # 50-term sum: ≤ (50 + 4)·eps ≈ 1.2e-14
                               2.0e4 * 0.1 / (1.0e-4 * e), rtol=1e-12)


def test_germs_of_a_realization_do_not_depend_on_the_study_size(tmp_path):
    small = run_study(load_study(bar_study(tmp_path, name="small", options="realizations = 5")),
                      show_progress=False)
    large = run_study(load_study(bar_study(tmp_path, name="large", options="realizations = 20")),
                      show_progress=False)
    np.testing.assert_array_equal(small.runs["germ_E"].values, large.runs["germ_E"].values[:5])
    np.testing.assert_array_equal(small.runs["end_displacement"].values,
                                  large.runs["end_displacement"].values[:5])


def test_large_scatter_is_clipped_never_nan(tmp_path):
    amplitude = 'divisor = 2\ngerm = { kind = "symmetric-weibull", scale = 1.0, shape = 0.8 }'
    out = run_study(load_study(bar_study(tmp_path, amplitude=amplitude,
                                         options="realizations = 40")), show_progress=False)
    assert (out.runs["status"].values == "ok").all()
    assert out.runs["clipped_points"].values.sum() > 0
    assert np.isfinite(out.runs["end_displacement"].values).all()


@pytest.mark.slow
def test_field_study_is_identical_in_process_and_on_two_workers(tmp_path):
    trees = []
    for workers in (0, 2):
        out = run_study(load_study(bar_study(tmp_path, name=f"w{workers}", workers=workers)),
                        show_progress=False)
        trees.append(uqflow.open_result(out.path))
    runs = [t["runs"].to_dataset().drop_vars("wall_time") for t in trees]
    xr.testing.assert_identical(runs[0], runs[1])


def test_a_field_on_a_parameter_the_solver_cannot_vary_in_space(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(bar_study(tmp_path).read_text().replace('parameters = ["bar.E"]',
                                                            'parameters = ["bar.nu"]'))
    with pytest.raises(uqflow.StudyError) as err:
        load_study(path)
    assert err.value.key == "fields[0].parameters[0]"


@pytest.mark.parametrize("kind, options", [("taylor", ""), ("monte-carlo", "samples = 8"),
                                           ("sobol", "samples = 8")])
def test_methods_without_field_support_refuse_fields(tmp_path, kind, options):
    inputs = '\n[[inputs]]\nname = "bar.E"\ndistribution = "normal"\nmean = 1e11\ncv = 0.1\n'
    with pytest.raises(uqflow.StudyError, match="takes no random fields") as err:
        load_study(bar_study(tmp_path, kind=kind, options=options, inputs=inputs))
    assert err.value.key == "fields"


def test_field_table_errors_name_the_key(tmp_path):
    path = bar_study(tmp_path, amplitude="divisor = 10\nbogus = 1")
    with pytest.raises(uqflow.StudyError) as err:
        load_study(path)
    assert err.value.key == "fields[0].bogus"
    path = bar_study(tmp_path, amplitude="divisor = -1")
    with pytest.raises(uqflow.StudyError) as err:
        load_study(path)
    assert err.value.key == "fields[0].divisor"


def test_store_values_keeps_the_field_the_solver_saw(tmp_path):
    out = run_study(load_study(bar_study(tmp_path, amplitude="divisor = 10\nstore_values = true",
                                         options="realizations = 6")), show_progress=False)
    e = out.runs["field_bar_E"].values
    assert e.shape == (6, 50)
    dx = 0.1 / 50
    np.testing.assert_allclose(out.runs["end_displacement"].values,
                               # the same 50-term sum two ways: ≤ 2·50·eps ≈ 2e-14
                               2.0e4 / 1.0e-4 * (dx / e).sum(axis=1), rtol=1e-12)
    assert "field_bar_E" not in out.statistics
