"""The symbolic work (orders, PARDISO analyses) one factorisation hands to the next of the
same pattern (solvers/sph/symbolic.py)."""

import gc
import pickle
import sys
import threading
import weakref
from pathlib import Path

import cloudpickle
import numpy as np
import pytest
import scipy.sparse as sp

from solvers.sph import SPHSolver, linear, symbolic
from solvers.sph.linear import Factor
from solvers.sph.problem import ElasticProblem
from solvers.sph.symbolic import SymbolicStore, covering_pattern, embedded, pattern_key

from .test_linear import (NEEDS_PARDISO, agreement_bound, free_grid, lu_residual_bound,
                          plate)

sys.path.insert(0, str(Path(__file__).parent))
from _scenes import example1  # noqa: E402


# -- the store --------------------------------------------------------------------------------

def test_the_store_keeps_its_capacity_releasing_the_least_recently_used():
    released = []
    store = SymbolicStore(capacity=2)
    for name in "abc":
        store.keep(name, name.upper(), released.append)
        if name == "b":
            assert store.lookup("a") == "A"         # a used: b is now the older
    assert released == ["B"] and len(store) == 2
    assert store.take("a") == "A" and store.take("a") is None      # taken: nobody else's
    store.keep("c", "second C", released.append)    # c holds one: the newcomer goes
    assert released == ["B", "second C"] and store.lookup("c") == "C"
    assert store.hits == 3
    store.clear()
    assert released == ["B", "second C", "C"] and len(store) == 0


def test_the_store_releases_what_it_holds_when_it_is_collected():
    released = []
    store = SymbolicStore()
    store.keep("a", "A", released.append)
    del store
    gc.collect()
    assert released == ["A"]


def test_a_pickled_store_arrives_empty_with_its_capacity():
    store = SymbolicStore(capacity=3)
    store.keep("a", "A")
    for module in (pickle, cloudpickle):        # multiprocessing's and dask's
        copy_ = module.loads(module.dumps(store))
        assert len(copy_) == 0 and copy_.capacity == 3
        copy_.keep("b", "B")
        assert copy_.lookup("b") == "B" and store.lookup("b") is None


