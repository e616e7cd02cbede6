"""MPM verification problems with exact answers (docs/mpm_verification.md), and the guards
triggered by purposely broken scenes. The problems' scenes are studies/scenes/verify_*.toml
(each with its exact solution in a header comment); variants override keys of the loaded
table."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from solvers.mpm import MPMSolver
from solvers.mpm.materials import elastic, library, state
from uqflow.errors import SolverError

SCENES = Path(__file__).resolve().parents[3] / "studies" / "scenes"


def load_scene(name):
    """A verification scene (studies/scenes/<name>.toml) as a fresh dict."""
    with open(SCENES / f"{name}.toml", "rb") as f:
        return tomllib.load(f)


# ------------------------------------------------------------------------------------------
# Axial vibration of a fixed–free elastic bar: v(x, t) = v0 cos(ω1 t) sin(β1 x), β1 = π/(2L)
# (studies/scenes/verify_elastic_bar.toml)
# ------------------------------------------------------------------------------------------
L, E_BAR, RHO_BAR, V0 = 1.0, 100.0, 1.0, 0.01
C_BAR = math.sqrt(E_BAR / RHO_BAR)          # ν = 0: plane-strain P modulus = E, a 1-D bar
BETA = math.pi / (2 * L)
PERIOD = 2 * math.pi / (BETA * C_BAR)


def bar_scene(cells=32, flip=1.0, shape="quadratic", periods=5, samples=100):
    """The shipped bar (32 cells, 5 periods) with its resolution, transfer and shape set."""
    s = load_scene("verify_elastic_bar")
    dx = L / cells
    s.update(cell_size=dx, flip=flip, shape=shape, end_time=periods * PERIOD,
             output_interval=PERIOD / samples)
    s["domain"]["y"] = [0.0, 6 * dx]
    s["bodies"][0]["max"] = [L, dx]
    return s


def run_bar(**kw):
    s = MPMSolver.from_scene(bar_scene(**kw))
    s.parts.vx[:] = V0 * np.sin(BETA * s.parts.x)      # the first mode's velocity, at rest
    ds = s.run({})
    mass = RHO_BAR * L * (L / kw.get("cells", 32))       # bar of height dx (half of 2 dx)
    return ds, ds.momentum_x.values / mass


def zero_crossings(t, v):
    k = np.flatnonzero(v[:-1] * v[1:] < 0)
    return t[k] - v[k] * (t[k + 1] - t[k]) / (v[k + 1] - v[k])


@pytest.fixture(scope="module")
def bar():
    return run_bar(cells=32)


def test_bar_period(bar):
    ds, vcm = bar
    z = zero_crossings(ds.time.values, vcm)
    assert z.size >= 9                                    # 5 periods: 10 crossings
    period = 2 * np.mean(np.diff(z))
    assert abs(period / PERIOD - 1) < 0.01               # measured 0.06 % (32 cells)


def test_bar_centre_of_mass_amplitude(bar):
    ds, vcm = bar
    amp = np.max(np.abs(vcm))
    assert abs(amp / (2 * V0 / math.pi) - 1) < 0.02       # measured 0.003 %
    # and the whole history follows (2 v0/π) cos(ω1 t) (the 0.06 % period error is a phase
    # drift of 0.02 rad after 5 periods)
    exact = 2 * V0 / math.pi * np.cos(2 * math.pi * ds.time.values / PERIOD)
    assert np.max(np.abs(vcm - exact)) < 0.04 * 2 * V0 / math.pi   # measured 2.5 %


def test_bar_energy(bar):
    ds, _ = bar
    e = ds.total_energy.values
    exact = RHO_BAR * (L / 32) * V0**2 * L / 4            # ρ A v0² L / 4, A = dx (per metre)
    assert abs(e[0] / exact - 1) < 1e-3                  # measured 2e-16
    assert abs(e[-1] / e[0] - 1) < 0.01                  # drift over 5 periods: −0.03 %
    assert np.max(np.abs(e / e[0] - 1)) < 0.02           # measured 0.66 %


@pytest.mark.parametrize("shape", ["linear", "gimp"])
def test_bar_other_shape_functions(shape):
    ds, vcm = run_bar(cells=32, shape=shape, periods=2)
    z = zero_crossings(ds.time.values, vcm)
    assert abs(2 * np.mean(np.diff(z)) / PERIOD - 1) < 0.01         # measured 0.03 %
    e = ds.total_energy.values
    assert abs(e[-1] / e[0] - 1) < 0.01                              # measured −0.007 %


def test_bar_period_converges_second_order():
    """The image-method fixed wall keeps the bar length exact: error ∝ dx²."""
    errs = []
    for n in (16, 32):
        ds, vcm = run_bar(cells=n, periods=2)
        z = zero_crossings(ds.time.values, vcm)
        errs.append(abs(2 * np.mean(np.diff(z)) / PERIOD - 1))
    assert errs[1] < errs[0] / 2.5      # measured 0.247 % → 0.061 % (ratio 4.0)


# ------------------------------------------------------------------------------------------
# Two colliding elastic disks (Sulsky, Chen & Schreyer 1994)
# (studies/scenes/verify_colliding_disks.toml)
# ------------------------------------------------------------------------------------------

def disks_scene(flip=1.0, end=3.0):
    s = load_scene("verify_colliding_disks")
    s.update(flip=flip, end_time=end)
    return s


@pytest.fixture(scope="module")
def disks():
    return MPMSolver.from_scene(disks_scene()).run({})


def test_disks_symmetric_to_round_off(disks):
    a, b = disks.sel(probe="a"), disks.sel(probe="b")
    assert np.max(np.abs(a.velocity_x.values + b.velocity_x.values)) < 1e-12   # 1.5e-15
    assert np.max(np.abs(a.velocity_y.values + b.velocity_y.values)) < 1e-12
    assert np.max(np.abs(a.position_x.values + b.position_x.values - 1.0)) < 1e-12
    scale = np.max(np.abs(a.S11.values))
    assert scale > 1.0                                   # they did collide
    assert np.max(np.abs(a.S11.values - b.S11.values)) < 1e-10 * scale     # 5.4e-14
    assert np.max(np.abs(disks.momentum_x.values)) < 1e-12


def test_disks_collide_and_rebound(disks):
    a = disks.sel(probe="a")
    assert a.velocity_x.values[0] == pytest.approx(0.1)
    assert a.velocity_x.values[-1] < -0.03               # moving back: measured −0.074 m/s
    k = disks.kinetic_energy.values
    assert k.min() < 0.2 * k[0]                          # stored as strain energy: 4.5 % left


def test_disks_energy(disks):
    e = disks.total_energy.values
    assert e[0] == pytest.approx(2 * 0.5 * 1000.0 * math.pi * 0.2**2 * 0.02, rel=0.05)
    assert np.max(np.abs(e / e[0] - 1)) < 0.05           # measured −2.0 % … +0.6 %


def test_pic_dissipates():
    """The transfer scheme's energy behaviour: pure FLIP (MUSL) conserves, PIC damps."""
    e = MPMSolver.from_scene(disks_scene(flip=0.0, end=2.0)).run({}).total_energy.values
    assert e[-1] < 0.6 * e[0]                            # measured −53 % in 2 s


