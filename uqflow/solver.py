"""The Solver contract: a scene in, a deterministic model out.

A solver is built once per worker from its scene (``from_scene``), tells which parameters a
study may make uncertain (``nominal``, dotted names, SI units) and what it returns
(``outputs``: a template dataset), and runs one realization (``run``). It knows nothing of
studies, methods or dask. Solvers register with ``@register_solver("name")`` or through the
entry-point group ``uqflow.solvers``.

Optional capability, local sensitivities: a solver that can differentiate some outputs with
respect to some parameters inside one run (analytically, holding the state it computed fixed:
a "frozen-state" derivative, which leaves out the feedback of a parameter on the history
that led to that state) lists them in ``local_sensitivities`` and returns them from
``run_with_sensitivities``. Methods that need them (``taylor-local``; a control variate built
on it) ask the executor for such runs through the design (``uqflow.realization``); the
framework never imports a solver to find out.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
import xarray as xr

from uqflow.errors import SceneError, SolverError
# A solver marks its diagnostics with these: importable from here beside the contract,
# their home is ``uqflow.layout``.
from uqflow.layout import DIAGNOSTIC_KIND, is_diagnostic
from uqflow.registry import Registry

__all__ = ["Solver", "SolverError", "SceneError", "register_solver", "get_solver",
           "solver_registry", "DIAGNOSTIC_KIND", "is_diagnostic"]

#: Solvers by name; the packages of ``solvers/`` (the built-ins, also in a source tree that
#: was never pip-installed) register on the first lookup, third-party ones by entry point.
solver_registry = Registry("uqflow.solvers", "solver", builtins=("solvers",))


def register_solver(name: str):
    """Class decorator: make a Solver available to study files as ``solver = name``."""
    return solver_registry.register(name)


def get_solver(name: str) -> type["Solver"]:
    return solver_registry.get(name)


class Solver(abc.ABC):
    """Base class of every solver back-end.

    Outputs and diagnostics: every variable of the ``outputs()`` template is stored per
    realization in the result's runs. One whose attribute ``output_kind`` is "diagnostic"
    (``uqflow.layout.DIAGNOSTIC_KIND``) says how the run went rather than what it
    predicts (a wall time per phase, a step or iteration count): it is stored in the runs
    like the others, but no method gives it statistics, the report draws no figure of it, and
    no method allocates samples on it (``uqflow.layout.is_diagnostic``). An output
    without the attribute, or with ``output_kind = "quantity"``, is an uncertain quantity.
    """

    name: ClassVar[str] = ""
    #: True when ``run_with_sensitivities``' derivatives are those of the whole run (a closed
    #: form), not frozen-state ones: the derivative a caller of the solver as a black box
    #: would mean (``uqflow serve`` answers UM-Bridge's /Gradient and /ApplyJacobian with
    #: them). The MPM's constitutive sensitivities are frozen-state: False.
    sensitivities_are_total: ClassVar[bool] = False

    @classmethod
    @abc.abstractmethod
    def from_scene(cls, scene: Mapping) -> "Solver":
        """Validate ``scene`` (raise ``SceneError`` naming the key) and build the model."""

    @abc.abstractmethod
    def nominal(self) -> dict[str, float]:
        """Every parameter a study may make uncertain, by dotted name, with its nominal value."""

    @abc.abstractmethod
    def outputs(self) -> xr.Dataset:
        """Template of ``run``'s result: names, dims, coords and ``units`` attributes
        (``output_kind = "diagnostic"`` on timings and counters, see the class docstring)."""

    @abc.abstractmethod
    def run(self, params: Mapping[str, float],
            fields: Mapping[str, np.ndarray] | None = None) -> xr.Dataset:
        """One realization with ``params`` overriding the nominal values."""

    def parameter_units(self) -> dict[str, str]:
        """Units of the parameters in ``nominal`` (SI); empty where dimensionless."""
        return {}

    def field_points(self, name: str) -> np.ndarray:
        """Coordinates, shape (n_points, n_dims), where field ``name`` is evaluated."""
        raise SceneError(f"solver '{self.name}' has no random field '{name}'", key="fields")

    def local_sensitivities(self) -> dict[str, tuple[str, ...]]:
        """Outputs for which ``run_with_sensitivities`` returns analytic local derivatives, each
        with the parameters (names as in ``nominal()``) it has derivatives for. Default {}: the
        solver has no such capability. An output absent from the dict has no local
        derivative."""
        return {}

    def run_with_sensitivities(self, params: Mapping[str, float], wrt: Sequence[str],
                               outputs: Sequence[str]) -> xr.Dataset:
        """``run(params)``'s dataset plus, for every name ``o`` in ``outputs`` (each a key of
        ``local_sensitivities()``, and every name in ``wrt`` in its tuple): ``o + "__gradient"``
        with dims (*o's dims, "parameter") and ``o + "__hessian"`` with dims (*o's dims,
        "parameter", "parameter_j"); coordinates ``parameter`` = ``parameter_j`` = list(wrt).
        Derivatives are at the realization's own parameter values, with the state the run
        computed held fixed (``uqflow.layout.gradient_variable``/``hessian_variable`` give the
        names)."""
        raise NotImplementedError(f"solver '{self.name}' has no local sensitivities "
                                  f"(local_sensitivities() is empty)")

    def compile_shares(self) -> int:
        """How many independent shares of compiled code (numba) this solver's runs still need
        compiled on this machine: 0 when there is nothing to compile or all of it is in the
        on-disk cache (the default). The study compiles the shares side by side before the
        first run, in as many processes as there are cores or dask workers
        (uqflow/warm_up.py, docs/architecture.md "Compiling before the first run")."""
        return 0

    def warm_up(self, part: int, parts: int) -> None:
        """Compile (or load from the cache) share ``part`` of ``parts`` of what
        ``compile_shares`` counts, without running a realization; the other processes then
        load it from the shared cache. Called only when ``compile_shares()`` is positive."""

    @classmethod
    def report(cls, trees: list, folder, figures: bool = True, **options) -> tuple[str, list]:
        """What results of this solver add to ``uqflow report`` and ``uqflow run``: text
        printed after the framework's summary, and the paths of figures written into
        ``folder`` (through ``uqflow.report.figure_path``; none when ``figures`` is False).

        ``trees`` are one or more results (``xr.DataTree``) of this solver. A solver draws here
        what only it knows: a map of its scene with the probes, a comparison with a reference
        solution, a seed table beside ours. Keyword ``options`` come from the command line
        (``uqflow report --time 1e-5``); an override must name each it takes in its signature:
        one it does not take is refused naming it. The default adds nothing.
        """
        return "", []

    def describe(self) -> str:
        return f"{self.name} solver"
