"""The MPM comparison report (solvers/mpm/report.py): seed 000's Tables 6-8 and 3/9 layouts
and Figs. 5-6, 9-12 from several results of one scene.

The result files are built here with known numbers in the layout ``uqflow.store`` writes
(groups ``runs`` and ``statistics``, root provenance attributes; copied from a real tiny MPM
study), so every printed relative error and speed-up can be checked by hand. One slow test
runs two tiny real MPM studies end to end."""

from __future__ import annotations

import filecmp
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from solvers.mpm import report as mpm_report
from uqflow.errors import StudyError
from uqflow.store import open_result, write_result

ROOT = Path(__file__).resolve().parents[3]
PROBES = ["H", "I", "G", "K"]
TIMES = np.array([0.0, 5e-6, 10e-6])
JC = ["steel.jc.A", "steel.jc.n"]
SCENE_SHA = "5de88107976d0d6d3d2f2a02f0f11943941c3a8026e548d1735dcd3f8d0cca8f"


def _field(value) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, float), (TIMES.size, len(PROBES))).copy()


def write(path: Path, *, method: str, mean=1.0e9, variance=5e15, stderr=None, values=None,
          status=None, wall=1.0, cv=0.1, parameters=JC, scene=("scene.toml", SCENE_SHA),
          outputs=("flow_stress",), stats_attrs=None, statistics=True,
          with_sensitivities=None, extra_stats=None, compile_time=None, study_text=True,
          extra_runs=None, probe_xy=None, long_names=None, attrs_extra=None,
          with_variance=True, moments=True) -> Path:
    """A result file: ``values`` (realization, time, probe) or one realization at ``mean``;
    statistics ``mean``, ``variance``, ``std`` (and ``stderr`` when given) over (time, probe);
    ``compile_time`` (s per realization) as the executor records it, none when None (a result
    from before it did); ``study_text=False``: the study text not stored (too large);
    ``probe_xy``: the probes' points (m) as coordinates probe_x, probe_y, as the solver writes
    them; ``long_names``: {output: long_name}; ``attrs_extra``: more root attributes;
    ``with_variance=False``: mean and std only, as subset simulation stores them;
    ``moments=False``: the outputs at the design point only, as FORM and SORM store them."""
    values = np.asarray(values if values is not None else _field(mean)[None], float)
    n = values.shape[0]
    status = np.asarray(status if status is not None else ["ok"] * n)
    wall = np.broadcast_to(np.asarray(wall, float), (n,)).copy()
    coords = {"time": ("time", TIMES, {"units": "s"}), "probe": PROBES,
              "parameter": list(parameters)}
    if probe_xy is not None:
        xy = np.asarray(probe_xy, float)
        coords["probe_x"] = ("probe", xy[:, 0], {"units": "m", "long_name": "x"})
        coords["probe_y"] = ("probe", xy[:, 1], {"units": "m", "long_name": "y"})
    long_names = long_names or {}

    def _attrs(o):
        return {"units": "Pa", **({"long_name": long_names[o]} if o in long_names else {})}
    inputs = {"input_cv": ("parameter", np.full(len(parameters), cv))}
    runs = xr.Dataset(
        {**{o: (("realization", "time", "probe"), values, _attrs(o)) for o in outputs},
         "status": ("realization", status), "message": ("realization", [""] * n),
         "wall_time": ("realization", wall), **inputs},
        coords={**coords, "realization": np.arange(n)})
    if with_sensitivities is not None:
        runs["with_sensitivities"] = ("realization", np.asarray(with_sensitivities, bool))
    if compile_time is not None:
        runs["compile_time"] = ("realization", np.broadcast_to(
            np.asarray(compile_time, float), (n,)).copy(), {"units": "s"})
    for name, var in (extra_runs or {}).items():
        runs[name] = var
    stats = None
    if statistics:
        labels = ["mean", "variance", "std"] + (["stderr"] if stderr is not None else [])
        block = [_field(mean), _field(variance), np.sqrt(_field(variance))]
        if stderr is not None:
            block.append(_field(stderr))
        if not with_variance:
            del labels[1], block[1]
        if not moments:
            labels, block = ["design_point"], [_field(mean)]
        stats = xr.Dataset({o: (("statistic", "time", "probe"), np.stack(block),
                                _attrs(o)) for o in outputs} | inputs,
                           coords={**coords, "statistic": labels})
        stats.attrs.update({"method": method, "solver_runs": int(np.sum(status != "pending")),
                            "failed_runs": int(np.sum(status == "failed")),
                            "solver_wall_time": float(wall[status != "pending"].sum()),
                            "warnings": "", **(stats_attrs or {})})
        for name, var in (extra_stats or {}).items():
            stats[name] = var
    attrs = {"study_name": path.stem, "study": f'name = "{path.stem}"\nsolver = "mpm"\n'
                                               f'scene = "{scene[0]}"\n',
             "study_read_files": json.dumps({"scene": list(scene)}), "solver": "mpm",
             "solver_description": "mpm: test", "method": method, "method_options": "{}"}
    attrs.update(attrs_extra or {})
    if not study_text:
        del attrs["study"]
        attrs["study_text_omitted"] = ("the study text (2000000 bytes) is larger than 1048576 "
                                       "bytes and is not stored; study_text_sha256 identifies "
                                       "it")
    write_result(path, runs, stats, attrs)
    return path