# ------------------------------------------------------------------------------------------
# Symmetric plate impact, steel_4340 on itself at 300 and 500 m/s, in the hydrodynamic limit
# (shear_modulus = 0): u_p = v/2, U_s = C + S1 u_p, p = ρ0 U_s u_p
# (studies/scenes/verify_plate_impact_300.toml, verify_plate_impact_500.toml)
# ------------------------------------------------------------------------------------------
PLATE_SPEEDS = (300, 500)
BEHIND_FRONT = 0.3e-6   # s: a probe's plateau starts this long after the front (half of p)
#                         passed it, ≈ 1.5 mm = 12 cells behind it (the 10–90 % rise of the
#                         front takes ≈ 0.15 µs); it ends at end_time, before any release


def plate_scene(speed, strength=False, dx=None):
    """The shipped scene; ``strength``: the library's 4340 (JC strength, elastic precursor);
    ``dx``: another cell size (the strip stays 6 cells high, probes at its middle)."""
    s = load_scene(f"verify_plate_impact_{speed}")
    if strength:
        del s["materials"]["steel"]["shear_modulus"]
    if dx is not None:
        s["cell_size"] = dx
        s["domain"]["y"] = [0.0, 6 * dx]
        for b in s["bodies"]:
            b["max"][1] = 6 * dx
        for pr in s["probes"]:
            pr["point"][1] = 3 * dx
    return s


def arrival(t, p, level):
    """First time p reaches level, interpolated linearly between the two samples around it."""
    k = int(np.flatnonzero(p >= level)[0])
    return t[k - 1] + (level - p[k - 1]) * (t[k] - t[k - 1]) / (p[k] - p[k - 1])


