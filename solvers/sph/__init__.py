"""Corrected SPH with master–slave constraints for particulate composites (seed 001;
docs/sph.md)."""

from solvers.sph.solver import SPHSolver

__all__ = ["SPHSolver"]
