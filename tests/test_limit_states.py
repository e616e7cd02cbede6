"""Limit states (issue 18, point 1): margins and failures of every reduction and comparison
against numbers computed by hand on tiny datasets, series and parallel systems, NaN for
realizations that did not run ok, a one-line error naming the key for every malformed
[[limit_states]] table, and a study file with limit states loaded and run."""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from uqflow import cli
from uqflow.errors import StudyError
from uqflow.limit_states import LimitStates
from uqflow.methods import get_method
from uqflow.study import load_study

# A field y (time, probe) recorded at times interval * i, as solvers write them (the last
# time is 0.30000000000000004, not the 0.3 a user writes), and a scalar s.
TIMES = 0.1 * np.arange(1, 4)
TEMPLATE = xr.Dataset(
    {"y": (("time", "probe"), np.full((3, 3), np.nan), {"units": "m"}),
     "s": ((), np.nan, {"units": "Pa"}),
     "by_probe": (("probe",), np.full(3, np.nan), {"units": "1"})},
    coords={"time": ("time", TIMES, {"units": "s"}), "probe": ["H", "I", "J"]})

# Realization 0: y = [[0, 1, 2], [3, 4, 5], [6, 7, 8]]; realization 1: 8 - that; both ok.
# Realization 2 failed and realization 3 is pending: finite numbers are stored for them here,
# so only their status can make their margins NaN.
Y0 = np.arange(9.0).reshape(3, 3)
Y = np.stack([Y0, 8.0 - Y0, Y0, Y0])
S = np.array([1.0, -2.0, 5.0, 5.0])
STATUS = np.array(["ok", "ok", "failed", "pending"], dtype=object)


def runs(y=Y, s=S, status=STATUS) -> xr.Dataset:
    n = len(status)
    return xr.Dataset(
        {"y": (("realization", "time", "probe"), y), "s": ("realization", s),
         "by_probe": (("realization", "probe"), y[:, 0, :]), "status": ("realization", status)},
        coords={"realization": np.arange(n), "time": TIMES, "probe": ["H", "I", "J"]})


def states(*tables) -> LimitStates:
    return LimitStates.from_tables([dict(t) for t in tables], TEMPLATE, "study.toml")


def margins_of(table) -> list[float]:
    return states(dict(table, name="g")).margins(runs()).sel(limit_state="g").values.tolist()


NAN = math.nan


# ----------------------------------------------------------------------------- reductions
# Each: (table, margins of realizations 0 and 1 by hand). Integers and halves: exact in float.
REDUCTIONS = {
    "max-exceeds": ({"output": "y", "reduce": "max", "exceeds": 6.5}, [6.5 - 8, 6.5 - 8]),
    "max-below": ({"output": "y", "reduce": "max", "below": 6.5}, [8 - 6.5, 8 - 6.5]),
    "min-below": ({"output": "y", "reduce": "min", "below": 0.5}, [0 - 0.5, 0 - 0.5]),
    "min-exceeds": ({"output": "y", "reduce": "min", "exceeds": -1}, [-1 - 0, -1 - 0]),
    # last time: realization 0 [6, 7, 8], realization 1 [2, 1, 0]; the probes left are
    # covered by their worst: the largest for exceeds, the smallest for below
    "final-exceeds": ({"output": "y", "reduce": "final", "exceeds": 7.5}, [7.5 - 8, 7.5 - 2]),
    "final-below": ({"output": "y", "reduce": "final", "below": 0.5}, [6 - 0.5, 0 - 0.5]),
    # time 0.2, probe J: realization 0 y = 5, realization 1 y = 3
    "at-time-and-probe": ({"output": "y", "reduce": {"at": {"time": 0.2, "probe": "J"}},
                           "exceeds": 4}, [4 - 5, 4 - 3]),
    "at-the-last-time-as-written": ({"output": "y", "reduce": {"at": {"time": 0.3,
                                                                      "probe": "H"}},
                                     "below": 2}, [6 - 2, 2 - 2]),
    # probe I alone: the times left are covered by the worst (a first passage)
    "at-probe-exceeds": ({"output": "y", "reduce": {"at": {"probe": "I"}}, "exceeds": 6},
                         [6 - 7, 6 - 7]),
    "at-probe-below": ({"output": "y", "reduce": {"at": {"probe": "I"}}, "below": 2},
                       [1 - 2, 1 - 2]),
    # max over probes H and J and every time: realization 0 max(0,2,3,5,6,8) = 8,
    # realization 1 max(8,6,5,3,2,0) = 8; over H alone 6 and 8
    "max-over-two-probes": ({"output": "y", "reduce": {"max_over": {"probe": ["H", "J"]}},
                             "exceeds": 7}, [7 - 8, 7 - 8]),
    "max-over-one-probe-below": ({"output": "y", "reduce": {"max_over": {"probe": ["H"]}},
                                  "below": 7}, [6 - 7, 8 - 7]),
    "max-over-times": ({"output": "y", "reduce": {"max_over": {"time": [0.1, 0.2]}},
                        "exceeds": 4}, [4 - 5, 4 - 8]),
    "scalar-exceeds": ({"output": "s", "exceeds": 0}, [0 - 1, 0 + 2]),
    "scalar-below": ({"output": "s", "below": -1.5}, [1 + 1.5, -2 + 1.5]),
    "scalar-max-is-its-value": ({"output": "s", "reduce": "max", "below": 0}, [1, -2]),
}


