"""Debonding under incremental tension (seed Examples 2-3; docs/sph.md § 7)."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from solvers.sph import SPHSolver
from solvers.sph.layouts import Box, random_layout
from solvers.sph.loading import pair_normal_stress, run_tension, tension_boundary_values
from solvers.sph.problem import ElasticProblem
from solvers.sph.stiffness import Discretisation
from solvers.sph.verification import example2_rotations
from uqflow.errors import SolverError

sys.path.insert(0, str(Path(__file__).parent))
from _scenes import example3  # noqa: E402


class SharedLoad:
    """A fake problem: each intact pair of an inclusion carries an equal share of a load that
    grows with the step, times a per-pair factor; so breaking pairs raises the others'."""

    def __init__(self, layout, factor):
        self.layout, self.factor = layout, np.asarray(factor, float)
        self.setup_timings = {}

    def solve(self, values, intact, detached):
        load = np.nanmax(values[:, 1])
        stress = np.zeros((self.layout.x.shape[0], 3))
        owner = self.layout.pair_inclusion
        share = np.bincount(owner, minlength=2) / np.maximum(
            np.bincount(owner[intact], minlength=2), 1)
        s = np.where(intact, load * self.factor * share[owner], 0.0)
        stress[self.layout.pairs[:, 0], 1] = s
        stress[self.layout.pairs[:, 1], 1] = s
        return SimpleNamespace(stress=stress, constraint_residual=0.0, pair_error=0.0,
                               timings={}, displacement=None)


def fake_layout():
    pairs = np.c_[np.arange(0, 8), np.arange(8, 16)]
    x = np.zeros((18, 2))
    x[16], x[17] = (0.0, -1.0), (0.0, 1.0)
    return SimpleNamespace(x=x, volume=np.ones(18), pairs=pairs,
                           pair_normal=np.tile([0.0, 1.0], (8, 1)),
                           pair_inclusion=np.repeat([0, 1], 4), inclusions=(0, 1),
                           boundary=np.array([16, 17]),
                           boundary_normal=np.array([[0.0, -1.0], [0.0, 1.0]]))


def test_pairs_above_strength_break_together_and_the_step_is_solved_again():
    lay = fake_layout()
    factor = [1.0, 1.0, 0.5, 0.4, 0.2, 0.2, 0.2, 0.2]
    h = run_tension(SharedLoad(lay, factor), lay, strength=1.5, step=1.0, steps=3)
    # step 1: no pair above 1.5; step 2: pairs 0, 1 carry 2.0 and break together, then the
    # inclusion's other two carry 2x share: 0.5*2*2 = 2.0 > 1.5 breaks pair 2 and leaves one
    # pair: detached; inclusion 1 (0.2 * 2 = 0.4) holds; step 3 too (0.6)
    assert h.pair_break_step.tolist() == [2, 2, 2, 2, 0, 0, 0, 0]
    assert h.pair_break_resolve.tolist()[:4] == [0, 0, 1, 1]
    assert h.inclusion_detach_step.tolist() == [2, 0]
    assert h.intact_pairs.tolist() == [8, 4, 4]
    assert h.detached_inclusions.tolist() == [0, 1, 1]
    again = run_tension(SharedLoad(lay, factor), lay, strength=1.5, step=1.0, steps=3)
    assert np.array_equal(again.pair_break_step, h.pair_break_step)


def test_normal_stress_uses_the_mean_of_both_sides_along_the_normal():
    stress = np.array([[1.0, 3.0, 0.5], [3.0, 1.0, -0.5]])
    n = np.array([[np.sqrt(0.5), np.sqrt(0.5)]])
    # mean stress [2, 2, 0]: n.s.n = 2
    assert pair_normal_stress(stress, np.array([[0, 1]]), n)[0] == pytest.approx(2.0, rel=1e-15)