def plate_impact(speed, strength=False, dx=None):
    """Run one plate impact; returns the exact Hugoniot state and the measured one.

    U_s: least-squares slope of the probes' initial x against the arrival of half the exact
    shocked pressure (interpolated between samples). p (EOS pressure p*), s_n = p* − s_xx
    (total normal stress; q ≈ 0 behind the front) and u: means over every probe's plateau."""
    scene = plate_scene(speed, strength, dx)
    s = MPMSolver.from_scene(scene)
    nom = s.nominal()
    up = speed / 2
    us = nom["steel.eos.C"] + nom["steel.eos.S1"] * up
    exact = dict(us=us, p=nom["steel.rho0"] * us * up, u=up)
    ds = s.run({})
    t = ds.time.values
    x = np.array([pr["point"][0] for pr in scene["probes"]])
    P, U, S = ds.pressure.values, ds.velocity_x.values, ds.S11.values
    arr = np.array([arrival(t, P[:, k], 0.5 * exact["p"]) for k in range(x.size)])
    behind = t[:, None] > arr[None, :] + BEHIND_FRONT
    e = ds.total_energy.values
    return dict(exact=exact, ds=ds, arrivals=arr,
                measured=dict(us=np.polyfit(arr, x, 1)[0], p=P[behind].mean(),
                              u=U[behind].mean(), sn=(P - S)[behind].mean()),
                energy_drift=e[-1] / e[0] - 1)


@pytest.fixture(scope="module", params=PLATE_SPEEDS)
def plate(request):
    return request.param, plate_impact(request.param)


def _rel(r, key):
    return r["measured"][key] / r["exact"][key] - 1


def test_plate_impact_shock_speed(plate):
    v, r = plate
    assert abs(_rel(r, "us")) < 0.03       # measured −0.63 % (300 m/s), −0.39 % (500 m/s)


def test_plate_impact_pressure(plate):
    v, r = plate
    assert abs(_rel(r, "p")) < 0.03        # measured +0.19 % (300 m/s), +0.83 % (500 m/s)


def test_plate_impact_particle_velocity(plate):
    v, r = plate
    assert abs(_rel(r, "u")) < 0.03        # measured +0.02 % (300 m/s), −0.05 % (500 m/s)


def test_plate_impact_energy(plate):
    v, r = plate
    assert abs(r["energy_drift"]) < 0.01   # measured −0.10 % (300 m/s), −0.28 % (500 m/s)


def test_plate_impact_with_strength():
    """The library's 4340 (JC strength) at 500 m/s: the symmetry still fixes u_p = v/2, and
    the hydrodynamic p = ρ0 U_s u_p falls between the EOS pressure p* (below) and the total
    normal stress p* − s_xx (above) behind the plastic shock (docs/mpm_verification.md)."""
    r = plate_impact(500, strength=True)
    m, p = r["measured"], r["exact"]["p"]
    assert abs(_rel(r, "u")) < 0.03        # measured −0.59 %
    assert abs(_rel(r, "us")) < 0.03       # measured −0.21 % (plastic front; precursor ahead)
    assert m["p"] < p < m["sn"]            # measured 9.45 < 9.67 < 9.95 GPa (−2.3 %, +2.8 %)
    assert abs(r["energy_drift"]) < 0.01   # measured −0.09 %


# ------------------------------------------------------------------------------------------
# Guards: each a SolverError naming step, particle, material and the value
# ------------------------------------------------------------------------------------------

def block_scene(**over):
    s = dict(domain=dict(x=[0.0, 0.1], y=[0.0, 0.1]), cell_size=0.01, particles_per_cell=2,
             materials=dict(m=dict(model="elastic", rho0=1000.0, E=1e6, nu=0.3)),
             bodies=[dict(name="block", material="m", shape="rectangle", min=[0.06, 0.02],
                          max=[0.1, 0.06], velocity=[0.0, 0.0])],
             end_time=0.01, output_interval=0.001, outputs=["pressure"])
    s.update(over)
    return s


def test_guard_particle_leaves_grid():
    sc = block_scene()
    sc["bodies"][0]["velocity"] = [50.0, 0.0]      # flies out through the free right side
    with pytest.raises(SolverError) as e:
        MPMSolver.from_scene(sc).run({})
    msg = str(e.value)
    assert "left the padded grid" in msg
    assert "step " in msg and "particle " in msg and "material 'm'" in msg
    assert "body 'block'" in msg and "position (" in msg


def test_guard_dt_floor():
    with pytest.raises(SolverError, match=r"step 0 .*time step .* below the floor 1 s.*"
                                          r"particle \d+ .*material 'm'.*c \+ \|v\| ="):
        MPMSolver.from_scene(block_scene(dt_min=1.0)).run({})


def test_guard_non_finite_velocity():
    s = MPMSolver.from_scene(block_scene())
    s.parts.vx[3] = np.nan
    with pytest.raises(SolverError, match=r"step 0 .*particle \d+ .*material 'm'.*non-finite"):
        s.run({})
    s.parts.vx[3] = 0.0
    assert np.isfinite(s.run({}).pressure.values).all()     # the solver is reusable


