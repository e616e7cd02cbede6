"""A plain Python function as a solver: ``solver_from_function(f, outputs=..., units=...)``.

``f(**params)`` takes the parameters by name and returns a number (one scalar output) or a
dict of outputs, each a number or an array laid out on the dims declared for it. The class
returned is a full ``uqflow.solver.Solver``: register it with ``register_solver`` or name it
in a package's ``uqflow.solvers`` entry point, and check it with
``uqflow.testing.check_solver`` (docs/writing-a-solver.md).

Its scene sets nominal values: ``scene = { L = 2.0 }`` runs with L = 2 where a study leaves
L certain; any other key is refused naming it. Instances pickle through ``f`` (by reference
for a module-level function, by value under cloudpickle for a closure), so dask ships them
like any solver.
"""

from __future__ import annotations

import inspect
import math
import re
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import xarray as xr

from uqflow.errors import SceneError, SolverError
from uqflow.layout import LONG_NAME, UNITS
from uqflow.solver import Solver

__all__ = ["FunctionSolver", "solver_from_function"]

_DOTTED = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")
#: classes made so far, so that the same call gives the same class (and an unpickled
#: instance is an instance of the class its process already has)
_MADE: dict = {}


def _finite_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and \
        not isinstance(value, (bool, np.bool_)) and math.isfinite(float(value))


def _nominal_from_signature(f: Callable) -> dict[str, float]:
    """The parameters of ``f`` with numeric defaults: the nominal values when none are given."""
    found = {}
    for p in inspect.signature(f).parameters.values():
        if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue
        if p.default is p.empty or not _finite_number(p.default):
            raise TypeError(f"solver_from_function: parameter '{p.name}' of {f.__name__} has "
                            f"no numeric default; give parameters={{'{p.name}': value, ...}}")
        found[p.name] = float(p.default)
    return found


