"""Sensitivity runs: realizations flagged ``with_sensitivities`` in a design run
``solver.run_with_sensitivities`` and store their derivatives on the ``sensitivity_run`` dim,
in-process and on dask, through checkpoints and resumes (uqflow/realization.py)."""

import numpy as np
import pytest
import xarray as xr

import uqflow
from solvers.analytic import AnalyticSolver
from uqflow.errors import StudyError
from uqflow.execute import run_study
from uqflow.inputs import InputSpace, RandomInput
from uqflow.layout import (WITH_SENSITIVITIES as SENSITIVITY_FLAG, gradient_variable,
                           hessian_variable, output_names)
from uqflow.methods.base import make_design
from uqflow.realization import evaluate_design, realization_prefix, sensitivity_arrays
from uqflow.store import read_runs, write_result
from uqflow.study import load_study

FLAGGED = [1, 2, 5]
# beta before alpha: the model lists alpha first, so storing in the solver's order would show
DECAY_INPUTS = """
[[inputs]]
name = "beta"
distribution = "normal"
mean = 0.15
std = 0.02

[[inputs]]
name = "alpha"
distribution = "normal"
mean = 1.5
std = 0.1
"""
DECAY_SCENE = '{ model = "exponential_decay", t = { start = 0.0, stop = 10.0, num = 4 } }'


def _flag_some(study, flagged=FLAGGED):
    """Make the study's (monte-carlo) design ask for sensitivities at ``flagged``."""
    plan = study.method.plan

    def planned(space, fields, seed):
        design = plan(space, fields, seed)
        flags = np.zeros(design.sizes["realization"], dtype=bool)
        flags[flagged] = True
        return design.assign({SENSITIVITY_FLAG: ("realization", flags)})

    study.method.plan = planned
    return study


def _decay_study(write_study, name="decay", execution="workers = 0", flagged=FLAGGED,
                 scene=DECAY_SCENE, inputs=DECAY_INPUTS):
    path = write_study(name=name, scene=scene, inputs=inputs,
                       method='kind = "monte-carlo"\nsamples = 8',
                       execution=execution + "\nseed = 11")
    return _flag_some(load_study(path), flagged)


def _closed_form(alpha, beta, t):
    """d/d(beta, alpha) of alpha exp(-beta t), written out independently of the model."""
    e = np.exp(-beta * t)
    gradient = np.stack([-alpha * t * e, e], axis=-1)
    hessian = np.empty((t.size, 2, 2))
    hessian[:, 0, 0] = alpha * t**2 * e
    hessian[:, 0, 1] = hessian[:, 1, 0] = -t * e
    hessian[:, 1, 1] = 0.0
    return gradient, hessian


def _comparable(path):
    runs = uqflow.open_result(path)["runs"].to_dataset()
    return runs.drop_vars("wall_time")


def test_flagged_realizations_call_run_with_sensitivities_the_others_run(write_study,
                                                                         monkeypatch):
    study = _decay_study(write_study)
    calls = []
    run, with_sensitivities = AnalyticSolver.run, AnalyticSolver.run_with_sensitivities

    def spy_run(self, params, fields=None):
        calls.append(("run", params["alpha"]))
        return run(self, params, fields)

    def spy_sensitivities(self, params, wrt, outputs):
        calls.append(("sensitivities", params["alpha"], tuple(wrt), tuple(outputs)))
        return with_sensitivities(self, params, wrt, outputs)

    monkeypatch.setattr(AnalyticSolver, "run", spy_run)
    monkeypatch.setattr(AnalyticSolver, "run_with_sensitivities", spy_sensitivities)
    out = run_study(study, show_progress=False)
    alphas = out.runs["inputs"].sel(parameter="alpha").values
    # run_with_sensitivities calls run itself: each flagged realization shows both, in order
    expected = []
    for i, a in enumerate(alphas):
        if i in FLAGGED:
            expected += [("sensitivities", a, ("beta", "alpha"), ("y",)), ("run", a)]
        else:
            expected.append(("run", a))
    assert calls == expected


