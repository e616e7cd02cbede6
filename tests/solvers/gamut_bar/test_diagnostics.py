"""The gamut bar's diagnostics: outputs that say how a run went (its load steps and Newton
work), not what it predicts. The template marks them ``output_kind = "diagnostic"``
(uqflow.solver.Solver), so the runs store them and no method, figure or allocation treats
them as uncertain quantities."""

from __future__ import annotations

import pytest

from ._common import small_solver

DIAGNOSTICS = {"load_steps": "steps", "newton_iterations": "newton_iterations",
               "factorisations": "factorisations"}      # output: the run attribute it copies


@pytest.mark.parametrize("loading", ["monotonic", "cyclic"])
def test_the_template_marks_the_counters_as_diagnostics_and_a_run_fills_them(loading):
    s = small_solver(loading)
    template = s.outputs()
    marked = {n for n, v in template.data_vars.items()
              if v.attrs.get("output_kind") == "diagnostic"}
    assert marked == set(DIAGNOSTICS)
    assert all(template[n].dims == () and template[n].attrs["units"] == "1" for n in marked)
    ds = s.run({})
    for name, attr in DIAGNOSTICS.items():
        assert ds[name].item() == ds.attrs[attr] > 0, name
