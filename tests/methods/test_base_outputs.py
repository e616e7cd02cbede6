"""What every method shares: which runs variables are uncertain outputs (diagnostics are not),
the cost attributes with numba's compile time apart, and the warning of a method that
reduced an output's dims (issue 16, Found 2, 6 and 7)."""

import numpy as np
import pytest
import xarray as xr

import uqflow
from solvers.analytic import AnalyticSolver
from uqflow.execute import run_study
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import get_method
from uqflow.methods.base import (MethodOptions, PropagationMethod, cost_attrs,
                                 finish_statistics, make_design, ok_mask, output_names)
from uqflow.realization import evaluate_design
from uqflow.solver import Solver, register_solver
from uqflow.study import load_study


def normal(name, mean=1.5, std=0.2):
    return RandomInput.from_spec({"name": name, "distribution": "normal", "mean": mean,
                                  "std": std})


DECAY_SPACE = InputSpace([normal("alpha"), normal("beta", 0.15, 0.02)])


@register_solver("decay-with-timing-test")
class DecayWithTiming(AnalyticSolver):
    """exponential_decay y(t) plus two diagnostics of the run: a timing and a counter."""

    @classmethod
    def from_scene(cls, scene):
        return super().from_scene({"model": "exponential_decay"})

    def outputs(self):
        template = super().outputs()
        template["solve_time"] = xr.Variable((), np.nan, {"units": "s",
                                                          "output_kind": "diagnostic"})
        template["steps"] = xr.Variable((), np.nan, {"output_kind": "diagnostic"})
        return template

    def run(self, params, fields=None):
        ds = super().run(params, fields)
        ds["solve_time"] = xr.Variable((), 1e-3 * float(params["alpha"]))
        ds["steps"] = xr.Variable((), 21.0)
        return ds


# --------------------------------------------------------------------------- diagnostics

def test_diagnostics_are_stored_but_get_no_statistics():
    solver = DecayWithTiming.from_scene({})
    method = get_method("monte-carlo")(samples=8, rule="random")
    design = method.plan(DECAY_SPACE, None, np.random.SeedSequence(0))
    runs = evaluate_design(solver, design)
    from uqflow.methods.base import is_diagnostic

    assert is_diagnostic(runs["solve_time"]) and is_diagnostic(runs["steps"])
    assert not is_diagnostic(runs["y"])
    assert np.all(runs["steps"].values == 21.0)  # stored per realization
    assert output_names(runs) == ["y"]
    stats = method.analyze(design, runs)
    assert "solve_time" not in stats and "steps" not in stats
    assert not any(str(v).startswith(("solve_time", "steps")) for v in stats.data_vars)


def test_the_diagnostic_mark_survives_into_the_result_file(tmp_path):
    study = tmp_path / "timing.toml"
    study.write_text('name = "timing"\nsolver = "decay-with-timing-test"\nscene = {}\n'
                     '[[inputs]]\nname = "alpha"\ndistribution = "normal"\nmean = 1.5\n'
                     'std = 0.2\n[method]\nkind = "monte-carlo"\nsamples = 4\n'
                     'rule = "random"\n[execution]\nworkers = 0\n'
                     '[output]\npath = "timing.nc"\nfigures = true\n')
    out = run_study(load_study(study), show_progress=False)
    tree = uqflow.open_result(out.path)
    runs = tree["runs"].to_dataset()
    assert runs["solve_time"].attrs["output_kind"] == "diagnostic"
    assert output_names(runs) == ["y"]
    stats = tree["statistics"].to_dataset()
    assert [str(v) for v in stats.data_vars if "statistic" in stats[v].dims] == ["y"]
    from uqflow.report import summary_table, write_figures
    assert "solve_time" not in summary_table(tree)
    assert all(not p.name.startswith(("solve_time", "steps"))
               for p in write_figures(tree, tmp_path / "figs"))


# --------------------------------------------------------------------------- compile time

