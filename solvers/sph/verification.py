"""Measurements of the seed's Example 1 shared by the tests, the figures and the docs table
(`python -m solvers.sph.verification` prints the table of docs/sph.md § 9)."""

from __future__ import annotations

import time

import numpy as np

from solvers.sph.exact import eshelby_constant, eshelby_radial
from solvers.sph.layouts import polar_layout
from solvers.sph.problem import ElasticProblem
from solvers.sph.stiffness import Discretisation

#: the seed's Example 1 (R = 20, eps* = 0.01; inclusion E = 1000, nu = 0.28; matrix 900, 0.33)
RADIUS, OUTER, EIGENSTRAIN = 20.0, 60.0, 0.01
INCLUSION, MATRIX = (1000.0, 0.28), (900.0, 0.33)


def example1_problem(spacing=2.0, method="master-slave", variant="plane_strain", **extra):
    layout = polar_layout(RADIUS, OUTER, spacing)
    disc = Discretisation(layout, extra.pop("smoothing_ratio", 2.0))
    inside = layout.phase > 0
    E = np.where(inside, INCLUSION[0], MATRIX[0])
    nu = np.where(inside, INCLUSION[1], MATRIX[1])
    eigen = np.zeros((layout.n, 3))
    eigen[inside, :2] = EIGENSTRAIN
    zz = np.where(inside, EIGENSTRAIN, 0.0) if variant == "plane_strain_3d" else None
    state = "plane_stress" if variant == "plane_stress" else "plane_strain"
    problem = ElasticProblem(disc, E, nu, state, eigenstrain=eigen, eigenstrain_zz=zz,
                             method=method, **extra)
    return layout, problem


def example1_errors(spacing=2.0, method="master-slave", variant="plane_strain",
                    condition=False, **extra) -> dict:
    """Radial-displacement error (max over particles, relative to u_r(R)), the radial strain
    on both sides of the interface, the pair error (seed eq. 25), the x/y-axis symmetry error
    (eq. 26), the constraint residual, the condition estimate and the wall time."""
    t0 = time.perf_counter()
    layout, problem = example1_problem(spacing, method, variant, **extra)
    C = eshelby_constant(EIGENSTRAIN, *INCLUSION, *MATRIX, variant)
    edge = layout.x[layout.boundary]
    r_edge = np.hypot(edge[:, 0], edge[:, 1])
    values = edge * (eshelby_radial(r_edge, RADIUS, C)[0] / r_edge)[:, None]
    sol = problem.solve(values, condition=condition)
    x = layout.x
    r = np.hypot(x[:, 0], x[:, 1])
    safe = np.where(r > 0, r, 1.0)
    u_r = np.where(r > 0, (sol.displacement * x).sum(axis=1) / safe, 0.0)
    exact = eshelby_radial(r, RADIUS, C)[0]
    n = x / safe[:, None]
    e = sol.strain
    e_rr = e[:, 0] * n[:, 0] ** 2 + e[:, 1] * n[:, 1] ** 2 + e[:, 2] * n[:, 0] * n[:, 1]
    m_side, i_side = layout.pairs[:, 0], layout.pairs[:, 1]
    on_x = (np.abs(x[:, 1]) == 0.0) & (x[:, 0] > 0)
    on_y = (np.abs(x[:, 0]) == 0.0) & (x[:, 1] > 0)
    # the layout is bitwise D4-symmetric: each x-axis particle has its twin on the y axis
    keys = {round(float(v), 12): i for i, v in zip(np.flatnonzero(on_y), x[on_y, 1])}
    twins = [(i, keys[round(float(v), 12)]) for i, v in zip(np.flatnonzero(on_x), x[on_x, 0])]
    sym = max(abs(u_r[i] - u_r[j]) for i, j in twins) / (C * RADIUS)
    return {"spacing": spacing, "particles": layout.n, "method": method,
            "radial_error": float(np.abs(u_r - exact).max() / (C * RADIUS)),
            "C": C, "strain_inside": float(np.mean(e_rr[i_side])),
            "strain_outside": float(np.mean(e_rr[m_side])),
            "pair_error": sol.pair_error, "symmetry_error": float(sym),
            "constraint_residual": sol.constraint_residual, "condition": sol.condition,
            "seconds": time.perf_counter() - t0}


def example1_table(spacing=2.0):
    rows = [example1_errors(spacing, "master-slave", condition=True),
            example1_errors(spacing, "master-slave-local", condition=True)]
    for threshold in (1e-10, 1e-6, 1e-3):
        rows.append(dict(example1_errors(spacing, "master-slave-cutoff", condition=True,
                                         cutoff_threshold=threshold), threshold=threshold))
    for w in (1e2, 1e4, 1e6):
        rows.append(dict(example1_errors(spacing, "penalty", condition=True, penalty=w),
                         penalty=w))
    return rows


