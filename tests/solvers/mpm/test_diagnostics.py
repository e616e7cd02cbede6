"""The MPM's diagnostics: outputs that say how a run went (its time steps), not what it
predicts. The template marks them ``output_kind = "diagnostic"`` (uqflow.solver.Solver), so
the runs store them and no method, figure or allocation treats them as uncertain quantities."""

from __future__ import annotations

import numpy as np

from solvers.mpm.solver import MPMSolver

from .test_core import small_scene

DIAGNOSTICS = {"time_steps": "1", "dt_min": "s", "dt_max": "s"}


def test_the_template_marks_the_timing_and_counter_outputs_as_diagnostics():
    template = MPMSolver.from_scene(small_scene()).outputs()
    kinds = {name: var.attrs.get("output_kind") for name, var in template.data_vars.items()}
    assert {n for n, k in kinds.items() if k == "diagnostic"} == set(DIAGNOSTICS)
    for name, units in DIAGNOSTICS.items():
        assert template[name].dims == () and template[name].attrs["units"] == units
    # every other output is a physical quantity at the probes or of the whole body
    assert all("time" in template[n].dims for n, k in kinds.items() if k != "diagnostic")


def test_a_run_fills_the_diagnostics_with_what_it_did():
    ds = MPMSolver.from_scene(small_scene()).run({})
    assert ds["time_steps"].item() == ds.attrs["steps"] > 0
    assert 0 < ds["dt_min"].item() == ds.attrs["dt_min"] <= ds["dt_max"].item() \
        == ds.attrs["dt_max"]
    # the steps cover the run: dt_min x steps <= end_time <= dt_max x steps, up to rounding:
    # the run's clock is a sum of `steps` rounded additions, relative error <= steps x eps
    end = float(ds["time"].values[-1])
    steps = ds["time_steps"].item()
    slack = 1.0 + 2.0 * steps * np.finfo(float).eps
    assert ds["dt_min"].item() * steps <= end * slack
    assert end <= ds["dt_max"].item() * steps * slack
    assert np.all(np.isfinite([ds[n].item() for n in DIAGNOSTICS]))