@pytest.mark.parametrize("case", list(REDUCTIONS), ids=list(REDUCTIONS))
def test_margins_of_each_reduction_and_comparison(case):
    table, expected = REDUCTIONS[case]
    # exact: integers and halves, reduced by max/min/selection and one subtraction
    assert margins_of(table)[:2] == expected


def test_failures_are_the_margins_at_or_below_zero():
    ls = states({"name": "a", "output": "y", "reduce": "max", "exceeds": 8},     # g = 0, 0
                {"name": "b", "output": "s", "below": 0},                        # g = 1, -2
                {"name": "c", "output": "s", "exceeds": 3})                      # g = 2, 5
    failed = ls.failures(runs())
    assert failed.dims == ("realization", "limit_state")
    assert failed.sel(limit_state=["a", "b", "c"]).values[:2].tolist() == \
        [[True, False, False], [True, True, False]]


def test_series_is_the_min_and_parallel_the_max_of_the_members():
    ls = states({"name": "high", "output": "y", "reduce": "max", "exceeds": 7.5},   # -0.5, -0.5
                {"name": "low", "output": "s", "below": 0},                         # 1, -2
                {"name": "end", "output": "y", "reduce": "final", "exceeds": 7.5},  # -0.5, 5.5
                {"name": "any", "series": ["low", "end"]},
                {"name": "all", "parallel": ["low", "end"]},
                {"name": "cut", "series": ["all", "high"]})          # a system of a system
    assert ls.names == ["high", "low", "end", "any", "all", "cut"]
    g = ls.margins(runs())
    assert g.sel(limit_state="any").values[:2].tolist() == [-0.5, -2.0]
    assert g.sel(limit_state="all").values[:2].tolist() == [1.0, 5.5]
    assert g.sel(limit_state="cut").values[:2].tolist() == [-0.5, -0.5]
    failed = ls.failures(runs())
    assert failed.sel(limit_state="any").values[:2].tolist() == [True, True]
    assert failed.sel(limit_state="all").values[:2].tolist() == [False, False]


def test_a_realization_that_did_not_run_ok_has_nan_margins_and_is_no_failure():
    ls = states({"name": "a", "output": "y", "reduce": "max", "exceeds": 0},
                {"name": "b", "output": "s", "exceeds": 0},
                {"name": "both", "parallel": ["a", "b"]})
    g, failed = ls.margins(runs()), ls.failures(runs())
    # realizations 2 (failed) and 3 (pending) store values that would fail every state
    assert np.isnan(g.values[2:]).all()
    assert not failed.values[2:].any()
    assert failed.values[0].tolist() == [True, True, True]