def rigid_rotation(x, u):
    """Least-squares rigid rotation (radians) of displacements ``u`` at points ``x``."""
    p = x - x.mean(axis=0)
    v = u - u.mean(axis=0)
    return float(np.sum(p[:, 0] * v[:, 1] - p[:, 1] * v[:, 0]) / np.sum(p * p))


def example2_rotations(layout, inclusion: int, kept_pairs, methods, pull=0.05e-6,
                       integration="vci", spacing_ratio=2.0):
    """Rotation of inclusion ``inclusion`` held only by ``kept_pairs`` (indices into its own
    pairs) under the seed's Example 2 load, per (method, penalty) in ``methods``; relative
    to the plate's strain so it reads as an angle per unit strain."""
    from solvers.sph.loading import tension_boundary_values
    disc = Discretisation(layout, spacing_ratio)
    inside = layout.phase > 0
    E = np.where(inside, 150e6, 1e6)
    nu = np.where(inside, 0.3, 0.4)
    own = np.flatnonzero(layout.pair_inclusion == inclusion)
    intact = np.ones(layout.pairs.shape[0], dtype=bool)
    intact[own] = False
    intact[own[np.asarray(kept_pairs, dtype=int)]] = True
    members = layout.phase == inclusion + 1
    strain = 2.0 * pull / (layout.x[:, 1].max() - layout.x[:, 1].min())
    out = {}
    for method, penalty in methods:
        problem = ElasticProblem(disc, E, nu, method=method, penalty=penalty or 1e4,
                                 integration=integration)
        sol = problem.solve(tension_boundary_values(layout, pull), intact)
        out[(method, penalty)] = rigid_rotation(layout.x[members],
                                                sol.displacement[members]) / strain
    return out


def study_realization_seed(study_seed: int, index: int) -> int:
    """The layout seed uqflow gives realization ``index`` of a study seeded ``study_seed``
    (uqflow.execute: a SeedSequence spawned by realization index)."""
    return int(np.random.SeedSequence(study_seed, spawn_key=(index,)).generate_state(1)[0])


def window_refinement(scene: dict, layout_seed: int, resolutions=(1, 2, 3, 4),
                      methods=("master-slave-local", "master-slave"), params=None):
    """The apparent modulus of one random window, its ellipses held fixed, at finer spacings:
    rows (method, resolution, particles, E, E/HS lower, E/Reuss, E/Voigt)."""
    import math

    from solvers.sph.scene import parse
    from solvers.sph.scene_layout import scene_layout
    from solvers.sph.solver import SPHSolver
    base = dict(scene, steps=1)
    layout = scene_layout(parse(base), layout_seed)
    fixed = dict(base, layout="regular",
                 inclusions=[dict(centre=[e.cx, e.cy], semi_axes=[e.a, e.b],
                                  angle_deg=math.degrees(e.angle)) for e in layout.inclusions])
    fixed.pop("random", None)
    rows = []
    for method in methods:
        for r in resolutions:
            ds = SPHSolver.from_scene(dict(fixed, constraints=method, resolution=float(r))) \
                .run(params or {})
            E = ds.effective_modulus.item()
            rows.append((method, r, int(ds.particles.item()), E, E / ds.modulus_hs_lower.item(),
                         E / ds.modulus_reuss_bound.item(), E / ds.modulus_voigt_bound.item()))
    return rows


if __name__ == "__main__":
    import sys
    if sys.argv[1:] == ["--window"]:
        # docs/sph.md § 8: realization 2 of studies/sph/composite_mc.toml (study seed 2021)
        import tomllib
        from pathlib import Path
        with open(Path(__file__).parents[2] / "studies/scenes/sph_example3.toml", "rb") as fh:
            scene = tomllib.load(fh)
        print("| constraints | resolution | particles | E (Pa) | E / HS lower | E / Reuss | "
              "E / Voigt |")
        print("|---|---|---|---|---|---|---|")
        for m, r, n, E, hs, reuss, voigt in window_refinement(
                scene, study_realization_seed(2021, 2)):
            print(f"| {m} | {r} | {n:,} | {E:.6g} | {hs:.4f} | {reuss:.4f} | {voigt:.4f} |")
    else:
        print("| method | parameter | radial error | pair error | symmetry error | condition |")
        print("|---|---|---|---|---|---|")
        for row in example1_table():
            p = row.get("threshold", row.get("penalty", ""))
            print(f"| {row['method']} | {p} | {row['radial_error']:.2e} | {row['pair_error']:.1e} "
                  f"| {row['symmetry_error']:.1e} | {row['condition']:.1e} |")
