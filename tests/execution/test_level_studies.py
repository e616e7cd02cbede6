"""Studies with fidelity levels end to end: coupled rows on their level's solver, rounds added
by the method, 1 and 2 workers and a resumed study giving the same numbers, failures at one
level, alignment of outputs across levels, and the study-file errors."""

import numpy as np
import pytest
import xarray as xr

import uqflow
from uqflow.errors import StudyError
from uqflow.execute import run_study
from uqflow.store import read_runs, write_result
from uqflow.study import load_study

from ._common import comparable

K_INPUT = """
[[inputs]]
name = "k"
distribution = "uniform"
lower = {low}
upper = {high}
"""


def level_study(write_study, name, method="multilevel", steps=(4, 8, 16), target=0.01,
                extra="", levels_extra="", outputs='["y"]', execution="workers = 0",
                low=0.5, high=1.5, costs=True):
    cost_line = f"costs = {[float(s) for s in steps]}\n" if costs else ""
    body = (f"\n[levels]\nkey = \"steps\"\nvalues = {list(steps)}\n{levels_extra}\n")
    scene = '{ model = "euler_decay" }'
    path = write_study(name=name, scene=scene, inputs=K_INPUT.format(low=low, high=high),
                       body=body, execution=execution + "\nseed = 5",
                       method=f'kind = "{method}"\ntarget_rmse = {target}\npilot = 8\n'
                              f'{cost_line}{extra}')
    text = path.read_text().replace('solver = "analytic"',
                                    f'solver = "analytic"\noutputs = {outputs}')
    path.write_text(text)
    return path


@pytest.mark.parametrize("method", ["multilevel", "multifidelity"])
def test_rows_run_on_their_level_with_shared_inputs_and_seeds(write_study, method):
    outcome = run_study(load_study(level_study(write_study, method, method)),
                        show_progress=False)
    runs = outcome.runs
    assert (runs["status"].values == "ok").all()
    assert runs["round"].values.max() >= 1          # the method added rows after the pilot
    steps = np.array([4, 8, 16])[runs["level"].values]
    k = runs["inputs"].values[:, 0]
    # each row's output is the Euler value at its own level's step count: the model and this
    # line evaluate the same numpy float64 power of the same operands, so they agree bitwise on
    # any machine (no BLAS involved); a row run at another level would differ by far more
    np.testing.assert_array_equal(runs["y"].values, (1.0 - k / steps) ** steps)
    for key in np.unique(runs["seed_key"].values):
        same = runs["seed_key"].values == key
        assert np.unique(runs["inputs"].values[same, 0]).size == 1
        assert np.unique(runs["realization_seed"].values[same]).size == 1


@pytest.mark.parametrize("method, extra", [("multilevel", ""), ("multifidelity", ""),
                                           ("multifidelity", 'surrogate = "taylor-local"')])
def test_one_and_two_workers_give_identical_results(write_study, method, extra):
    paths = [run_study(load_study(level_study(write_study, f"{method}{w}", method, extra=extra,
                                              execution=f"workers = {w}\nbatch = 7")),
                       show_progress=False).path for w in (0, 2)]
    (runs0, stats0), (runs2, stats2) = map(comparable, paths)
    xr.testing.assert_identical(runs0, runs2)
    xr.testing.assert_identical(stats0, stats2)


def _cut(path, keep_rounds, finished_in_last):
    """The checkpoint of a study killed in round ``keep_rounds - 1``: later rounds absent,
    the last kept round finished for its first ``finished_in_last`` rows only."""
    runs, attrs = read_runs(path)
    rounds = runs["round"].values
    runs = runs.isel(realization=np.flatnonzero(rounds < keep_rounds))
    last = np.flatnonzero(runs["round"].values == keep_rounds - 1)[finished_in_last:]
    runs["status"].values[last] = "pending"
    runs["message"].values[last] = ""
    runs["wall_time"].values[last] = np.nan
    runs["y"].values[last] = np.nan
    attrs.update(complete=0)
    attrs.pop("runs_sha256", None)
    write_result(path, runs, None, attrs)


