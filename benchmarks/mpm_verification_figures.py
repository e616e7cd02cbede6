"""Figures and numbers of the MPM verification problems (docs/mpm_verification.md).

Runs the problems of tests/solvers/mpm/test_verification.py through that module's own scene
loaders and measurements (the scenes are studies/scenes/verify_*.toml), prints every number the
doc quotes and writes docs/figures/mpm_verify_{bar,disks,plate_impact,tnt,detonation,free_end}.png.
About a minute once numba's cache is warm:

    python benchmarks/mpm_verification_figures.py                  # everything
    python benchmarks/mpm_verification_figures.py detonation       # one problem (names below)
    python benchmarks/mpm_verification_figures.py --refine         # + the 0.125 mm / 40 µs runs
    python benchmarks/mpm_verification_figures.py --perturbations  # + the ±10 % JWL table
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from solvers.mpm import MPMSolver  # noqa: E402
from tests.solvers.mpm import test_verification as V  # noqa: E402

FIGURES = ROOT / "docs" / "figures"
DPI = 100


def bar():
    amp = 2 * V.V0 / math.pi
    for cells in (16, 32, 64):
        ds, vcm = V.run_bar(cells=cells)
        z = V.zero_crossings(ds.time.values, vcm)
        e = ds.total_energy.values
        period = 2 * np.mean(np.diff(z)) / V.PERIOD - 1
        print(f"bar {cells:3d} cells: period {100 * period:+.3f} %, <v> amplitude "
              f"{100 * (np.max(np.abs(vcm)) / amp - 1):+.4f} %, energy drift "
              f"{100 * (e[-1] / e[0] - 1):+.3f} % "
              f"(max |dev| {100 * np.max(np.abs(e / e[0] - 1)):.2f} %)")
        if cells == 32:
            keep = ds, vcm
    for shape in ("linear", "gimp"):
        ds, vcm = V.run_bar(cells=32, shape=shape, periods=2)
        z = V.zero_crossings(ds.time.values, vcm)
        e = ds.total_energy.values
        period = 2 * np.mean(np.diff(z)) / V.PERIOD - 1
        print(f"bar 32 cells {shape}: period {100 * period:+.3f} %, "
              f"energy drift {100 * (e[-1] / e[0] - 1):+.3f} %")
    ds, vcm = keep
    t = ds.time.values
    w = 2 * math.pi / V.PERIOD
    fig, ax = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    tip = ds.velocity_x.sel(probe="tip").values
    ax[0].plot(t, tip * 1e3, "C0", lw=1.5, label="tip (MPM)")
    ax[0].plot(t, V.V0 * np.cos(w * t) * 1e3, "k--", lw=0.8,
               label="tip, exact $v_0\\cos\\omega_1 t$")
    ax[0].plot(t, vcm * 1e3, "C1", lw=1.5, label="centre of mass (MPM)")
    ax[0].plot(t, amp * np.cos(w * t) * 1e3, "k:", lw=0.8,
               label="c.o.m., exact $(2v_0/\\pi)\\cos\\omega_1 t$")
    ax[0].set_ylabel("velocity (mm/s)")
    ax[0].set_ylim(-17, 11)
    ax[0].legend(fontsize=7, ncol=2, loc="lower center")
    e = ds.total_energy.values
    ax[1].plot(t, 100 * (e / e[0] - 1), "C2")
    ax[1].set_ylabel("total energy (% of initial)")
    ax[1].set_xlabel("time (s)")
    fig.suptitle("Fixed–free elastic bar, first mode, 32 cells (verify_elastic_bar.toml)",
                 fontsize=9)
    _save(fig, "mpm_verify_bar.png")


def disks():
    ds = MPMSolver.from_scene(V.disks_scene()).run({})
    a, b = ds.sel(probe="a"), ds.sel(probe="b")
    e = ds.total_energy.values
    dv = np.max(np.abs(a.velocity_x.values + b.velocity_x.values))
    ds11 = np.max(np.abs(a.S11.values - b.S11.values)) / np.max(np.abs(a.S11.values))
    k = ds.kinetic_energy.values
    print(f"disks: max |v_a + v_b| = {dv:.1e}, max |S11_a - S11_b| / max|S11| = {ds11:.1e}, "
          f"energy {100 * (e / e[0] - 1).min():+.2f} … {100 * (e / e[0] - 1).max():+.2f} %, "
          f"final v_a = {a.velocity_x.values[-1]:.4f}, min KE / KE0 = {k.min() / k[0]:.3f}")
    pic = MPMSolver.from_scene(V.disks_scene(flip=0.0, end=2.0)).run({}).total_energy.values
    print(f"disks PIC (2 s): energy {100 * (pic[-1] / pic[0] - 1):+.1f} %")
    t = ds.time.values
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(t, ds.kinetic_energy.values, label="kinetic")
    ax.plot(t, ds.internal_energy.values, label="strain")
    ax.plot(t, e, "k", label="total (FLIP)")
    ax.axhline(2 * 0.5 * 1000.0 * math.pi * 0.2**2 * 0.02, color="k", ls=":", lw=0.8,
               label="exact total")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("energy (J/m)")
    ax.legend(fontsize=7)
    ax.set_title("Two colliding elastic disks, 20 cells (verify_colliding_disks.toml)",
                 fontsize=9)
    _save(fig, "mpm_verify_disks.png")


def plate():
    runs = {v: V.plate_impact(v) for v in V.PLATE_SPEEDS}
    runs["500 + strength"] = V.plate_impact(500, strength=True)
    for key, r in runs.items():
        ex, m = r["exact"], r["measured"]
        print(f"plate {key} m/s: U_s {m['us']:.1f} vs {ex['us']:.1f} "
              f"({100 * V._rel(r, 'us'):+.2f} %); p* {m['p'] / 1e9:.3f} vs "
              f"{ex['p'] / 1e9:.3f} GPa ({100 * V._rel(r, 'p'):+.2f} %); p*-s_xx "
              f"{m['sn'] / 1e9:.3f} GPa ({100 * (m['sn'] / ex['p'] - 1):+.2f} %); u "
              f"{m['u']:.1f} vs {ex['u']:.1f} ({100 * V._rel(r, 'u'):+.2f} %); energy drift "
              f"{100 * r['energy_drift']:+.3f} %; wall {r['ds'].attrs['wall_time']:.2f} s")
    fig, ax = plt.subplots(2, 2, figsize=(9, 5.5), sharex=True)
    for col, v in enumerate(V.PLATE_SPEEDS):
        for key, ls in ((v, "-"), ("500 + strength", "--")):
            if key == "500 + strength" and v != 500:
                continue
            r = runs[key]
            ds, t = r["ds"], r["ds"].time.values * 1e6
            for k, name in enumerate(ds.probe.values):
                lab = f"{name}" if key == v else None
                ax[0, col].plot(t, ds.pressure.values[:, k] / 1e9, f"C{k}", ls=ls, lw=1,
                                label=lab)
                ax[1, col].plot(t, ds.velocity_x.values[:, k], f"C{k}", ls=ls, lw=1)
                ax[0, col].axvline((r["arrivals"][k] + V.BEHIND_FRONT) * 1e6, color=f"C{k}",
                                   lw=0.5, ls=":")
        ex = runs[v]["exact"]
        ax[0, col].axhline(ex["p"] / 1e9, color="k", lw=1, ls=":",
                           label=f"$\\rho_0 U_s u_p$ = {ex['p'] / 1e9:.2f} GPa")
        ax[1, col].axhline(ex["u"], color="k", lw=1, ls=":",
                           label=f"$u_p = v/2$ = {ex['u']:.0f} m/s")
        ax[0, col].set_title(f"{v} m/s, G = 0" + (" (dashed: JC strength)" if v == 500 else ""),
                             fontsize=9)
        ax[0, col].legend(fontsize=7, loc="lower right")
        ax[1, col].legend(fontsize=7, loc="lower right")
        ax[1, col].set_xlabel("time (µs)")
    ax[0, 0].set_ylabel("EOS pressure p* (GPa)")
    ax[1, 0].set_ylabel("particle velocity (m/s)")
    fig.suptitle("Symmetric 4340 plate impact, dx = 0.125 mm; probes 3, 5, 7, 9 mm into the "
                 "target; dotted verticals: start of each plateau window", fontsize=9)
    _save(fig, "mpm_verify_plate_impact.png")


def plate_resolution():
    """The hydrodynamic 500 m/s impact at four cell sizes (the tests use 0.125 mm)."""
    for dx in (0.5e-3, 0.25e-3, 0.125e-3, 0.0625e-3):
        r = V.plate_impact(500, dx=dx)
        print(f"plate 500 m/s, dx = {dx * 1e3:.4g} mm: U_s {100 * V._rel(r, 'us'):+.2f} %, "
              f"p {100 * V._rel(r, 'p'):+.2f} %, u {100 * V._rel(r, 'u'):+.2f} %")


def tnt():
    ds, D = V.tnt_slab()
    e = ds.total_energy.values
    peak = ds.pressure.sel(probe="b").values.max()
    peak_a = ds.pressure.sel(probe="a").values.max()
    print(f"tnt: D = {D:.0f} m/s ({100 * (D / V.D_TNT - 1):+.2f} %), peak at b {peak / 1e9:.2f} "
          f"GPa ({100 * (peak / V.P_CJ_PUBLISHED - 1):+.1f} %; at a {peak_a / 1e9:.2f} GPa), "
          f"energy drift {100 * (e[-1] / e[0] - 1):+.3f} %")
    t = ds.time.values * 1e6
    fig, ax = plt.subplots(figsize=(7, 3.2))
    for k, (name, x) in enumerate((("a", 0.03), ("b", 0.06))):
        ax.plot(t, ds.pressure.sel(probe=name).values / 1e9, f"C{k}",
                label=f"probe {name}, x = {x} m")
        ax.axvline(x / V.D_TNT * 1e6, color=f"C{k}", ls=":", lw=0.8)
    ax.axhline(V.P_CJ_PUBLISHED / 1e9, color="k", ls="--", lw=0.8, label="$P_{CJ}$ = 21 GPa")
    _label(ax, "time (µs)  (dotted: arrival at D = 6930 m/s)", "pressure (GPa)",
           "1-D TNT slab, dx = 0.5 mm (verify_tnt_slab.toml)")
    _save(fig, "mpm_verify_tnt.png")


def _label(ax, xlabel, ylabel, title):
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=7)
    ax.set_title(title, fontsize=9)


def _save(fig, name):
    fig.tight_layout()
    fig.savefig(FIGURES / name, dpi=DPI)
    plt.close(fig)


def _percent(errors):
    return ", ".join(f"{k} {100 * v:+.2f} %" for k, v in errors.items())


def _wall_rate(profile):
    """The TNT wall's momentum rate (per unit area, fitted over 2–10 µs) against p_w, in %:
    not a test (it does not converge below 0.25 mm, docs/mpm_verification.md)."""
    ds, dx = profile["ds"], profile["dx"]
    t = ds.time.values
    late = t > 2e-6
    slope = np.polyfit(t[late], ds.momentum_x.values[late] / (6 * dx), 1)[0]
    return 100 * (slope / profile["wave"].wall_pressure - 1)


def detonation(refine=False, perturbations=False):
    """The checks the physics decides (CJ state, Taylor wave, γ = 3 wall impulse), the
    refinement numbers their tolerances come from, and the figure."""
    from solvers.mpm.detonation_exact import (gamma3_wall_momentum, polytropic_gamma,
                                                     polytropic_taylor_pressure)
    r = V.tnt_checks()
    wave = r["fine"]["wave"]
    cj = wave.cj
    print(f"detonation: CJ point V {cj.V:.4f}, D {cj.D:.1f} m/s, p {cj.p / 1e9:.3f} GPa, "
          f"rho {cj.rho:.1f}, u {cj.u:.1f}, c {cj.c:.1f} m/s; wall p_w {wave.wall_pressure / 1e9:.3f}"
          f" GPa, c_w {wave.wall_edge:.1f} m/s")
    for name in ("coarse", "fine"):
        print(f"  dx {r[name]['dx'] * 1e3:g} mm: {_percent(r[name]['errors'])}; "
              f"wall rate {_wall_rate(r[name]):+.2f} %")
    print(f"  fit bias on the exact solution: {_percent(r['fit_bias'])}")
    checked = {k: v for k, v in r["errors"].items() if "ratio" not in k}
    ratios = ", ".join(f"{p} {r['errors'][f'fan_{p}_order_ratio']:.2f}" for p in V.FAN_PARTS)
    print(f"  checked (CJ at 0.25 mm, fan Richardson): {_percent(checked)}; "
          f"e(0.5 mm)/e(0.25 mm): {ratios}")
    if refine:
        f = V.tnt_profile(0.125e-3)
        print(f"  dx 0.125 mm: {_percent(f['errors'])}; wall rate {_wall_rate(f):+.2f} %")
        print("  Richardson 0.25/0.125 mm: " + ", ".join(
            f"fan_{p} {100 * (2 * f['errors'][f'fan_{p}'] - r['fine']['errors'][f'fan_{p}']):+.2f} %"
            for p in V.FAN_PARTS))
    g3 = V.gamma3_wall_checks()
    print(f"gamma3 wall impulse: largest error t_d..3 t_d {100 * g3['error']:.2f} %, at 3 t_d "
          f"{100 * (g3['measured'][-1] / g3['exact'][-1] - 1):+.2f} %")
    if perturbations:
        from solvers.mpm.materials.library import MATERIALS
        TNT = MATERIALS["tnt"][1]
        from uqflow.errors import SolverError
        for name in V.PERTURBED_CONSTANTS:
            for factor in (0.9, 1.1):
                try:
                    e = V.tnt_checks({name: factor * TNT[name]})["errors"]
                    shown = {k: v for k, v in e.items() if "ratio" not in k}
                    print(f"  {name} x {factor}: fails {V.failed_checks(e) or 'nothing'}; "
                          f"{_percent(shown)}")
                except SolverError as exc:
                    print(f"  {name} x {factor}: run stopped ({exc})")
        gas = V.load_scene("verify_gamma3_wall_impulse")["materials"]["gas"]
        for name in ("eos.omega", "eos.E0"):
            for factor in (0.9, 1.1):
                err = V.gamma3_wall_checks(over={name: factor * gas[name]})["error"]
                print(f"  gamma3 {name} x {factor}: largest error {100 * err:.2f} %")

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 3.6))
    xi = np.linspace(0.0, cj.D, 600)
    for name, style in (("coarse", "C1."), ("fine", "C0.")):
        m = r[name]
        ax.plot(m["xi"], m["p"] / 1e9, style, ms=1.5, label=f"MPM, dx = {m['dx'] * 1e3:g} mm")
    ax.plot(xi, wave.at(xi)[0] / 1e9, "k-", lw=1.2, label="Taylor wave, JWL isentrope")
    g = polytropic_gamma(V.TNT_EOS.rho0, cj.D, cj.p)
    ax.plot(xi, polytropic_taylor_pressure(xi, V.TNT_EOS.rho0, cj.D, g) / 1e9, "k:", lw=1,
            label=f"polytropic, γ = {g:.2f}")
    ax.plot([cj.D], [cj.p / 1e9], "k^", label="CJ point (tangency)")
    ax.set_xlim(0, 7500)
    _label(ax, "ξ = x / t (m/s), last three samples to 10 µs", "pressure (GPa)",
           "TNT detonated at a rigid wall (verify_tnt_taylor_wave.toml)")
    t_d = 0.04 / V.D_TNT
    bx.plot(g3["t"] / t_d, g3["measured"] / 1e3, "C0.", ms=3, label="MPM, dx = 0.5 mm")
    t = np.linspace(0.0, 3 * t_d, 200)
    bx.plot(t / t_d, [gamma3_wall_momentum(1630.0, V.D_TNT, 0.04, tk) / 1e3 for tk in t], "k-",
            lw=1, label="closed form (γ = 3)")
    bx.axhline(8 / 27 * 1630.0 * V.D_TNT * 0.04 / 1e3, color="k", ls="--", lw=0.8,
               label="8/27 ρ0 D ℓ (t → ∞)")
    _label(bx, "t / t_d  (t_d = ℓ / D)", "wall impulse (kN s/m²)",
           "γ = 3 slab, ℓ = 40 mm (verify_gamma3_wall_impulse.toml)")
    _save(fig, "mpm_verify_detonation.png")


# ξ windows of the free end's fan where R2 ± 10 % moves the exact pressure by 2–5 %: what a
# comparison against ξ = x/t would see (printed, not tested: FLIP noise is as large)
FREE_END_XI_WINDOWS = ((-1500.0, -700.0), (-700.0, 0.0), (0.0, 700.0), (700.0, 1500.0))


def _free_end_xi_errors(fan, profile):
    """Mean relative p error and mean u error (m/s) of the particles in each ξ window."""
    out = []
    for lo, hi in FREE_END_XI_WINDOWS:
        k = (profile["xi"] > lo) & (profile["xi"] < hi)
        p, _, u = fan.at(profile["xi"][k])
        out.append((100 * (np.sum(profile["p"][k]) / np.sum(p) - 1),
                    float(np.mean(profile["u"][k] - u))))
    return out


def free_end(refine=False, perturbations=False):
    """The free-end slab: the products against the CJ isentrope in two bands of V, the
    refinement pairs (10/20 µs, and 20/40 µs with --refine), R2 ± 10 % in the exact fan, the
    perturbation column of the doc's table, and the figure."""
    from solvers.mpm.materials.library import MATERIALS
    TNT = MATERIALS["tnt"][1]
    from solvers.mpm.detonation_exact import JWL, free_end_fan
    from uqflow.errors import SolverError
    fan = V.TNT_FREE_END
    shifted = {}
    for factor in (0.9, 1.1):
        prm = dict(TNT, **{"eos.R2": factor * TNT["eos.R2"]})
        shifted[factor] = free_end_fan(JWL.from_parameters(prm))
    for v in (1.5, 2.0, 3.0, 4.0):
        print(f"free end: V {v}: p {fan.isentrope_pressure(v) / 1e9:.3f} GPa "
              f"(R2 x 0.9 {shifted[0.9].isentrope_pressure(v) / 1e9:.3f}, x 1.1 "
              f"{shifted[1.1].isentrope_pressure(v) / 1e9:.3f})")
    for band, (lo, hi) in V.FREE_END_BANDS.items():
        grid = np.linspace(lo, hi, 400)
        ref = np.sum(fan.isentrope_pressure(grid))
        print(f"  band {band}: R2 x 0.9 / x 1.1 move the isentrope "
              + " / ".join(f"{100 * (np.sum(shifted[f].isentrope_pressure(grid)) / ref - 1):+.1f} %"
                           for f in (0.9, 1.1)))
    xi_shift = {}
    for f in (0.9, 1.1):
        cells = []
        for lo, hi in FREE_END_XI_WINDOWS:
            x = np.linspace(lo, hi, 200)
            cells.append((100 * (np.sum(shifted[f].at(x)[0]) / np.sum(fan.at(x)[0]) - 1),
                          float(np.mean(shifted[f].at(x)[2] - fan.at(x)[2]))))
        xi_shift[f] = cells
    print("  ξ windows " + ", ".join(f"{lo:g}..{hi:g}" for lo, hi in FREE_END_XI_WINDOWS)
          + ": R2 x 0.9 p/u " + "; ".join(f"{a:+.1f} % {b:+.0f} m/s" for a, b in xi_shift[0.9])
          + " | x 1.1 " + "; ".join(f"{a:+.1f} % {b:+.0f} m/s" for a, b in xi_shift[1.1]))
    if refine:
        r = V.free_end_checks(length=0.3, end_time=40e-6, times=(10e-6, 20e-6, 40e-6))
    else:
        r = V.free_end_checks()
    for raw, prof in zip(r["raw"], r["profiles"]):
        counts = {b: int(np.sum((prof["V"] > lo) & (prof["V"] < hi)))
                  for b, (lo, hi) in V.FREE_END_BANDS.items()}
        print(f"  t {prof['t'] * 1e6:.0f} µs (dx/t {0.5e-3 / prof['t']:.1f} m/s): "
              f"{_percent(raw)}; particles per band {counts}")
        print("    ξ windows, MPM p/u error: " + "; ".join(
            f"{a:+.1f} % {b:+.0f} m/s" for a, b in _free_end_xi_errors(fan, prof)))
    for k, pair in enumerate(r["pairs"]):
        print(f"  pair {k}: Richardson " + ", ".join(
            f"{band} {100 * value:+.2f} % (ratio {ratio:.2f})"
            for band, (value, ratio) in pair.items()))
    if perturbations:
        for name in V.PERTURBED_CONSTANTS:
            for factor in (0.9, 1.1):
                try:
                    p = V.free_end_checks({name: factor * TNT[name]})
                    values = ", ".join(f"{band} {100 * value:+.2f} %"
                                       for band, (value, _) in p["pairs"][0].items())
                    print(f"  free end {name} x {factor}: fails "
                          f"{V.failed_free_end_checks(p) or 'nothing'}; Richardson {values}")
                except SolverError as exc:
                    print(f"  free end {name} x {factor}: run stopped ({exc})")

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 3.6))
    grid = np.geomspace(1.0, 6.0, 300)
    nominal = fan.isentrope_pressure(grid)
    for prof, style in zip(r["profiles"][:2], ("C1.", "C0.")):
        on = prof["V"] > 1.0
        ax.plot(prof["V"][on], 100 * (prof["p"][on] / fan.isentrope_pressure(prof["V"][on]) - 1),
                style, ms=2.5,
                label=f"MPM, t = {prof['t'] * 1e6:.0f} µs (dx/t = {0.5e-3 / prof['t']:.0f} m/s)")
        bx.plot(prof["xi"], prof["p"] / 1e9, style, ms=1.5,
                label=f"MPM, t = {prof['t'] * 1e6:.0f} µs")
    for f, ls in ((0.9, "--"), (1.1, ":")):
        ax.plot(grid, 100 * (shifted[f].isentrope_pressure(grid) / nominal - 1), "k" + ls,
                lw=1, label=f"exact, R2 × {f}")
    ax.axhline(0.0, color="k", lw=1.2, label="exact (CJ isentrope)")
    for (lo, hi), shade in zip(V.FREE_END_BANDS.values(), ("0.92", "0.85")):
        ax.axvspan(lo, hi, color=shade, zorder=0)
    ax.set_xlim(1.0, 6.0)
    ax.set_ylim(-10, 15)
    _label(ax, "V = ρ0/ρ (the two checked bands shaded)", "p / p_isentrope(V) − 1 (%)",
           "TNT detonated at a free end: p against the CJ isentrope")
    xi = np.linspace(fan.xi[-1], fan.cj.D, 600)
    bx.plot(xi, fan.at(xi)[0] / 1e9, "k-", lw=1.2, label="centred fan to vacuum")
    bx.set_yscale("log")
    bx.set_xlim(-3500, 7500)
    bx.set_ylim(0.01, 30)
    _label(bx, "ξ = x / t (m/s)", "pressure (GPa)",
           "the same runs against ξ (verify_tnt_free_end.toml)")
    _save(fig, "mpm_verify_free_end.png")


PROBLEMS = {"bar": bar, "disks": disks, "plate": plate, "plate_resolution": plate_resolution,
            "tnt": tnt, "detonation": detonation, "free_end": free_end}


def main(argv):
    FIGURES.mkdir(parents=True, exist_ok=True)
    flags = {a for a in argv if a.startswith("--")}
    names = [a for a in argv if not a.startswith("--")] or list(PROBLEMS)
    unknown = [n for n in names if n not in PROBLEMS] + sorted(
        flags - {"--refine", "--perturbations"})
    if unknown:
        sys.exit(f"unknown problem or flag: {', '.join(unknown)} (problems: "
                 f"{', '.join(PROBLEMS)}; flags: --refine, --perturbations)")
    t0 = time.perf_counter()
    for name in names:
        if name in ("detonation", "free_end"):
            PROBLEMS[name](refine="--refine" in flags, perturbations="--perturbations" in flags)
        else:
            PROBLEMS[name]()
    print(f"total {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main(sys.argv[1:])