def test_a_nan_point_of_a_field_is_no_value_not_a_skipped_point():
    y = Y.copy()
    y[0, 1, 1] = np.nan          # realization 0 at time 0.2, probe I
    g = states({"name": "m", "output": "y", "reduce": "max", "exceeds": 100},
               {"name": "elsewhere", "output": "y", "reduce": {"at": {"probe": "H"}},
                "exceeds": 100}).margins(runs(y=y))
    assert np.isnan(g.values[0, 0]) and g.values[0, 1] == 100 - 6
    assert g.values[1].tolist() == [100 - 8, 100 - 8]


def test_a_numeric_coordinate_is_matched_within_rounding_not_to_the_nearest():
    # the stored last time is 0.3 + 1 ulp: a few ulp away from what is written, still that time
    assert TIMES[2] != 0.3
    for written in (0.3, np.nextafter(TIMES[2], 1.0), np.nextafter(TIMES[2], 0.0)):
        assert margins_of({"output": "y", "reduce": {"at": {"time": float(written),
                                                            "probe": "H"}},
                           "exceeds": 0})[0] == -6
    # 1e-6 of the grid's largest value off: another time, refused with the nearest named
    with pytest.raises(StudyError, match=r"no time = 0\.300001 .*nearest is 0\.3\)"):
        states({"name": "g", "output": "y", "reduce": {"at": {"time": 0.300001}},
                "exceeds": 0})


def test_describe_says_the_event_in_words():
    ls = states({"name": "a", "output": "y", "reduce": {"at": {"time": 0.2, "probe": "J"}},
                 "exceeds": 4},
                {"name": "b", "output": "y", "reduce": "final", "below": 0.5},
                {"name": "c", "output": "s", "exceeds": 2e8},
                {"name": "d", "series": ["a", "c"]})
    assert ls["a"].describe() == "y at time = 0.2, probe = J > 4 m"
    assert ls["b"].describe() == "y at the last time < 0.5 m"
    assert ls["c"].describe() == "s > 2e+08 Pa"
    assert ls["d"].describe() == "a or c fails"


def test_a_dim_without_coordinate_is_labelled_by_position():
    template = xr.Dataset({"u": (("point",), np.full(3, np.nan))})
    ls = LimitStates.from_tables([{"name": "g", "output": "u", "reduce": {"at": {"point": 2}},
                                   "exceeds": 1},
                                  {"name": "f", "output": "u", "reduce": "final",
                                   "below": 1}], template, "study.toml")
    data = xr.Dataset({"u": (("realization", "point"), [[0.0, 1.0, 4.0]]),
                       "status": ("realization", np.array(["ok"], dtype=object))})
    assert ls.margins(data).values.tolist() == [[1 - 4, 4 - 1]]