def _takes(f: Callable, names: Sequence[str]) -> None:
    """Refuse parameter names ``f`` cannot be called with, when the function is made."""
    signature = inspect.signature(f).parameters.values()
    if any(p.kind == p.VAR_KEYWORD for p in signature):
        return
    accepted = {p.name for p in signature if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    missing = [n for n in names if n not in accepted]
    if missing:
        raise TypeError(f"solver_from_function: {f.__name__} takes no argument '{missing[0]}' "
                        f"(a dotted name needs f(**params))")


def _class_name(name: str) -> str:
    words = re.findall(r"[A-Za-z0-9]+", name)
    text = "".join(w[:1].upper() + w[1:] for w in words) or "Function"
    return text if text[0].isalpha() else "Solver" + text


def solver_from_function(f: Callable, outputs: str | Sequence[str] | Mapping[str, Sequence[str]],
                         units: str | Mapping[str, str], parameters: Mapping[str, float] | None
                         = None, name: str | None = None, *,
                         long_names: Mapping[str, str] | None = None,
                         coords: Mapping[str, Sequence[float]] | None = None,
                         coord_units: Mapping[str, str] | None = None,
                         parameter_units: Mapping[str, str] | None = None) -> type[Solver]:
    """A ``Solver`` class that runs ``f(**params)``.

    ``outputs``: a name, a list of names (scalar outputs) or a dict ``{name: dims}`` (a tuple
    of dim names, ``()`` for a scalar). ``units``: SI units of each output (a string when
    there is one output). ``parameters``: nominal value of each parameter (default: the
    numeric defaults of ``f``'s arguments); names with dots need ``f(**params)``.
    ``coords``: the coordinate values of each dim of an array output (with ``coord_units``).
    ``long_names``: a label a reader understands per output (default: the name with spaces).
    ``name``: the solver's name (``register_solver`` sets it again when registering).
    """
    if isinstance(outputs, str):
        outputs = {outputs: ()}
    elif not isinstance(outputs, Mapping):
        outputs = {o: () for o in outputs}
    outputs = {str(o): tuple(d) for o, d in outputs.items()}
    if not outputs:
        raise ValueError("solver_from_function: outputs names no output")
    if isinstance(units, str):
        if len(outputs) != 1:
            raise ValueError("solver_from_function: give units as {output: units} for "
                             "several outputs")
        units = {next(iter(outputs)): units}
    missing = [o for o in outputs if o not in units]
    if missing:
        raise ValueError(f"solver_from_function: output '{missing[0]}' has no units "
                         f"(units={{'{missing[0]}': 'm', ...}}; '1' for a dimensionless one)")
    nominal = _nominal_from_signature(f) if parameters is None else \
        {str(k): float(v) for k, v in parameters.items()}
    for key, value in nominal.items():
        if not _DOTTED.match(key):
            raise ValueError(f"solver_from_function: parameter name '{key}' is not a dotted "
                             f"name (letters, digits, _ and dots)")
        if not math.isfinite(value):
            raise ValueError(f"solver_from_function: nominal value of '{key}' is {value}")
    _takes(f, list(nominal))
    coords = {str(d): np.asarray(v, dtype=float) for d, v in (coords or {}).items()}
    for out, dims in outputs.items():
        for d in dims:
            if d not in coords:
                raise ValueError(f"solver_from_function: dim '{d}' of output '{out}' has no "
                                 f"coordinate values (coords={{'{d}': [...]}})")
    arguments = dict(outputs=outputs, units=dict(units), parameters=nominal,
                     name=name or f.__name__, long_names=dict(long_names or {}),
                     coords={d: tuple(v.tolist()) for d, v in coords.items()},
                     coord_units=dict(coord_units or {}),
                     units_of_parameters=dict(parameter_units or {}))
    key = (f, repr(sorted(arguments.items())))
    if key not in _MADE:
        _MADE[key] = _make_class(f, arguments)
    return _MADE[key]


class FunctionSolver(Solver):
    """Base of the classes ``solver_from_function`` makes: each sets ``function`` (the
    Python function), ``arguments`` (what ``solver_from_function`` was given, normalised)
    and ``template`` (the outputs' template)."""

    function: Callable
    arguments: dict
    template: xr.Dataset

    def __init__(self, values: Mapping[str, float] | None = None):
        defaults = self.arguments["parameters"]
        self._nominal = dict(defaults if values is None else values)

    @classmethod
    def from_scene(cls, scene: Mapping) -> "FunctionSolver":
        defaults = cls.arguments["parameters"]
        if not isinstance(scene, Mapping):
            raise SceneError("must be a table of nominal parameter values", key="scene")
        values = dict(defaults)
        for key, value in scene.items():
            if key not in defaults:
                raise SceneError(f"unknown key (the scene sets nominal values of "
                                 f"{', '.join(defaults) or 'no parameter'})", key=f"scene.{key}")
            if not _finite_number(value):
                raise SceneError(f"must be a finite number, got {value!r}", key=f"scene.{key}")
            values[key] = float(value)
        return cls(values)

    def __reduce__(self):
        return _instance, (self.function, self.arguments, self._nominal)

    def nominal(self) -> dict[str, float]:
        return dict(self._nominal)

    def parameter_units(self) -> dict[str, str]:
        return dict(self.arguments["units_of_parameters"])

    def outputs(self) -> xr.Dataset:
        return self.template.copy(deep=True)

    def describe(self) -> str:
        return f"{self.name} (function {self.function.__name__})"

    def run(self, params, fields=None) -> xr.Dataset:
        f = self.function
        if fields:
            raise SolverError(f"solver '{self.name}' takes no random fields")
        values = dict(self._nominal)
        for key, value in params.items():
            if key not in values:
                raise SolverError(f"unknown parameter '{key}' (known: {', '.join(values)})")
            values[key] = float(value)
        result = f(**values)
        outputs = self.arguments["outputs"]
        if not isinstance(result, Mapping):
            if len(outputs) != 1:
                raise SolverError(f"{f.__name__} returned {type(result).__name__}, not a dict "
                                  f"of the outputs {', '.join(outputs)}")
            result = {next(iter(outputs)): result}
        ds = self.outputs()
        for out in outputs:
            if out not in result:
                raise SolverError(f"{f.__name__} returned no output '{out}'")
            value = np.asarray(result[out], dtype=float)
            if value.shape != ds[out].shape:
                raise SolverError(f"{f.__name__} returned output '{out}' of shape "
                                  f"{value.shape}; its dims {ds[out].dims} have shape "
                                  f"{ds[out].shape}")
            ds[out].values[...] = value
        return ds


def _make_class(f: Callable, arguments: dict) -> type[Solver]:
    outputs = arguments["outputs"]
    coords = {d: xr.Variable(d, np.asarray(v), {UNITS: arguments["coord_units"].get(d, "")})
              for d, v in arguments["coords"].items()}
    template = xr.Dataset(
        {o: xr.Variable(dims, np.full(tuple(len(coords[d]) for d in dims), np.nan),
                        {UNITS: arguments["units"][o],
                         LONG_NAME: arguments["long_names"].get(o, o.replace("_", " "))})
         for o, dims in outputs.items()},
        coords={d: c for d, c in coords.items() if any(d in dims for dims in outputs.values())})
    cls = type(_class_name(arguments["name"]), (FunctionSolver,), {
        "__doc__": (f.__doc__ or f"{arguments['name']}: a function as a solver").strip(),
        "__module__": getattr(f, "__module__", __name__),
        "name": arguments["name"], "function": staticmethod(f), "arguments": arguments,
        "template": template})
    cls.__qualname__ = cls.__name__
    return cls


def _instance(f: Callable, arguments: dict, values: dict) -> Solver:
    """An instance of the class ``solver_from_function`` makes for ``f`` (for pickle)."""
    given = {k: v for k, v in arguments.items() if k != "units_of_parameters"}
    made = solver_from_function(f, parameter_units=arguments["units_of_parameters"], **given)
    return made(values)
