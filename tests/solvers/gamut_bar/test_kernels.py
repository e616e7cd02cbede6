"""The numba kernels on their own: banded Cholesky, return mapping, Newton."""

from __future__ import annotations

import numpy as np
import pytest

from solvers.gamut_bar import kernels as K

from ._common import EPS


def chain(n, b, seed=0):
    """Random springs between points 0..n with degree ≤ b (point 0 pinned)."""
    rng = np.random.default_rng(seed)
    ei, ej = [], []
    for d in range(1, b + 1):
        for p in range(n + 1 - d):
            ei.append(p)
            ej.append(p + d)
    ei, ej = np.array(ei), np.array(ej)
    return ei, ej, rng.uniform(0.5, 2.0, ei.size)


def dense(n, ei, ej, k):
    Kd = np.zeros((n + 1, n + 1))
    for i, j, kk in zip(ei, ej, k):
        Kd[np.ix_([i, j], [i, j])] += kk * np.array([[1, -1], [-1, 1]])
    return Kd[1:, 1:]


@pytest.mark.parametrize("n, b", [(1, 1), (7, 3), (60, 9)])
def test_banded_cholesky_solves_like_numpy(n, b):
    ei, ej, k = chain(n, b)
    ab = np.zeros((n, b + 1))
    st = np.zeros(k.size, dtype=np.int8)
    assert K.factor(ab, np.zeros(n), st, ei, ej, k, 0.0) == -1
    r = np.random.default_rng(1).normal(size=n)
    x = np.zeros(n)
    K.solve(ab, r, x)
    Kd = dense(n, ei, ej, k)
    exact = np.linalg.solve(Kd, r)
    # both solves are backward stable: ‖Δx‖ ≤ κ(K)·n·eps·‖x‖ each (n·eps: Higham's γ_n)
    bound = 2 * np.linalg.cond(Kd) * n * EPS * np.linalg.norm(exact)
    assert np.linalg.norm(x - exact) <= bound


def test_factor_reports_a_singular_tangent():
    ei, ej, k = chain(5, 1)                 # a plain chain: every element crosses one cut
    st = np.zeros(k.size, dtype=np.int8)
    st[2] = 1                               # slipping: the cut between points 2 and 3 is free
    ab = np.zeros((5, 2))
    # u_3..u_5 float free: the last pivot of that block vanishes
    assert K.factor(ab, np.zeros(5), st, ei, ej, k, 0.0) == 4
    assert K.factor(ab, np.zeros(5), st, ei, ej, k, 1e-4) == -1  # regularised


def test_return_mapping_and_energy():
    ei, ej = np.array([0]), np.array([1])
    k, fc = np.array([2.0]), np.array([1.0])
    ep_n = np.array([0.0])
    ep, st, r = np.zeros(1), np.zeros(1, dtype=np.int8), np.zeros(1)
    u = np.array([0.0, 0.25])
    rmax, _ = K.trial(u, 0.5, ei, ej, k, fc, ep_n, ep, st, r, st)
    assert st[0] == 0 and rmax == pytest.approx(0.0)
    u = np.array([0.0, 1.5])                 # trial force 3 > 1: slips, e_p = 1.5 − 1/2
    K.trial(u, 1.0, ei, ej, k, fc, ep_n, ep, st, r, st)
    assert st[0] == 1 and ep[0] == pytest.approx(1.0) and r[0] == pytest.approx(0.0)
    u = np.array([0.0, -1.5])
    K.trial(u, -1.0, ei, ej, k, fc, ep_n, ep, st, r, st)
    assert st[0] == -1 and ep[0] == pytest.approx(-1.0)
    # energy change: elastic to slipping, ψ(d) = f_c|d| − f_c²/2k beyond d = 1/2
    dpi = K.energy_change(np.array([0.0, 0.0]), np.array([1.5]), 1.0, 0.0, ei, ej, k, fc,
                          ep_n)
    assert dpi == pytest.approx(1.0 * 1.5 - 1.0 / 4.0)


def test_newton_reaches_a_slipping_equilibrium():
    # two parallel Jenkins elements and a never-slipping spring between points 0 and 1
    ei, ej = np.array([0, 0, 0]), np.array([1, 1, 1])
    k = np.array([1.0, 1.0, 0.1])
    fc = np.array([0.5, 1.0, np.inf])
    u = np.zeros(2)
    ne = 3
    ep_n, ep = np.zeros(ne), np.zeros(ne)
    st, fst = np.zeros(ne, dtype=np.int8), np.zeros(ne, dtype=np.int8)
    ab, diag = np.zeros((1, 2)), np.zeros(1)
    fmeta, fmeta_f = np.zeros(3, dtype=np.int64), np.zeros(1)
    work = (np.zeros(1), np.zeros(1), np.zeros(ne), np.zeros(ne, dtype=np.int8), np.zeros(1),
            np.zeros(2))
    status, it, nref = K.newton_step(1.8, 1e-12, u, ep_n, ep, st, ei, ej, k, fc, ab, diag, fst,
                                     fmeta, fmeta_f, *work, 50, 1e9)
    assert status == K.OK
    # 2.1 d up to d = 0.5, then 0.5 + 1.1 d up to d = 1 (force 1.6), then 1.5 + 0.1 d = 1.8
    # Newton stops at |residual| ≤ 1e-12 N; the tangent stiffness there is 0.1, so
    # |u − 3| ≤ 1e-12 / 0.1
    assert u[1] == pytest.approx(3.0, abs=1e-12 / 0.1)
    assert list(st) == [1, 1, 0]
    ep_n[:] = ep
    status, *_ = K.newton_step(1.55, 1e-12, u, ep_n, ep, st, ei, ej, k, fc, ab, diag, fst,
                               fmeta, fmeta_f, *work, 50, 1e9)
    # unloading by 0.25 is elastic with the full stiffness 2.1
    # residual ≤ 1e-12 N at the tangent stiffness 2.1: |Δu| ≤ 1e-12 / 2.1
    assert status == K.OK and u[1] == pytest.approx(3.0 - 0.25 / 2.1, abs=1e-12 / 2.1)
    assert list(st) == [0, 0, 0]
