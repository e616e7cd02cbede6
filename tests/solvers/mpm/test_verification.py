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

from solvers.mpm.detonation_exact import (JWL, cj_point, free_end_fan, gamma3_wall_momentum,
                               polytropic_gamma, polytropic_taylor_pressure, taylor_wave)

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
    # bound: the two halves' sums differ only in their order, ≈ eps × 0.1 m/s per step over
    # ≈ 260 steps: ≈ 1e-14 (measured 1.5e-15); the stress likewise relative to its peak
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
# Detonation: what the physics decides. Programmed burn lights each particle at |x − x_det|/D,
# so the front speed is an input; the state behind the front, the Taylor wave and the wall's
# impulse are not: they follow from the JWL constants and E0 (detonation_exact.py computes
# them with scipy from the constants alone).
# (studies/scenes/verify_tnt_taylor_wave.toml, verify_gamma3_wall_impulse.toml,
# verify_tnt_slab.toml)
# ------------------------------------------------------------------------------------------
D_TNT, P_CJ_PUBLISHED = 6930.0, 21e9        # Dobratz & Crawford 1985, to 3 and 2 digits
TNT = library.MATERIALS["tnt"][1]      # the TNT data: jwl.py's defaults
TNT_EOS = JWL.from_parameters(TNT)
# the CJ state is extrapolated to the front (ξ = D) from a quadratic fit of the fan between
# ξ = D − CJ_FIT_SPAN and SMEARED_CELLS cells behind the front (the burn ramp of 1.5 cells
# and the bulk viscosity smear ≈ 6 cells at dx = 0.5 mm: docs/mpm_verification.md)
CJ_FIT_SPAN, SMEARED_CELLS = 1500.0, 8
PROFILE_TIMES = 3           # the last three output times: self-similar, so they overlay
FAN_PARTS = ("rear", "middle", "front")   # the fan ξ ∈ (c_w, D − smeared) in three thirds
COARSE_DX, FINE_DX = 0.5e-3, 0.25e-3      # the refinement pair of the profile checks
# CJ: the extrapolation's error does not fall steadily with dx (the smeared zone narrows
# slowly: ≈ 3, 3, 2 mm at 0.5, 0.25, 0.125 mm), so its bound is the largest error seen over
# that trio, 1.6 % (u at 0.125 mm), rounded up; the fit's own bias on the exact solution is
# 0.35 % at most
CJ_TOL = 0.02
# Taylor wave: the mean pressure error over each third of the fan falls at first order
# (ratios 2.0–2.2 from 0.5 to 0.25 mm and 1.9–3.9 from 0.25 to 0.125 mm), so the
# Richardson value 2 e(h) − e(2h) removes it; what is left, the next order, is ≤ 0.53 % in
# both pairs (0.5/0.25 and 0.25/0.125 mm): tolerance about twice that
FAN_TOL = 0.01
GAMMA3_TOL = 0.02    # wall momentum vs closed form: largest error 0.9 % (0.5 mm), 1.4 % (0.25)


def tnt_profile_scene(dx=None, over=None):
    """verify_tnt_taylor_wave with one probe per cell along the slab; ``dx`` another cell
    size, ``over`` material overrides (e.g. a perturbed E0)."""
    s = load_scene("verify_tnt_taylor_wave")
    dx = dx or s["cell_size"]
    length = s["bodies"][0]["max"][0]
    s["cell_size"] = dx
    s["domain"]["y"] = [0.0, 6 * dx]
    s["bodies"][0]["max"] = [length, 6 * dx]
    n = int(round(length / dx))
    s["probes"] = [dict(name=f"x{k}", point=[(k + 0.5) * dx, 0.0], body="slab")
                   for k in range(n)]
    s["materials"]["tnt"].update(over or {})
    return s


