"""The gamut-bar report (solvers/gamut_bar/report.py): seed 002's Table 1 beside ours, the
mean monotonic curve, the figures. Tiny studies (40 local bonds, 3 cycles, 3 realizations)
run in-process into a temporary folder."""

from __future__ import annotations

import filecmp
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import uqflow
from solvers.gamut_bar import GamutBarSolver
from solvers.gamut_bar import report as gb
from uqflow.execute import run_study
from uqflow.study import load_study

from ._common import field_table

ROOT = Path(__file__).resolve().parents[3]

FIELDS = "".join(field_table(name, params, correlation_length=0.01, captured_variance=0.95)
                 for name, params in (("E", '["bar.E", "bar.rho"]'), ("R", '["bar.R"]'),
                                      ("w", '["bar.w"]')))

# (material, extra scene text, loading, grid, stochastic)
CASES = [
    ("M1", "", "monotonic", "uniform", True),
    ("M1", "", "monotonic", "uniform", False),
    ("M1", "", "cyclic", "uniform", True),
    ("M1", "", "cyclic", "uniform", False),
    ("M1", "", "cyclic", "stochastic", True),
    ("M2", ", n_ro = 21.0", "cyclic", "uniform", True),
]


def _write_study(folder: Path, material, extra, loading, grid, stochastic) -> Path:
    kind = "stochastic" if stochastic else "deterministic"
    name = f"t-{material.lower()}{'-nro21' if extra else ''}-{loading}-{kind}-{grid}"
    cycles = ", cycles = 3" if loading == "cyclic" else ""
    method = (FIELDS + '\n[method]\nkind = "kl-weibull"\nrealizations = 3\n' if stochastic
              else '\n[method]\nkind = "nominal"\n')
    text = (f'name = "{name}"\nsolver = "gamut_bar"\n'
            f'scene = {{ material = "{material}"{extra}, local_bonds = 40, grid = "{grid}", '
            f'loading = "{loading}"{cycles} }}\n{method}\n'
            f'[execution]\nseed = 5\nworkers = 0\n\n'
            f'[output]\npath = "out/{name}.nc"\nfigures = false\n')   # relative to the study
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gamut_report")
    paths = []
    for case in CASES:
        outcome = run_study(load_study(_write_study(folder, *case)), workers=0,
                            show_progress=False)
        assert outcome.path == folder / "out" / outcome.path.name
        paths.append(outcome.path)
    return paths


@pytest.fixture(scope="module")
def trees(results):
    return [uqflow.open_result(p) for p in results]


def _by_name(trees, part):
    return next(t for t in trees if t.attrs["study_name"] == f"t-{part}")


def _ok_mean(tree, name):
    runs = tree["runs"].to_dataset()
    ok = runs["status"].values.astype(str) == "ok"
    return float(np.asarray(runs[name].values)[ok].mean())


# ----------------------------------------------------------------------------- seed numbers

def test_seed_numbers_are_an_exact_copy_of_the_shipped_file():
    copy = ROOT / "solvers" / "gamut_bar" / "data" / "seed_tables.toml"
    assert filecmp.cmp(copy, ROOT / "tests" / "data" / "seed_tables.toml", shallow=False)
    seed = gb.seed_tables()
    assert seed["table1_material1"]["stochastic_grid"][0] == 0.0777
    assert seed["table1_material2"]["experimental_K_range"] == [1340.5e6, 1537.6e6]


# ----------------------------------------------------------------------------- identify

def test_results_are_identified_from_their_study_text(trees):
    found = {(r.case, r.loading, r.grid, r.stochastic, r.n_ok, r.total)
             for r in map(gb.identify, trees)}
    assert found == {
        ("M1", "monotonic", "uniform", True, 3, 3), ("M1", "monotonic", "uniform", False, 1, 1),
        ("M1", "cyclic", "uniform", True, 3, 3), ("M1", "cyclic", "uniform", False, 1, 1),
        ("M1", "cyclic", "stochastic", True, 3, 3),
        ("M2 (n_ro = 21)", "cyclic", "uniform", True, 3, 3)}
    nro21 = gb.identify(_by_name(trees, "m2-nro21-cyclic-stochastic-uniform"))
    assert nro21.overrides == {"n_ro": 21.0} and nro21.slug == "m2_nro21"