def test_one_item_taken_by_eight_threads_at_once_goes_to_one():
    store = SymbolicStore()
    store.keep("a", "A")
    got, start = [], threading.Barrier(8)

    def take():
        start.wait()
        got.append(store.take("a"))
    threads = [threading.Thread(target=take) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(got, key=str) == ["A"] + [None] * 7


def test_a_key_changes_with_one_entry_of_the_pattern_or_one_point_not_with_the_values():
    A, points = free_grid(6, shift=1.0)
    key = pattern_key("dissection", A, points)
    scaled = A.copy()
    scaled.data *= 3.0
    assert pattern_key("dissection", scaled, points) == key
    moved = points.copy()
    moved[5, 0] = np.nextafter(moved[5, 0], np.inf)
    assert pattern_key("dissection", A, moved) != key
    grown = (A + sp.csr_matrix(([1.0], ([0], [35])), shape=A.shape)).tocsr()
    assert pattern_key("dissection", grown, points) != key
    assert pattern_key("pardiso", A) != pattern_key("dissection", A)
    assert pattern_key("x", A.tocsc()) != pattern_key("x", A.T.tocsr())   # same arrays


# -- a kept pattern serving a matrix -----------------------------------------------------------

def distinct_grid(m):
    """free_grid's matrix with every entry distinct (free_grid's reads the same backwards)."""
    A, points = free_grid(m, shift=1.0)
    A.data *= 1.0 + np.arange(A.nnz) / A.nnz
    return A, points


def with_entry(A, row, column, value):
    """A with one more entry (an explicit one, even a zero)."""
    coo = A.tocoo()
    return sp.csr_matrix((np.r_[coo.data, value], (np.r_[coo.row, row], np.r_[coo.col, column])),
                         shape=A.shape)


def test_a_kept_pattern_serves_a_matrix_it_covers_with_zeros_where_the_matrix_has_none():
    A, _ = distinct_grid(5)
    assert np.array_equal(embedded(A, A.indptr, A.indices), A.data)
    # the kept pattern has one entry more: the matrix's entries in place, a zero there
    wider = with_entry(A, 0, 24, 0.0)
    data = embedded(A, wider.indptr, wider.indices)
    assert data.size == A.nnz + 1
    served = sp.csr_matrix((data, wider.indices, wider.indptr), shape=A.shape)
    assert abs(served - A).max() == 0.0 and served[0, 24] == 0.0


def test_a_kept_pattern_leaves_out_rounding_errors_and_refuses_real_entries():
    A, _ = distinct_grid(5)
    largest = np.abs(A.data).max()
    # a sum cancelled to a rounding error at an entry the kept pattern lacks: left out
    flicker = with_entry(A, 3, 17, 1e-16 * largest)
    data = embedded(flicker, A.indptr, A.indices)
    assert np.array_equal(data, A.data)
    # at the bound it is still left out; past it, the matrix is not covered
    at = with_entry(A, 3, 17, symbolic.NEGLIGIBLE * largest)
    assert embedded(at, A.indptr, A.indices) is not None
    past = with_entry(A, 3, 17, -np.nextafter(symbolic.NEGLIGIBLE * largest, np.inf))
    assert embedded(past, A.indptr, A.indices) is None
    # a kept pattern beyond PATTERN_SLACK more entries is another system's
    many = A.copy().tolil()
    for k in range(int(symbolic.PATTERN_SLACK * A.nnz) + 1):
        many[k % 25, (k * 7 + 13) % 25] = 1.0
    many = many.tocsr()
    assert many.nnz > (1 + symbolic.PATTERN_SLACK) * A.nnz
    assert embedded(A, many.indptr, many.indices) is None


def test_the_covering_pattern_is_the_union_within_the_slack_else_the_matrixs_own():
    A, _ = free_grid(5, shift=1.0)
    kept = with_entry(A, 0, 24, 1.0)
    grown = with_entry(A, 24, 0, 1.0)
    indptr, indices = covering_pattern(grown, kept.indptr, kept.indices)
    union = sp.csr_matrix((np.ones(indices.size), indices, indptr), shape=A.shape)
    assert union.nnz == A.nnz + 2 and union[0, 24] == union[24, 0] == 1.0
    assert embedded(grown, indptr, indices) is not None
    far = sp.csr_matrix(np.ones(A.shape))          # every entry: far past the slack
    indptr, indices = covering_pattern(grown, far.indptr, far.indices)
    assert np.array_equal(indptr, grown.indptr) and np.array_equal(indices, grown.indices)


# -- the direct solver's order ----------------------------------------------------------------

def count_dissections(monkeypatch):
    calls = []
    original = linear.nested_dissection

    def counted(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)
    monkeypatch.setattr(linear, "nested_dissection", counted)
    monkeypatch.setattr(linear, "DISSECTION_ABOVE", 0)
    return calls


def test_a_dissection_order_is_reused_for_the_same_pattern_and_gives_the_same_bits(monkeypatch):
    calls = count_dissections(monkeypatch)
    A, points = free_grid(14, shift=0.3)
    b = np.arange(A.shape[0], dtype=float)
    store = SymbolicStore()
    first = Factor(A, "direct", points=points, store=store)
    stiffer = A.copy()
    stiffer.data *= 1.0 + 0.5 * np.random.default_rng(3).random(A.nnz)
    second = Factor(stiffer, "direct", points=points, store=store)
    assert len(calls) == 1 and store.hits == 1
    assert first.ordering == second.ordering == "nested dissection"
    alone = Factor(stiffer, "direct", points=points)
    assert len(calls) == 2
    # the same order and matrix: the same factorisation, bit for bit
    assert np.array_equal(second.solve(b)[0], alone.solve(b)[0])
    x = second.solve(b)[0]
    assert np.abs(b - stiffer @ x).sum() <= lu_residual_bound(second, stiffer, x)
    # one more coupling is another pattern: ordered afresh, never by a stale order
    grown = (stiffer + sp.csr_matrix(([-0.1, -0.1], ([0, 50], [50, 0])), shape=A.shape)).tocsr()
    Factor(grown, "direct", points=points, store=store)
    assert len(calls) == 3 and store.hits == 1


class RandomFields:
    """Both phases' moduli drawn anew at every point (the realization's own generator)."""

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)

    def __contains__(self, name):
        return name in ("matrix.E", "inclusion.E")

    def values(self, name, points, mean, low, high):
        return mean * (1.0 + 0.1 * self.rng.uniform(-1.0, 1.0, points.shape[0]))