def tnt_profile(dx=None, over=None):
    """Run the slab at one resolution; the measured relative errors against the exact
    solution of the nominal TNT constants: the CJ state (the fan extrapolated to ξ = D) and
    the mean pressure error over each third of the fan; and the profile for the figure."""
    scene = tnt_profile_scene(dx, over)
    dx = scene["cell_size"]
    ds = MPMSolver.from_scene(scene).run({})
    wave = taylor_wave(TNT_EOS)
    cj = wave.cj
    t = ds.time.values
    last = slice(-PROFILE_TIMES, None)
    xi = (ds.position_x.values[last] / t[last, None]).ravel()
    p, rho, u = (ds[k].values[last].ravel() for k in ("pressure", "density", "velocity_x"))
    front = cj.D - SMEARED_CELLS * dx / t[-PROFILE_TIMES]
    window = (xi > cj.D - CJ_FIT_SPAN) & (xi < front)
    exact_window = dict(zip(("p", "rho", "u"), wave.at(xi[window])))
    errors, fit_bias = {}, {}
    for name, q, ref in (("p", p, cj.p), ("rho", rho, cj.rho), ("u", u, cj.u)):
        errors[f"cj_{name}"] = np.polyval(np.polyfit(xi[window] - cj.D, q[window], 2), 0) / ref - 1
        fit_bias[name] = np.polyval(np.polyfit(xi[window] - cj.D, exact_window[name], 2),
                                    0) / ref - 1
    edges = np.linspace(wave.wall_edge, front, len(FAN_PARTS) + 1)
    for part, lo, hi in zip(FAN_PARTS, edges[:-1], edges[1:]):
        k = (xi > lo) & (xi < hi)
        p_exact = wave.at(xi[k])[0]
        errors[f"fan_{part}"] = np.sum(p[k] - p_exact) / np.sum(p_exact)
    return dict(errors=errors, fit_bias=fit_bias, xi=xi, p=p, rho=rho, u=u, wave=wave, ds=ds,
                dx=dx)


def tnt_checks(over=None):
    """The detonation checks: the CJ state at the tests' resolution (0.25 mm) and the
    Richardson-extrapolated fan errors from the pair 0.5/0.25 mm."""
    coarse, fine = tnt_profile(COARSE_DX, over), tnt_profile(FINE_DX, over)
    errors = {k: v for k, v in fine["errors"].items() if k.startswith("cj_")}
    for part in FAN_PARTS:
        key = f"fan_{part}"
        errors[key] = 2 * fine["errors"][key] - coarse["errors"][key]
        errors[f"{key}_order_ratio"] = coarse["errors"][key] / fine["errors"][key]
    return dict(errors=errors, fit_bias=fine["fit_bias"], coarse=coarse, fine=fine)


def failed_checks(errors, parts=FAN_PARTS):
    """The names of the detonation checks these errors fail (the perturbation record)."""
    tol = {f"cj_{n}": CJ_TOL for n in ("p", "rho", "u")}
    tol.update({f"fan_{part}": FAN_TOL for part in parts})
    return sorted(k for k, t in tol.items() if not abs(errors[k]) < t)


def gamma3_wall_checks(dx=None, over=None):
    """The γ = 3 slab: the wall's momentum (the gas momentum: the wall is the only external
    force) against the closed form at every sample from t_d to 3 t_d; returns the largest
    relative error."""
    s = load_scene("verify_gamma3_wall_impulse")
    if dx is not None:
        s["cell_size"] = dx
        s["domain"]["y"] = [0.0, 6 * dx]
        s["bodies"][0]["max"][1] = 6 * dx
    s["materials"]["gas"].update(over or {})
    ds = MPMSolver.from_scene(s).run({})
    gas = s["materials"]["gas"]
    rho0, length = TNT["rho0"], s["bodies"][0]["max"][0]
    D = math.sqrt(16 * gas["eos.E0"] / rho0)         # the scene's CJ speed, = 6930 m/s
    assert D == pytest.approx(D_TNT, rel=1e-12) or over   # E0 = ρ0 D²/16 to round-off
    # from t_d on: the rarefaction from the free end at work; earlier the wall's momentum is
    # p_w t, checked on TNT above, and its start-up delay (burn ramp, ≈ 0.1 µs) dominates
    late = ds.time.values >= length / D_TNT
    t = ds.time.values[late]
    measured = ds.momentum_x.values[late] / s["domain"]["y"][1]
    exact = np.array([gamma3_wall_momentum(rho0, D_TNT, length, tk) for tk in t])
    return dict(error=np.max(np.abs(measured / exact - 1)), t=t, measured=measured,
                exact=exact)