def test_a_result_is_identified_with_its_recorded_set_overrides(trees):
    # --set scene.n_ro=25 ran another case than the study text says: the case names it
    tree = _by_name(trees, "m1-monotonic-stochastic-uniform").copy()
    tree.attrs = dict(tree.attrs, study_overrides="scene.n_ro = 25.0\n")
    assert gb.identify(tree).case == "M1 (n_ro = 25)"


def test_other_solvers_give_nothing(trees):
    tree = trees[0].copy()
    tree.attrs = dict(tree.attrs, solver="analytic")
    assert gb.identify(tree) is None
    assert GamutBarSolver.report([tree], Path("unused")) == ("", [])


# ----------------------------------------------------------------------------- the table

def test_table1_has_the_seeds_numbers_and_ours(trees, tmp_path):
    text, _ = GamutBarSolver.report(trees, tmp_path, figures=False)
    seed = gb.seed_tables()
    m1, m2 = seed["table1_material1"], seed["table1_material2"]
    # the seed's numbers, as it prints them (K' in MPa)
    for value in (m1["stochastic_grid"][0], m1["uniform_grid"][0], m1["deterministic"][0],
                  m1["experimental"][0], m2["stochastic_grid"][0], m2["deterministic"][0],
                  m2["experimental_n"]):
        assert f"{value:.10g}" in text
    for value in (m1["stochastic_grid"][1], m1["uniform_grid"][1], m2["uniform_grid"][1]):
        assert f"{value / 1e6:.10g}" in text
    assert "1340.5–1537.6" in text
    # ours beside them, with the relative difference
    table1 = text.split("Table 1")[1].split("n' and K' over")[0]
    for name, column, q in (("m1-cyclic-stochastic-uniform", "uniform_grid", "n"),
                            ("m1-cyclic-stochastic-stochastic", "stochastic_grid", "n"),
                            ("m1-cyclic-deterministic-uniform", "deterministic", "n"),
                            ("m1-cyclic-stochastic-uniform", "uniform_grid", "K")):
        tree = _by_name(trees, name)
        ours = _ok_mean(tree, "n_prime" if q == "n" else "K_prime")
        ref = m1[column][0 if q == "n" else 1]
        shown = f"{ours:.4g}" if q == "n" else f"{ours / 1e6:.1f}"
        rel = f"{100 * (ours / ref - 1):+.1f} %"
        ref_text = f"{ref:.10g}" if q == "n" else f"{ref / 1e6:.10g}"
        assert f"{shown} / {ref_text} ({rel})" in table1
    rows = [line for line in table1.splitlines()
            if line.startswith(("M1 ", "M2 ")) and " / " in line]
    assert [r.split("  ")[0] for r in rows] == [
        "M1 n'", "M1 K' [MPa]", "M2 n'", "M2 K' [MPa]", "M2 (n_ro = 21) n'",
        "M2 (n_ro = 21) K' [MPa]"]
    # M2 as printed was not given: the seed's numbers only
    assert "– / 0.0381" in rows[2]
    ours_21 = _ok_mean(_by_name(trees, "m2-nro21-cyclic-stochastic-uniform"), "n_prime")
    assert f"{ours_21:.4g} / 0.0481" in rows[4]
    assert "stochastic grid" in table1.splitlines()[2] and "experimental" in table1


def test_monotonic_tables(trees, tmp_path):
    text, _ = GamutBarSolver.report(trees, tmp_path, figures=False)
    sto = _by_name(trees, "m1-monotonic-stochastic-uniform")
    runs = sto["runs"].to_dataset()
    failure = float(runs["failure_strain"].mean())
    assert "Failure" in text and f"{failure:.4g}" in text
    mean, count = gb.mean_curve(runs, gb.STRAINS)
    curves = text.split("Monotonic curves")[1]
    for eps, m, c in zip(gb.STRAINS, mean, count):
        line = next(x for x in curves.splitlines() if x.split()[:3] == ["M1", "uniform",
                                                                           f"{eps:g}"])
        assert f"{c} of 3" in line
        if c:
            assert f"{m / 1e6:.1f}" in line
        else:
            assert " – " in line
    # the strains beyond every realization's failure count none
    fs = runs["failure_strain"].values
    assert list(count) == [int((fs >= e).sum()) for e in gb.STRAINS]


