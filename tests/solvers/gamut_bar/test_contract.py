"""The Solver contract: scene validation, nominal parameters, the output template, fields,
grids and errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solvers.gamut_bar import GamutBarSolver
from solvers.gamut_bar.network import stochastic_grid
from uqflow.errors import SceneError, SolverError
from uqflow.solver import Solver, get_solver

from ._common import EPS, FakeFields, material, run, small_solver, solver


def test_registered_and_a_solver():
    assert get_solver("gamut_bar") is GamutBarSolver
    assert issubclass(GamutBarSolver, Solver)
    assert "M1 monotonic" in solver().describe()


def test_nominal_and_units():
    nom = solver().nominal()
    m = material("M1")
    assert set(nom) == {"bar.E", "bar.R", "bar.w", "bar.rho", "bar.sigma_y", "bar.sigma_f",
                        "bar.eps_f", "bar.n_ro", "bar.K_ro", "bar.area", "bar.length"}
    assert nom["bar.E"] == m["E"] and nom["bar.w"] == 1.0
    assert nom["bar.R"] == pytest.approx(0.8514, abs=1e-4)
    assert nom["bar.area"] == 1e-4 and nom["bar.length"] == 0.1
    units = solver().parameter_units()
    assert units["bar.E"] == "Pa" and units["bar.sigma_y"] == "Pa" and set(units) == set(nom)
    nom2 = solver(material="M2", n_ro=21.0, E=100e9).nominal()
    assert nom2["bar.n_ro"] == 21.0 and nom2["bar.E"] == 100e9


@pytest.mark.parametrize("loading", ["monotonic", "cyclic"])
def test_template_matches_the_run(loading):
    s = small_solver(loading)
    t = s.outputs()
    ds = s.run({})
    assert set(t.data_vars) == set(ds.data_vars)
    for name, var in t.data_vars.items():
        assert ds[name].dims == var.dims and ds[name].shape == var.shape, name
        assert ds[name].attrs["units"] == var.attrs["units"], name
        assert np.all(np.isfinite(ds[name].values)), name
        assert np.all(np.isnan(var.values)), name
    assert t["strain"].attrs["units"] == "1" and t["stress"].attrs["units"] == "Pa"
    assert t.sizes["point"] == 41 and t.sizes["bond"] == 40
    if loading == "monotonic":
        assert t.sizes["step"] == 400
    else:
        assert {"stress_amplitude", "plastic_strain_amplitude", "n_prime", "K_prime"} <= \
            set(t.data_vars) and t.sizes["loop"] == 3
    t["strain"].values[:] = 0.0                 # the template handed out is a copy
    assert np.all(np.isnan(s.outputs()["strain"].values))


@pytest.mark.parametrize("loading", ["monotonic", "cyclic"])
def test_every_output_says_in_words_what_it_is_and_in_which_si_unit(loading):
    t = solver(loading=loading, local_bonds=20, cycles=3).outputs()
    for name, var in t.data_vars.items():
        words = var.attrs.get("long_name", "")
        assert len(words.split()) >= 2 and "_" not in words, (name, words)
        assert var.attrs.get("units") in ("1", "Pa", "m", "kg"), name     # SI; "1": ratio
    for dim in t.dims:
        assert t[dim].attrs.get("long_name"), dim
    assert t["stress"].attrs["long_name"] == "stress in the bar (end force / cross-section)"


def test_curve_points_and_mass_and_sigma():
    ds = run(curve_points=50)
    assert ds.sizes["step"] == 50
    m = material("M1")
    # Σ ρ A l over 500 segments: a sum of n terms errs by at most n·eps relative
    assert ds["mass"].item() == pytest.approx(m["rho"] * 1e-4 * 0.1, rel=500 * EPS)
    sig = ds["sigma_stdev"].values
    assert sig.shape == (501,) and np.all(np.isfinite(sig))
    # eq. 31 recovers σ_stdev; bound: the lengths are differences of a 500-term cumsum
    # (absolute error n·eps·L), relative to the nearest bond (2 spacings) that is
    # n·eps·L/(2 L/n) = n²·eps/2, and l_far²−l_near² and the log ratio add a factor ≤ 4
    assert sig == pytest.approx(8 * 0.1 / 500, rel=4 * 500**2 / 2 * EPS)
    st = run(grid="stochastic")["sigma_stdev"].values
    assert np.all(np.isfinite(st)) and abs(np.median(st) / (8 * 0.1 / 500) - 1) < 0.2
    dens = FakeFields({"bar.rho": lambda x: np.where(x < 0.05, 2.0, 1.0)})
    # a 500-term sum: n·eps relative
    assert solver().run({}, dens)["mass"].item() == pytest.approx(1.5 * m["rho"] * 1e-5,
                                                                   rel=500 * EPS)


def test_field_points():
    s = solver(local_bonds=20)
    for name in ("bar.E", "bar.R", "bar.rho", "E"):
        p = s.field_points(name)
        assert p.shape == (20, 1)
        assert p[:, 0] == pytest.approx((np.arange(20) + 0.5) * 0.1 / 20)
    w = s.field_points("bar.w")
    assert w.ndim == 2 and w.shape[1] == 1 and np.all(np.diff(w[:, 0]) > 0)
    assert w[0, 0] == pytest.approx(0.1 / 20)            # midpoint of the first bond (0, 2)
    with pytest.raises(SceneError):
        s.field_points("bar.sigma_y")


def test_stochastic_grid_eq_36():
    rng = np.random.default_rng(5)
    x = stochastic_grid(1000, 0.1, 0.65, 0.05, rng)
    s = np.diff(x) / (0.1 / 1000)
    # the rescaled spacings' cumsum of 1000 terms: n·eps relative
    assert x[0] == 0.0 and x[-1] == pytest.approx(0.1, rel=1000 * EPS)
    assert s.min() > 0.34 and s.max() < 1.66               # s̄ (1 ± 0.65), rescaled to L
    # a larger factor draws overlaps; they are redrawn
    x = stochastic_grid(1000, 0.1, 1.5, 0.05, np.random.default_rng(6))
    assert np.diff(x).min() >= 0.049 * 0.1 / 1000


def test_grid_seed_and_run_seed():
    a = run(grid="stochastic")
    b = run(grid="stochastic", grid_seed=1)
    assert not np.array_equal(a["x"].values, b["x"].values)
    s = solver(grid="stochastic", grid_seed=1)
    assert np.array_equal(s.run({})["x"].values, b["x"].values)
    assert np.array_equal(s.run({}, seed=0)["x"].values, a["x"].values)
    u = run()["x"].values
    # a cumsum of 500 equal spacings: absolute error ≤ n·eps·L
    assert u == pytest.approx(np.linspace(0, 0.1, 501), abs=500 * EPS * 0.1)


BAD_SCENES = [
    ({"foo": 1}, "scene.foo"),
    ({"eps_y": 0.01}, "scene.eps_y"),
    ({"material": "M3"}, "scene.material"),
    ({"grid": "random"}, "scene.grid"),
    ({"loading": "fatigue"}, "scene.loading"),
    ({"E": -1.0}, "scene.E"),
    ({"E": 0.0}, "scene.E"),
    ({"E": "71.6e9"}, "scene.E"),
    ({"E": True}, "scene.E"),
    ({"area": 0.0}, "scene.area"),
    ({"length": -0.1}, "scene.length"),
    ({"local_bonds": 1}, "scene.local_bonds"),
    ({"local_bonds": 10.0}, "scene.local_bonds"),
    ({"sigma_stdev": 0.0}, "scene.sigma_stdev"),
    ({"sigma_f": 500e6}, "scene.sigma_f"),               # below σ_y = 538.6 MPa
    ({"eps_f": 0.009}, "scene.eps_f"),                   # below ε_y = 0.009522
    ({"cutoff": 0.2}, "scene.cutoff"),
    ({"grid_factor": -0.1}, "scene.grid_factor"),
    ({"grid_seed": -1}, "scene.grid_seed"),
    ({"curve_points": 1}, "scene.curve_points"),
    ({"cycles": 1}, "scene.cycles"),
    ({"amplitude_range": [1.0]}, "scene.amplitude_range"),
    ({"amplitude_range": [1.3, 0.5]}, "scene.amplitude_range"),
    ({"amplitude_range": [1.0, 1.3]}, "scene.amplitude_range"),      # beyond σ(ε_f)
    ({"force_growth": 1.0}, "scene.force_growth"),
    ({"cyclic_increment": 0.03}, "scene.cyclic_increment"),
    ({"R": 1.2}, "scene.R"),
    ({"rho": -5.0}, "scene.rho"),
]


@pytest.mark.parametrize("scene, key", BAD_SCENES)
def test_bad_scenes_name_the_key(scene, key):
    with pytest.raises(SceneError) as err:
        GamutBarSolver.from_scene(scene)
    assert err.value.key == key
    assert key in str(err.value)


def test_scene_must_be_a_table():
    with pytest.raises(SceneError):
        GamutBarSolver.from_scene([1, 2])


@pytest.mark.parametrize("params, what", [
    ({"bar.E": -1.0}, "bar.E"),
    ({"bar.R": 1.0}, "bar.R"),
    ({"bar.R": 0.0}, "bar.R"),
    ({"bar.w": 0.0}, "bar.w"),
    ({"bar.sigma_f": 400e6}, "bar.sigma_f"),
    ({"bar.area": 0.0}, "bar.area"),
    ({"bar.E": math.nan}, "bar.E"),
    ({"bar.nu": 0.3}, "bar.nu"),
])
def test_bad_parameters_raise_solver_error(params, what):
    with pytest.raises(SolverError, match=what.replace(".", r"\.")):
        solver(local_bonds=20).run(params)


@pytest.mark.parametrize("name, value, lo", [
    ("bar.E", -0.2, "0"), ("bar.E", 0.0, "0"), ("bar.R", 1.3, "0, 1"), ("bar.R", -0.5, "0, 1"),
    ("bar.w", -1.0, "0"), ("bar.rho", 0.0, "0"), ("bar.E", math.nan, "0"),
])
def test_fields_outside_their_range_raise_solver_error(name, value, lo):
    # a field that does not clip (or clips onto the bound): SolverError naming bond and value
    f = FakeFields({name: lambda x: np.where(x > 0.06, value, 1.0)}, clip=False)
    with pytest.raises(SolverError) as err:
        solver().run({}, f)
    msg = str(err.value)
    assert name in msg and "bond" in msg and "x = 0.06" in msg


def test_unknown_field_raises_solver_error():
    with pytest.raises(SolverError, match="sigma_y"):
        solver().run({}, FakeFields({"bar.sigma_y": lambda x: np.ones_like(x)}))


def test_short_field_names_are_accepted():
    f = FakeFields({"E": lambda x: np.where(x < 0.05, 0.8, 1.0)})
    ds = solver(local_bonds=50).run({}, f)
    assert f.calls and f.calls[0][0] == "E" and f.calls[0][3] == 0.0
    assert ds["bond_strain"].values[:20].mean() > ds["bond_strain"].values[30:].mean()


def test_field_arguments():
    f = FakeFields({k: (lambda x: np.ones_like(x)) for k in ("bar.E", "bar.R", "bar.w",
                                                             "bar.rho")})
    solver(local_bonds=30).run({"bar.E": 70e9}, f)
    calls = {c[0]: c for c in f.calls}
    assert calls["bar.E"][1:] == (30, 70e9, 0.0, math.inf)
    assert calls["bar.R"][3:] == (0.0, 1.0)
    assert calls["bar.w"][2] == 1.0 and calls["bar.w"][1] > 30      # nonlocal bond midpoints
    assert calls["bar.rho"][3] == 0.0
