"""Zero-energy (checkerboard) modes of particle integration and the stabilisation option
(docs/sph.md § 4 and § 9, "Zero-energy modes")."""

import numpy as np
import pytest
import scipy.linalg as la
import scipy.sparse as sp

from solvers.sph.constraints import master_slave
from solvers.sph.layouts import Box, Ellipse, regular_layout
from solvers.sph.problem import ElasticProblem
from solvers.sph.stiffness import Discretisation

LAYOUT = regular_layout(Box(-8.0, -8.0, 8.0, 8.0), 1.0, [Ellipse(0.0, 0.0, 3.0, 3.0)])
DISC = Discretisation(LAYOUT, 2.0)


def lowest_modes(beta, count=20):
    """Eigenvalues (per unit volume) of the reduced MS system and each mode's oscillation
    ||U - phi U|| / ||U|| (0 for smooth fields, ~1 for a checkerboard)."""
    problem = ElasticProblem(DISC, 900.0, 0.33, stabilisation=beta)
    c, _ = problem.constraints(np.zeros((LAYOUT.boundary.size, 2)),
                               np.ones(LAYOUT.pairs.shape[0], bool))
    ms = master_slave(problem.K, problem.f, c)
    P = ms.P.toarray()
    K = ms.K_hat.toarray()
    M = P.T @ (np.repeat(DISC.volume, 2)[:, None] * P)
    w, v = la.eigh(0.5 * (K + K.T), M)
    U = (P @ v[:, :count]).T.reshape(count, -1, 2)
    R = sp.identity(DISC.n) - DISC.phi
    osc = np.array([np.linalg.norm(R @ u) / np.linalg.norm(u) for u in U])
    return w[:count], osc


def test_particle_integration_has_low_oscillatory_modes_that_stabilisation_lifts():
    w0, osc0 = lowest_modes(0.0)
    w1, osc1 = lowest_modes(1.0)
    # without stabilisation the lowest modes are checkerboard-like
    assert np.mean(osc0 > 0.3) >= 0.9
    # with beta = 1 smooth modes come first and the oscillatory ones sit higher
    assert np.mean(osc1 > 0.3) < np.mean(osc0 > 0.3)
    assert osc1[0] < 0.3
    assert w1[osc1 > 0.3].min() > 2.0 * w1[0]


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_all_reduced_modes_have_positive_energy(beta):
    w, _ = lowest_modes(beta, count=1)
    assert w[0] > 0.0