def test_without_a_deterministic_result_its_columns_are_left_out(trees, tmp_path):
    """A study of random fields alone has no deterministic counterpart: its curve table
    printed "mean/det. - 1 ... +nan %". The columns against the deterministic bar are left
    out, with a note; with a deterministic result they are there, and never NaN."""
    alone = _by_name(trees, "m1-monotonic-stochastic-uniform")
    text, _ = GamutBarSolver.report([alone], tmp_path, figures=False)
    assert "nan" not in text.lower()
    assert "mean/det." not in text and "deterministic [MPa]" not in text
    assert text.count(gb.NO_DETERMINISTIC_NOTE) == 2          # curve and failure tables
    assert "mean/RO - 1" in text
    both = [alone, _by_name(trees, "m1-monotonic-deterministic-uniform")]
    text, _ = GamutBarSolver.report(both, tmp_path, figures=False)
    assert "mean/det. - 1" in text and "nan" not in text.lower()
    assert gb.NO_DETERMINISTIC_NOTE not in text
    assert gb._rel(1.0, float("nan")) == "" and gb._rel(float("nan"), 1.0) == ""


def _without_study(tree, **attrs):
    kept = {k: v for k, v in tree.attrs.items() if k != "study"}
    return xr.DataTree.from_dict({"/": xr.Dataset(attrs={**kept, **attrs}),
                                  "runs": tree["runs"].to_dataset()})


def test_a_result_without_its_study_text_reports_with_a_note(trees, tmp_path):
    """A study text larger than 1 MiB is not stored (its hash is): the case is read from the
    solver's description, and the report says so in one line; without that either, the
    result is left out, one line; nothing crashes."""
    omitted = ("the study text (2000000 bytes) is larger than 1048576 bytes and is not "
               "stored; study_text_sha256 identifies it")
    big = _without_study(_by_name(trees, "m1-monotonic-stochastic-uniform"),
                         study_text_omitted=omitted)
    text, _ = GamutBarSolver.report([big], tmp_path, figures=False)
    assert ("t-m1-monotonic-stochastic-uniform: the study text (2000000 bytes) is larger than "
            "1048576 bytes and is not stored; its case is read from the solver's description, "
            "which names no property override (such as n_ro)") in text
    assert gb.identify(big).describe() == "M1, uniform grid, monotonic"
    bare = _without_study(_by_name(trees, "m1-cyclic-stochastic-uniform"),
                          solver_description="gamut_bar")
    text, pngs = GamutBarSolver.report([big, bare], tmp_path, figures=False)
    assert ("note: t-m1-cyclic-stochastic-uniform: the result stores no study text, and the "
            "solver's description names no case: left out") in text
    assert "cyclic" not in text.split("gamut_bar results")[1].split("\n\n")[0]
    assert GamutBarSolver.report([bare], tmp_path) == (
        "note: t-m1-cyclic-stochastic-uniform: the result stores no study text, and the "
        "solver's description names no case: left out", [])


def test_a_failed_realization_is_left_out(trees, tmp_path):
    tree = _by_name(trees, "m1-cyclic-stochastic-uniform")
    runs = tree["runs"].to_dataset()
    status = runs["status"].values.astype(object)
    status[0] = "failed"
    runs["status"] = ("realization", status.astype(str))
    runs["n_prime"] = runs["n_prime"].where(runs["status"] == "ok")
    broken = xr.DataTree.from_dict({"/": xr.Dataset(attrs=dict(tree.attrs)), "runs": runs})
    text, _ = GamutBarSolver.report([broken], tmp_path, figures=False)
    expected = float(runs["n_prime"].values[1:].mean())
    assert f"{expected:.4g} / 0.0612" in text
    assert "means over the 2 of 3 realizations" in text


# ----------------------------------------------------------------------------- mean_curve

def _paths(*paths, status=None):
    steps = max(len(p[0]) for p in paths)
    e = np.full((len(paths), steps), np.nan)
    s = np.full((len(paths), steps), np.nan)
    for k, (pe, ps) in enumerate(paths):
        e[k, :len(pe)], s[k, :len(ps)] = pe, ps
    ds = xr.Dataset({"strain": (("realization", "step"), e),
                     "stress": (("realization", "step"), s)})
    if status is not None:
        ds["status"] = ("realization", np.array(status))
    return ds