def trees(*paths):
    return [open_result(p) for p in paths]


# ----------------------------------------------------------------------------- seed numbers

def test_seed_numbers_are_an_exact_copy_and_convert_to_si():
    copy = ROOT / "solvers" / "mpm" / "data" / "seed_tables.toml"
    shipped = ROOT / "tests" / "data" / "seed_tables.toml"
    assert filecmp.cmp(copy, shipped, shallow=False)
    row = tomllib.loads(shipped.read_text())["smpm"]["example2_jc"]["table6_flow_stress"][0]
    assert row[:2] == ["H", 0.10]
    seed = mpm_report.seed_moments("flow_stress")[("H", 0.10)]
    # 1e-2 Mbar = 1 GPa and 1e-6 Mbar² = 1e-2 GPa² (1 Mbar = 100 GPa): products of exact
    # powers of ten, so one rounding of the product: relative 2 ulp bounds it.
    assert seed.mc_mean == pytest.approx(row[2] * 1e9, rel=4.5e-16)
    assert seed.smpm_variance == pytest.approx(row[5] * 1e-2 * 1e18, rel=4.5e-16)
    assert mpm_report.seed_moments("pressure") == {}
    costs = mpm_report.seed_costs()
    assert (costs["jc"].smpm_seconds, costs["jc"].mc_seconds) == (93, 874579)
    assert round(costs["eos"].speedup) == round(costs["jc"].speedup) == 9404   # docs


def test_the_seed_row_is_printed_in_gpa_beside_ours(tmp_path):
    a = write(tmp_path / "mc.nc", method="monte-carlo", stderr=0.005e9)
    text, _ = mpm_report.report(trees(a), tmp_path, figures=False)
    seed_rows = [line for line in text.splitlines()
                 if line.startswith("H ") and " seed " in line]
    # Table 6, H, C.V. 0.10: MC 0.91345878 (1e-2 Mbar) = 0.91346 GPa, variance
    # 0.61061724e-6 Mbar² = 0.006106 GPa²; 8.65 % below our 1.0 GPa reference
    assert "0.91346" in seed_rows[0] and "0.006106" in seed_rows[0] and "-8.65 %" in seed_rows[0]
    assert "0.91238" in seed_rows[1] and "SMPM" in seed_rows[1]


