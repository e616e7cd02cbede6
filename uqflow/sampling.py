"""Points in the unit hypercube for Monte Carlo rules, from one seed and no global state.

chaospy's own samplers draw from numpy's global random state; scipy.stats.qmc takes a
Generator, so the same study seed gives the same design on every machine and worker count.
The points are mapped to the inputs through their chaospy marginals (``InputSpace``).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.stats import qmc

RULES = ("random", "lhs", "sobol", "halton")
#: Rules whose points are not independent: their error comes from independent replicates.
QUASI_RANDOM_RULES = ("sobol", "halton")


def unit_hypercube(rule: str, n_points: int, dimension: int,
                   seed: np.random.SeedSequence) -> np.ndarray:
    """``n_points`` points of (0, 1)^dimension, shape (n_points, dimension).

    ``sobol`` and ``halton`` are scrambled (LMS + digital shift / random digit permutations),
    so they are unbiased and repeated designs with other seeds give an error estimate.
    ``seed`` is not advanced: the same seed (object or value) always gives the same points.
    """
    if rule not in RULES:
        raise ValueError(f"unknown sampling rule '{rule}' (known: {', '.join(RULES)})")
    n_points, dimension = int(n_points), int(dimension)
    if n_points < 0 or dimension < 0:
        raise ValueError(f"need n_points >= 0 and dimension >= 0, got {n_points}, {dimension}")
    # scipy's qmc engines spawn a child from the Generator's SeedSequence, i.e. they advance
    # the caller's object: the same seed object passed twice gave two designs. Use a copy.
    if isinstance(seed, np.random.SeedSequence):
        seed = np.random.SeedSequence(seed.entropy, spawn_key=seed.spawn_key,
                                      pool_size=seed.pool_size)
    rng = np.random.default_rng(seed)
    if dimension == 0:
        return np.zeros((n_points, 0))
    if rule == "random":
        u = rng.random((n_points, dimension))
    elif rule == "lhs":
        u = qmc.LatinHypercube(d=dimension, rng=rng).random(n_points)
    elif rule == "sobol":
        with warnings.catch_warnings():
            # Balance properties need powers of two; other counts are valid, only less even.
            warnings.simplefilter("ignore", UserWarning)
            u = qmc.Sobol(d=dimension, scramble=True, rng=rng).random(n_points)
    else:
        u = qmc.Halton(d=dimension, scramble=True, rng=rng).random(n_points)
    # Generator.random and the digital (Sobol, Halton) points lie in [0, 1): 0 itself can come
    # out (with tiny probability). Keep the promise of the open interval.
    return np.maximum(u, np.finfo(float).tiny)


def replicate_seed(seed: np.random.SeedSequence, replicate: int) -> np.random.SeedSequence:
    """The seed of scrambling ``replicate``: the child ``seed.spawn`` would give, made without
    advancing ``seed`` (so the design stays a function of the study seed alone)."""
    return np.random.SeedSequence(seed.entropy, spawn_key=(*seed.spawn_key, int(replicate)),
                                  pool_size=seed.pool_size)


def replicated_unit_hypercube(rule: str, replicates: int, points_per_replicate: int,
                              dimension: int, seed: np.random.SeedSequence) -> np.ndarray:
    """``replicates`` independently scrambled copies of a quasi-random rule, interleaved.

    Row ``j * replicates + r`` is point ``j`` of replicate ``r``, so every prefix of
    ``replicates * m`` rows holds the first ``m`` points of every replicate: a prefix at
    ``replicates * 2**k`` is made of whole balanced Sobol' prefixes, and the spread of the
    replicate means over it is an honest error estimate (randomized QMC; Owen 1997, L'Ecuyer
    and Lemieux 2002). Shape (replicates * points_per_replicate, dimension).
    """
    if rule not in QUASI_RANDOM_RULES:
        raise ValueError(f"replicated designs are for the quasi-random rules "
                         f"({', '.join(QUASI_RANDOM_RULES)}), not '{rule}'")
    replicates, points_per_replicate = int(replicates), int(points_per_replicate)
    if replicates < 1 or points_per_replicate < 0:
        raise ValueError(f"need replicates >= 1 and points_per_replicate >= 0, got "
                         f"{replicates}, {points_per_replicate}")
    blocks = [unit_hypercube(rule, points_per_replicate, dimension, replicate_seed(seed, r))
              for r in range(replicates)]
    # (replicate, point, dim) -> (point, replicate, dim): point-major rows interleave them.
    stacked = np.stack(blocks, axis=1)
    return stacked.reshape(replicates * points_per_replicate, int(dimension))