@pytest.mark.parametrize("method, extra, target", [
    ("multilevel", "", 0.01), ("multifidelity", "", 0.01),
    # the surrogate meets 0.01 with the pilot alone: a target that takes a second round
    ("multifidelity", 'surrogate = "taylor-local"', 1e-4)])
@pytest.mark.parametrize("keep_rounds, finished", [(1, 5), (None, 3), (None, 10**9)])
def test_a_killed_study_resumes_to_the_uninterrupted_numbers(write_study, method, extra,
                                                             target, keep_rounds, finished):
    # killed in the pilot, or in the last round (None) before or after it finished
    whole = run_study(load_study(level_study(write_study, "whole", method, extra=extra,
                                             target=target)),
                      show_progress=False)
    last = int(whole.runs["round"].values.max())
    assert last >= 1
    keep_rounds = keep_rounds or last + 1
    cut = run_study(load_study(level_study(write_study, "cut", method, extra=extra,
                                           target=target)), show_progress=False)
    _cut(cut.path, keep_rounds, finished)
    resumed = run_study(load_study(level_study(write_study, "cut", method, extra=extra,
                                               target=target)), resume=True,
                        show_progress=False)
    assert resumed.resumed > 0
    (runs_w, stats_w), (runs_c, stats_c) = comparable(whole.path), comparable(cut.path)
    xr.testing.assert_identical(runs_w.drop_vars("message"), runs_c.drop_vars("message"))
    xr.testing.assert_identical(stats_w, stats_c)


def test_measured_costs_come_from_the_pilot_and_are_reported(write_study):
    outcome = run_study(load_study(level_study(write_study, "measured", costs=False)),
                        show_progress=False)
    stats = outcome.statistics
    runs = outcome.runs
    pilot = runs["round"].values == 0
    # a run's cost is its wall time less what numba spent compiling in it (paid once)
    seconds = runs["wall_time"].values - np.nan_to_num(runs["compile_time"].values, nan=0.0) \
        if "compile_time" in runs else runs["wall_time"].values
    for level in range(3):
        mine = pilot & (runs["level"].values == level)
        assert stats["level_run_cost"].values[level] == np.median(seconds[mine])
    assert stats["level_run_cost"].attrs["units"] == "s"


def test_a_level_that_fails_for_some_inputs_is_recorded_and_its_pairs_dropped(write_study):
    # one Euler step is unstable for k > 2: level 0 fails for a quarter of k ~ U(0.5, 2.5)
    path = level_study(write_study, "failing", steps=(1, 2, 4), low=0.5, high=2.5,
                       target=0.02,
                       execution="workers = 0\nmax_failure_fraction = 0.5")
    outcome = run_study(load_study(path), show_progress=False)
    runs, stats = outcome.runs, outcome.statistics
    failed = runs["status"].values == "failed"
    assert failed.any() and np.all(runs["level"].values[failed] == 0)
    assert np.all(runs["inputs"].values[failed, 0] > 2.0)
    assert all("Euler step unstable" in m for m in runs["message"].values[failed])
    # level 0's failures leave correction 0 and correction 1 (whose coarse run is level 0)
    dropped = stats["level_failed_pairs"].values
    assert dropped[0] > 0 and dropped[1] > 0 and dropped[2] == 0
    assert dropped.sum() == failed.sum()
    assert any("failed pairs dropped per level" in w for w in outcome.warnings)
    assert np.isfinite(stats["y"].values).all()


def test_mfmc_drops_a_failed_sample_from_every_model(write_study):
    path = level_study(write_study, "mf_failing", "multifidelity", steps=(1, 2, 4), low=0.5,
                       high=2.5, target=0.02,
                       execution="workers = 0\nmax_failure_fraction = 0.5")
    outcome = run_study(load_study(path), show_progress=False)
    runs, stats = outcome.runs, outcome.statistics
    bad = set(runs["sample"].values[runs["status"].values == "failed"].tolist())
    assert bad and stats.attrs["dropped_samples"] == len(bad)
    used = stats["model_samples"].values
    drawn = [int((runs["level"].values == lv).sum()) for lv in (2, 1, 0)]
    assert all(u <= d for u, d in zip(used, drawn))
    assert any("dropped from every model" in w for w in outcome.warnings)