def test_no_seed_row_for_other_inputs_or_cv(tmp_path):
    eos = write(tmp_path / "eos.nc", method="monte-carlo", stderr=0.005e9,
                parameters=["steel.eos.S1"])
    other_cv = write(tmp_path / "cv.nc", method="monte-carlo", stderr=0.005e9, cv=0.2,
                     scene=("scene.toml", SCENE_SHA))
    for path in (eos, other_cv):
        text, _ = mpm_report.report(trees(path), tmp_path, figures=False)
        assert " seed " not in "\n".join(l for l in text.splitlines() if l.startswith("H "))


# ----------------------------------------------------------------------------- Tables 6-8

def test_relative_errors_against_the_reference(tmp_path):
    noisy = write(tmp_path / "mc_small.nc", method="monte-carlo", mean=1.01e9, stderr=0.02e9)
    ref = write(tmp_path / "mc_big.nc", method="monte-carlo", mean=1.0e9, variance=5e15,
                stderr=0.005e9)
    taylor = write(tmp_path / "taylor.nc", method="taylor-local", mean=1.02e9, variance=6e15)
    results, outputs, _ = mpm_report.load_results(trees(noisy, ref, taylor))
    k, when = mpm_report.table_time(results, None)
    assert (k, when) == (2, "t = 10 µs (the last output time)")
    # the smaller standard error wins, whatever the order of the files
    assert mpm_report.choose_reference(results, outputs, k).file == "mc_big.nc"
    assert mpm_report.choose_reference(results, outputs, k, "mc_small").file == "mc_small.nc"
    text = mpm_report.moments_tables(results, outputs)
    row = next(l for l in text.splitlines() if l.startswith("H ") and "taylor.nc" in l)
    # (1.02 - 1.00)/1.00 = +2 %, (1.02 - 1.00)/0.005 = +4 standard errors, 6/5 - 1 = +20 %
    assert "+2 % (+4)" in row and "+20 %" in row
    ref_row = next(l for l in text.splitlines() if l.startswith("H ") and "(ref)" in l)
    assert "mc_big.nc" in ref_row and "1 ± 0.005" in ref_row
    assert "C.V. 0.1: reference mc_big.nc" in text


def test_a_reference_without_a_variance_error_prints_its_variance_alone(tmp_path):
    """Control-variate RQMC with replicates of one reports no variance error: no "± n/a"."""
    ref = write(tmp_path / "cvmc.nc", method="monte-carlo", mean=1.0e9, variance=5e15,
                stderr=0.005e9, stats_attrs={"control": "taylor-local"})
    results, outputs, _ = mpm_report.load_results(trees(ref))
    text = mpm_report.moments_tables(results, outputs)
    ref_row = next(l for l in text.splitlines() if l.startswith("H ") and "(ref)" in l)
    assert "n/a" not in ref_row and "0.005" in ref_row


def _row_beside_a_reference(tmp_path, file, only=None, **kwargs) -> str:
    """Probe H's row of result ``file`` in the moments table beside a Monte Carlo reference
    of variance 5e15; ``only``: the statistics it keeps."""
    ref = write(tmp_path / "mc.nc", method="monte-carlo", variance=5e15, stderr=0.005e9)
    other = write(tmp_path / file, **kwargs)
    results, outputs, _ = mpm_report.load_results(trees(ref, other))
    if only is not None:
        results[1].stats = results[1].stats.sel(statistic=only)
    text = mpm_report.moments_tables(results, outputs)
    return next(l for l in text.splitlines() if l.startswith("H ") and file in l)


def test_a_result_with_mean_and_std_only_prints_the_std_squared_as_variance(tmp_path):
    """Subset simulation stores its level-0 samples' mean and std, no variance."""
    row = _row_beside_a_reference(tmp_path, "sus.nc", method="subset-simulation",
                                  variance=6e15, with_variance=False)
    # sqrt(6e15)**2 = 6e15 to a few ulps; 6/5 - 1 = +20 %
    assert "nan" not in row and "+20 %" in row


