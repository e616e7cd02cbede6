"""The reduced stiffness P^T K P assembled cluster by cluster (solvers/sph/constraints.py,
docs/sph.md § 5): the dense products of plain MS's clusters give the sparse product's K^."""

import numpy as np
import pytest
import scipy.sparse as sp

from solvers.sph import constraints as constraints_module
from solvers.sph.problem import ElasticProblem

from .test_linear import plate

EPS = np.finfo(float).eps


@pytest.fixture(scope="module")
def plate_systems():
    disc, materials, edge = plate(16)
    out = {}
    for method in ("master-slave", "master-slave-cutoff"):
        p = ElasticProblem(disc, **materials, method=method, cutoff_threshold=1e-8)
        c, _ = p.constraints(edge, np.ones(p.pairs.shape[0], dtype=bool))
        out[method] = (sp.csr_matrix(p.K), c)
    return out


@pytest.mark.parametrize("method", ["master-slave", "master-slave-cutoff"])
@pytest.mark.parametrize("dense_fill", [0.0, np.inf])
def test_the_clusters_products_sum_to_p_transpose_k_p(plate_systems, monkeypatch, method,
                                                     dense_fill):
    K, c = plate_systems[method]
    # 0: every cluster of two or more slaves as a dense product; inf: every one sparse
    monkeypatch.setattr(constraints_module, "DENSE_CLUSTER_FILL", dense_fill)
    ms = constraints_module.master_slave(K, np.zeros(K.shape[0]), c,
                                         threshold=1e-8 if method.endswith("cutoff") else 0.0)
    P = ms.P
    reference = (P.T @ K @ P).toarray()
    # both form P^T (K P) with sums in other orders: |fl(AB) - AB| <= gamma_n |A||B| twice
    # (Higham § 3.5) puts each within (gamma_colP + gamma_rowK) (|P|^T |K| |P|)_ij of exact
    terms = np.diff(P.tocsc().indptr).max() + np.diff(K.indptr).max() + 1
    magnitude = (abs(P).T @ abs(K) @ abs(P)).toarray()
    assert np.all(np.abs(ms.K_hat.toarray() - reference) <= 2 * terms * EPS * magnitude)
    # no entry of the product's pattern is lost but exact zeros
    lost = (reference != 0) & (ms.K_hat.toarray() == 0)
    assert not lost.any()


def test_plain_ms_clusters_are_dense_enough_for_the_dense_product(plate_systems):
    # the premise of the dense branch: Phi_ss^-1 of a chain of slaves has no zeros, so a
    # cluster's rows of T fill every master it uses
    K, c = plate_systems["master-slave"]
    ms = constraints_module.master_slave(K, np.zeros(K.shape[0]), c)
    _, label = constraints_module.slave_clusters(c.rows.tocsc()[:, c.slaves].tocsr())
    largest = np.flatnonzero(label == np.bincount(label).argmax())
    Tk = ms.T[largest]
    assert Tk.nnz == largest.size * np.unique(Tk.indices).size