def test_tension_holds_the_middle_of_the_top_and_bottom_edges_only():
    lay = random_layout(Box(-10.0, -10.0, 10.0, 10.0), 1.0, 1, ((3.0, 2.0), (3.0, 2.0)),
                        np.random.default_rng(0), min_gap=4.5)
    v = tension_boundary_values(lay, 0.1)
    assert np.count_nonzero(np.isfinite(v[:, 0])) == 2
    assert set(v[np.isfinite(v[:, 1]), 1]) == {0.1, -0.1}
    assert np.count_nonzero(np.isfinite(v[:, 1])) == 2 * 21   # top and bottom rows


@pytest.fixture(scope="module")
def plate():
    scene = example3()
    solver = SPHSolver.from_scene(scene)
    return solver.layout


def histories(layout, methods):
    disc = Discretisation(layout, 2.0)
    inside = layout.phase > 0
    E, nu = np.where(inside, 150e6, 1e6), np.where(inside, 0.3, 0.4)
    out = {}
    for method, extra in methods:
        problem = ElasticProblem(disc, E, nu, method=method, **extra)
        out[method] = run_tension(problem, layout, 0.04e6, 0.05e-6, 30)
    return out


def test_master_slave_variants_debond_in_the_same_order(plate):
    h = histories(plate, [("master-slave", {}),
                          ("master-slave-cutoff", {"cutoff_threshold": 1e-8}),
                          ("master-slave-local", {})])
    ms, ms1, ms2 = h["master-slave"], h["master-slave-cutoff"], h["master-slave-local"]
    assert ms.intact_pairs[-1] < ms.intact_pairs[0]                  # the plate debonds
    assert np.array_equal(ms.pair_break_step, ms1.pair_break_step)   # a 1e-8 cut-off is exact
    # MS2 changes the interpolation at the pairs, so pairs break at other steps (the seed
    # says so too); the order is the same: a pair MS breaks earlier, MS2 does not break later
    both = (ms.pair_break_step > 0) & (ms2.pair_break_step > 0)
    assert both.sum() >= 10
    a, b = ms.pair_break_step[both], ms2.pair_break_step[both]
    earlier = a[:, None] < a[None, :]
    concordant = np.mean((b[:, None] <= b[None, :])[earlier])
    # not identical: pairs whose MS break steps are close swap under MS2's interpolation;
    # measured 0.89 of the ordered pairs keep their order (docs/sph.md § 9 says so)
    assert concordant > 0.8, concordant
    assert ms2.intact_pairs[-1] >= ms.intact_pairs[-1]
    assert np.all(np.diff(ms.macro_stress) > 0)                       # still loading


def test_an_inclusion_with_one_intact_pair_is_refused_unless_detached(plate):
    disc = Discretisation(plate, 2.0)
    problem = ElasticProblem(disc, np.where(plate.phase > 0, 150e6, 1e6), 0.35)
    intact = np.ones(plate.pairs.shape[0], dtype=bool)
    own = np.flatnonzero(plate.pair_inclusion == 0)
    intact[own[1:]] = False
    values = tension_boundary_values(plate, 0.05e-6)
    with pytest.raises(SolverError, match="inclusion 0 keeps 1 intact pair"):
        problem.solve(values, intact)
    detached = np.zeros(len(plate.inclusions), dtype=bool)
    detached[0] = True
    sol = problem.solve(values, intact, detached)
    members = plate.phase == 1
    assert np.isnan(sol.displacement[members]).all()
    assert np.isfinite(sol.displacement[~members]).all()


def test_penalty_rotations_of_a_weakly_held_inclusion_converge_to_master_slave(plate):
    own = np.flatnonzero(plate.pair_inclusion == 0).size
    methods = [("master-slave", None), ("penalty", 1e2), ("penalty", 1e4), ("penalty", 1e6)]
    for kept in ([0, 1], [0, own // 2]):
        for integration in ("vci", "nodal"):
            r = example2_rotations(plate, 0, kept, methods, integration=integration)
            ms = r[("master-slave", None)]
            gaps = np.array([abs(r[("penalty", w)] - ms) for w in (1e2, 1e4, 1e6)])
            # no spurious rotation: the penalty's rotation approaches MS's like 1/w
            assert gaps[1] < 0.03 * gaps[0] and gaps[0] < 0.01 * abs(ms)
