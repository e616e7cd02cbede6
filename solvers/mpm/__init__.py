"""Explicit 2-D plane-strain material point method (seed 000; docs/mpm.md)."""

from solvers.mpm.solver import MPMSolver

__all__ = ["MPMSolver"]