def test_a_weighted_mean_without_a_variance_prints_a_dash(tmp_path):
    """Importance sampling stores its weighted mean only."""
    row = _row_beside_a_reference(tmp_path, "is.nc", only=["mean"],
                                  method="importance-sampling")
    assert "nan" not in row and row.split()[-2:] == ["-", "-"]


def test_a_result_without_moments_says_so_instead_of_nan(tmp_path):
    """SORM stores the outputs at its design point, no mean or variance."""
    row = _row_beside_a_reference(tmp_path, "sorm.nc", method="sorm", moments=False)
    assert "nan" not in row and "no moments" in row


def test_each_cv_has_its_own_reference_and_rows(tmp_path):
    a = write(tmp_path / "mc10.nc", method="monte-carlo", stderr=0.005e9)
    b = write(tmp_path / "mc15.nc", method="monte-carlo", stderr=0.007e9, cv=0.15)
    c = write(tmp_path / "t15.nc", method="taylor", mean=0.993e9, cv=0.15)
    text, _ = mpm_report.report(trees(a, b, c), tmp_path, figures=False)
    assert "C.V. 0.1: reference mc10.nc" in text and "C.V. 0.15: reference mc15.nc" in text
    row = next(l for l in text.splitlines() if l.startswith("H ") and "t15.nc" in l)
    assert "-0.7 % (-1)" in row           # against mc15 (its C.V.), not mc10


def test_the_table_time_is_the_nearest_output_time(tmp_path):
    # mean 3 GPa at t = 5 µs only
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7,
               mean=np.array([[1.05e9] * 4, [3e9] * 4, [1.05e9] * 4]))
    text, _ = mpm_report.report(trees(mc), tmp_path, figures=False, time=6e-6)
    assert "t = 5 µs (the output time nearest the requested 6 µs)" in text
    assert "3 ± 0.01" in next(l for l in text.splitlines() if l.startswith("H "))


def test_variance_error_formulas(tmp_path):
    rng = np.random.default_rng(7)
    n = 4000
    normal = rng.standard_normal((n, 1, 1)) * np.ones((1, TIMES.size, len(PROBES)))
    uniform = rng.uniform(-1, 1, (n, 1, 1)) * np.ones((1, TIMES.size, len(PROBES)))
    for values, kurtosis in ((normal, 3.0), (uniform, 1.8)):
        path = write(tmp_path / f"iid{kurtosis}.nc", method="monte-carlo", values=values,
                     stderr=0.0, stats_attrs={"stderr_kind": "iid"})
        res = mpm_report.load_results(trees(path))[0][0]
        err, how = mpm_report.variance_error(res, "flow_stress")
        s2 = values[:, 0, 0].var(ddof=1)
        # Var(s²) ≈ σ⁴ (κ - 1)/n: the sample kurtosis of 4000 draws is within ± 5 sqrt(24/n)
        # = ± 0.39 of κ, so the error is within 15 % of sqrt((κ - 1)/n) s²
        expected = s2 * math.sqrt((kurtosis - 1) / n)
        assert float(err.isel(time=0, probe=0)) == pytest.approx(expected, rel=0.15), how
        assert how == f"kurtosis formula, {n} i.i.d. runs"
    # randomized QMC: realization i in replicate i mod 4; replicate r holds (0, d_r), so its
    # variance is d_r²/2 and the error the spread of those over sqrt(4)
    d = np.array([1.0, 2.0, 3.0, 4.0])
    values = np.concatenate([np.zeros(4), d])[:, None, None] * np.ones((1, 3, 4))
    path = write(tmp_path / "rqmc.nc", method="monte-carlo", values=values, stderr=0.0,
                 stats_attrs={"stderr_kind": "rqmc", "replicates": 4})
    res = mpm_report.load_results(trees(path))[0][0]
    err, how = mpm_report.variance_error(res, "flow_stress")
    # numpy's ddof=1 std of four numbers, divided by 2: a few roundings of numbers of order 1
    assert float(err.isel(time=1, probe=2)) == pytest.approx(np.std(d**2 / 2, ddof=1) / 2,
                                                             rel=1e-12)
    assert how == "spread of 4 replicate variances"
    # a method that reports it is believed; a method without it says so
    reported = write(tmp_path / "cvmc.nc", method="monte-carlo", stderr=1.0,
                     stats_attrs={"control": "taylor-local"},
                     extra_stats={"flow_stress_variance_stderr": (("time", "probe"),
                                                                  _field(3.0))})
    res = mpm_report.load_results(trees(reported))[0][0]
    assert float(mpm_report.variance_error(res, "flow_stress")[0].max()) == 3.0
    taylor = write(tmp_path / "taylor.nc", method="taylor")
    res = mpm_report.load_results(trees(taylor))[0][0]
    assert mpm_report.variance_error(res, "flow_stress") == (None, "not available")


