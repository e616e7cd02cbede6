"""MPM core: shape functions, grid, scene validation, contract, scatter conservation,
symmetry/image boundaries, threads, and a small contact-explosion run."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest

from solvers.mpm import MPMSolver
from solvers.mpm import step as K
from solvers.mpm.grid import Grid
from solvers.mpm.materials import state as ST
from solvers.mpm.shapes import GIMP, KINDS, LINEAR, QUADRATIC, shape1d
from uqflow.errors import SceneError, SolverError
from uqflow.solver import get_solver

from ._common import set_at

SCENES = Path(__file__).resolve().parents[3] / "studies" / "scenes"


# ------------------------------------------------------------------------------------------
# shape functions
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", [QUADRATIC, LINEAR, GIMP])
def test_shapes_partition_of_unity_and_linear_reproduction(kind):
    rng = np.random.default_rng(0)
    for xi in rng.uniform(2.0, 10.0, 500):
        base, w0, w1, w2, d0, d1, d2 = shape1d(kind, xi, 0.25)
        w = np.array([w0, w1, w2])
        d = np.array([d0, d1, d2])
        nodes = base + np.arange(3)
        assert np.all(w >= -1e-15)
        # bound: three O(1) weights from a few flops each, ≈ 10 eps = 2e-15 (50× margin below)
        assert w.sum() == pytest.approx(1.0, abs=1e-13)
        assert d.sum() == pytest.approx(0.0, abs=1e-12)
        assert (w * nodes).sum() == pytest.approx(xi, abs=1e-12)   # Σ N x_i = x
        assert (d * nodes).sum() == pytest.approx(1.0, abs=1e-12)  # Σ ∇N x_i = 1


def test_shape_gradients_are_derivatives():
    h = 1e-6
    for kind in KINDS.values():
        for xi in (3.1, 3.37, 3.5 + 1e-3, 3.9):
            b, *wd = shape1d(kind, xi, 0.25)
            bp, *wp = shape1d(kind, xi + h, 0.25)
            bm, *wm = shape1d(kind, xi - h, 0.25)
            if b == bp == bm:
                for k in range(3):
                    assert wd[3 + k] == pytest.approx((wp[k] - wm[k]) / (2 * h), abs=1e-5)


# ------------------------------------------------------------------------------------------
# grid
# ------------------------------------------------------------------------------------------

def test_grid_geometry_and_masks():
    g = Grid.cover(0.0, 1.0, -0.5, 0.49, 0.1, pad=3,
                   sides=dict(left="fixed", bottom="symmetry", top="roller"),
                   clamps=[(0.5, 0.0, 0.6, 0.1)])
    assert (g.ncx, g.ncy) == (10, 10)                  # 0.99 → 10 whole cells
    assert g.y1 == pytest.approx(0.5)
    assert (g.nnx, g.nny) == (17, 17)
    assert g.ox == pytest.approx(-0.3)
    fx, fy = g.masks()
    il, ir, jb, jt = g.boundary_nodes()
    assert fx[il].all() and fy[il].all()               # fixed: both on the line
    assert not fx[il - 1].any()                        # ghosts left to the image
    assert fy[:, jb].all() and not fx[il + 1:, jb].any()
    assert fy[:, jt].all()
    xs, ys = g.node_x(), g.node_y()
    clamp = (xs[:, None] >= 0.5 - 1e-9) & (xs[:, None] <= 0.6 + 1e-9) & \
        (ys[None, :] >= -1e-9) & (ys[None, :] <= 0.1 + 1e-9)
    assert clamp.sum() == 4
    assert fx[clamp].all() and fy[clamp].all()


# ------------------------------------------------------------------------------------------
# scenes
# ------------------------------------------------------------------------------------------

def small_scene():
    return dict(domain=dict(x=[0.0, 0.1], y=[0.0, 0.1]), cell_size=0.01, particles_per_cell=2,
                materials=dict(m=dict(model="elastic", rho0=1000.0, E=1e6, nu=0.3)),
                bodies=[dict(name="block", material="m", shape="rectangle", min=[0.02, 0.02],
                             max=[0.08, 0.08], velocity=[1.0, 0.0])],
                end_time=0.002, output_interval=0.0005,
                probes=[dict(name="c", point=[0.05, 0.05], body="block")])


def _set(path, value):
    return lambda scene: set_at(scene, path, value)


BAD = [
    (_set(["cell_size"], KeyError), "scene.cell_size"),
    (_set(["cell_size"], -1.0), "scene.cell_size"),
    (_set(["nonsense"], 1), "scene.nonsense"),
    (_set(["domain", "x"], [1.0, 0.0]), "scene.domain.x"),
    (_set(["domain", "z"], [0.0, 1.0]), "scene.domain.z"),
    (_set(["particles_per_cell"], 0), "scene.particles_per_cell"),
    (_set(["shape"], "cubic"), "scene.shape"),
    (_set(["flip"], 1.5), "scene.flip"),
    (_set(["cfl"], 0.0), "scene.cfl"),
    (_set(["extent"], "half"), "scene.extent"),
    (_set(["extent_margin"], -1), "scene.extent_margin"),
    (_set(["outputs"], ["pressure", "vorticity"]), "scene.outputs[1]"),
    (_set(["boundaries"], {"left": "sticky"}), "scene.boundaries.left"),
    (_set(["boundaries"], {"front": "free"}), "scene.boundaries.front"),
    (_set(["clamps"], [{"min": [0.0, 0.0]}]), "scene.clamps[0].max"),
    (_set(["materials", "m", "model"], "granite"), "scene.materials.m.model"),
    (_set(["materials", "m", "jc.A"], 1.0), "scene.materials.m.jc.A"),
    (_set(["materials", "m", "E"], "stiff"), "scene.materials.m.E"),
    (_set(["bodies"], []), "scene.bodies"),
    (_set(["bodies", 0, "material"], "steel"), "scene.bodies[0].material"),
    (_set(["bodies", 0, "shape"], "star"), "scene.bodies[0].shape"),
    (_set(["bodies", 0, "max"], [0.5, 0.08]), "scene.bodies[0]"),
    (_set(["bodies", 0, "velocity"], [1.0]), "scene.bodies[0].velocity"),
    (_set(["bodies", 0, "radius"], 1.0), "scene.bodies[0].radius"),
    (_set(["probes", 0, "body"], "plate"), "scene.probes[0].body"),
    (_set(["probes", 0, "point"], [0.095, 0.095]), "scene.probes[0].point"),
    (_set(["output_interval"], 1.0), "scene.output_interval"),
    (_set(["end_time"], KeyError), "scene.end_time"),
]


@pytest.mark.parametrize("mutate, key", BAD)
def test_scene_errors_name_the_key(mutate, key):
    s = small_scene()
    mutate(s)
    with pytest.raises(SceneError) as e:
        MPMSolver.from_scene(s)
    assert e.value.key == key, str(e.value)


def test_explosive_needs_a_detonation_point():
    s = small_scene()
    s["materials"]["hx"] = dict(model="tnt")
    s["bodies"].append(dict(name="charge", material="hx", shape="circle", center=[0.01, 0.01],
                            radius=0.008))
    with pytest.raises(SceneError) as e:
        MPMSolver.from_scene(s)
    assert e.value.key == "scene.detonation"


def test_bodies_fill_in_order_and_shapes():
    s = small_scene()
    s["domain"] = dict(x=[0.0, 0.2], y=[0.0, 0.2])
    s["bodies"] = [dict(name="disk", material="m", shape="circle", center=[0.1, 0.1],
                        radius=0.05),
                   dict(name="tri", material="m", shape="polygon",
                        vertices=[[0.0, 0.0], [0.2, 0.0], [0.0, 0.2]]),
                   dict(name="rest", material="m", shape="rectangle", min=[0.0, 0.0],
                        max=[0.2, 0.2])]
    s["probes"] = [dict(name="c", point=[0.1, 0.1], body="disk")]
    sol = MPMSolver.from_scene(s)
    p = sol.parts
    assert p.x.size == 40 * 40                          # every lattice point owned once
    h = 0.005
    disk = p.body == 0
    assert disk.sum() * h * h == pytest.approx(np.pi * 0.05**2, rel=0.03)
    tri = p.body == 1
    assert np.all(p.x[tri] + p.y[tri] <= 0.2 + 1e-12)
    assert not np.any(tri & ((p.x - 0.1) ** 2 + (p.y - 0.1) ** 2 <= 0.05**2))
    assert np.all(p.vol0 == pytest.approx(h * h))


def test_nominal_names_every_material_parameter():
    s = small_scene()
    s["materials"] = dict(steel=dict(model="steel_4340", jc=dict(A=800e6)),
                          water=dict(model="water"), unused=dict(model="tnt"))
    s["bodies"] = [dict(name="plate", material="steel", shape="rectangle", min=[0.04, 0.0],
                        max=[0.06, 0.1]),
                   dict(name="sea", material="water", shape="rectangle", min=[0.0, 0.0],
                        max=[0.1, 0.1])]
    s["probes"] = [dict(name="c", point=[0.05, 0.05], body="plate")]
    sol = MPMSolver.from_scene(s)
    nom = sol.nominal()
    from solvers.mpm.materials import johnson_cook, water
    # the steel's conventions flag is the scene's `conventions`, not a material parameter
    assert set(nom) == ({f"steel.{k}" for k in johnson_cook.PARAMETERS
                         if k != johnson_cook.CONVENTIONS_PARAMETER}
                        | {f"water.{k}" for k in water.PARAMETERS})
    assert nom["steel.jc.A"] == 800e6                     # nested table override
    assert nom["steel.eos.S1"] == 1.49
    units = sol.parameter_units()
    assert units["steel.jc.A"] == "Pa" and units["steel.eos.S1"] == ""


def test_explosive_core_parameters_not_listed():
    sc = tomllib.loads((SCENES / "mpm_contact_thin.toml").read_text())
    sc["resolution"] = 0.25
    sol = MPMSolver.from_scene(sc)
    nom = sol.nominal()
    assert "tnt.eos.E0" in nom and "tnt.D" in nom
    assert not any(k.startswith("tnt.det_") or k == "tnt.burn_width" for k in nom)
    assert {"steel.eos.S1", "steel.eos.gamma0", "steel.eos.a", "steel.jc.A", "steel.jc.B",
            "steel.jc.C", "steel.jc.n", "steel.jc.m"} <= set(nom)


@pytest.mark.parametrize("name", ["mpm_contact_thin.toml", "mpm_contact_thick.toml",
                                  "mpm_contact_thin_small.toml",
                                  "mpm_contact_thick_small.toml"])
def test_scene_files_load(name):
    sc = tomllib.loads((SCENES / name).read_text())
    sol = MPMSolver.from_scene(sc)
    assert sol.probe_index.size >= 2
    assert sol.outputs().sizes["time"] == round(sc["end_time"] / sc["output_interval"]) + 1


def test_registered():
    assert get_solver("mpm") is MPMSolver


# ------------------------------------------------------------------------------------------
# contract
# ------------------------------------------------------------------------------------------

def test_outputs_template_and_run_match():
    s = small_scene()
    s["outputs"] = ["pressure", "S11", "velocity_x"]
    sol = MPMSolver.from_scene(s)
    tpl = sol.outputs()
    assert set(tpl.data_vars) == {"pressure", "S11", "velocity_x", "kinetic_energy",
                                  "internal_energy", "plastic_work", "explosive_release",
                                  "total_energy", "momentum_x", "momentum_y",
                                  "time_steps", "dt_min", "dt_max"}     # the diagnostics
    assert tpl.pressure.dims == ("time", "probe") and tpl.sizes == {"time": 5, "probe": 1}
    assert tpl.kinetic_energy.dims == ("time",)
    assert all("units" in v.attrs for v in tpl.data_vars.values())
    assert np.isnan(tpl.pressure.values).all()
    ds = sol.run({})
    assert ds.sizes == tpl.sizes and set(ds.data_vars) == set(tpl.data_vars)
    np.testing.assert_allclose(ds.time.values, [0, 5e-4, 1e-3, 1.5e-3, 2e-3])
    assert np.isfinite(ds.pressure.values).all()
    assert ds.velocity_x.values[0, 0] == 1.0
    assert ds.attrs["steps"] > 0
    # bound: 144 particles × 28 steps, each transfer exact up to ~eps per term: ≈ 4e3 eps = 9e-13 → 1e-11
    np.testing.assert_allclose(ds.momentum_x.values, ds.momentum_x.values[0], rtol=1e-11)
    assert np.isnan(sol.outputs().pressure.values).all()   # template untouched by a run


def test_parameters_change_the_run():
    s = small_scene()
    s["bodies"][0]["velocity"] = [0.0, 0.0]
    s["gravity"] = [0.0, -100.0]
    s["boundaries"] = dict(bottom="fixed")
    s["bodies"][0]["min"] = [0.02, 0.0]
    s["probes"][0]["point"] = [0.05, 0.0025]
    s["outputs"] = ["pressure"]
    sol = MPMSolver.from_scene(s)
    soft = sol.run({"m.E": 0.5e6}).pressure.values[-1, 0]
    stiff = sol.run({}).pressure.values[-1, 0]
    assert soft != stiff
    with pytest.raises(SolverError, match="random fields"):
        sol.run({}, fields={"m.E": np.ones(3)})


# ------------------------------------------------------------------------------------------
# kernels
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("nthreads", [1, 2])
def test_p2g_conserves_mass_momentum_and_force_balance(nthreads):
    rng = np.random.default_rng(1)
    n, dx = 500, 0.1
    x = rng.uniform(0.5, 1.5, n)
    y = rng.uniform(0.5, 1.5, n)
    vx, vy, m = rng.normal(size=n), rng.normal(size=n), rng.uniform(1, 2, n)
    S = np.zeros((n, ST.N_STATE))
    S[:, ST.RHO] = 1000.0
    S[:, ST.SXX], S[:, ST.SYY], S[:, ST.SXY] = rng.normal(size=(3, n)) * 1e5
    g = Grid.cover(0.0, 2.0, 0.0, 2.0, dx)
    shp = (g.nnx, g.nny)
    gm, gpx, gpy, gfx, gfy = (np.zeros(shp) for _ in range(5))
    for kind in KINDS.values():
        skipped = K.p2g(x, y, vx, vy, m, S, kind, 0.25, g.ox, g.oy, 1 / dx, 0.0, -9.81,
                        K.grid_buffers(nthreads, *shp), gm, gpx, gpy, gfx, gfy)
        assert skipped == 0
        # bound: sums of 500 particles × 9 weights, each ≤ eps relative: ≈ 5e3 eps worst case, ≈ 70 eps typical; 1e-12 with the moments' cancellation
        assert gm.sum() == pytest.approx(m.sum(), rel=1e-12)
        assert gpx.sum() == pytest.approx((m * vx).sum(), rel=1e-12, abs=1e-12)
        assert gpy.sum() == pytest.approx((m * vy).sum(), rel=1e-12, abs=1e-12)
        # internal forces sum to zero (Σ ∇N = 0); only gravity remains
        assert gfx.sum() == pytest.approx(0.0, abs=1e-9 * np.abs(gfx).max())
        assert gfy.sum() == pytest.approx(-9.81 * m.sum(), rel=1e-9)


def test_p2g_skips_off_grid_particles():
    g = Grid.cover(0.0, 1.0, 0.0, 1.0, 0.1)
    shp = (g.nnx, g.nny)
    arrays = [np.zeros(shp) for _ in range(5)]
    S = np.zeros((2, ST.N_STATE))
    S[:, ST.RHO] = 1.0
    skipped = K.p2g(np.array([0.5, 99.0]), np.array([0.5, 0.5]), np.zeros(2), np.zeros(2),
                    np.ones(2), S, 0, 0.25, g.ox, g.oy, 10.0, 0.0, 0.0,
                    K.grid_buffers(1, *shp), *arrays)
    assert skipped == 1 and arrays[0].sum() == pytest.approx(1.0)


def _disk_scene(full):
    """An elastic disk hitting the symmetry plane y = 0 (half) or its mirror twin (full)."""
    y0 = -0.5 if full else 0.0
    bodies = [dict(name="d", material="m", shape="circle", center=[0.25, 0.15], radius=0.1,
                   velocity=[0.05, -0.5])]
    if full:
        bodies.append(dict(name="e", material="m", shape="circle", center=[0.25, -0.15],
                           radius=0.1, velocity=[0.05, 0.5]))
    return dict(domain=dict(x=[0.0, 0.5], y=[y0, 0.5]), cell_size=0.025, particles_per_cell=2,
                materials=dict(m=dict(model="elastic", rho0=1000.0, E=1e5, nu=0.3)),
                bodies=bodies, boundaries=dict(bottom="symmetry") if not full else {},
                bulk_viscosity=dict(Q1=1.5, Q2=0.06), end_time=0.2, output_interval=0.02,
                outputs=["velocity_x", "velocity_y", "S11", "S12", "position_y"],
                probes=[dict(name="p", point=[0.24375, 0.06875], body="d"),
                        dict(name="q", point=[0.30625, 0.19375], body="d")])


def test_symmetry_plane_equals_mirror_image():
    half = MPMSolver.from_scene(_disk_scene(False)).run({})
    full = MPMSolver.from_scene(_disk_scene(True)).run({})
    assert np.min(half.position_y.values) < 0.07       # it reached the plane and deformed
    for v in ("velocity_x", "velocity_y", "S11", "S12", "position_y"):
        a, b = half[v].values, full[v].values
        assert np.max(np.abs(a - b)) <= 1e-9 * max(np.max(np.abs(b)), 1e-30), v


def _wall_scene(full, vy=0.0, nu=0.0, end=0.1):
    x0 = -0.5 if full else 0.0
    bodies = [dict(name="d", material="m", shape="rectangle", min=[0.0, 0.1], max=[0.2, 0.3],
                   velocity=[-0.3, vy])]
    if full:
        bodies.append(dict(name="e", material="m", shape="rectangle", min=[-0.2, 0.1],
                           max=[0.0, 0.3], velocity=[0.3, -vy]))
    return dict(domain=dict(x=[x0, 0.5], y=[0.0, 0.5]), cell_size=0.025, particles_per_cell=2,
                materials=dict(m=dict(model="elastic", rho0=1000.0, E=1e5, nu=nu)),
                bodies=bodies, boundaries={} if full else dict(left="fixed"),
                bulk_viscosity=dict(Q1=0.0, Q2=0.0), end_time=end, output_interval=0.01,
                outputs=["velocity_x", "velocity_y", "S11"],
                probes=[dict(name="p", point=[0.00625, 0.20625], body="d"),
                        dict(name="q", point=[0.10625, 0.10625], body="d")])


def test_fixed_wall_is_the_odd_image_in_1d():
    """With ν = 0 and motion along x only the problem is 1-D, where the odd image of the
    material is the exact fixed wall: the half model equals the full one to round-off."""
    half = MPMSolver.from_scene(_wall_scene(False)).run({})
    full = MPMSolver.from_scene(_wall_scene(True)).run({})
    assert np.abs(half.S11.values).max() > 1e3                 # it hit the wall
    for v in ("velocity_x", "S11"):
        a, b = half[v].values, full[v].values
        assert np.max(np.abs(a - b)) <= 1e-9 * np.max(np.abs(b)), v
    assert np.abs(half.velocity_y.values).max() < 1e-12


def test_fixed_wall_2d_is_energy_consistent():
    """In 2-D the fold is the Galerkin projection on velocities constrained to be odd across
    the wall (no exact image exists): a block sliding into a no-slip wall keeps its energy."""
    ds = MPMSolver.from_scene(_wall_scene(False, vy=0.2, nu=0.3, end=0.3)).run({})
    e = ds.total_energy.values
    assert ds.kinetic_energy.values.min() < 0.8 * e[0]
    assert np.max(np.abs(e / e[0] - 1)) < 0.05


def test_threads_agree():
    s = small_scene()
    s["outputs"] = ["velocity_x", "S11"]
    r1 = MPMSolver.from_scene(dict(s, threads=1)).run({})
    r2 = MPMSolver.from_scene(dict(s, threads=2)).run({})
    assert r2.attrs["threads"] in (1, 2)
    for v in ("velocity_x", "S11", "total_energy"):
        # bound: the 2-thread P2G sums in another order (≈ eps per node per step); over the run's steps that stays ≪ 1e-9
        np.testing.assert_allclose(r1[v].values, r2[v].values, rtol=1e-9, atol=1e-12)


def test_serial_twins_give_the_parallel_kernels_bits_on_one_thread(monkeypatch):
    # the same arithmetic in the same order (one thread: one scatter buffer, reductions from
    # 0), so bit for bit: a twin that drifted from its kernel would show here
    sc = tomllib.loads((SCENES / "mpm_contact_thin_small.toml").read_text())
    sc.update(end_time=4e-6, resolution=0.5, threads=1)
    serial = MPMSolver.from_scene(sc).run({})
    assert serial.attrs["threads"] == 1
    loop_for = K.loop_for
    monkeypatch.setattr(K, "kernels", lambda parallel: K.PARALLEL)
    monkeypatch.setattr(K, "loop_for", lambda module, parallel: loop_for(module, True))
    parallel = MPMSolver.from_scene(sc).run({})
    assert serial.time_steps.item() > 10
    for name in serial.data_vars:
        np.testing.assert_array_equal(serial[name].values, parallel[name].values, err_msg=name)


@pytest.mark.parametrize("parallel", [True, False], ids=["parfors", "serial twin"])
@pytest.mark.parametrize("name", ["water", "steel_4340", "tnt", "elastic"])
def test_every_material_loop_flags_an_overflowing_bulk_viscosity(name, parallel):
    # finite arguments, but q = ρ l (Q1 l ε̇v² − Q2 c ε̇v) overflows for an absurd length:
    # the water loop trusts its advance to refuse the non-finite q (no row check), the
    # others find it in the row check; either way the particle is flagged, never stepped on
    from solvers.mpm.materials import library
    module, defaults = library.MATERIALS[name]
    prm = module.pack(defaults)
    S = ST.new_state(1)
    assert module.init(prm, S, 0) == ST.OK
    before = S.copy()
    idx = np.zeros(1, dtype=np.int64)
    Lg = np.array([[-1e3, 0.0, 0.0, -1e3]])
    xy, v, err = np.zeros(1), np.zeros(1), np.zeros(1, dtype=np.int32)
    loop, _init = K.loop_for(module, parallel)
    nbad, _ = loop(prm, S, idx, Lg, 1.5, 0.06, 1e200, 1e-9, 0.0, xy, xy, v, v, err)
    assert nbad == 1 and err[0] in (ST.ERR_NONFINITE, K.ERR_CORE_NONFINITE)
    assert S[0, ST.Q] == np.inf
    if module.__dict__.get("ADVANCE_CHECKS_ITS_WRITES"):
        # its advance refused the step: every column but the core's Q as it was
        keep = np.arange(ST.N_STATE) != ST.Q
        assert err[0] == ST.ERR_NONFINITE
        np.testing.assert_array_equal(S[0, keep], before[0, keep])


# ------------------------------------------------------------------------------------------
# the seed's scene, small: TNT + steel + water
# ------------------------------------------------------------------------------------------

def test_contact_explosion_small():
    sc = tomllib.loads((SCENES / "mpm_contact_thin_small.toml").read_text())
    sc = copy.deepcopy(sc)
    sc["end_time"] = 12e-6
    sc["resolution"] = 0.5
    sol = MPMSolver.from_scene(sc)
    ds = sol.run({})
    e = ds.total_energy.values
    assert e[0] == pytest.approx(7.0e9 * 0.08 * 0.04, rel=0.02)   # TNT chemical energy (half)
    assert abs(e[-1] / e[0] - 1) < 0.02
    # the burn releases the charge's chemical energy: nothing at t = 0, never decreasing,
    # all of it (E0 × the charge's volume, half charge) once the front has crossed the charge
    # (0.04 m from the centre at D = 6930 m/s: 5.8 µs)
    rel = ds.explosive_release.values
    tnt = sol.parts.material == sol.labels.index("tnt")
    assert rel[0] == 0.0 and np.all(np.diff(rel) >= 0.0)
    # bound: the same n-term sum of E0·V0 in another order, ≤ n eps with n ≈ 100 TNT particles: 2e-14
    assert rel[-1] == pytest.approx(7.0e9 * sol.parts.vol0[tnt].sum(), rel=1e-12)
    assert 0.0 < rel[ds.time.values.searchsorted(3e-6)] < 0.5 * rel[-1]
    p = ds.pressure.sel(probe="H").values
    assert np.isfinite(p).all() and p.max() > 2e9               # shock through the plate
    assert ds.plastic_work.values[-1] > 0
    sy = ds.flow_stress.sel(probe="H").values
    assert sy[0] == pytest.approx(792e6) and sy.max() > 792e6   # hardening
    # a stronger steel: the flow stress follows jc.A
    ds2 = sol.run({"steel.jc.A": 900e6})
    assert ds2.flow_stress.sel(probe="H").values[0] == pytest.approx(900e6)


def test_extent_auto_crops_without_changing_the_probes():
    sc = tomllib.loads((SCENES / "mpm_contact_thin_small.toml").read_text())
    sc.update(resolution=0.5, end_time=12e-6, output_interval=1e-6)
    full = MPMSolver.from_scene(sc)
    auto = MPMSolver.from_scene(dict(sc, extent="auto"))
    info = auto.extent_info
    assert info["cells_saved"] > 0.5 * info["full_cells"]
    assert auto.cfg.grid.cells == info["extent_cells"]
    assert auto.cfg.grid.sides["bottom"] == "symmetry"          # kept at the scene boundary
    assert auto.cfg.grid.sides["top"] == "symmetry"             # cropped: a wall
    assert "cells saved" in auto.describe()
    a, b = full.run({}), auto.run({})
    assert b.attrs["cells_saved"] == info["cells_saved"]
    for v in ("pressure", "S11", "velocity_x", "plastic_strain"):
        scale = np.max(np.abs(a[v].values))
        assert scale > 0
        assert np.max(np.abs(a[v].values - b[v].values)) < 1e-8 * scale, v


def test_extent_auto_needs_a_probe():
    s = small_scene()
    s["probes"] = []
    s["extent"] = "auto"
    with pytest.raises(SceneError) as e:
        MPMSolver.from_scene(s)
    assert e.value.key == "scene.extent"


# ------------------------------------------------------------------------------------------
# absorbing (far-field) sides: viscous dashpots ρ c on the boundary line
# ------------------------------------------------------------------------------------------

def _plane_pulse(right, model, amplitude, cells=200):
    """A cos² velocity pulse at the middle of a 1-D column (length 1 m), split into two waves;
    the probe at x = 0.7 sees the right-going one at t ≈ 0.2 L/c and its reflection from the
    right side at t ≈ 0.8 L/c."""
    dx = 1.0 / cells
    mats = {"elastic": dict(m=dict(model="elastic", rho0=1000.0, E=1e9, nu=0.0)),
            "water": dict(m=dict(model="water"))}[model]
    c = 1000.0 if model == "elastic" else 1480.0
    sc = dict(domain=dict(x=[0.0, 1.0], y=[0.0, 6 * dx]), cell_size=dx, particles_per_cell=2,
              materials=mats, bulk_viscosity=dict(Q1=0.0, Q2=0.0),
              bodies=[dict(name="b", material="m", shape="rectangle", min=[0.0, 0.0],
                           max=[1.0, 6 * dx])],
              boundaries=dict(left="absorbing", right=right, bottom="symmetry", top="symmetry"),
              end_time=1.0 / c, output_interval=0.01 / c, outputs=["velocity_x"],
              probes=[dict(name="p", point=[0.7, 0.0], body="b")])
    sol = MPMSolver.from_scene(sc)
    x = sol.parts.x
    sol.parts.vx[:] = amplitude * np.where(np.abs(x - 0.5) < 0.05,
                                           np.cos(np.pi * (x - 0.5) / 0.1) ** 2, 0.0)
    ds = sol.run({})
    v = ds.velocity_x.values[:, 0]
    tau = ds.time.values * c
    incident = np.abs(v[(tau > 0.1) & (tau < 0.35)]).max()
    reflected = v[(tau > 0.6) & (tau < 1.0)]
    return incident, reflected[np.argmax(np.abs(reflected))]


@pytest.mark.parametrize("model, amplitude", [("elastic", 1.0), ("water", 0.01)])
def test_absorbing_side_passes_a_plane_wave(model, amplitude):
    """Normal incidence, 20 cells per pulse width: the absorbing side reflects < 6 % of the
    amplitude (measured 4.5 %: 0.2 % of the energy; 6.2 % at 10 cells per width), the free
    side most of it with the velocity's sign (σ = 0 there; measured 85 % of the amplitude at
    the probe, the rest spread by dispersion). The water amplitude stays below the
    cavitation cut-off."""
    inc, ref = _plane_pulse("absorbing", model, amplitude)
    assert inc == pytest.approx(0.5 * amplitude, rel=0.05)
    assert abs(ref) < 0.06 * inc
    inc_free, ref_free = _plane_pulse("free", model, amplitude)
    assert ref_free > 0.75 * inc_free


def test_absorbing_side_is_validated_and_needs_no_images():
    sc = small_scene()
    sc["boundaries"] = {"right": "absorbing", "top": "absorbing"}
    MPMSolver.from_scene(sc)
    sc["boundaries"] = {"right": "absorbent"}
    with pytest.raises(SceneError, match="scene.boundaries.right"):
        MPMSolver.from_scene(sc)


def test_single_particle_falls_freely():
    """One particle (the smallest scene): under gravity alone its velocity is exactly g t (the
    grid update v + g dt reproduces it for any weights), it does not strain (a uniform velocity
    has no gradient: stresses at round-off) and the total momentum equals m g t."""
    sc = dict(domain=dict(x=[0.0, 1.0], y=[0.0, 1.0]), cell_size=0.1, particles_per_cell=1,
              materials=dict(m=dict(model="elastic", rho0=1000.0, E=1e6, nu=0.3)),
              bodies=[dict(name="p", material="m", shape="rectangle", min=[0.5, 0.5],
                           max=[0.55, 0.55])],
              gravity=[0.0, -9.81], end_time=0.05, output_interval=0.01,
              outputs=["velocity_y", "position_x", "pressure", "S11"],
              probes=[dict(name="p", point=[0.5, 0.5], body="p")])
    sol = MPMSolver.from_scene(sc)
    assert sol.parts.x.size == 1
    ds = sol.run({})
    t = ds.time.values
    vy = ds.velocity_y.sel(probe="p").values
    # bound: v = Σ g dt over ≤ 1000 steps, one rounding each: ≤ 1000 eps ≈ 2e-13 of g t
    np.testing.assert_allclose(vy, -9.81 * t, rtol=1e-12, atol=1e-15)
    assert np.all(ds.position_x.sel(probe="p").values == ds.position_x.values[0, 0])
    # Σ ∇N_i = 0 to round-off: strains ~1e-18 against E = 1e6 Pa (measured |p| < 2e-12 Pa)
    assert np.abs(ds.pressure.values).max() < 1e-9 and np.abs(ds.S11.values).max() < 1e-9
    mass = 1000.0 * sol.parts.vol0[0]
    np.testing.assert_allclose(ds.momentum_y.values, -9.81 * mass * t, rtol=1e-12, atol=1e-15)


def _quadrant_pulse_energy_left(right_top, size, cells=40):
    """Energy left inside the unit square at t = 2 L/c of a cylindrical acoustic pulse started
    at the corner of a water quadrant (symmetry planes at x = 0 and y = 0), as a fraction of
    the initial energy. ``size`` = 2 with free sides: nothing comes back from the far sides by
    then, so this is the unbounded answer (the 2-D wake keeps energy near the source)."""
    from solvers.mpm.solver import _Run
    dx = 1.0 / cells
    sc = dict(domain=dict(x=[0.0, size], y=[0.0, size]), cell_size=dx, particles_per_cell=2,
              materials=dict(w=dict(model="water")),
              bodies=[dict(name="b", material="w", shape="rectangle", min=[0.0, 0.0],
                           max=[size, size])],
              boundaries=dict(left="symmetry", right=right_top, bottom="symmetry",
                              top=right_top),
              end_time=2.0 / 1480.0, output_interval=1.0 / 1480.0, outputs=["velocity_x"])
    sol = MPMSolver.from_scene(sc)
    r = np.hypot(sol.parts.x, sol.parts.y)
    speed = 0.01 * np.where(r < 0.15, np.cos(0.5 * np.pi * r / 0.15) ** 2, 0.0)
    sol.parts.vx[:] = speed * sol.parts.x / np.maximum(r, 1e-12)
    sol.parts.vy[:] = speed * sol.parts.y / np.maximum(r, 1e-12)
    run = _Run(sol, sol._parameters({}))

    def energy_in_unit_square():
        m = (run.x < 1.0) & (run.y < 1.0)
        kinetic = 0.5 * np.sum(run.mass[m] * (run.vx[m] ** 2 + run.vy[m] ** 2))
        return kinetic + np.sum(run.S[m, ST.E] * run.vol0[m])

    e0 = energy_in_unit_square()
    run.advance()
    return energy_in_unit_square() / e0


# the energy the absorbing sides keep beyond the unbounded answer (points of the initial
# energy) is reflection, which falls with resolution: 2.4 points at 40 cells, 2.0 at 60; the
# bound at 40 cells is the measured value with a margin, the 40-cell value bounds 60 cells
@pytest.mark.parametrize("cells, bound", [
    (40, 0.05),
    pytest.param(60, 0.025, marks=pytest.mark.slow),
])
def test_absorbing_sides_match_the_unbounded_domain_in_2d(cells, bound):
    """Oblique incidence: the energy left in the unit square with absorbing sides is within
    ``bound`` (of the initial energy) of the unbounded answer (measured at 40 cells: 71.8 %
    vs 69.4 %, free sides keep 101.2 %; at 60 cells 51.7 % vs 49.7 % and 100.5 %)."""
    unbounded = _quadrant_pulse_energy_left("free", 2.0, cells)
    absorbing = _quadrant_pulse_energy_left("absorbing", 1.0, cells)
    free = _quadrant_pulse_energy_left("free", 1.0, cells)
    assert 0.0 < absorbing - unbounded < bound      # keeps more, never less: reflection
    assert free > 0.95
