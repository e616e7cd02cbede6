"""Incremental tension with interface debonding (seed §3.2 and Example 3; docs/sph.md § 6).

The rule, decided here because the seed leaves it open:
- the normal stress of a pair is n·σ̄·n with σ̄ the mean of its two particles' stresses (the
  traction is continuous across an intact interface; the mean is its natural estimate) and n
  the interface normal at the pair; tension is positive;
- after each solve every intact pair above its strength breaks, all together (so there are no
  ties to break and the outcome is bitwise reproducible), and the same load step is solved
  again until no new pair breaks;
- an inclusion left with fewer than two intact pairs cannot carry load (one point cannot hold
  an elastic body in equilibrium against a net force, and its rotation is free): it is
  **detached**, its last pair released, and its particles leave the system;
- the load is a prescribed displacement, so each step is a fresh linear solve (the seed's
  "Euler method": no path-dependent state but the pairs).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

TIMING_KEYS = ("neighbours", "assembly", "transformation", "solve")


def tension_boundary_values(layout, displacement: float) -> np.ndarray:
    """(nb, 2) prescribed values: u_y = ±displacement on the top and bottom edges, u_x = 0
    at the middle particle of each (no rigid motion, free lateral contraction); NaN = free."""
    normal = np.asarray(layout.boundary_normal, dtype=float)
    x = np.asarray(layout.x, dtype=float)[np.asarray(layout.boundary)]
    values = np.full((x.shape[0], 2), np.nan)
    top, bottom = normal[:, 1] > 0.5, normal[:, 1] < -0.5
    values[top, 1] = displacement
    values[bottom, 1] = -displacement
    middle = 0.5 * (x[:, 0].min() + x[:, 0].max())
    for edge in (top, bottom):
        idx = np.flatnonzero(edge)
        values[idx[np.argmin(np.abs(x[idx, 0] - middle))], 0] = 0.0
    return values


def pair_normal_stress(stress: np.ndarray, pairs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """n·σ̄·n per pair, σ̄ the mean of the matrix-side and inclusion-side stresses."""
    s = 0.5 * (stress[pairs[:, 0]] + stress[pairs[:, 1]])
    nx, ny = normals[:, 0], normals[:, 1]
    return s[:, 0] * nx * nx + s[:, 1] * ny * ny + 2.0 * s[:, 2] * nx * ny


@dataclass
class TensionHistory:
    strain: np.ndarray                 # (steps,) applied strain 2·displacement/height
    macro_stress: np.ndarray           # (steps,) volume mean of σ_yy over the plate
    intact_pairs: np.ndarray           # (steps,) after the step's last re-solve
    detached_inclusions: np.ndarray    # (steps,)
    constraint_residual: np.ndarray    # (steps,)
    pair_error: np.ndarray             # (steps,)
    effective_modulus: float           # σ̄_yy/ε̄ with every pair intact
    pair_break_step: np.ndarray        # (npairs,) step (1-based) a pair broke, 0 = never
    pair_break_resolve: np.ndarray     # (npairs,) re-solve within that step, -1 = never
    inclusion_detach_step: np.ndarray  # (n_inclusions,) 0 = never
    solves: int = 0
    timings: dict = field(default_factory=dict)
    last: object = None                # the final Solution


def run_tension(problem, layout, strength, step: float, steps: int,
                max_resolves: int | None = None) -> TensionHistory:
    """Pull the top and bottom edges apart by ``step`` per load step for ``steps`` steps."""
    pairs = np.asarray(layout.pairs).reshape(-1, 2)
    normals = np.asarray(layout.pair_normal, dtype=float).reshape(-1, 2)
    owner = np.asarray(layout.pair_inclusion)
    n_incl = len(layout.inclusions)
    strength = np.broadcast_to(np.asarray(strength, dtype=float), (pairs.shape[0],))
    volume = np.asarray(layout.volume, dtype=float)
    y = np.asarray(layout.x, dtype=float)[:, 1]
    height = float(y.max() - y.min())
    area = float(volume.sum())
    max_resolves = pairs.shape[0] + n_incl + 1 if max_resolves is None else max_resolves

    intact = np.ones(pairs.shape[0], dtype=bool)
    detached = np.zeros(n_incl, dtype=bool)
    h = TensionHistory(strain=2.0 * step * np.arange(1, steps + 1) / height,
                       macro_stress=np.zeros(steps), intact_pairs=np.zeros(steps, dtype=int),
                       detached_inclusions=np.zeros(steps, dtype=int),
                       constraint_residual=np.zeros(steps), pair_error=np.zeros(steps),
                       effective_modulus=np.nan,
                       pair_break_step=np.zeros(pairs.shape[0], dtype=int),
                       pair_break_resolve=np.full(pairs.shape[0], -1),
                       inclusion_detach_step=np.zeros(n_incl, dtype=int),
                       timings={k: problem.setup_timings.get(k, 0.0) for k in TIMING_KEYS})
    for k in range(1, steps + 1):
        values = tension_boundary_values(layout, k * step)
        for resolve in range(max_resolves):
            sol = problem.solve(values, intact, detached)
            h.solves += 1
            for key, seconds in sol.timings.items():
                h.timings[key] += seconds
            mean_stress = float(np.nansum(volume * sol.stress[:, 1])) / area
            if k == 1 and resolve == 0:
                h.effective_modulus = mean_stress / h.strain[0]
            broken = intact & (pair_normal_stress(sol.stress, pairs, normals) > strength)
            if not broken.any():
                break
            h.pair_break_step[broken] = k
            h.pair_break_resolve[broken] = resolve
            intact &= ~broken
            left = np.bincount(owner[intact], minlength=n_incl)
            newly = ~detached & (left < 2)
            if newly.any():
                detached |= newly
                h.inclusion_detach_step[newly] = k
                released = intact & newly[owner]
                h.pair_break_step[released] = k
                h.pair_break_resolve[released] = resolve
                intact &= ~released
        else:
            raise RuntimeError(f"step {k}: pairs still breaking after {max_resolves} re-solves")
        h.macro_stress[k - 1] = mean_stress
        h.intact_pairs[k - 1] = int(intact.sum())
        h.detached_inclusions[k - 1] = int(detached.sum())
        h.constraint_residual[k - 1] = sol.constraint_residual
        h.pair_error[k - 1] = sol.pair_error
        h.last = sol
    return h