# ----------------------------------------------------------------------------- Tables 3/9

def test_speedup_against_ten_thousand_runs_at_our_per_run_time(tmp_path):
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7,
               values=np.stack([_field(1e9)] * 8), wall=2.0)
    local = write(tmp_path / "local.nc", method="taylor-local", wall=2.2,
                  with_sensitivities=[True])
    text = mpm_report.cost_table(mpm_report.load_results(trees(mc, local))[0])
    # per-run time: the median of the 8 plain runs, 2 s (the sensitivity run is not plain);
    # 10,000 x 2 s = 20,000 s; speed-ups 20,000/16 = 1,250 and 20,000/2.2 = 9,091
    assert "(median run time of the 8 plain ok runs)" in text
    assert "10,000 × 2 s = 5.56 h" in text
    rows = {l.split()[0]: l for l in text.splitlines()}
    assert rows["mc.nc"].split()[-1] == "1,250" and " 8 " in rows["mc.nc"]
    assert rows["local.nc"].split()[-1] == "9,091"
    # beside them the seed's Table 9 (JC inputs): 874,579 s / 93 s = 9,404
    seed = [l for l in text.splitlines() if l.startswith("seed example 2 (Table 9)")]
    assert seed[0].split()[-1] == "9,404" and "87.5 s" in seed[1]
    assert "Table 3" not in text


def test_compile_time_is_left_out_of_every_time_and_printed_on_its_own(tmp_path):
    """Numba compiles in the first run of a process: counted there, the header's per-run time
    (a median) and the row's (a mean) disagreed, 0.975 s against 5.35 s in the quickstart.
    Every time is now a run time, wall - compile; the compile time has its own line."""
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7,
               values=np.stack([_field(1e9)] * 8), wall=[4.0] + [1.0] * 7,
               compile_time=[3.0] + [0.0] * 7)
    local = write(tmp_path / "local.nc", method="taylor-local", wall=2.5, compile_time=0.5,
                  with_sensitivities=[True])
    text = mpm_report.cost_table(mpm_report.load_results(trees(mc, local))[0])
    # run times: 8 x 1 s (mc), 2 s (local); per-run time 1 s, 10,000 x 1 s = 2.78 h; speed-ups
    # 10,000 s / 8 s = 1,250 and 10,000 s / 2 s = 5,000 (all exact in binary)
    assert "Our per-run time 1 s (median run time of the 8 plain ok runs)" in text
    assert "10,000 × 1 s = 2.78 h" in text
    rows = {l.split()[0]: l.split() for l in text.splitlines()}
    assert rows["mc.nc"][-5:] == ["8", "s", "1", "s", "1,250"]     # solver time, per run
    assert rows["local.nc"][-5:] == ["2", "s", "2", "s", "5,000"]
    compile_lines = [l for l in text.splitlines() if l.startswith("numba compile time")]
    assert len(compile_lines) == 1 and compile_lines[0].endswith("mc.nc 3 s, local.nc 0.5 s")
    assert "no compile time recorded" not in text