def test_interpolated_levels_put_coarse_paths_on_the_finest_grid(write_study):
    path = level_study(write_study, "aligned", steps=(4, 16), outputs='["y", "path"]',
                       levels_extra='align = "interpolate"', extra='allocate_on = ["y"]')
    runs = run_study(load_study(path), show_progress=False).runs
    assert runs["path"].sizes["t"] == 17
    coarse = np.flatnonzero(runs["level"].values == 0)[0]
    k = runs["inputs"].values[coarse, 0]
    own = (1.0 - k / 4) ** np.arange(5)
    # np.interp and xarray's linear interpolation: one rounding of a convex combination each
    np.testing.assert_allclose(runs["path"].values[coarse],
                               np.interp(np.linspace(0, 1, 17), np.linspace(0, 1, 5), own),
                               rtol=4 * np.finfo(float).eps, atol=0)


@pytest.mark.parametrize("change, key, match", [
    (lambda t: t.replace('kind = "multilevel"', 'kind = "monte-carlo"\nsamples = 8')
     .replace("target_rmse = 0.01\npilot = 8\ncosts = [4.0, 8.0, 16.0]\n", ""),
     "levels", "does not use fidelity levels"),
    (lambda t: t.replace("values = [4, 8, 16]", "values = [0, 8, 16]"), "levels.values",
     "steps = 0 \\(level 0\\) gives a bad scene: scene.steps"),
    (lambda t: t.replace("values = [4, 8, 16]", "values = [4, 4, 16]"), "levels.values",
     "must differ"),
    (lambda t: t.replace('outputs = ["y"]', 'outputs = ["y", "path"]')
     .replace("pilot = 8", 'pilot = 8\nallocate_on = ["y"]'), "levels.align",
     "'path' on other 't' coordinates .* set levels.align = .interpolate."),
    (lambda t: t.replace("costs = [4.0, 8.0, 16.0]", "costs = [4.0, 8.0]"), "method.costs",
     "2 values for 3 levels"),
    (lambda t: t.replace("target_rmse = 0.01", "target_rel_rmse = 0.01\ntarget_rmse = 0.01"),
     "method", "exactly one of target_rmse and target_rel_rmse"),
    (lambda t: t.replace('key = "steps"', 'key = "model.name"'), "levels.key",
     "scene key 'model' is not a table"),
])
def test_level_errors_name_the_key(write_study, change, key, match):
    path = level_study(write_study, "bad")
    path.write_text(change(path.read_text()))
    with pytest.raises(StudyError, match=match) as info:
        load_study(path)
    assert info.value.key.startswith(key)


def test_a_multilevel_study_needs_levels(write_study):
    path = level_study(write_study, "nolevels")
    text = path.read_text()
    path.write_text(text[:text.index("[levels]")] + text[text.index("[method]"):])
    with pytest.raises(StudyError, match="add a \\[levels\\] table") as info:
        load_study(path)
    assert info.value.key == "levels"


def test_results_open_with_the_level_table(write_study):
    outcome = run_study(load_study(level_study(write_study, "table")), show_progress=False)
    stats = uqflow.open_result(outcome.path)["statistics"].to_dataset()
    assert stats["level_value"].values.tolist() == [4.0, 8.0, 16.0]
    assert stats["level_samples"].dims == ("level",)
    assert stats["y_level_variance"].dims == ("level",)
    assert set(stats["statistic"].values) >= {"mean", "variance", "stderr", "bias", "rmse"}


@pytest.mark.parametrize("method, table", [("multilevel", "levels (cost per run"),
                                           ("multifidelity", "models (0 = high fidelity")])