def test_mean_curve_interpolates_exactly_and_counts_the_survivors():
    a = ([0.0, 0.01, 0.03], [0.0, 100.0, 300.0])          # fails at 0.03
    b = ([0.0, 0.02, 0.06, 0.08], [0.0, 400.0, 800.0, 900.0])
    c = ([0.0, 0.05], [0.0, 1000.0])                        # failed run: never counts
    runs = _paths(a, b, c, status=["ok", "ok", "failed"])
    mean, count = gb.mean_curve(runs, [0.0, 0.005, 0.02, 0.03, 0.05, 0.08, 0.1])
    # a at 0.005: 50; b: 100 -> 75. At 0.02: a 200, b 400. At 0.03: a 300 (its last state),
    # b 500. At 0.05: b only, 700. At 0.08: b's last state. 0.1: nobody.
    np.testing.assert_array_equal(count, [2, 2, 2, 2, 1, 1, 0])
    # each value: a linear interpolation (≤ 4 roundings) and a mean of two (2 more): ≤ 6 eps
    np.testing.assert_allclose(mean[:6], [0.0, 75.0, 300.0, 400.0, 700.0, 900.0], rtol=1e-14)
    assert np.isnan(mean[6])


def test_mean_curve_without_status_and_single_run():
    runs = _paths(([0.0, 0.1], [0.0, 10.0]), ([0.0, 0.2], [0.0, 40.0]))
    mean, count = gb.mean_curve(runs, [0.05, 0.15])
    np.testing.assert_allclose(mean, [(5.0 + 10.0) / 2, 30.0])
    np.testing.assert_array_equal(count, [2, 1])
    single = xr.Dataset({"strain": ("step", [0.0, 0.1]), "stress": ("step", [0.0, 10.0])})
    mean, count = gb.mean_curve(single, 0.025)
    assert mean.tolist() == [2.5] and count.tolist() == [1]


def test_mean_curve_on_a_result_matches_numpy_interp(trees):
    runs = _by_name(trees, "m1-monotonic-stochastic-uniform")["runs"].to_dataset()
    strains = [0.003, 0.01]
    mean, count = gb.mean_curve(runs, strains)
    by_hand = [np.interp(strains, runs["strain"].values[r], runs["stress"].values[r])
               for r in range(3)]
    # the same interpolation and 3-term mean in another order: ≤ 2 × 7 eps ≈ 3e-15
    np.testing.assert_allclose(mean, np.mean(by_hand, axis=0), rtol=1e-12)
    assert count.tolist() == [3, 3]


# ----------------------------------------------------------------------------- figures

PNG = b"\x89PNG\r\n\x1a\n"


def test_figures_are_pngs(trees, tmp_path):
    folder = tmp_path / "figs"
    _, pngs = GamutBarSolver.report(trees, folder)
    names = {p.name for p in pngs}
    assert names == {
        *(f"bar_fields_{t.attrs['study_name']}.png" for t in trees),
        "gamut_bar_m1_uniform_monotonic.png",
        *(f"gamut_bar_m1_{g}_cyclic_{k}.png" for g in ("uniform", "stochastic")
          for k in ("loops", "loglog", "constants")),
        *(f"gamut_bar_m2_nro21_uniform_cyclic_{k}.png" for k in ("loops", "loglog",
                                                                 "constants"))}
    from matplotlib.image import imread
    for p in pngs:
        assert p.parent == folder and p.read_bytes()[:8] == PNG
        image = imread(p)
        assert image.shape[0] > 300 and image.shape[1] > 500