# ----------------------------------------------------------------------------- malformed
GOOD = {"name": "g", "output": "y", "reduce": "max", "exceeds": 1.0}
SYSTEM_MEMBERS = [GOOD, dict(GOOD, name="h", output="s", reduce="min")]
MALFORMED = {   # id: (tables, key, words of the reason)
    "unknown-output": ([dict(GOOD, output="z")], "limit_states[0].output",
                       "no output 'z' (it has y, s, by_probe)"),
    "output-not-a-string": ([dict(GOOD, output=3)], "limit_states[0].output", "got 3"),
    "missing-output": ([{"name": "g", "exceeds": 1}], "limit_states[0].output",
                       "required key is missing"),
    "missing-name": ([{"output": "s", "exceeds": 1}], "limit_states[0].name",
                     "required key is missing"),
    "blank-name": ([dict(GOOD, name=" ")], "limit_states[0].name", "empty or blank"),
    "unknown-key": ([dict(GOOD, colour=1)], "limit_states[0].colour", "unknown key"),
    "misspelt-key": ([{"name": "g", "output": "s", "exceed": 1}], "limit_states[0].exceed",
                     "did you mean 'exceeds'?"),
    "both-exceeds-and-below": ([dict(GOOD, below=0.0)], "limit_states[0].below", "not both"),
    "neither-exceeds-nor-below": ([{"name": "g", "output": "s"}], "limit_states[0].exceeds",
                                  "exactly one of exceeds"),
    "infinite-threshold": ([dict(GOOD, exceeds=math.inf)], "limit_states[0].exceeds",
                           "finite number, got inf"),
    "nan-threshold": ([{"name": "g", "output": "s", "below": math.nan}],
                      "limit_states[0].below", "finite number, got nan"),
    "boolean-threshold": ([dict(GOOD, exceeds=True)], "limit_states[0].exceeds",
                          "must be a number"),
    "string-threshold": ([dict(GOOD, exceeds="1 mm")], "limit_states[0].exceeds",
                         "must be a number"),
    "field-without-reduce": ([{"name": "g", "output": "y", "exceeds": 1}],
                             "limit_states[0].reduce", "has dims (time, probe)"),
    "unknown-reduction": ([dict(GOOD, reduce="mean")], "limit_states[0].reduce",
                          "unknown reduction 'mean'"),
    "unknown-table-reduction": ([dict(GOOD, reduce={"att": {"probe": "H"}})],
                                "limit_states[0].reduce.att", "did you mean 'at'?"),
    "two-reductions": ([dict(GOOD, reduce={"at": {"probe": "H"}, "max_over": {}})],
                       "limit_states[0].reduce", "a table with one key"),
    "final-without-numeric-dim": ([dict(GOOD, output="by_probe", reduce="final")],
                                  "limit_states[0].reduce", "no numeric dim"),
    "unknown-dim": ([dict(GOOD, reduce={"at": {"depth": 1.0}})],
                    "limit_states[0].reduce.at.depth", "no dim 'depth' (its dims: time, probe)"),
    "unknown-label": ([dict(GOOD, reduce={"at": {"probe": "K"}})],
                      "limit_states[0].reduce.at.probe", "no probe 'K' (its probe labels: H, "
                                                         "I, J)"),
    "time-not-recorded": ([dict(GOOD, reduce={"at": {"time": 0.25}})],
                          "limit_states[0].reduce.at.time", "no time = 0.25"),
    "number-for-a-label": ([dict(GOOD, reduce={"at": {"probe": 1}})],
                           "limit_states[0].reduce.at.probe", "give one as a string"),
    "string-for-a-time": ([dict(GOOD, reduce={"at": {"time": "end"}})],
                          "limit_states[0].reduce.at.time", "numeric coordinates"),
    "empty-at": ([dict(GOOD, reduce={"at": {}})], "limit_states[0].reduce.at",
                 "at least one of the output's dims"),
    "max-over-unknown-label": ([dict(GOOD, reduce={"max_over": {"probe": ["H", "K"]}})],
                               "limit_states[0].reduce.max_over.probe[1]", "no probe 'K'"),
    "max-over-not-a-list": ([dict(GOOD, reduce={"max_over": {"probe": "H"}})],
                            "limit_states[0].reduce.max_over.probe", "non-empty list"),
    "max-over-label-twice": ([dict(GOOD, reduce={"max_over": {"probe": ["H", "H"]}})],
                             "limit_states[0].reduce.max_over.probe[1]", "listed twice"),
    "duplicate-name": ([GOOD, dict(GOOD, output="s", reduce="min")], "limit_states[1].name",
                       "declared twice (also limit_states[0])"),
    "system-named-like-a-state": ([*SYSTEM_MEMBERS, {"name": "g", "series": ["g", "h"]}],
                                  "limit_states[2].name", "declared twice"),
    "system-unknown-member": ([*SYSTEM_MEMBERS, {"name": "s", "series": ["g", "k"]}],
                              "limit_states[2].series[1]", "no limit state 'k'"),
    "system-names-itself": ([*SYSTEM_MEMBERS, {"name": "s", "parallel": ["s", "g"]}],
                            "limit_states[2].parallel[0]", "its own member"),
    "system-before-its-member": ([GOOD, {"name": "s", "series": ["g", "h"]},
                                  dict(GOOD, name="h")], "limit_states[1].series[1]",
                                 "no limit state 'h' is declared before"),
    "system-of-one": ([*SYSTEM_MEMBERS, {"name": "s", "series": ["g"]}],
                      "limit_states[2].series", "at least two"),
    "system-member-twice": ([*SYSTEM_MEMBERS, {"name": "s", "series": ["g", "g"]}],
                            "limit_states[2].series[1]", "listed twice"),
    "series-and-parallel": ([*SYSTEM_MEMBERS, {"name": "s", "series": ["g", "h"],
                                               "parallel": ["g", "h"]}],
                            "limit_states[2].parallel", "not both"),
    "system-with-a-threshold": ([*SYSTEM_MEMBERS, {"name": "s", "series": ["g", "h"],
                                                   "exceeds": 1}],
                                "limit_states[2].exceeds", "unknown key"),
    "not-a-table": ([GOOD, 3], "limit_states[1]", "must be a table"),
    "not-a-list": ("g", "limit_states", "[[limit_states]]"),
    "empty": ([], "limit_states", "at least one"),
}