# The free end (verify_tnt_free_end.toml): behind the front the products expand to V = 1.5–4,
# where B e^{−R2 V} is 27–41 % of the pressure. Each particle's pressure is compared with the
# isentrope through the CJ point at its own density — the path the fan's products follow —
# as the mean relative error over two bands of V. The flow has no length scale but dx, so the
# samples at 10 and 20 µs (dx/t = 50 and 25 m/s) are a refinement pair: the error falls at
# first order (ratios 1.77, 1.79 from the pair 50/25 m/s; 1.66, 1.90 from 25/12.5 m/s, a
# 40 µs run) and the Richardson value 2 e(t) − e(t/2) removes it.
FREE_END_BANDS = {"V_1.5_2.5": (1.5, 2.5), "V_2.5_4": (2.5, 4.0)}
FREE_END_TIMES = (10e-6, 20e-6)
# what the Richardson value leaves, the next order, is ≤ 0.19 % (V 1.5–2.5) and ≤ 0.70 %
# (V 2.5–4) over both pairs (+0.19/+0.17 %, +0.70/+0.18 %): tolerances about twice that.
# R2 ± 10 % moves the exact isentrope by +5.7/−4.8 % and +8.8/−6.3 % in these bands,
# more than 3 × the tolerances
FREE_END_TOL = {"V_1.5_2.5": 0.005, "V_2.5_4": 0.015}
TNT_FREE_END = free_end_fan(TNT_EOS)


def free_end_scene(over=None, length=None, end_time=None, dx=None):
    """verify_tnt_free_end with a probe on every particle of the slab's lower row; ``over``
    material overrides, ``length`` and ``end_time`` another run (the domain scales with the
    length), ``dx`` another cell size."""
    s = load_scene("verify_tnt_free_end")
    slab = s["bodies"][0]
    if dx is not None:
        s["cell_size"] = dx
        s["domain"]["y"] = [0.0, 6 * dx]
        slab["max"][1] = 6 * dx
    dx = s["cell_size"]
    if length is not None:          # the domain scaled, its ends on whole cells from x = 0
        scale = length / slab["max"][0]
        s["domain"]["x"] = [math.floor(scale * s["domain"]["x"][0] / dx) * dx,
                            math.ceil(scale * s["domain"]["x"][1] / dx) * dx]
        slab["max"][0] = length
    if end_time is not None:
        s["end_time"] = end_time
    n = int(round(2 * slab["max"][0] / dx))          # particles_per_cell = 2 along x
    s["probes"] = [dict(name=f"x{k}", point=[(k + 0.5) * dx / 2, 0.0], body="slab")
                   for k in range(n)]
    s["materials"]["tnt"].update(over or {})
    return s


def free_end_errors(ds, t):
    """At the sample nearest t: the mean relative pressure error of the particles in each band
    of V against the nominal isentrope at their own V, and the profile (ξ, V, p, u)."""
    j = int(np.argmin(np.abs(ds.time.values - t)))
    V = TNT_EOS.rho0 / ds.density.values[j]
    p = ds.pressure.values[j]
    errors = {}
    for band, (lo, hi) in FREE_END_BANDS.items():
        k = (V > lo) & (V < hi)
        errors[band] = np.sum(p[k]) / np.sum(TNT_FREE_END.isentrope_pressure(V[k])) - 1
    return errors, dict(t=ds.time.values[j], xi=ds.position_x.values[j] / ds.time.values[j],
                        V=V, p=p, u=ds.velocity_x.values[j])


def free_end_checks(over=None, length=None, end_time=None, times=FREE_END_TIMES):
    """Run the free-end slab once; the band errors at each of ``times`` and, for each
    consecutive pair (t/2, t), the Richardson value and the ratio e(t/2)/e(t)."""
    ds = MPMSolver.from_scene(free_end_scene(over, length, end_time)).run({})
    raw, profiles = zip(*(free_end_errors(ds, t) for t in times))
    pairs = [{band: (2 * fine[band] - coarse[band], coarse[band] / fine[band])
              for band in FREE_END_BANDS} for coarse, fine in zip(raw[:-1], raw[1:])]
    return dict(raw=raw, pairs=pairs, profiles=profiles, ds=ds)


def failed_free_end_checks(result):
    """The bands whose Richardson value (the pair 10/20 µs) is outside its tolerance."""
    return sorted(f"free_{band}" for band, (value, _) in result["pairs"][0].items()
                  if not abs(value) < FREE_END_TOL[band])