def test_cost_attributes_hold_the_compile_time_apart():
    design = make_design(DECAY_SPACE, np.ones((3, 2)))
    runs = evaluate_design(AnalyticSolver.from_scene({"model": "exponential_decay"}), design)
    runs["wall_time"].values[:] = [5.0, 1.0, 2.0]
    runs["compile_time"].values[:] = [4.0, 0.0, 0.0]
    runs["status"].values[2] = "pending"
    cost = cost_attrs(runs)
    assert cost["solver_wall_time"] == 6.0 and cost["solver_compile_time"] == 4.0
    assert runs["compile_time"].attrs["units"] == "s"


# --------------------------------------------------------------------------- reduced dims

class _AverageOptions(MethodOptions):
    samples: int = 4


@uqflow.register_method("time-average-test")
class TimeAverage(PropagationMethod):
    """The README's custom method pattern: y(t) averaged into one number per statistic."""

    Options = _AverageOptions

    def plan(self, space, fields, seed):
        u = np.random.default_rng(seed).random((self.options.samples, len(space)))
        return make_design(space, space.from_unit_hypercube(u))

    def analyze(self, design, runs):
        ok = ok_mask(runs)
        data = {o: (("statistic",), [runs[o].values[ok].mean()]) for o in output_names(runs)}
        return finish_statistics(xr.Dataset(data, coords={"statistic": ["mean"]}),
                                 design, runs, self.name, [])


def test_a_method_that_reduces_an_output_s_dims_is_warned_about_by_name():
    method = TimeAverage()
    design = method.plan(DECAY_SPACE, None, np.random.SeedSequence(1))
    runs = evaluate_design(AnalyticSolver.from_scene({"model": "exponential_decay"}), design)
    stats = method.analyze(design, runs)
    warnings = stats.attrs["warnings"].splitlines()
    assert len(warnings) == 1
    assert "'y'" in warnings[0] and "'t'" in warnings[0] and "reduced" in warnings[0]


@pytest.mark.parametrize("kind, options", [("monte-carlo", {"samples": 8, "rule": "random"}),
                                           ("taylor", {})])
def test_methods_that_keep_the_dims_get_no_such_warning(kind, options):
    method = get_method(kind)(**options)
    design = method.plan(DECAY_SPACE, None, np.random.SeedSequence(1))
    runs = evaluate_design(AnalyticSolver.from_scene({"model": "exponential_decay"}), design)
    stats = method.analyze(design, runs)
    assert "reduced" not in stats.attrs["warnings"]


@pytest.mark.parametrize("kind, options", [("taylor-local", {}),
                                           ("monte-carlo", {"samples": 4, "rule": "random",
                                                            "control": "taylor-local"})])
def test_a_sensitivity_run_asks_no_derivative_of_a_diagnostic(kind, options):
    """A timing has no derivative: the method accepts the solver and its flagged run gives
    derivatives of the uncertain outputs alone."""
    solver = DecayWithTiming.from_scene({})
    method = get_method(kind)(**options)
    method.check_solver(solver, list(solver.outputs().data_vars), DECAY_SPACE.names)
    design = method.plan(DECAY_SPACE, None, np.random.SeedSequence(2))
    runs = evaluate_design(solver, design)
    assert (runs["status"].values == "ok").all(), runs["message"].values
    assert "y__gradient" in runs and "solve_time__gradient" not in runs
    stats = method.analyze(design, runs)
    assert [str(v) for v in stats.data_vars if "statistic" in stats[v].dims] == ["y"]


def test_sample_mask_leaves_out_failed_and_control_runs():
    import uqflow

    runs = xr.Dataset({"status": ("realization", ["ok", "ok", "failed", "ok"]),
                       "role": ("realization", ["control", "sample", "sample", "sample"])})
    assert uqflow.sample_mask(runs).tolist() == [False, True, False, True]
    assert uqflow.sample_mask(runs.drop_vars("role")).tolist() == [True, True, False, True]
