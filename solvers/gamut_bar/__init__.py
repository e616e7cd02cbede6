"""1-D nonlocal deformation-gamut bar (seed 002; docs/gamut_bar.md)."""

from solvers.gamut_bar.solver import GamutBarSolver

__all__ = ["GamutBarSolver"]