def test_jwl_cj_point_of_the_tnt_constants():
    """The reference itself: the tangency CJ point of the `tnt` JWL constants is the
    published TNT detonation (the constants were fitted to it)."""
    cj = cj_point(TNT_EOS)
    assert abs(cj.D - D_TNT) < 5.0                     # D given to 3 digits: ± 5 m/s; 6929.4
    assert abs(cj.p - P_CJ_PUBLISHED) < 0.5e9          # P_CJ to 2 digits: ± 0.5 GPa; 21.00
    # the CJ condition: the flow leaves the front at the sound speed, c = D − u;
    # c and D − u come from different formulas (isentrope slope, Rayleigh line), agreeing to
    # the tangency solve's accuracy, ≈ 1e-10 (central difference, docs of detonation_exact)
    assert cj.c == pytest.approx(cj.D - cj.u, rel=1e-6)   # bound: 1e-10 tangency error × 1e3 margin
    # the polytropic gas with the same ρ0, D, P_CJ has γ = 2.73, not the JWL's local 2.73 at
    # the front only: the isentropes part ways behind it (below)
    gamma = polytropic_gamma(TNT_EOS.rho0, cj.D, cj.p)
    assert gamma == pytest.approx(cj.rho * cj.c**2 / cj.p, rel=1e-6)   # bound: as above


def test_taylor_wave_quadrature_against_the_polytropic_closed_form():
    """JWL with A = B = 0 is the polytropic gas γ = 1 + ω: the quadrature of the Riemann
    invariant along the isentrope must reproduce Taylor's closed form."""
    gas = JWL(rho0=1630.0, A=0.0, B=0.0, R1=4.15, R2=0.95, omega=2.0, E0=1630.0 * D_TNT**2 / 16)
    wave = taylor_wave(gas)
    assert wave.cj.D == pytest.approx(D_TNT, rel=1e-9)  # bound: tangency solve ≈ 1e-10
    xi = np.linspace(0.0, D_TNT * (1 - 1e-9), 400)
    exact = polytropic_taylor_pressure(xi, 1630.0, D_TNT, 3.0)
    # bound: linear interpolation on 2001 points, (Δξ)² p''/8 ≈ 1e-7 of P_CJ, and the ODE's
    # rtol 1e-10
    assert np.max(np.abs(wave.at(xi)[0] / exact - 1)) < 1e-6
    assert wave.wall_pressure == pytest.approx(2 / 27 * 1630.0 * D_TNT**2, rel=1e-6)  # same
    # TNT: the polytropic cross-check with γ = ρ0 D²/P_CJ − 1 = 2.73 matches at the front and
    # departs towards the wall (JWL 5.64 GPa, polytropic 6.31 GPa): the JWL solution is the
    # reference
    tnt = taylor_wave(TNT_EOS)
    g = polytropic_gamma(TNT_EOS.rho0, tnt.cj.D, tnt.cj.p)
    front = polytropic_taylor_pressure([tnt.cj.D], TNT_EOS.rho0, tnt.cj.D, g)[0]
    assert front == pytest.approx(tnt.cj.p, rel=1e-9)  # bound: the same P_CJ, round-off
    assert tnt.wall_pressure / polytropic_taylor_pressure([0.0], TNT_EOS.rho0, tnt.cj.D, g)[0] \
        == pytest.approx(0.894, abs=0.001)     # 5.640 / 6.310 GPa, quoted to 3 digits


@pytest.fixture(scope="module")
def tnt():
    return tnt_checks()


def test_tnt_slab_cj_state(tnt):
    """p, ρ, u at the front (the fan at 0.25 mm extrapolated to ξ = D) are the JWL CJ point
    (P_CJ = 21.00 GPa, ρ = 2227.7 kg/m³, u = 1859.2 m/s)."""
    for name in ("p", "rho", "u"):
        assert abs(tnt["fit_bias"][name]) < 0.005    # the fit on the exact solution: ≤ 0.35 %
        assert abs(tnt["errors"][f"cj_{name}"]) < CJ_TOL    # measured −0.40, −0.15, −0.42 %


