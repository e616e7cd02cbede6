"""solvers/mpm/reductions.py: an output at one time, each realization's peak over time (with
its derivatives at the peak), the Monte Carlo rows of a control-variate design."""

from __future__ import annotations

import numpy as np
import xarray as xr

from solvers.mpm.reductions import at_time, monte_carlo_part, peak_over_time


def _runs():
    """Two realizations, 4 times, 2 probes, 2 parameters; realization 1 has derivatives."""
    y = np.array([[[0.0, 1.0], [3.0, -5.0], [2.0, 4.0], [1.0, np.nan]],
                  [[0.0, 2.0], [1.0, -1.0], [-6.0, 7.0], [0.5, 0.0]]])
    grad = np.arange(4 * 2 * 2, dtype=float).reshape(1, 4, 2, 2) + 1.0
    hess = np.arange(4 * 2 * 2 * 2, dtype=float).reshape(1, 4, 2, 2, 2) + 1.0
    return xr.Dataset(
        {"p": (("realization", "time", "probe"), y),
         "p__gradient": (("sensitivity_run", "time", "probe", "parameter"), grad),
         "p__hessian": (("sensitivity_run", "time", "probe", "parameter", "parameter_j"), hess),
         "e": (("realization", "time"), np.array([[1.0, -2.0, 0.5, 0.0], [0.0, 0.0, 4.0, 9.0]]))},
        coords={"realization": [0, 1], "time": [0.0, 1e-6, 2e-6, 3e-6], "probe": ["H", "I"],
                "parameter": ["a", "b"], "parameter_j": ["a", "b"],
                "sensitivity_realization": ("sensitivity_run", [1])})


def test_peak_is_max_abs_over_time_with_derivatives_at_the_peak_and_its_sign():
    runs = _runs()
    reduced = peak_over_time(runs, ["p", "e"])
    assert "time" not in reduced.dims
    assert reduced["p"].dims == ("realization", "probe")
    # realization 0: the NaN at probe I never wins; realization 1: |−6| at time 2
    assert reduced["p"].values.tolist() == [[3.0, 5.0], [6.0, 7.0]]
    assert reduced["e"].values.tolist() == [2.0, 9.0]
    grad, hess = runs["p__gradient"].values[0], runs["p__hessian"].values[0]
    # realization 1 peaks at time 2 at both probes: −6 (sign flips) at H, +7 at I
    np.testing.assert_array_equal(reduced["p__gradient"].values[0, 0], -grad[2, 0])
    np.testing.assert_array_equal(reduced["p__gradient"].values[0, 1], grad[2, 1])
    np.testing.assert_array_equal(reduced["p__hessian"].values[0, 0], -hess[2, 0])
    assert reduced["p__gradient"].dims == ("sensitivity_run", "probe", "parameter")


def test_at_time_takes_the_nearest_output_time():
    runs = _runs()
    assert at_time(runs, 1.4e-6)["time"].item() == 1e-6
    assert at_time(runs, 1.6e-6)["time"].item() == 2e-6
    assert at_time(runs, 1.0)["time"].item() == 3e-6            # past the end: the last
    assert at_time(runs, 1.6e-6)["p__gradient"].values.tolist() == \
        runs["p__gradient"].values[:, 2].tolist()


def test_monte_carlo_part_drops_the_control_rows_and_renumbers():
    n = 5
    design = xr.Dataset(
        {"inputs": (("realization", "input"), np.arange(2.0 * n).reshape(n, 2)),
         "role": ("realization", ["control", "control", "sample", "sample", "sample"]),
         "with_sensitivities": ("realization", [True, False, False, False, False])},
        coords={"realization": np.arange(n)},
        attrs={"control": "taylor-local", "control_runs": 2, "seed": 7})
    runs = xr.Dataset(
        {"y": ("realization", np.arange(10.0, 10.0 + n)),
         "y__gradient": (("sensitivity_run", "parameter"), [[1.0, 2.0]])},
        coords={"realization": np.arange(n),
                "sensitivity_realization": ("sensitivity_run", [0])})
    d, r = monte_carlo_part(design, runs)
    assert d["realization"].values.tolist() == r["realization"].values.tolist() == [0, 1, 2]
    assert d["inputs"].values.tolist() == [[4.0, 5.0], [6.0, 7.0], [8.0, 9.0]]
    assert r["y"].values.tolist() == [12.0, 13.0, 14.0]
    assert "role" not in d and "with_sensitivities" not in d and "sensitivity_run" not in r.dims
    assert d.attrs == {"seed": 7}
    d2, r2 = monte_carlo_part(design, runs, 2)
    assert r2["y"].values.tolist() == [12.0, 13.0]