@pytest.mark.parametrize("case", list(MALFORMED), ids=list(MALFORMED))
def test_every_malformed_limit_state_is_one_line_naming_file_and_key(case):
    tables, key, says = MALFORMED[case]
    with pytest.raises(StudyError) as caught:
        LimitStates.from_tables(tables, TEMPLATE, "study.toml")
    error = caught.value
    assert (error.file, error.key) == ("study.toml", key), str(error)
    assert says in error.reason, str(error)
    assert "\n" not in str(error) and str(error).startswith(f"study.toml: {key}: ")


# ----------------------------------------------------------------------------- study files
STUDY = """\
name = "decay"
solver = "analytic"
scene = {{ model = "exponential_decay", t = {{ start = 0.0, stop = 2.0, num = 3 }} }}

[[inputs]]
name = "alpha"
distribution = "normal"
mean = 1.5
std = 0.3

[[inputs]]
name = "beta"
distribution = "uniform"
lower = 0.1
upper = 0.5

[method]
kind = "{kind}"
{options}
[execution]
workers = 0

[output]
path = "out/result.nc"
figures = false
{limit_states}"""

LIMIT_STATES = """
[[limit_states]]
name = "end_high"
output = "y"
reduce = "final"
exceeds = 0.9

[[limit_states]]
name = "start_low"
output = "y"
reduce = { at = { t = 0.0 } }
below = 1.2

[[limit_states]]
name = "either"
series = ["end_high", "start_low"]
"""


def write_study(tmp_path, kind="monte-carlo", options="samples = 16\n",
                limit_states=LIMIT_STATES):
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(kind=kind, options=options, limit_states=limit_states),
                    encoding="utf-8")
    return path


@pytest.fixture
def monte_carlo_uses_limit_states(monkeypatch):
    """Monte Carlo as it estimates P[failure] (issue 18, point 2), whether or not that has
    landed: this file tests the limit states, not the estimator."""
    monkeypatch.setattr(get_method("monte-carlo"), "uses_limit_states", True)


def test_a_study_file_with_limit_states_loads_and_its_runs_give_the_margins(
        tmp_path, monte_carlo_uses_limit_states):
    from uqflow.execute import run_study
    from uqflow.store import open_result

    study = load_study(write_study(tmp_path))
    ls = study.limit_states
    assert study.method.limit_states is ls
    assert ls.names == ["end_high", "start_low", "either"]
    assert ls["end_high"].reduce.along == "t" and ls["end_high"].comparison == ">"
    assert ls["start_low"].reduce.labels == (("t", (0.0,)),)

    result = run_study(study, show_progress=False)
    runs = open_result(result.path)["runs"].to_dataset()       # as stored and read back
    alpha, beta = (runs["inputs"].sel(parameter=p).values for p in ("alpha", "beta"))
    y_end, y_start = alpha * np.exp(-2.0 * beta), alpha
    g = ls.margins(runs)
    # y(2) = alpha e^(-2 beta): np.exp within 1 ulp on any CPU, the product and the
    # subtraction 1/2 ulp each: 4 ulp of the larger of 0.9 and y bounds the difference
    assert np.allclose(g.sel(limit_state="end_high"), 0.9 - y_end, rtol=0,
                       atol=4 * np.finfo(float).eps * max(0.9, y_end.max()))
    assert g.sel(limit_state="start_low").values.tolist() == (y_start - 1.2).tolist()
    assert np.array_equal(g.sel(limit_state="either"),
                          np.minimum(g.sel(limit_state="end_high"),
                                     g.sel(limit_state="start_low")))
    failed = ls.failures(runs).sel(limit_state="either").values
    assert 0 < failed.sum() < 16          # the thresholds cut through the inputs' range


