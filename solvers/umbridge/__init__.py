"""A remote UM-Bridge model as a uqflow solver (docs/umbridge.md)."""

from solvers.umbridge.solver import UMBridgeSolver

__all__ = ["UMBridgeSolver"]