def test_report_prints_the_level_table_and_draws_the_levels_figure(write_study, tmp_path,
                                                                   method, table):
    from uqflow.report import summary_table, write_figures

    outcome = run_study(load_study(level_study(write_study, f"rep_{method}", method)),
                        show_progress=False)
    tree = uqflow.open_result(outcome.path)
    text = summary_table(tree)
    assert table in text and "cheaper than plain MC at the finest level" in text
    stats = outcome.statistics
    counts = stats["level_samples" if method == "multilevel" else "model_samples"].values
    assert all(str(int(n)) in text for n in counts)
    written = write_figures(tree, tmp_path / "figs")
    assert [p.name for p in written] == (["y_levels.png"] if method == "multilevel" else [])


def test_a_surrogate_needs_local_derivatives(write_study):
    path = write_study(name="nosens", scene='{ model = "random_E_bar" }',
                       inputs='\n[[inputs]]\nname = "bar.E"\ndistribution = "normal"\n'
                              'mean = 200e9\ncv = 0.1\n',
                       body='\n[levels]\nkey = "points"\nvalues = [10, 100]\n',
                       method='kind = "multifidelity"\ntarget_rel_rmse = 0.01\n'
                              'surrogate = "taylor-local"')
    with pytest.raises(StudyError, match="no local") as info:
        load_study(path)
    assert info.value.key == "method.surrogate"


def test_report_compares_error_against_cost_across_results(write_study, tmp_path):
    from uqflow.methods.level_report import cost_comparison

    ml = run_study(load_study(level_study(write_study, "cmp_ml")), show_progress=False)
    plain_path = write_study(name="cmp_plain", scene='{ model = "euler_decay", steps = 16 }',
                             inputs=K_INPUT.format(low=0.5, high=1.5),
                             method='kind = "monte-carlo"\nsamples = 64\nrule = "random"')
    plain = run_study(load_study(plain_path), show_progress=False)
    trees = [uqflow.open_result(p) for p in (plain.path, ml.path)]
    text, figures = cost_comparison(trees, tmp_path / "figs")
    assert "cmp_plain" in text and "cmp_ml" in text and "plain MC time" in text
    assert [f.name for f in figures] == ["y_error_vs_cost.png"]
    # the plain MC time for the plain result's own stderr is its own solver time
    row = next(line for line in text.splitlines() if line.strip().startswith("cmp_plain"))
    cells = row.split()
    assert float(cells[3]) == pytest.approx(float(cells[5]), rel=1e-3)   # 4 digits shown
    assert cost_comparison(trees[:1], tmp_path / "none") == ("", [])


@pytest.mark.parametrize("method", ["multilevel", "multifidelity"])
def test_max_rounds_zero_runs_the_pilot_alone_and_says_the_target_is_not_met(write_study,
                                                                              method):
    outcome = run_study(load_study(level_study(write_study, f"pilot_{method}", method,
                                               target=1e-4, extra="max_rounds = 0")),
                        show_progress=False)
    assert outcome.runs["round"].values.max() == 0
    assert outcome.runs.sizes["realization"] == 8 * (5 if method == "multilevel" else 3)
    assert any("max_rounds" in w for w in outcome.warnings)


def test_allocate_at_lets_only_the_chosen_points_drive_the_allocation(write_study):
    # the path's late points vary most; allocating on its first step (always 1: no
    # variance) asks nothing beyond the pilot, on its last step as much as y does
    def samples(at):
        extra = f"allocate_at = {{ t = [{at}] }}"
        outcome = run_study(load_study(level_study(write_study, f"at{at}", outputs='["path"]',
                                                   target=0.005, extra=extra,
                                                   levels_extra='align = "interpolate"')),
                            show_progress=False)
        return outcome.statistics["level_samples"].values.tolist()

    assert samples(0.0) == [8, 8, 8]
    assert samples(1.0) > [8, 8, 8]
    path = level_study(write_study, "at_bad", outputs='["path"]',
                       levels_extra='align = "interpolate"',
                       extra='allocate_at = { probe = ["H"] }')
    with pytest.raises(StudyError, match="no allocating output has a dimension 'probe'") as info:
        load_study(path)
    assert info.value.key == "method.allocate_at.probe"


