"""The kl-weibull method: design layout, reproducible germs, Monte Carlo statistics over field
realizations, and its checks.

Designs are evaluated in-process: by hand on a trivial runs dataset, and once through
``evaluate_design`` with a small solver that reads its fields from a ``FieldSample``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pydantic
import pytest
import xarray as xr

from uqflow.errors import StudyError
from uqflow.fields import FieldSample, FieldSpec, GermSpec, RandomField, germ_seed
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import get_method
from uqflow.methods.base import output_names
from uqflow.methods.kl_weibull import KLWeibull
from uqflow.methods.monte_carlo import MonteCarlo
from uqflow.fields import germ_variable
from uqflow.realization import evaluate_design
from uqflow.sampling import unit_hypercube

POINTS = np.linspace(0.0, 1.0, 41)


def normal(name, mean, std):
    return RandomInput.from_spec({"name": name, "distribution": "normal", "mean": mean,
                                  "std": std})


def two_fields():
    e = RandomField(FieldSpec(name="bar.E", correlation_length=0.2), POINTS)
    r = RandomField(FieldSpec(name="rho", parameters=["bar.rho"], correlation_length=0.6,
                              germ=GermSpec(kind="gaussian"), cv=0.05), POINTS)
    return [e, r]


def plan(n=10, seed=0, space=None, fields=None):
    method = KLWeibull(realizations=n)
    space = InputSpace([normal("F", 100.0, 5.0), normal("A", 1e-4, 1e-6)]) \
        if space is None else space
    fields = two_fields() if fields is None else fields
    return method, method.plan(space, fields, np.random.SeedSequence(seed)), fields


def test_registered_and_options():
    assert get_method("kl-weibull") is KLWeibull
    m = KLWeibull()
    assert m.options.realizations == 30 and m.options.samples == 30
    assert m.options.rule == "random" and m.options.quantiles == [0.05, 0.5, 0.95]
    assert KLWeibull(quantiles=[0.9, 0.1, 0.1]).options.quantiles == [0.1, 0.9]
    for bad in ({"samples": 10}, {"realizations": 0}, {"rule": "sobol"},
                {"quantiles": [1.5]}, {"confidence": 1.0}):
        with pytest.raises(pydantic.ValidationError):
            KLWeibull(**bad)


def test_plan_layout():
    method, design, (e, r) = plan(n=12)
    assert design.sizes["realization"] == 12
    assert design["inputs"].shape == (12, 2)
    ge, gr = design[germ_variable("bar.E")], design[germ_variable("rho")]
    assert ge.name == "germ_bar_E" and ge.dims == ("realization", "mode_bar_E")
    assert ge.shape == (12, e.n_modes) and gr.shape == (12, r.n_modes)
    assert ge.attrs["field"] == "bar.E" and gr.attrs["germ"] == "gaussian"
    assert json.loads(design.attrs["fields"]) == {"bar.E": "germ_bar_E", "rho": "germ_rho"}
    assert design.attrs["field_bar_E_modes"] == e.n_modes
    assert design.attrs["field_bar_E_captured_fraction"] == pytest.approx(e.captured_fraction)
    assert design.attrs["field_bar_E_captured_fraction"] >= 0.95
    assert design.attrs["field_rho_parameters"] == "bar.rho"
    assert design.attrs["rule"] == "random"
    # Symmetric-Weibull germs: both signs, |ξ| > 0.
    assert (ge.values > 0).any() and (ge.values < 0).any() and np.all(ge.values != 0)
    # The germs are not outputs.
    assert output_names(design) == []


def test_scalar_inputs_are_monte_carlo_random_samples():
    space = InputSpace([normal("F", 100.0, 5.0), normal("A", 1e-4, 1e-6)])
    _, design, _ = plan(n=16, seed=3, space=space)
    u = unit_hypercube("random", 16, 2, np.random.SeedSequence(3))
    np.testing.assert_array_equal(design["inputs"].values, space.from_unit_hypercube(u))
    mc = MonteCarlo(samples=16, rule="random").plan(space, None, np.random.SeedSequence(3))
    np.testing.assert_array_equal(design["inputs"].values, mc["inputs"].values)


def test_no_scalar_inputs():
    _, design, fields = plan(n=5, space=InputSpace([]))
    assert design["inputs"].shape == (5, 0) and design.sizes["parameter"] == 0
    assert design[germ_variable("bar.E")].shape == (5, fields[0].n_modes)


def test_germs_come_from_germ_seed():
    _, design, fields = plan(n=6, seed=11)
    seed = np.random.SeedSequence(11)
    for k, f in enumerate(fields):
        for i in (0, 5):
            expect = f.spec.germ.draw(f.n_modes, np.random.default_rng(germ_seed(seed, i, k)))
            np.testing.assert_array_equal(design[germ_variable(f.name)].values[i], expect)


def test_reproducible_and_independent_of_design_size():
    _, a, _ = plan(n=10, seed=5)
    _, b, _ = plan(n=30, seed=5)
    _, again, _ = plan(n=10, seed=5)
    xr.testing.assert_identical(a, again)
    for var in ("germ_bar_E", "germ_rho", "inputs"):
        np.testing.assert_array_equal(a[var].values, b[var].values[:10])
    _, other, _ = plan(n=10, seed=6)
    assert not np.array_equal(a["germ_bar_E"].values, other["germ_bar_E"].values)
    # Rows differ from each other (a fresh stream per realization).
    g = a["germ_bar_E"].values
    assert len({tuple(row) for row in g}) == 10


def test_seed_object_not_consumed():
    seed = np.random.SeedSequence(9)
    method, fields = KLWeibull(realizations=4), two_fields()
    space = InputSpace([normal("F", 1.0, 0.1)])
    first = method.plan(space, fields, seed)
    second = method.plan(space, fields, seed)
    xr.testing.assert_identical(first, second)


def test_check_needs_fields():
    space = InputSpace([normal("F", 1.0, 0.1)])
    for fields in (None, []):
        with pytest.raises(StudyError) as err:
            KLWeibull().check(space, fields)
        assert err.value.key == "fields"
        with pytest.raises(StudyError):
            KLWeibull().plan(space, fields, np.random.SeedSequence(0))
    KLWeibull().check(space, two_fields())
    # Field names that map to the same design variable are refused.
    clash = [RandomField(FieldSpec(name=n, correlation_length=0.3), POINTS)
             for n in ("a.b", "a_b")]
    with pytest.raises(StudyError, match="share the design variable"):
        KLWeibull().check(space, clash)
    # At load time the study may hand over field tables.
    KLWeibull().check(space, [{"name": "E"}])


def fake_runs(design, y, status=None):
    runs = design.copy()
    n = design.sizes["realization"]
    runs["y"] = ("realization", np.asarray(y, dtype=float), {"units": "m"})
    runs["status"] = ("realization", np.array(status if status is not None else ["ok"] * n,
                                              dtype=object))
    runs["message"] = ("realization", np.full(n, "", dtype=object))
    runs["wall_time"] = ("realization", np.full(n, 0.01), {"units": "s"})
    return runs


def test_analyze_trivial_runs():
    method, design, _ = plan(n=20, seed=1)
    y = design["germ_bar_E"].values[:, 0] + design["inputs"].values[:, 0]
    stats = method.analyze(design, fake_runs(design, y))
    assert list(stats.data_vars).count("y") == 1
    assert not any(v.startswith("germ") for v in stats.data_vars)
    assert stats["y"].sel(statistic="mean") == pytest.approx(y.mean())
    assert stats["y"].sel(statistic="variance") == pytest.approx(y.var(ddof=1))
    assert stats["y"].sel(statistic="q50") == pytest.approx(np.median(y))
    assert stats["y"].attrs["units"] == "m"
    assert stats.attrs["method"] == "kl-weibull" and stats.attrs["samples_ok"] == 20
    assert stats.attrs["solver_runs"] == 20
    assert stats.attrs["field_bar_E_modes"] == design.attrs["field_bar_E_modes"]
    assert "fields" in stats.attrs
    # Failed realizations are left out, with a warning.
    status = ["ok"] * 18 + ["failed"] * 2
    y2 = y.copy()
    y2[18:] = np.nan
    stats = method.analyze(design, fake_runs(design, y2, status))
    assert stats.attrs["samples_ok"] == 18
    assert stats["y"].sel(statistic="mean") == pytest.approx(y[:18].mean())
    assert "2 of 20 realizations failed" in stats.attrs["warnings"]


def test_analyze_reports_truncation_warnings():
    short = RandomField(FieldSpec(name="E", correlation_length=1e-5, quadrature_points=20),
                        POINTS)
    method = KLWeibull(realizations=4)
    design = method.plan(InputSpace([]), [short], np.random.SeedSequence(0))
    assert "field_E_warning" in design.attrs
    stats = method.analyze(design, fake_runs(design, np.arange(4.0)))
    assert "captured variance 0.95 not reached" in stats.attrs["warnings"]


def test_enough_on_target():
    method = KLWeibull(realizations=40, target_rel_stderr=0.05, min_samples=10)
    design = method.plan(InputSpace([]), two_fields(), np.random.SeedSequence(0))
    assert method.enough(design, fake_runs(design, 100 + design["germ_bar_E"].values[:, 0]))
    assert not method.enough(design, fake_runs(design, design["germ_bar_E"].values[:, 0]))


class BarSolver:
    """u(L) = F/A ∫ dx / E(x) on a unit bar with n elements; E a random field."""

    def __init__(self, n=40, E=2e11):
        self.x = np.linspace(0.0, 1.0, n + 1)
        self.mid = 0.5 * (self.x[1:] + self.x[:-1])
        self.E = E

    def outputs(self):
        return xr.Dataset({"u": ((), np.nan, {"units": "m"}),
                           "clipped": ((), np.nan, {"units": ""})})

    def run(self, params, fields=None):
        E = np.full(self.mid.size, self.E)
        clipped = 0
        if fields is not None:
            E = fields.values("bar.E", self.mid, mean=self.E, lower=0.0)
            clipped = fields.clipped["bar.E"]
        u = params.get("F", 100.0) / params.get("A", 1e-4) * np.sum(np.diff(self.x) / E)
        return xr.Dataset({"u": ((), u), "clipped": ((), float(clipped))})


def test_end_to_end_with_a_field_solver():
    solver = BarSolver()
    field = RandomField(FieldSpec(name="bar.E", correlation_length=0.3, divisor=10),
                        solver.mid)
    method = KLWeibull(realizations=25)
    space = InputSpace([normal("F", 100.0, 1.0)])
    design = method.plan(space, [field], np.random.SeedSequence(4))
    runs = evaluate_design(solver, design, fields=[field])
    assert np.all(runs["status"].values == "ok")
    # Realization 3 by hand.
    sample = FieldSample.from_design([field], design, 3)
    E = sample.values("bar.E", solver.mid, mean=2e11, lower=0.0)
    F = design["inputs"].values[3, 0]
    # the same n-term sum of dx/E two ways: ≤ 2·n·eps (n ≤ a few hundred: ≤ 1e-13)
    assert runs["u"].values[3] == pytest.approx(F / 1e-4 * np.sum(np.diff(solver.x) / E),
                                                rel=1e-12)
    stats = method.analyze(design, runs)
    u0 = 100.0 / 1e-4 / 2e11
    # A 10 % field: the mean displacement stays within a few % of the deterministic one.
    assert abs(float(stats["u"].sel(statistic="mean")) / u0 - 1) < 0.05
    assert float(stats["u"].sel(statistic="std")) > 0
    # With cv = 0 every realization is the deterministic bar (F fixed), bit for bit.
    flat = RandomField(FieldSpec(name="bar.E", correlation_length=0.3, cv=0.0), solver.mid)
    d0 = method.plan(InputSpace([]), [flat], np.random.SeedSequence(4))
    r0 = evaluate_design(solver, d0, fields=[flat])
    det = solver.run({})["u"].values
    assert np.all(r0["u"].values == det)
    assert math.isfinite(float(det))