def test_a_method_without_limit_states_refuses_them_in_one_line(tmp_path, capsys,
                                                                 monkeypatch):
    path = write_study(tmp_path, kind="taylor", options="order = 1\n")
    monkeypatch.chdir(tmp_path)
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"uqflow: error: {path}: limit_states: "
                                                   f"method 'taylor' estimates no failure")
    assert not (tmp_path / "out").exists()
    # the same study without [[limit_states]] is fine, and gives the method None
    study = load_study(write_study(tmp_path, kind="taylor", options="order = 1\n",
                                   limit_states=""))
    assert study.limit_states is None and study.method.limit_states is None


def test_a_malformed_limit_state_in_a_study_names_the_study_file(
        tmp_path, capsys, monkeypatch, monte_carlo_uses_limit_states):
    path = write_study(tmp_path, limit_states=LIMIT_STATES.replace(
        "reduce = { at = { t = 0.0 } }", "reduce = { at = { t = 0.5 } }"))
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", str(path)]) == 2
    err = capsys.readouterr().err
    assert err == f"uqflow: error: {path}: limit_states[1].reduce.at.t: output 'y' has no " \
                  f"t = 0.5 (its t runs from 0 to 2; the nearest is 0)\n"
    assert not (tmp_path / "out").exists()


def test_an_output_the_study_does_not_keep_is_named_so(tmp_path,
                                                       monte_carlo_uses_limit_states):
    text = STUDY.format(kind="monte-carlo", options="samples = 4\n", limit_states="""
[[limit_states]]
name = "end"
output = "path"
exceeds = 0.5
reduce = "final"
""").replace('{ model = "exponential_decay", t = { start = 0.0, stop = 2.0, num = 3 } }',
             '{ model = "euler_decay" }\noutputs = ["y"]')
    text = text.replace('name = "alpha"', 'name = "k"').replace(
        '[[inputs]]\nname = "beta"\ndistribution = "uniform"\nlower = 0.1\nupper = 0.5\n', "")
    (tmp_path / "study.toml").write_text(text, encoding="utf-8")
    with pytest.raises(StudyError) as caught:
        load_study(tmp_path / "study.toml")
    assert caught.value.key == "limit_states[0].output"
    assert "an output of the solver but not of this study: add it to outputs" in \
        caught.value.reason


def test_a_limit_state_threshold_can_be_set_from_the_command_line(
        tmp_path, monte_carlo_uses_limit_states):
    study = load_study(write_study(tmp_path), overrides={"limit_states.0.exceeds": 0.25})
    assert study.limit_states["end_high"].threshold == 0.25
    with pytest.raises(StudyError, match=r"limit_states\[0\]\.exceeds: must be a finite"):
        load_study(write_study(tmp_path), overrides={"limit_states.0.exceeds": math.inf})


# ----------------------------------------------------------------------------- the page
PAGE = Path(__file__).resolve().parents[1] / "docs" / "reliability.md"


def test_the_page_states_the_coordinate_tolerance_and_the_rounding_it_covers():
    from uqflow import limit_states
    text = " ".join(PAGE.read_text(encoding="utf-8").split())
    tolerance, time, written = re.search(
        r"within (\S+) of the coordinate's largest magnitude.*the 100th output time of 0\.5 µs "
        r"is (\S+), and `time = (\S+)` names it", text).groups()
    assert float(tolerance) == limit_states._COORD_RTOL
    stored = 0.5e-6 * np.arange(201)          # the MPM scene's output times (interval * i)
    assert repr(float(stored[100])) == time and float(written) != stored[100]
    template = xr.Dataset({"u": (("time",), np.full(201, np.nan))}, coords={"time": stored})
    ls = LimitStates.from_tables([{"name": "g", "output": "u", "exceeds": 0.0,
                                   "reduce": {"at": {"time": float(written)}}}], template)
    assert ls["g"].reduce.labels == (("time", (stored[100],)),)


