"""Closed-form models with exact moments, exposed through the same protocol as a physics solver."""

from solvers.analytic.models import MODELS, AnalyticSolver

__all__ = ["AnalyticSolver", "MODELS"]