def test_tnt_slab_taylor_wave(tnt):
    """The pressure over the fan, ξ = x/t from c_w = 3617 m/s to the front, is the Taylor wave
    on the JWL isentrope through the CJ point: each third's mean error converges at first
    order, and its Richardson value is within FAN_TOL."""
    for part in FAN_PARTS:
        assert 1.5 < tnt["errors"][f"fan_{part}_order_ratio"] < 3.0   # measured 2.0–2.2
        assert abs(tnt["errors"][f"fan_{part}"]) < FAN_TOL   # measured −0.47, −0.07, −0.15 %


def test_gamma3_slab_wall_impulse():
    """γ = 3 products detonated at the wall: the momentum the wall gives against the
    closed form until 3 t_d (free expansion of the far end included)."""
    assert gamma3_wall_checks()["error"] < GAMMA3_TOL        # measured 0.8 %


def test_free_end_fan_isentrope_and_riemann_invariant():
    """The exact fan itself: R2 ± 10 % moves the isentrope in both bands by ≥ 3 × their
    tolerances (the premise of the free-end check), and along the fan ξ = u + c falls from D
    and u below zero (the products stream backwards)."""
    for factor in (0.9, 1.1):
        prm = dict(TNT, **{"eos.R2": factor * TNT["eos.R2"]})
        other = free_end_fan(JWL.from_parameters(prm))
        for band, (lo, hi) in FREE_END_BANDS.items():
            V = np.linspace(lo, hi, 400)
            shift = np.sum(other.isentrope_pressure(V)) / np.sum(
                TNT_FREE_END.isentrope_pressure(V)) - 1
            assert abs(shift) > 3 * FREE_END_TOL[band]       # +5.7/−4.8 %, +8.8/−6.3 %
    fan = TNT_FREE_END
    # bound: ξ = u + c = D at the CJ point to the tangency solve's ≈ 1e-10 (c = D − u, above)
    assert fan.xi[0] == pytest.approx(fan.cj.D, rel=1e-9)
    assert np.all(np.diff(fan.xi) < 0) and fan.u[-1] < -3000.0   # −3583 m/s at ρ = 0.05 ρ0


@pytest.fixture(scope="module")
def free_end():
    return free_end_checks()


def test_free_end_run_depends_on_dx_over_t_alone(free_end):
    """The premise of the refinement pair in time: a run with half the cells at 5 µs gives
    the band errors of the nominal run at 10 µs."""
    half = free_end_scene(length=0.05, end_time=5e-6, dx=0.25e-3)    # front at 35 mm at 5 µs
    errors, _ = free_end_errors(MPMSolver.from_scene(half).run({}), 5e-6)
    coarse, fine = free_end["raw"]
    for band in FREE_END_BANDS:
        # the Richardson value inherits this difference: bound it by 5 % of the refinement
        # step e(2h) − e(h) it stands in for; measured 0.1 % and 0.03 % of it
        assert abs(errors[band] - coarse[band]) < 0.05 * abs(coarse[band] - fine[band])


def test_tnt_free_end_products_follow_the_cj_isentrope(free_end):
    """Behind a CJ front started at a free end the products expand along the JWL isentrope
    through the CJ point: in the bands V 1.5–2.5 and 2.5–4 the particles' pressure at their
    own density converges at first order (dx/t 50 → 25 m/s) to it within FREE_END_TOL."""
    for band in FREE_END_BANDS:
        value, ratio = free_end["pairs"][0][band]
        assert 1.3 < ratio < 3.0             # measured 1.77, 1.79
        assert abs(value) < FREE_END_TOL[band]      # measured +0.19 %, +0.71 %


# The checks above must fail when the physics they guard changes: each JWL constant and E0
# perturbed by ±10 % in the run (the exact solutions stay those of the nominal constants).
# The table of docs/mpm_verification.md, "Perturbations": the checks each perturbation must
# fail — the CJ state at 0.25 mm (one run; R2 moves it too little, below) and the free end's
# bands (one run), whose Richardson values the doc lists.
PERTURBED_CONSTANTS = ("eos.A", "eos.B", "eos.R1", "eos.R2", "eos.omega", "eos.E0")
BOTH_BANDS = {f"free_{band}" for band in FREE_END_BANDS}
EXPECTED_FAILURES = {
    ("eos.A", 0.9): {"cj_p"} | BOTH_BANDS, ("eos.A", 1.1): {"cj_p"} | BOTH_BANDS,
    ("eos.B", 0.9): {"cj_p", "free_V_1.5_2.5"}, ("eos.B", 1.1): {"cj_p"} | BOTH_BANDS,
    ("eos.R1", 0.9): {"cj_p"} | BOTH_BANDS, ("eos.R1", 1.1): {"cj_p", "free_V_2.5_4"},
    ("eos.R2", 0.9): BOTH_BANDS, ("eos.R2", 1.1): BOTH_BANDS,
    ("eos.omega", 0.9): {"cj_p"} | BOTH_BANDS, ("eos.omega", 1.1): {"cj_p"} | BOTH_BANDS,
    ("eos.E0", 0.9): {"cj_p"} | BOTH_BANDS, ("eos.E0", 1.1): {"cj_p"} | BOTH_BANDS,
}