def test_the_error_line_the_page_shows_is_what_uqflow_says(tmp_path,
                                                           monte_carlo_uses_limit_states):
    text = PAGE.read_text(encoding="utf-8")
    block = re.search(r"```toml\n(# invalid: [^\n]*\n.*?)```\n\nsays\n\n```\n(.*?)\n```", text,
                      re.S)
    fragment, line = tomllib.loads(block.group(1)), block.group(2)
    study = STUDY.format(kind="monte-carlo", options="samples = 4\n", limit_states="").replace(
        '{ model = "exponential_decay", t = { start = 0.0, stop = 2.0, num = 3 } }',
        '{ model = "exponential_decay" }')
    assert fragment["scene"] == {"model": "exponential_decay"}
    (tmp_path / "study.toml").write_text(study + "\n" + block.group(1).split("\n", 2)[2],
                                         encoding="utf-8")
    with pytest.raises(StudyError) as caught:
        load_study(tmp_path / "study.toml")
    assert str(caught.value).replace(str(tmp_path) + "/", "") == line


def test_stored_runs_can_stand_for_the_template():
    """A report rebuilds the limit states of a result from its study text and its runs: the
    runs' outputs are the outputs, the framework's columns are not."""
    ls = LimitStates.from_tables([{"name": "g", "output": "y", "reduce": {"at": {"probe": "I"}},
                                   "below": 2}], runs())
    assert ls.margins(runs()).values[:2, 0].tolist() == [1 - 2, 1 - 2]
    with pytest.raises(StudyError, match=r"no output 'status' \(it has y, s, by_probe\)"):
        LimitStates.from_tables([{"name": "g", "output": "status", "exceeds": 0}], runs())


# ----------------------------------------------------------------------------- discrete outcomes
# A solver's outcomes as the gamut bar declares them: a 0/1 flag, the cycle of the event
# (21 = not within the 20 cycles of the loading), a continuous output, one a break leaves
# without value, and a count with no declaration at all.
OUTCOMES = xr.Dataset({
    "broken": ((), NAN, {"units": "1", "flag_values": np.array([0, 1], dtype=np.int8),
                         "flag_meanings": "intact broken"}),
    "break_cycle": ((), NAN, {"units": "1", "output_values": "discrete",
                              "not_within_loading": 21.0}),
    "failure_strain": ((), NAN, {"units": "1"}),
    "n_prime": ((), NAN, {"units": "1", "undefined_when": "broken"}),
    "count": ((), NAN, {"units": "1"})})


def outcome_runs(broken, cycle, status=None):
    n = len(broken)
    status = np.array(["ok"] * n if status is None else status, dtype=object)
    return xr.Dataset({"broken": ("realization", np.asarray(broken, dtype=float)),
                       "break_cycle": ("realization", np.asarray(cycle, dtype=float)),
                       "failure_strain": ("realization", np.full(n, 0.1)),
                       "count": ("realization", np.asarray(broken, dtype=float)),
                       "status": ("realization", status)},
                      coords={"realization": np.arange(n)})


def outcome_states(*tables, template=OUTCOMES.drop_vars("n_prime")) -> LimitStates:
    return LimitStates.from_tables([dict(t) for t in tables], template, "study.toml")


def test_an_outcome_is_true_or_false_with_margins_plus_and_minus_one():
    ls = outcome_states({"name": "b", "output": "broken", "is": True},
                        {"name": "intact", "output": "broken", "is": False},
                        {"name": "half", "output": "broken", "exceeds": 0.5})
    # realization 3 failed (its stored 1 is no event), realization 4 holds 2: no outcome
    data = outcome_runs([0, 1, 1, 1, 2], [21, 3, 4, 4, 21], ["ok", "ok", "ok", "failed", "ok"])
    g = ls.margins(data)
    assert g.sel(limit_state="b").values.tolist()[:3] == [1.0, -1.0, -1.0]
    assert g.sel(limit_state="intact").values.tolist()[:3] == [-1.0, 1.0, 1.0]
    assert g.sel(limit_state="half").values.tolist()[:3] == [0.5, -0.5, -0.5]
    assert np.isnan(g.values[3]).all() and np.isnan(g.sel(limit_state="b").values[4])
    assert ls.failures(data).sel(limit_state="b").values.tolist() == \
        [False, True, True, False, False]
    assert ls["b"].describe() == "broken is true" and \
        ls["intact"].describe() == "broken is false"