def test_only_what_the_results_allow(trees, tmp_path):
    det = [_by_name(trees, "m1-monotonic-deterministic-uniform"),
           _by_name(trees, "m1-cyclic-deterministic-uniform")]
    text, pngs = GamutBarSolver.report(det, tmp_path)
    # no per-realization constants without stochastic results; loops of the deterministic run
    assert sorted(p.name for p in pngs) == [
        "bar_fields_t-m1-cyclic-deterministic-uniform.png",
        "bar_fields_t-m1-monotonic-deterministic-uniform.png",
        "gamut_bar_m1_uniform_cyclic_loglog.png", "gamut_bar_m1_uniform_cyclic_loops.png",
        "gamut_bar_m1_uniform_monotonic.png"]
    assert "n' and K' over the realizations" not in text
    assert "0.06244 (" in text                         # the deterministic column
    _, seed_only = gb.report(det, tmp_path / "seed", solver_class=GamutBarSolver,
                             bar_fields=False)          # benchmarks/gamut_bar_table1.py
    assert sorted(p.name for p in seed_only) == sorted(p.name for p in pngs)[2:]
    mono = [_by_name(trees, "m1-monotonic-deterministic-uniform")]
    text, pngs = GamutBarSolver.report(mono, tmp_path / "none", figures=False)
    assert pngs == [] and not (tmp_path / "none").exists()
    assert "Table 1" not in text and "Monotonic curves" in text


def test_cli_report_returns_0(results, tmp_path, capsys):
    from uqflow.cli import main

    assert main(["report", *map(str, results), "--no-figures"]) == 0
    out = capsys.readouterr().out
    assert all(f"== {p}" in out for p in results)


# ----------------------------------------------------------------------------- for engineers

def test_figures_speak_in_words_and_percent(trees):
    idx = gb._Index([gb.identify(t) for t in trees])
    mono = gb._fig_monotonic(idx, "M1", "uniform")
    loglog = gb._fig_loglog(idx, "M1", "uniform")
    constants = gb._fig_constants(idx, "M1", "uniform", gb.seed_tables())
    labels = {(ax.get_xlabel(), ax.get_ylabel()) for fig in (mono, loglog, constants)
              for ax in fig.axes}
    assert labels == {("strain [%]", "stress [MPa]"),
                      ("plastic strain amplitude [%]", "stress amplitude [MPa]"),
                      ("", "cyclic strain hardening exponent n' [-]"),
                      ("realization", "cyclic strength coefficient K' [MPa]")}
    # strains drawn in percent: the deterministic curve ends at 100 × its failure strain
    det = _by_name(trees, "m1-monotonic-deterministic-uniform")
    failure = float(det["runs"]["failure_strain"].values[0])
    (line,) = [ln for ln in mono.axes[0].lines if ln.get_label() == "deterministic"]
    assert line.get_xdata()[-1] == pytest.approx(100 * failure, rel=1e-12)  # ×100, rounding
    for fig in (mono, loglog, constants):        # the seed named, and said what it is
        assert fig.get_supxlabel() == gb.SEED_LINE
        assert "seed 002" in (fig.get_suptitle() + fig.axes[0].get_title())


def test_the_text_says_once_what_seed_002_is(trees, tmp_path):
    text, _ = GamutBarSolver.report(trees, tmp_path, figures=False)
    assert text.startswith("seed 002: the stochastic nonlocal deformation-gamut bar")
    assert text.count("deformation-gamut bar") == 1


def test_the_report_uses_public_report_names_only():
    """Only names uqflow.report exports, imported at module level from the package itself."""
    import ast

    import uqflow.report

    for path in (ROOT / "solvers" / "gamut_bar").glob("*.py"):
        tree = ast.parse(path.read_text())
        top = set(map(id, tree.body))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("uqflow"):
                assert id(node) in top, f"{path.name}:{node.lineno}: function-level import"
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                    "uqflow.report"):
                assert node.module == "uqflow.report", f"{path.name}: {node.module}"
                for alias in node.names:
                    assert alias.name in uqflow.report.__all__, f"{path.name}: {alias.name}"


def test_a_study_storing_scalars_alone_reports_without_the_curve(trees, tmp_path):
    """A reliability study stores what its limit state needs (failure_strain) and no
    stress-strain path: the report leaves the mean curve out instead of failing on it."""
    full = _by_name(trees, "m1-monotonic-stochastic-uniform")
    runs = full["runs"].to_dataset().drop_vars(["strain", "stress"])
    scalars = xr.DataTree.from_dict({"/": xr.Dataset(attrs=dict(full.attrs)), "runs": runs,
                                     "statistics": full["statistics"].to_dataset()})
    text, _ = GamutBarSolver.report([scalars], tmp_path, figures=True)
    assert "Monotonic curves" not in text and "failure" in text.lower()
    text, _ = GamutBarSolver.report([full], tmp_path, figures=False)
    assert "Monotonic curves" in text
