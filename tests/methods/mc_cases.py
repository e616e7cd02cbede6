"""Cases shared by the Monte Carlo tests: the Ishigami input space and an in-process run.

Designs are run with ``evaluate_design`` (no dask): the method sees exactly what the executor
would hand it.
"""

from __future__ import annotations

import math

import numpy as np

from solvers.analytic import AnalyticSolver
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods.monte_carlo import MonteCarlo
from uqflow.realization import evaluate_design


def uniform(name, lo, hi):
    return RandomInput.from_spec({"name": name, "distribution": "uniform", "lower": lo,
                                  "upper": hi})


def ishigami_space():
    return InputSpace([uniform(f"x{i}", -math.pi, math.pi) for i in (1, 2, 3)])


def run_mc(scene, space, seed=0, **options):
    """Plan, run and analyse a Monte Carlo study: (method, design, runs, statistics)."""
    method = MonteCarlo(**options)
    design = method.plan(space, None, np.random.SeedSequence(seed))
    runs = evaluate_design(AnalyticSolver.from_scene(scene), design)
    return method, design, runs, method.analyze(design, runs)