@pytest.mark.filterwarnings("error::RuntimeWarning")  # NaN moments are said, not warned
@pytest.mark.parametrize("method", ["multilevel", "multifidelity"])
def test_a_target_that_cannot_be_shown_met_says_so(write_study, method):
    # euler_decay fails where k h > 2: at 1 step every k in [2.5, 3] fails, so the coarsest
    # level has no run, its variance and the stderr are unknown and the rounds stop; that
    # stop was silent (a NaN stderr compared False with the target), and MFMC raised
    outcome = run_study(load_study(level_study(
        write_study, f"unknown_{method}", method, steps=(1, 8, 16), low=2.5, high=3.0,
        execution="workers = 0\nmax_failure_fraction = 1.0")), show_progress=False)
    said = [w for w in outcome.warnings if "target not met" in w]
    assert len(said) == 1 and said[0].startswith("y: target not met: stderr unknown")
    assert "no more samples could be allocated" in said[0]


def test_warnings_name_points_by_their_coordinates(write_study):
    # the bias (16 steps are far from converged for target 1e-5) and the target not met
    # (the pilot alone) both at the allocating point t = 1 s, named so, never "point 16"
    outcome = run_study(load_study(level_study(
        write_study, "named", outputs='["path"]', target=1e-5,
        extra="allocate_at = { t = [1.0] }\nmax_rounds = 0",
        levels_extra='align = "interpolate"')), show_progress=False)
    assert any(w.startswith("path at t = 1 s: the finest level's estimated bias")
               for w in outcome.warnings)
    assert any(w.startswith("path at t = 1 s: target not met: stderr")
               and w.endswith("max_rounds = 0 reached") for w in outcome.warnings)
    assert not any("point" in w for w in outcome.warnings)


@pytest.mark.parametrize("method", ["multilevel", "multifidelity"])
def test_stated_costs_allocate_alike_at_any_scale_they_take(write_study, method):
    # the allocation depends on the costs' ratios alone, up to the largest cost a study takes
    # (1e307 validated, then overflowed a pair's cost to inf: NaN counts cast to integers)
    from uqflow.methods.fidelity_sampling import MAX_COST

    path = level_study(write_study, "too_dear", method, costs=False,
                       extra="costs = [4e307, 8e307, 1.6e308]")
    with pytest.raises(StudyError, match="every cost must be <= 5.6e\\+299") as info:
        load_study(path)
    assert info.value.key == "method.costs"

    def counts(scale):
        extra = f"costs = {[scale * s for s in (4.0, 8.0, 16.0)]}"
        outcome = run_study(load_study(level_study(write_study, f"scale{int(scale > 1)}", method,
                                                   costs=False, extra=extra)),
                            show_progress=False)
        name = "level_samples" if method == "multilevel" else "model_samples"
        assert np.isfinite(outcome.statistics.attrs["total_cost"])
        return outcome.statistics[name].values.tolist(), outcome.warnings

    plain, _ = counts(1.0)
    dearest, warned = counts(MAX_COST / 16.0)
    assert dearest == plain and not any("target not met" in w for w in warned)
    assert plain > ([8, 8, 8] if method == "multilevel" else [8, 8, 8])


@pytest.mark.filterwarnings("error::RuntimeWarning")  # NaN moments are said, not warned
def test_a_target_whose_square_overflows_is_met_by_the_pilot(write_study):
    # eps^2 was Python's float power: OverflowError in the run; numpy's is inf, met by any
    # stderr, so the pilot alone answers and nothing is left unmet
    outcome = run_study(load_study(level_study(write_study, "wide", target=1e200)),
                        show_progress=False)
    assert outcome.statistics["level_samples"].values.tolist() == [8, 8, 8]
    assert not any("target not met" in w for w in outcome.warnings)