@pytest.mark.parametrize("workers", [0, 2])
def test_derivatives_are_stored_in_sensitivity_run_order(write_study, workers):
    study = _decay_study(write_study, name=f"w{workers}", execution=f"workers = {workers}")
    out = run_study(study, show_progress=False)
    runs = uqflow.open_result(out.path)["runs"].to_dataset()
    assert (runs["status"].values == "ok").all()
    assert output_names(runs) == ["y"]  # neither the flag nor the derivatives are outputs
    assert runs.sizes["sensitivity_run"] == len(FLAGGED)
    assert runs[gradient_variable("y")].dims == ("sensitivity_run", "t", "parameter")
    assert runs[hessian_variable("y")].dims == ("sensitivity_run", "t", "parameter",
                                                "parameter_j")
    index, gradient, hessian = sensitivity_arrays(runs, "y")
    assert index.tolist() == FLAGGED
    t = runs["t"].values
    for j, r in enumerate(FLAGGED):
        beta, alpha = runs["inputs"].values[r]
        g, h = _closed_form(alpha, beta, t)
        # the model and _closed_form evaluate the same few operations: a few ulps apart
        np.testing.assert_allclose(gradient[j], g, rtol=8 * np.finfo(float).eps, atol=0)
        np.testing.assert_allclose(hessian[j], h, rtol=8 * np.finfo(float).eps, atol=0)


def test_in_process_and_dask_store_identical_runs(write_study):
    paths = [run_study(_decay_study(write_study, name=f"same{w}",
                                    execution=f"workers = {w}\nbatch = 3"),
                       show_progress=False).path for w in (0, 2)]
    xr.testing.assert_identical(*map(_comparable, paths))


def _partial(path, finished):
    """Turn a complete result into the checkpoint a study killed after ``finished``
    realizations leaves: later realizations pending, their outputs and derivatives NaN."""
    runs, attrs = read_runs(path)
    later = runs["realization"].values >= finished
    runs["status"].values[later] = "pending"
    runs["message"].values[later] = ""
    runs["wall_time"].values[later] = np.nan
    runs["y"].values[later] = np.nan
    unfinished = runs["sensitivity_realization"].values >= finished
    for name in (gradient_variable("y"), hessian_variable("y")):
        runs[name].values[unfinished] = np.nan
    attrs.update(complete=0)
    attrs.pop("runs_sha256", None)
    write_result(path, runs, None, attrs)
    return runs


def test_a_resumed_study_finishes_with_the_uninterrupted_runs(write_study):
    whole = run_study(_decay_study(write_study, name="whole"), show_progress=False).path
    study = _decay_study(write_study, name="cut")
    cut = run_study(study, show_progress=False).path
    partial = _partial(cut, finished=2)  # realization 1 done, 2 and 5 not
    assert np.isfinite(partial[gradient_variable("y")].values[0]).all()
    assert np.isnan(partial[gradient_variable("y")].values[1:]).all()
    outcome = run_study(_decay_study(write_study, name="cut"), resume=True,
                        show_progress=False)
    assert outcome.resumed == 2
    xr.testing.assert_identical(_comparable(whole), _comparable(cut))
    # the checksum covers the derivatives: the resumed file verifies
    read_runs(cut, verify=True)


def test_a_checkpoint_with_an_edited_derivative_is_refused(write_study):
    import netCDF4

    path = run_study(_decay_study(write_study, name="edited"), show_progress=False).path
    _partial(path, finished=2)
    with netCDF4.Dataset(path, "a") as nc:  # a hand edit: the checksum stays as it was
        nc.groups["runs"][gradient_variable("y")][0, 1, 0] += 1.0
    with pytest.raises(StudyError, match="do not match their checksum"):
        run_study(_decay_study(write_study, name="edited"), resume=True, show_progress=False)