def perturbed_failures(name, factor, problems=("cj", "free")):
    """The checks of ``problems`` (the wall case's CJ state, the free end) that a run with
    ``name`` × ``factor`` fails (a run that cannot finish fails its checks too: "run")."""
    over = {name: factor * TNT[name]}
    runs = {"cj": lambda: failed_checks(tnt_profile(FINE_DX, over)["errors"], parts=()),
            "free": lambda: failed_free_end_checks(free_end_checks(over))}
    failed = set()
    for problem in problems:
        try:
            failed.update(runs[problem]())
        except SolverError:
            failed.add("run")
    return failed


@pytest.mark.slow
@pytest.mark.parametrize("name, factor", sorted(EXPECTED_FAILURES))
def test_detonation_checks_fail_for_perturbed_jwl(name, factor):
    expected = EXPECTED_FAILURES[name, factor]
    problems = {check.split("_")[0] for check in expected}     # only the runs the row needs
    failed = perturbed_failures(name, factor, sorted(problems))
    assert expected <= failed or "run" in failed, failed


@pytest.mark.slow
@pytest.mark.parametrize("factor", (0.9, 1.1))
@pytest.mark.parametrize("name", ("eos.omega", "eos.E0"))
def test_gamma3_wall_impulse_fails_for_perturbed_products(name, factor):
    """A = B = 0 in this scene (nothing to perturb) and R1, R2 multiply nothing."""
    gas = load_scene("verify_gamma3_wall_impulse")["materials"]["gas"]
    assert gamma3_wall_checks(over={name: factor * gas[name]})["error"] > GAMMA3_TOL


def test_r2_matters_only_where_the_products_have_expanded():
    """Why the wall case cannot catch R2 ± 10 % and the free end can: the exact CJ pressure
    moves by 0.3 % and the wall pressure (V = 1.12) by 0.6 %, under the tolerances the
    resolution allows there (CJ_TOL, FAN_TOL); the free end's isentrope, at V 1.5–4, moves by
    more than 3 × its tolerances (test_free_end_fan_isentrope_and_riemann_invariant)."""
    base = taylor_wave(TNT_EOS)
    for factor in (0.9, 1.1):
        prm = dict(TNT, **{"eos.R2": factor * TNT["eos.R2"]})
        w = taylor_wave(JWL.from_parameters(prm))
        assert abs(w.cj.p / base.cj.p - 1) < 0.004          # 0.20 %, 0.29 %
        assert abs(w.wall_pressure / base.wall_pressure - 1) < 0.007   # 0.54 %, 0.62 %
    assert TNT_EOS.rho0 / base.rho[0] < 1.15        # the wall state's V: 1.116


# A sanity check only: programmed burn lights each particle at |x − x_det|/D, so the front
# speed is an input, and halving E0 leaves it unchanged. What the physics decides is checked
# above (CJ state, Taylor wave, wall impulse).
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


def test_tnt_slab_detonation_sanity():
    ds, D = tnt_slab()
    for name in ("a", "b"):
        assert ds.burn_fraction.sel(probe=name).values[-1] == 1.0
    assert D == pytest.approx(D_TNT, rel=0.03)   # the input; ± 1.2 % from 0.05 µs sampling
    peak = ds.pressure.sel(probe="b").values.max()
    assert abs(peak / P_CJ_PUBLISHED - 1) < 0.15      # measured 18.3 GPa (−12.8 %): smeared spike
    e = ds.total_energy.values
    assert abs(e[-1] / e[0] - 1) < 0.01       # measured −0.16 % (chemical → kinetic + internal)