def test_an_event_cycle_below_n_counts_the_events_by_cycle_n_and_never_the_survivors():
    ls = outcome_states({"name": "early", "output": "break_cycle", "below": 4},
                        {"name": "late", "output": "break_cycle", "exceeds": 21})
    data = outcome_runs([1, 1, 1, 0], [3, 4, 5, 21])
    # a value at the threshold fails: cycles 3 and 4 are "by cycle 4", 21 is never below
    assert ls.failures(data).sel(limit_state="early").values.tolist() == \
        [True, True, False, False]
    # exceeds = 21 (the value "not within the loading"): the survivors, whose break lies past
    assert ls.failures(data).sel(limit_state="late").values.tolist() == \
        [False, False, False, True]


def test_discrete_limit_states_are_told_apart_and_refused_by_a_gradient_method():
    ls = outcome_states({"name": "b", "output": "broken", "is": True},
                        {"name": "half", "output": "broken", "exceeds": 0.5},
                        {"name": "early", "output": "break_cycle", "below": 4},
                        {"name": "strain", "output": "failure_strain", "below": 0.05},
                        {"name": "count", "output": "count", "exceeds": 0.5},
                        {"name": "either", "series": ["strain", "b"]},
                        {"name": "both", "parallel": ["strain", "count"]})
    assert [ls.is_discrete(n) for n in ls.names] == [True, True, True, False, False, True,
                                                     False]
    ls.require_continuous("strain", "form")
    ls.require_continuous("both", "form")
    with pytest.raises(StudyError) as caught:
        ls.require_continuous("either", "subset-simulation")
    assert caught.value.key == "method.limit_state" and "\n" not in str(caught.value)
    assert "'either' has a discrete margin" in caught.value.reason and \
        "subset-simulation needs a continuous one" in caught.value.reason


DISCRETE_MALFORMED = {   # id: (table, key, words of the reason)
    "is-a-number": ({"output": "broken", "is": 1}, "limit_states[0].is", "true or false"),
    "is-on-a-continuous-output": ({"output": "failure_strain", "is": True},
                                  "limit_states[0].is", "not a 0/1 outcome"),
    "is-and-exceeds": ({"output": "broken", "is": True, "exceeds": 0.5},
                       "limit_states[0].is", "not both (exceeds and is)"),
    "all-three": ({"output": "broken", "is": True, "exceeds": 0.5, "below": 0.5},
                  "limit_states[0].is", "not all three"),
    "below-the-not-within-loading-value": ({"output": "break_cycle", "below": 21},
                                           "limit_states[0].below",
                                           "would count those realizations as failures"),
    "exceeds-past-it": ({"output": "break_cycle", "exceeds": 21.5},
                        "limit_states[0].exceeds", "would count those realizations as safe"),
}


@pytest.mark.parametrize("case", list(DISCRETE_MALFORMED), ids=list(DISCRETE_MALFORMED))
def test_every_malformed_outcome_limit_state_is_one_line(case):
    table, key, says = DISCRETE_MALFORMED[case]
    with pytest.raises(StudyError) as caught:
        outcome_states(dict(table, name="g"))
    assert (caught.value.file, caught.value.key) == ("study.toml", key), str(caught.value)
    assert says in caught.value.reason and "\n" not in str(caught.value)


def test_a_study_storing_what_an_outcome_leaves_without_value_is_refused_naming_outputs():
    """n' has no value for a broken bar, so a study storing it keeps broken bars failed: a
    limit state on the break would silently leave out every break."""
    with pytest.raises(StudyError) as caught:
        outcome_states({"name": "b", "output": "broken", "is": True}, template=OUTCOMES)
    assert caught.value.key == "outputs" and "'n_prime'" in caught.value.reason
    assert "where 'broken' is 1" in caught.value.reason
    # a limit state on n' itself judges the bars that have it: no refusal
    ls = outcome_states({"name": "soft", "output": "n_prime", "below": 0.05},
                        template=OUTCOMES)
    assert ls.names == ["soft"] and not ls.is_discrete("soft")
