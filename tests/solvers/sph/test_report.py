"""`uqflow report` on sph results (solvers/sph/report.py)."""

import ast
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from solvers.sph.report import clopper_pearson, composite_figure, detach_counts, report

EPS = np.finfo(float).eps


def fake_runs(detached, E=None, level=None):
    detached = np.asarray(detached, float)
    r, s = detached.shape
    E = np.linspace(1.3e6, 1.5e6, r) if E is None else np.asarray(E, float)
    runs = xr.Dataset({
        "status": ("realization", np.array(["ok"] * r)),
        "effective_modulus": ("realization", E),
        "modulus_reuss_bound": ("realization", np.full(r, 1.0e6)),
        "modulus_voigt_bound": ("realization", np.full(r, 1.4e6)),
        "modulus_hs_lower": ("realization", np.full(r, 1.2e6)),
        "modulus_hs_upper": ("realization", np.full(r, 3.0e6)),
        "volume_fraction": ("realization", np.full(r, 0.1)),
        "strain": (("realization", "step"), np.tile(np.arange(1, s + 1) * 1e-3, (r, 1))),
        "macro_stress": (("realization", "step"), np.tile(np.arange(1, s + 1) * 1e3, (r, 1))),
        "detached_inclusions": (("realization", "step"), detached)})
    if level is not None:
        runs["level"] = ("realization", np.asarray(level))
    return runs


def fake_tree(*args, **kwargs):
    return xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "t"}),
                                  "/runs": fake_runs(*args, **kwargs)})


def test_detach_counts_per_step():
    k, n = detach_counts(fake_runs([[0, 0, 1], [0, 1, 1], [0, 0, 0], [0, 0, 2]]))
    assert k.tolist() == [0, 1, 3] and n == 4


@pytest.mark.numerics
def test_clopper_pearson_meets_its_closed_forms_and_the_beta_quantiles():
    n = np.array([1, 6, 50, 1000])
    lo, hi = clopper_pearson(np.zeros(4, int), n)
    # k = 0: P(0 of n) = (1 - p)^n = alpha/2 at the upper end. 1 - x cancels by c = x/(1 - x)
    # (270 at n = 1000): 4 ulp of the power and ~100 eps of scipy's inverse beta, both times c
    x = 0.025 ** (1 / n)
    cancel = 1 + x / (1 - x)
    np.testing.assert_array_less(np.abs(hi - (1 - x)), 104 * cancel * EPS * (1 - x))
    assert (lo == 0).all()
    assert hi[1] == pytest.approx(0.4593, abs=5e-5)      # "0 of 6: [0, 0.46]"
    lo, hi = clopper_pearson(n, n)                        # k = n mirrors k = 0
    np.testing.assert_array_less(np.abs(lo - x), 104 * EPS * x)   # no cancellation here
    assert (hi == 1).all()
    # 3 of 10: scipy.stats.binomtest(3, 10).proportion_ci('exact') = [0.0667, 0.6525]
    lo, hi = clopper_pearson(3, 10)
    assert (lo, hi) == (pytest.approx(0.0667, abs=5e-5), pytest.approx(0.6525, abs=5e-5))


def test_report_states_a_proportion_with_its_exact_interval(tmp_path):
    text, pngs = report([fake_tree(np.zeros((6, 3)))], tmp_path)
    assert "P(an inclusion fully debonded by 0.3 % strain): 0 of 6, 95% CI [0, 0.459] " \
           "(Clopper-Pearson)" in text
    assert "±" not in text.split("P(an inclusion")[1]
    assert len(pngs) == 1 and pngs[0].exists()


def test_report_counts_each_window_within_its_voigt_reuss_bounds(tmp_path):
    E = [0.9e6, 1.0e6, 1.3e6, 1.4e6, 1.5e6]                # 1.0 and 1.4 on a bound: within
    text, _ = report([fake_tree(np.zeros((5, 3)), E=E)], tmp_path, figures=False)
    assert "within its own Voigt-Reuss bounds (each window, its phase areas): 3 of 5" in text
    assert "Hashin-Shtrikman" in text and "not each window" in text


def test_report_puts_the_ensemble_mean_against_the_hashin_shtrikman_bounds(tmp_path):
    def verdict(E):
        text, _ = report([fake_tree(np.zeros((len(E), 1)), E=E)], tmp_path, figures=False)
        return text.split("ensemble mean ")[1].split(" the Hashin")[0]
    # HS lower 1.2e6; standard error of the mean of (a, b) = |a - b| / 2
    assert verdict([1.25e6, 1.27e6]) == "within"
    assert verdict([1.17e6, 1.21e6]) == "consistent with (within 2 standard errors of)"
    assert verdict([1.10e6, 1.12e6]) == "outside"


def test_a_multilevel_result_is_reported_level_by_level(tmp_path):
    detached = np.zeros((6, 2))
    detached[:2, 1] = 1                                    # level 0's two runs debond
    tree = fake_tree(detached, E=[1.1e6, 1.1e6, 1.3e6, 1.3e6, 1.3e6, 1.3e6],
                     level=[0, 0, 1, 1, 1, 1])
    text, pngs = report([tree], tmp_path)
    assert "6 runs over 2 levels, reported per level" in text
    assert "t, level 0: 2 realizations" in text and "t, level 1: 4 realizations" in text
    assert "2 of 2, 95% CI" in text and "0 of 4, 95% CI" in text
    assert "of 6" not in text                               # never pooled
    assert len(pngs) == 2


def test_the_figures_speak_in_words_with_readable_units():
    fig = composite_figure(fake_runs(np.zeros((4, 3))))
    stress, modulus, debonding = fig.axes[:3]
    # macro_stress 1e3 .. 3e3 Pa, moduli 1.3e6 .. 1.5e6 Pa, strain 0.1 .. 0.3 %
    assert stress.get_xlabel() == "applied strain [%]"
    assert stress.get_ylabel() == "mean tensile stress σ_yy of the plate [kPa]"
    assert stress.get_lines()[0].get_xdata() == pytest.approx([0.1, 0.2, 0.3])
    assert modulus.get_ylabel() == "apparent Young's modulus [MPa]"
    assert debonding.get_xlabel() == "applied strain [%]"
    band = stress.collections[0].get_label()
    assert band == "95% of the realizations (2.5–97.5 % quantiles)"


def test_the_text_gives_the_modulus_in_readable_units(tmp_path):
    text, _ = report([fake_tree(np.zeros((5, 3)))], tmp_path, figures=False)
    assert "apparent Young's modulus: mean 1.4 MPa, standard deviation 0.07906 MPa, " \
           "standard error of the mean 0.0354 MPa" in text
    assert "seed" not in text.lower()      # no seed table is compared here: no seed named


SPH = Path(__file__).resolve().parents[3] / "solvers" / "sph"


def test_the_sph_package_imports_only_public_uqflow_names():
    for module in SPH.glob("*.py"):
        for node in ast.walk(ast.parse(module.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("uqflow"):
                assert not node.module.startswith("uqflow.report."), (module.name, node.module)
                assert all(not a.name.startswith("_") for a in node.names), module.name