def test_the_header_and_the_row_of_one_result_give_the_same_per_run_time(tmp_path):
    """The quickstart's control run (with sensitivities, slower) counted in the row's median
    but not in the header's: 1.03 s against 1.02 s. One definition for both."""
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7,
               values=np.stack([_field(1e9)] * 4), wall=[6.0, 1.0, 1.0, 2.0],
               compile_time=0.0, with_sensitivities=[True, False, False, False])
    text = mpm_report.cost_table(mpm_report.load_results(trees(mc))[0])
    # plain runs 1, 1, 2 s: median 1 s in the header and in the row (the control run's 6 s
    # would make the row's median of all four 1.5 s)
    assert "Our per-run time 1 s (median run time of the 3 plain ok runs)" in text
    row = next(l.split() for l in text.splitlines() if l.startswith("mc.nc"))
    assert row[-3:-1] == ["1", "s"]


def test_a_result_without_compile_times_falls_back_to_wall_times_and_says_so(tmp_path):
    old = write(tmp_path / "old.nc", method="monte-carlo", stderr=1e7,
                values=np.stack([_field(1e9)] * 3), wall=[4.0, 1.0, 1.0])
    text = mpm_report.cost_table(mpm_report.load_results(trees(old))[0])
    assert "Our per-run time 1 s" in text
    assert "old.nc" in text and "6 s" in text.splitlines()[3]
    assert ("no compile time recorded in old.nc (a result written before it was): its times "
            "are wall times and include numba's compiling") in text
    assert "numba compile time (" not in text


def test_the_seed_rows_say_why_they_differ_and_where_the_docs_explain_it(tmp_path):
    a = write(tmp_path / "mc.nc", method="monte-carlo", stderr=0.005e9,
              outputs=("flow_stress", "S11"))
    text, _ = mpm_report.report(trees(a), tmp_path, figures=False)
    why = [l for l in text.splitlines() if l.startswith("seed rows:")]
    assert len(why) == 1 and "early snapshot" in why[0] and "t = 10 µs" in why[0]
    section = mpm_report.SEED_DIFFERENCE_SECTION
    assert why[0].endswith(f'docs/mpm_report.md, "{section}"')
    headings = (ROOT / "docs" / "mpm_report.md").read_text(encoding="utf-8").splitlines()
    assert f"## {section}" in headings
    eos = write(tmp_path / "eos.nc", method="monte-carlo", stderr=0.005e9,
                parameters=["steel.eos.S1"])
    assert "seed rows:" not in mpm_report.report(trees(eos), tmp_path, figures=False)[0]


def test_an_unfinished_result_prints_its_units(tmp_path):
    """Without statistics the units were read from nowhere: "mean [-]" over seed values in
    Pa. They come from the runs (the solver template's attributes) or the scene schema."""
    unfinished = write(tmp_path / "mc.nc", method="monte-carlo", statistics=False,
                       values=np.stack([_field(1e9)] * 4),
                       status=["ok", "ok", "pending", "pending"])
    text, _ = mpm_report.report(trees(unfinished), tmp_path, figures=False)
    assert "mean [GPa], variance [GPa²]" in text and "[-]" not in text
    seed = next(l for l in text.splitlines() if l.startswith("H ") and " seed " in l)
    assert "0.91346" in seed                   # Table 6, H, C.V. 0.10 in GPa, not 913458780
    results = mpm_report.load_results(trees(unfinished))[0]
    bare = results[0].runs.copy()
    bare["flow_stress"].attrs.clear()
    results[0].runs = bare
    assert mpm_report.output_units(results, "flow_stress") == "Pa"     # the scene schema's


