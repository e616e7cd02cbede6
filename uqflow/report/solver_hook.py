"""``solver_report``: what the results' solver adds to their report, through its
``Solver.report`` hook (uqflow/solver.py)."""

from __future__ import annotations

import inspect
from pathlib import Path

from uqflow.errors import StudyError
from uqflow.layout import SOLVER
from uqflow.solver import get_solver


def solver_report(trees: list, folder: Path, figures: bool = True,
                  **options) -> tuple[str, list[Path]]:
    """What the results' solver adds: its ``report(trees, folder, figures, **options)``.

    A solver knows the comparisons its users look at (a seed's table beside ours, a map of its
    scene); results of different solvers are not mixed. ``options`` given as None are left
    out; one the solver's report does not name in its signature is a ``StudyError`` naming it
    (``uqflow report --time`` on results of a solver without times).
    """
    options = {k: v for k, v in options.items() if v is not None}
    solvers = {str(t.attrs.get(SOLVER, "")) for t in trees}
    if len(solvers) != 1 or "" in solvers:
        if options:
            raise StudyError(f"--{next(iter(options))} applies to a solver's comparison of "
                             f"results of one solver; these are of {sorted(solvers)}",
                             key=next(iter(options)))
        return "", []
    name = solvers.pop()
    try:
        solver_class = get_solver(name)
    except StudyError:
        return "", []
    named = {p.name for p in inspect.signature(solver_class.report).parameters.values()
             if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
    for key in options:
        if key not in named:
            raise StudyError(f"--{key}: the '{name}' solver's report takes no such option",
                             key=key)
    return solver_class.report(trees, Path(folder), figures=figures, **options)
