"""Explicit 2-D plane-strain material point method (seed 000; docs/mpm.md)."""

# first: the kernels' numba cache must be stamped with their dependencies (kernel_cache.py)
from solvers.mpm import kernel_cache  # noqa: F401  isort: skip
from solvers.mpm.solver import MPMSolver

__all__ = ["MPMSolver"]