def test_a_checkpoint_with_other_flags_is_another_design(write_study):
    path = run_study(_decay_study(write_study, name="flags"), show_progress=False).path
    _partial(path, finished=2)
    with pytest.raises(StudyError, match="does not hold this study's design"):
        run_study(_decay_study(write_study, name="flags", flagged=[1, 3]), resume=True,
                  show_progress=False)


FAULTY_INPUTS = """
[[inputs]]
name = "x"
distribution = "uniform"
lower = 0.0
upper = 1.0
"""


@pytest.mark.parametrize("workers", [0, 2])
def test_a_failed_sensitivity_run_leaves_nan_derivatives(write_study, workers):
    path = write_study(name=f"faulty{workers}", scene='{ model = "faulty", raise_above = 0.5 }',
                       inputs=FAULTY_INPUTS, method='kind = "monte-carlo"\nsamples = 8',
                       execution=f"workers = {workers}\nseed = 2\nmax_failure_fraction = 0.9")
    study = _flag_some(load_study(path), flagged=list(range(8)))
    runs = run_study(study, show_progress=False).runs
    failed = runs["status"].values == "failed"
    assert failed.any() and not failed.all()
    index, gradient, hessian = sensitivity_arrays(runs, "y")
    assert index.tolist() == list(range(8))
    assert np.isnan(gradient[failed]).all() and np.isnan(hessian[failed]).all()
    assert (gradient[~failed] == 1.0).all() and (hessian[~failed] == 0.0).all()


def test_a_non_finite_hessian_fails_the_realization_not_the_batch():
    # y = x^1.5: finite value and gradient at x = 0, infinite second derivative
    solver = AnalyticSolver.from_scene({"model": "power", "p": 1.5})
    space = InputSpace([RandomInput.from_spec({"name": "x", "distribution": "uniform",
                                                "lower": 0.0, "upper": 2.0})])
    design = make_design(space, np.array([[0.0], [1.0], [0.0]]))
    design[SENSITIVITY_FLAG] = ("realization", np.array([True, True, False]))
    runs = evaluate_design(solver, design, ["y"])
    assert runs["status"].values.tolist() == ["failed", "ok", "ok"]
    assert runs["message"].values[0] == "non-finite derivative 'y__hessian'"
    index, gradient, hessian = sensitivity_arrays(runs, "y")
    assert index.tolist() == [0, 1]
    assert np.isnan(gradient[0]).all() and np.isnan(hessian[0]).all()
    assert gradient[1].tolist() == [1.5] and hessian[1].tolist() == [[0.75]]


def test_a_design_without_flags_has_no_sensitivity_dim():
    solver = AnalyticSolver.from_scene({"model": "power"})
    space = InputSpace([RandomInput.from_spec({"name": "x", "distribution": "uniform",
                                                "lower": 0.0, "upper": 2.0})])
    runs = evaluate_design(solver, make_design(space, np.array([[1.0]])), ["y"])
    assert "sensitivity_run" not in runs.dims
    with pytest.raises(KeyError, match="no sensitivity runs"):
        sensitivity_arrays(runs, "y")


def test_a_prefix_keeps_only_its_own_sensitivity_runs():
    solver = AnalyticSolver.from_scene({"model": "power"})
    space = InputSpace([RandomInput.from_spec({"name": "x", "distribution": "uniform",
                                                "lower": 0.0, "upper": 2.0})])
    design = make_design(space, np.arange(1.0, 6.0)[:, None])
    design[SENSITIVITY_FLAG] = ("realization", np.array([True, False, True, True, False]))
    runs = evaluate_design(solver, design, ["y"])
    prefix = realization_prefix(runs, 3)
    assert prefix.sizes["realization"] == 3
    assert prefix["sensitivity_realization"].values.tolist() == [0, 2]
    # d(x^2)/dx = 2x at x = 1 and 3: exact in floating point
    assert prefix[gradient_variable("y")].values.ravel().tolist() == [2.0, 6.0]
