"""Execution: determinism across worker counts, failures, early stopping, the store."""

import numpy as np
import pytest
import xarray as xr

import uqflow
from uqflow.execute import StudyFailed, run_study
from uqflow.study import load_study

FAULTY_INPUT = """
[[inputs]]
name = "x"
distribution = "normal"
mean = 0.0
std = 1.0
"""


def _comparable(tree):
    runs = tree["runs"].to_dataset().drop_vars("wall_time")
    stats = tree["statistics"].to_dataset()
    stats.attrs.pop("solver_wall_time")
    return runs, stats


@pytest.mark.slow
def test_one_and_two_workers_give_identical_results(write_study):
    # Bitwise: the design is fixed before anything runs and statistics use realization order.
    results = []
    for workers in (1, 2):
        study = load_study(write_study(name=f"w{workers}", execution=f"workers = {workers}\n"
                                       "batch = 16\nseed = 7"))
        out = run_study(study, show_progress=False)
        results.append(_comparable(uqflow.open_result(out.path)))
    (runs1, stats1), (runs2, stats2) = results
    xr.testing.assert_identical(runs1, runs2)
    xr.testing.assert_identical(stats1, stats2)
    assert (runs1["status"].values == "ok").all()


def test_in_process_matches_dask_sizes_and_stores_layout(write_study):
    study = load_study(write_study(execution="workers = 0\nseed = 3"))
    out = run_study(study, show_progress=False)
    tree = uqflow.open_result(out.path)
    assert set(tree.children) == {"runs", "statistics"}
    runs = tree["runs"]
    assert runs.sizes["realization"] == 256
    assert list(runs["parameter"].values) == ["x1", "x2", "x3"]
    assert runs["wall_time"].attrs["units"] == "s"
    assert tree.attrs["complete"] == 1
    assert tree.attrs["seed"] == 3
    assert "x1" in tree.attrs["study"]
    for pkg in ("uqflow", "numpy", "numba", "dask"):
        assert tree.attrs[f"version_{pkg}"]
    assert tree["statistics"].attrs["solver_runs"] == 256
    # Per-realization seeds are spawned by index: independent of the design's size.
    seeds = runs["realization_seed"].values
    assert seeds[5] == np.random.SeedSequence(3, spawn_key=(5,)).generate_state(1)[0]


def test_failures_are_recorded_and_the_study_goes_on(write_study):
    study = load_study(write_study(scene='{ model = "faulty", raise_above = 2.0, '
                                   'nan_below = -2.0 }', inputs=FAULTY_INPUT,
                                   method='kind = "monte-carlo"\nsamples = 400'))
    out = run_study(study, show_progress=False)
    runs = out.runs
    x = runs["inputs"].sel(parameter="x").values
    status = runs["status"].values
    np.testing.assert_array_equal(status == "failed", (x > 2.0) | (x < -2.0))
    raised = np.flatnonzero(x > 2.0)[0]
    assert "SolverError" in runs["message"].values[raised]
    assert "exceeds" in runs["message"].values[raised]
    nan = np.flatnonzero(x < -2.0)[0]
    assert runs["message"].values[nan] == "non-finite output 'y'"
    assert np.isnan(runs["y"].values[status == "failed"]).all()
    ok = status == "ok"
    # Same n <= 400 numbers (|x| <= 2) summed in possibly another order: the difference of
    # the means is at most 2 log2(n) eps max|x| ~ 8e-15; the mean itself is near 0, so abs.
    assert out.statistics["y"].sel(statistic="mean") == pytest.approx(x[ok].mean(), abs=1e-13)
    assert out.statistics.attrs["failed_runs"] == int((~ok).sum())
    assert any("failed" in w for w in out.warnings)


def test_a_solver_failing_everywhere_stops_cleanly(write_study):
    study = load_study(write_study(scene='{ model = "faulty", raise_above = -100.0 }',
                                   inputs=FAULTY_INPUT,
                                   method='kind = "monte-carlo"\nsamples = 200',
                                   execution="workers = 0\nbatch = 10"))
    with pytest.raises(StudyFailed, match=r"max_failure_fraction 0.1.*realization 0: "
                                          r"SolverError: diverged"):
        run_study(study, show_progress=False)
    runs = uqflow.open_result(study.output_path)["runs"]
    # Stopped just past 10 % of 200: 30 realizations in three batches, the rest pending.
    assert (runs["status"].values == "failed").sum() == 30
    assert (runs["status"].values == "pending").sum() == 170
    assert uqflow.open_result(study.output_path).attrs["complete"] == 0


def test_existing_result_is_kept_without_resume_or_force(write_study):
    study = load_study(write_study())
    run_study(study, show_progress=False)
    before = study.output_path.read_bytes()
    with pytest.raises(uqflow.StudyError, match="output.path.*--resume.*--force"):
        run_study(study, show_progress=False)
    assert study.output_path.read_bytes() == before
    run_study(study, show_progress=False, force=True)


def test_resume_of_a_complete_result_recomputes_nothing(write_study):
    study = load_study(write_study())
    first = run_study(study, show_progress=False)
    again = run_study(study, show_progress=False, resume=True)
    assert again.resumed == 256
    xr.testing.assert_identical(first.statistics.drop_attrs(), again.statistics.drop_attrs())


def test_resume_refuses_a_result_of_another_study(write_study, tmp_path):
    run_study(load_study(write_study()), show_progress=False)
    changed = load_study(write_study(method='kind = "monte-carlo"\nsamples = 128'))
    with pytest.raises(uqflow.StudyError, match="different version of this study"):
        run_study(changed, show_progress=False, resume=True)