def test_a_result_without_its_study_text_reports_with_a_note(tmp_path):
    big = write(tmp_path / "big.nc", method="monte-carlo", stderr=1e7, study_text=False)
    text, _ = mpm_report.report(trees(big), tmp_path, figures=False)
    notes = [l for l in text.splitlines() if l.startswith("note: big.nc: the study text")]
    assert notes == ["note: big.nc: the study text (2000000 bytes) is larger than 1048576 bytes "
                     "and is not stored; its scene is identified by scene file scene.toml "
                     "(sha256 5de88107976d)"]
    tree = open_result(big)
    tree.attrs = {k: v for k, v in tree.attrs.items()
                  if k not in ("study_text_omitted", "study_read_files")}
    text, _ = mpm_report.report([tree], tmp_path, figures=False)
    assert "note: big.nc: the result stores no study text; its scene is identified by scene " \
           "'mpm: test'" in text


def test_diagnostic_outputs_are_not_compared(tmp_path):
    steps = xr.Variable(("realization", "time", "probe"), np.ones((1, TIMES.size, len(PROBES))),
                        {"units": "1", "output_kind": "diagnostic"})
    unfinished = write(tmp_path / "mc.nc", method="monte-carlo", statistics=False,
                       extra_runs={"probe_steps": steps})
    results, outputs, _ = mpm_report.load_results(trees(unfinished))
    assert outputs == ["flow_stress"]


# ----------------------------------------------------------------------------- robustness

def test_a_result_of_another_scene_is_refused_naming_the_file(tmp_path):
    a = write(tmp_path / "a.nc", method="monte-carlo", stderr=1e7)
    b = write(tmp_path / "b.nc", method="taylor", scene=("scene.toml", "f" * 64))
    with pytest.raises(StudyError) as err:
        mpm_report.report(trees(a, b), tmp_path, figures=False)
    assert str(err.value).startswith("b.nc: scene: scene file scene.toml (sha256 ffffffffffff)")
    assert "\n" not in str(err.value)
    c = write(tmp_path / "c.nc", method="taylor", outputs=("S11",))
    with pytest.raises(StudyError,
                       match=r"^c\.nc: outputs: no output in common with the results before"):
        mpm_report.report(trees(a, c), tmp_path, figures=False)


def test_cli_refuses_other_scenes_with_exit_2(tmp_path, capsys):
    from uqflow.cli import main
    a = write(tmp_path / "a.nc", method="monte-carlo", stderr=1e7)
    b = write(tmp_path / "b.nc", method="taylor", scene=("other.toml", SCENE_SHA[::-1]))
    assert main(["report", str(a), str(b), "--no-figures"]) == 2
    assert "b.nc: scene:" in capsys.readouterr().err


def test_unfinished_and_failing_results_still_report(tmp_path):
    values = np.stack([_field(1e9)] * 10)
    failed = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7, values=values,
                   status=["ok"] * 7 + ["failed"] * 3, outputs=("flow_stress", "S11"))
    unfinished = write(tmp_path / "pce.nc", method="pce", statistics=False,
                       values=np.stack([_field(1e9)] * 4),
                       status=["ok", "failed", "pending", "pending"])
    text, _ = mpm_report.report(trees(failed, unfinished), tmp_path, figures=False)
    assert "note: mc.nc: 3 of 10 runs failed; its statistics are over the others" in text
    assert "note: pce.nc: no statistics (the study did not finish): 2 runs done, 1 failed" in text
    assert "no statistics (study did not finish)" in text
    assert "note: mc.nc: S11 not in every result: not compared" in text
    assert "S11 at" not in text


# ----------------------------------------------------------------------------- figures, hook

def test_figures_are_written_and_no_pyplot_figure_is_left(tmp_path):
    import matplotlib.pyplot as plt

    open_before = plt.get_fignums()
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7,
               outputs=("flow_stress", "S11"))
    rqmc_free = write(tmp_path / "local.nc", method="taylor-local", mean=1.01e9,
                      outputs=("flow_stress", "S11"))
    _, pngs = mpm_report.report(trees(mc, rqmc_free), tmp_path / "figs")
    assert sorted(p.name for p in pngs) == sorted(
        f"mpm_{o}_{p}.png" for o in ("flow_stress", "S11") for p in PROBES)
    assert all(p.is_file() and p.stat().st_size > 0 for p in pngs)
    assert plt.get_fignums() == open_before