@njit(cache=True)
def _faulty_update(prm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y):
    """elastic, but returns the code prm[3] once the density passes prm[4]·ρ0."""
    code = elastic.update(prm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y)
    if code == 0 and S[i, state.RHO] > prm[4] * prm[0]:
        return int(prm[3])
    return code


class _Faulty:
    """A material module (elastic + a failure code) for the core's error path."""
    NAME = "faulty"
    PARAMETERS = dict(elastic.PARAMETERS, code=float(state.ERR_DENSITY), ratio=1.001)
    HAS_STRENGTH = True
    init = staticmethod(elastic.init)
    update = staticmethod(_faulty_update)

    @staticmethod
    def pack(values):
        return state.pack_parameters(_Faulty.PARAMETERS, values, "faulty")


@pytest.mark.parametrize("code, text", [(state.ERR_DENSITY, "non-positive density"),
                                        (state.ERR_MG_DENOMINATOR, "Mie-Gruneisen"),
                                        (state.ERR_NONFINITE, "non-finite")])
def test_guard_material_codes(monkeypatch, code, text):
    monkeypatch.setitem(library.MATERIALS, "faulty", (_Faulty, {}))
    sc = block_scene(materials=dict(m=dict(model="faulty", rho0=1000.0, E=1e6, nu=0.3,
                                           code=float(code))))
    sc["bodies"][0]["velocity"] = [-5.0, 0.0]
    sc["boundaries"] = dict(left="fixed")
    sc["bodies"][0]["min"] = [0.0, 0.02]
    sc["bodies"][0]["max"] = [0.04, 0.06]
    with pytest.raises(SolverError) as e:
        MPMSolver.from_scene(sc).run({})
    msg = str(e.value)
    assert text in msg and f"[code {code}]" in msg
    assert "material update" in msg and "material 'm' [faulty]" in msg
    assert "particle " in msg and "rho = " in msg and "mu = " in msg


def test_guards_under_numba_boundscheck(tmp_path):
    """The guard tests above again in a fresh process with NUMBA_BOUNDSCHECK=1 (every array
    access of every kernel checked, a fresh numba cache so everything compiles with the
    checks): a guard that let a bad particle index the grid would raise IndexError there
    instead of the SolverError the tests expect."""
    repo = Path(__file__).resolve().parents[3]
    env = dict(os.environ, NUMBA_BOUNDSCHECK="1", NUMBA_CACHE_DIR=str(tmp_path),
               PYTHONPATH=str(repo) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          str(Path(__file__)), "-k", "test_guard_ and not boundscheck"],
                         cwd=repo, env=env, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert " passed" in out.stdout and "failed" not in out.stdout


def test_guard_bad_parameter_is_solver_error():
    s = MPMSolver.from_scene(block_scene())
    with pytest.raises(SolverError, match=r"material .m. .*nu = 0.7"):
        s.run({"m.nu": 0.7})
    with pytest.raises(SolverError, match="unknown parameter 'm.X'"):
        s.run({"m.X": 1.0})
    with pytest.raises(SolverError, match="not finite"):
        s.run({"m.E": float("nan")})


# ------------------------------------------------------------------------------------------
# 1-D TNT slab, detonated at one end: front at D, peak towards P_CJ
# (studies/scenes/verify_tnt_slab.toml)
# ------------------------------------------------------------------------------------------
D_TNT, P_CJ = 6930.0, 21e9


def tnt_slab():
    """Run the slab; returns (ds, front speed from the arrival of half the peak pressure at
    probes a and b, 0.03 m apart — the sample at or past the level, as sampled)."""
    ds = MPMSolver.from_scene(load_scene("verify_tnt_slab")).run({})
    t = ds.time.values
    arrival = {}
    for name in ("a", "b"):
        p = ds.pressure.sel(probe=name).values
        arrival[name] = t[np.flatnonzero(p > 0.5 * p.max())[0]]
    return ds, 0.03 / (arrival["b"] - arrival["a"])


def test_tnt_slab_detonation():
    ds, D = tnt_slab()
    for name in ("a", "b"):
        assert ds.burn_fraction.sel(probe=name).values[-1] == 1.0
    assert D == pytest.approx(D_TNT, rel=0.03)   # measured 6897 m/s, −0.5 % (0.05 µs samples)
    peak = ds.pressure.sel(probe="b").values.max()
    assert abs(peak / P_CJ - 1) < 0.15                # measured 18.3 GPa (−12.8 %)
    e = ds.total_energy.values
    assert abs(e[-1] / e[0] - 1) < 0.01       # measured −0.16 % (chemical → kinetic + internal)
