"""Our versions of seed 001's Figs. 4-6, 8, 11 and 14-15, written to docs/figures/sph_*.png.

    python benchmarks/sph_figures.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import FIGURES  # noqa: E402

from solvers.sph import SPHSolver  # noqa: E402
from solvers.sph.exact import eshelby_radial  # noqa: E402
from solvers.sph.verification import (RADIUS, example1_errors, example1_problem,  # noqa: E402
                                      example1_table)


def radial_profiles(ax_u, ax_e):
    """Fig. 4: radial displacement and strain along the x axis against the exact solution."""
    for method, style in (("master-slave", "o"), ("penalty", "x")):
        layout, problem = example1_problem(2.0, method, penalty=1e4)
        r0 = example1_errors(2.0, method, penalty=1e4) if method == "penalty" else \
            example1_errors(2.0, method)
        C = r0["C"]
        edge = layout.x[layout.boundary]
        re = np.hypot(*edge.T)
        sol = problem.solve(edge * (eshelby_radial(re, RADIUS, C)[0] / re)[:, None])
        on = (layout.x[:, 1] == 0) & (layout.x[:, 0] >= 0)
        r = layout.x[on, 0]
        order = np.argsort(r, kind="stable")
        ax_u.plot(r[order], sol.displacement[on, 0][order], style, ms=4, mfc="none",
                  label=method)
        ax_e.plot(r[order], sol.strain[on, 0][order], style, ms=4, mfc="none", label=method)
    rr = np.linspace(0, 60, 601)
    u, err, _ = eshelby_radial(rr, RADIUS, C)
    ax_u.plot(rr, u, "k-", lw=1, label="exact")
    ax_e.plot(rr, err, "k-", lw=1, label="exact")
    ax_u.set(xlabel="r", ylabel="u_r", title="radial displacement (Fig. 4a)")
    ax_e.set(xlabel="r", ylabel="ε_rr", title="radial strain (Fig. 4b)")
    ax_u.legend()


def main():
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    radial_profiles(*ax)
    fig.tight_layout()
    fig.savefig(FIGURES / "sph_example1_radial.png", dpi=110)
    plt.close(fig)

    rows = example1_table()
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    labels = [r["method"].replace("master-slave", "MS") + (f" {r.get('threshold', r.get('penalty', ''))}"
                                                           if "threshold" in r or "penalty" in r else "")
              for r in rows]
    for a, key, title in ((ax[0], "pair_error", "pair error (Figs. 5, 11)"),
                          (ax[1], "symmetry_error", "x/y symmetry error (Fig. 6)")):
        a.bar(range(len(rows)), [max(r[key], 1e-17) for r in rows])
        a.set_yscale("log")
        a.set_xticks(range(len(rows)), labels, rotation=60, ha="right", fontsize=8)
        a.set_title(title)
    fig.tight_layout()
    fig.savefig(FIGURES / "sph_example1_errors.png", dpi=110)
    plt.close(fig)

    example3_figure()
    example2_figure()


def plate_scene(method, steps, **extra):
    """The seed's Example 2/3 plate: the ellipses random sequential addition draws from
    layout_seed = 3 (docs/sph.md § 9), given as a fixed layout so every particle's
    displacement and stress are outputs."""
    drawn = SPHSolver.from_scene(dict(
        layout="random", width=100e-6, height=100e-6, spacing=2.5e-6,
        random=dict(count=9, semi_axes_min=[6e-6, 3e-6], semi_axes_max=[10e-6, 6e-6],
                    layout_seed=3), matrix=dict(E=1e6, nu=0.4), inclusion=dict(E=150e6, nu=0.3),
        loading="tension", step=0.05e-6, steps=1)).layout.inclusions
    inclusions = [dict(centre=[e.cx, e.cy], semi_axes=[e.a, e.b],
                       angle_deg=float(np.degrees(e.angle))) for e in drawn]
    return dict(layout="regular", width=100e-6, height=100e-6, spacing=2.5e-6,
                inclusions=inclusions, matrix=dict(E=1e6, nu=0.4),
                inclusion=dict(E=150e6, nu=0.3), interface_strength=0.04e6, loading="tension",
                step=0.05e-6, steps=steps, constraints=method, **extra)


def example3_figure():
    """Figs. 14-15: the stress-strain curve of each method, and sigma_yy after 30 steps."""
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for method in ("master-slave", "master-slave-cutoff", "master-slave-local", "penalty"):
        solver = SPHSolver.from_scene(plate_scene(method, 30))
        ds = solver.run({})
        ax[0].plot(ds.strain * 100, ds.macro_stress / 1e3, label=method)
        if method == "master-slave":
            x = ds.x.values
            sc = ax[1].scatter(x[:, 0] * 1e6, x[:, 1] * 1e6, c=ds.stress.values[:, 1] / 1e3,
                               s=4, cmap="viridis")
            fig.colorbar(sc, ax=ax[1], label="σ_yy (kPa)")
            ax[1].set(aspect="equal", xlabel="x (µm)", ylabel="y (µm)",
                      title="σ_yy after 30 steps, MS (Fig. 15)")
    ax[0].set(xlabel="applied strain (%)", ylabel="mean σ_yy (kPa)",
              title="Example 3 stress–strain (Fig. 14)")
    ax[0].legend()
    fig.tight_layout()
    fig.savefig(FIGURES / "sph_example3.png", dpi=110)
    plt.close(fig)


def example2_figure():
    """Fig. 8: displacement vectors of the inclusion particles after 30 steps with debonding,
    MS and the penalty at 10^6, 10^4, 10^2 (relative weights), relative to each inclusion's
    mean displacement so that rotations show."""
    cases = [("master-slave", {}, "MS"), ("penalty", {"penalty": 1e6}, "PF 10⁶"),
             ("penalty", {"penalty": 1e4}, "PF 10⁴"), ("penalty", {"penalty": 1e2}, "PF 10²")]
    fig, axes = plt.subplots(1, 4, figsize=(16, 4.4))
    for ax, (method, extra, label) in zip(axes, cases):
        solver = SPHSolver.from_scene(plate_scene(method, 30, **extra))
        ds = solver.run({})
        x, u = ds.x.values, ds.displacement.values
        phase = solver.layout.phase
        rel = np.zeros_like(u)
        for k in np.unique(phase[phase > 0]):
            mine = phase == k
            rel[mine] = u[mine] - u[mine].mean(axis=0)
        inside = phase > 0
        ax.quiver(x[inside, 0] * 1e6, x[inside, 1] * 1e6, rel[inside, 0], rel[inside, 1],
                  angles="xy", scale_units="xy", scale=None, width=0.003)
        ax.set(aspect="equal", xlim=(-50, 50), ylim=(-50, 50), xlabel="x (µm)",
               title=f"{label}: {int(ds.intact_pairs.values[-1])} pairs intact")
    axes[0].set_ylabel("y (µm)")
    fig.suptitle("Displacement of the inclusion particles about each inclusion's mean, "
                 "30 steps (Fig. 8)")
    fig.tight_layout()
    fig.savefig(FIGURES / "sph_example2_vectors.png", dpi=110)
    plt.close(fig)

if __name__ == "__main__":
    main()