def test_a_result_without_moments_draws_no_empty_mean_figure(tmp_path):
    sorm = write(tmp_path / "sorm.nc", method="sorm", moments=False)
    _, pngs = mpm_report.report(trees(sorm), tmp_path / "figs")
    assert not [p for p in pngs if p.name.startswith("mpm_")]


def test_the_mpm_solver_hook_is_the_report(tmp_path):
    from uqflow.report import solver_report

    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7)
    text, pngs = solver_report(trees(mc), tmp_path, figures=False)
    assert text.startswith("MPM comparison: ") and pngs == []


# ----------------------------------------------------------------------------- real results

TINY_STUDY = """
name = "{name}"
solver = "mpm"
scene = "scene.toml"
outputs = ["flow_stress", "S11", "S22"]
[[inputs]]
name = "steel.jc.A"
distribution = "normal"
mean = 792.0e6
cv = 0.10
[method]
{method}
[execution]
workers = 0
[output]
path = "{name}.nc"
figures = false
"""


@pytest.mark.slow
def test_real_tiny_mpm_results_report(tmp_path):
    """Two tiny real studies (thin plate, resolution 0.25, 5 µs): the report reads what
    uqflow.store writes for MPM results."""
    from uqflow.execute import run_study
    from uqflow.study import load_study

    scene = (ROOT / "studies" / "scenes" / "mpm_contact_thin_small.toml").read_text()
    scene = scene.replace("resolution = 1.0", "resolution = 0.25")
    scene = scene.replace("end_time = 100e-6", "end_time = 5e-6")
    (tmp_path / "scene.toml").write_text(scene)
    paths = []
    for name, method in (("mc", 'kind = "monte-carlo"\nsamples = 16\nrule = "sobol"'),
                         ("taylor", 'kind = "taylor"\nvariance = "first-order"')):
        study = tmp_path / f"{name}.toml"
        study.write_text(TINY_STUDY.format(name=name, method=method))
        paths.append(run_study(load_study(study), workers=0, show_progress=False).path)
    text, pngs = mpm_report.report(trees(*paths), tmp_path / "figs")
    assert "C.V. 0.1: reference mc.nc (monte-carlo sobol 16)" in text
    assert "t = 5 µs (the last output time)" in text
    assert len(pngs) == 13 and all(p.stat().st_size > 0 for p in pngs)
    assert pngs[0].name == "scene_map.png"        # the scene the studies read, drawn


def test_module_command_line_takes_time_and_reference(tmp_path, capsys):
    small = write(tmp_path / "mc_small.nc", method="monte-carlo", mean=1.01e9, stderr=0.02e9)
    big = write(tmp_path / "mc_big.nc", method="monte-carlo", stderr=0.005e9)
    argv = [str(small), str(big), "--time", "4e-6", "--reference", "mc_small", "--no-figures"]
    assert mpm_report.main(argv) == 0
    out = capsys.readouterr().out
    assert "t = 5 µs (the output time nearest the requested 4 µs)" in out
    assert "C.V. 0.1: reference mc_small.nc" in out
    other = write(tmp_path / "other.nc", method="taylor", scene=("x.toml", "0" * 64))
    assert mpm_report.main([str(big), str(other), "--no-figures"]) == 2
    assert capsys.readouterr().err.startswith("error: other.nc: scene:")


def test_uqflow_report_takes_time_and_reference(tmp_path, capsys):
    from uqflow.cli import main
    small = write(tmp_path / "mc_small.nc", method="monte-carlo", mean=1.01e9, stderr=0.02e9)
    big = write(tmp_path / "mc_big.nc", method="monte-carlo", stderr=0.005e9)
    argv = ["report", str(small), str(big), "--time", "4e-6", "--reference", "mc_small",
            "--no-figures"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "t = 5 µs (the output time nearest the requested 4 µs)" in out
    assert "C.V. 0.1: reference mc_small.nc" in out
