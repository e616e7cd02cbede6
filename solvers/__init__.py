"""Solver back-ends shipped with uqflow; each implements ``uqflow.solver.Solver``."""