@pytest.mark.parametrize("method", ["master-slave-local", "penalty"])
def test_a_study_on_a_fixed_layout_orders_once_with_every_realization_unchanged(
        monkeypatch, method):
    calls = count_dissections(monkeypatch)
    scene = example1(spacing=6.0, constraints=method)
    reusing = SPHSolver.from_scene(scene)
    alone = SPHSolver.from_scene(scene)
    alone.symbolic = None
    for seed in range(3):
        params = {"inclusion.E": 1000.0 + 100.0 * seed}
        a = reusing.run(params, fields=RandomFields(seed))
        b = alone.run(params, fields=RandomFields(seed))
        assert np.array_equal(a.displacement.values, b.displacement.values)
        assert np.array_equal(a.stress.values, b.stress.values)
    # a modulus per particle: no sum cancels, every realization has the same pattern
    assert reusing.symbolic.hits == 2 and len(calls) == 1 + 3
    # one modulus per phase: symmetric couplings cancel to zero or not (symbolic.py), the
    # pattern flickers and is ordered afresh — never by another pattern's order
    for E in (700.0, 1300.0):
        a, b = reusing.run({"matrix.E": E}), alone.run({"matrix.E": E})
        assert np.array_equal(a.displacement.values, b.displacement.values)
    # dask ships the solver: its copy starts with an empty store and runs the same
    shipped = cloudpickle.loads(cloudpickle.dumps(reusing))
    assert len(shipped.symbolic) == 0
    assert np.array_equal(shipped.run({"matrix.E": E}).displacement.values,
                          b.displacement.values)


@pytest.mark.parametrize("method", ["master-slave-local", "master-slave"])
def test_a_layouts_geometry_is_built_once_and_solves_as_on_a_fresh_discretisation(method):
    disc, materials, edge = plate()
    first = ElasticProblem(disc, **materials, method=method)
    first.solve(edge)
    stiffer = dict(materials, E=1.3 * materials["E"], nu=0.9 * materials["nu"])
    second = ElasticProblem(disc, **stiffer, method=method)
    assert second.test is first.test            # the corrected test gradients, built once
    fresh = ElasticProblem(plate()[0], **stiffer, method=method)
    assert second.test is not fresh.test
    assert np.array_equal(second.solve(edge).u, fresh.solve(edge).u)
    # the other method's slave rows differ, and so do its test gradients: not shared
    other = {"master-slave-local": "master-slave", "master-slave": "master-slave-local"}[method]
    on_shared = ElasticProblem(disc, **materials, method=other)
    on_fresh = ElasticProblem(plate()[0], **materials, method=other)
    assert on_shared.test is not first.test
    assert np.array_equal(on_shared.solve(edge).u, on_fresh.solve(edge).u)


# -- PARDISO's analysis -----------------------------------------------------------------------

@NEEDS_PARDISO
def test_a_pardiso_analysis_is_handed_on_in_single_precision_only(monkeypatch):
    monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", 0)
    A, _ = free_grid(14, shift=0.3)
    b = np.arange(A.shape[0], dtype=float)
    store = SymbolicStore()
    first = Factor(A, "pardiso", store=store)
    assert not first.lu.factors.analysis_reused and len(store) == 0
    del first                       # its factors released, its analysis kept
    assert len(store) == 1
    stiffer = A.copy()
    stiffer.data *= 1.0 + 0.5 * np.random.default_rng(3).random(A.nnz)
    second = Factor(stiffer, "pardiso", store=store)
    assert second.lu.factors.analysis_reused and len(store) == 0 and store.hits == 1
    assert second.lu.precision == "single, refined"
    x = second.solve(b)[0]
    # refined to a double LU's backward error (refinement.RESIDUAL_SLACK gamma (|b| + |A||x|))
    assert np.abs(b - stiffer @ x).sum() <= second.lu._refinement.target(b, x)
    fresh = Factor(stiffer, "pardiso").solve(b)[0]
    assert np.abs(x - fresh).sum() <= agreement_bound(stiffer, b, x, fresh)
    del second
    double = Factor(A, "pardiso", store=store, single_precision=False)
    assert not double.lu.analysis_reused      # double's analysis scales and matches by value
    del double
    assert len(store) == 1


@NEEDS_PARDISO
def test_a_pardiso_analysis_serves_covered_patterns_and_grows_to_cover_a_new_entry(
        monkeypatch):
    monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", 0)
    A, _ = distinct_grid(14)
    b = np.arange(A.shape[0], dtype=float)
    store = SymbolicStore()
    Factor(A, "pardiso", store=store)
    coupled = with_entry(A, 3, 150, -0.2)           # a real entry the kept pattern lacks
    factor = Factor(coupled, "pardiso", store=store)
    assert not factor.lu.factors.analysis_reused     # analysed afresh, on the union
    x = factor.solve(b)[0]
    assert np.abs(b - coupled @ x).sum() <= factor.lu._refinement.target(b, x)
    del factor
    for matrix in (A, with_entry(A, 40, 90, 1e-17)):    # covered; a rounding error outside
        factor = Factor(matrix, "pardiso", store=store)
        assert factor.lu.factors.analysis_reused
        x = factor.solve(b)[0]
        # refined, not fallen back to double: the single factors are of this matrix
        assert factor.lu.precision == "single, refined"
        assert np.abs(b - matrix @ x).sum() <= factor.lu._refinement.target(b, x)
        del factor


@NEEDS_PARDISO
def test_a_kept_pardiso_analysis_leaves_nothing_to_the_cyclic_collector(monkeypatch):
    monkeypatch.setattr(linear, "MIXED_PRECISION_ABOVE", 0)
    A, _ = free_grid(8, shift=0.05)
    store = SymbolicStore()
    Factor(A, "pardiso", store=store)
    gc.collect()
    gc.disable()
    try:
        factor = Factor(A, "pardiso", store=store)
        factor.solve(np.ones(A.shape[0]))
        dropped = weakref.ref(factor)
        del factor
        assert dropped() is None and len(store) == 1
        assert gc.collect() == 0
    finally:
        gc.enable()


def test_docs_state_the_constants_the_store_uses():
    text = (Path(__file__).parents[3] / "docs" / "sph.md").read_text()
    assert symbolic.NEGLIGIBLE == 1e-10 and "`symbolic.NEGLIGIBLE` = 10⁻¹⁰" in text
    assert symbolic.PATTERN_SLACK == 0.01 and "`symbolic.PATTERN_SLACK` = 1 %" in text
    # single precision's unit roundoff over NEGLIGIBLE, as docs/sph.md § 5 rounds it
    assert round(float(np.finfo(np.float32).eps) / 2 / symbolic.NEGLIGIBLE, -2) == 600
    assert "whose own errors are 600 times" in text.replace("\n", " ")
