"""Conformance suites for solvers and propagation methods: ``check_solver``, ``check_method``.

A third party runs them on their own solver or method (docs/writing-a-solver.md,
docs/writing-a-method.md); every built-in passes them in the test suite. Each check is a named
function; one that finds a problem raises ``ConformanceError`` (an ``AssertionError``) whose
message says which check, what is wrong and how to fix it. ``check_solver`` and
``check_method`` run every check and raise one ``ConformanceError`` listing every failure
(``.failures``: check name -> message); they return ``{check: "ok" | "not applicable: why"}``.
``solver_checks(...)`` and ``method_checks(...)`` give the checks one by one as
``(name, callable)`` for ``pytest.mark.parametrize``; a check that does not apply raises
``NotApplicable`` (a ``unittest.SkipTest``, which pytest reports as a skip).

The method suite runs the method on a tiny built-in model, ``TinyModel`` (registered as the
solver ``uqflow-testing-tiny``): two inputs, a scalar output and a profile over a dim, exact
local derivatives (for methods that need them), a random field on ``x1`` and a ``resolution``
scene key for fidelity levels. Each suite takes a few seconds.
"""

from __future__ import annotations

import copy
import inspect
import json
import math
import pickle
import re
import tempfile
import unittest
import warnings
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import cloudpickle
import numpy as np
import xarray as xr

from uqflow.errors import SceneError, SolverError, StudyError, UqflowError
from uqflow.execute import run_study
from uqflow.layout import (FAILED_RUNS, GRADIENT_SUFFIX, HESSIAN_SUFFIX, INPUTS, LONG_NAME,
                           MESSAGE, METHOD, PARAMETER, PARAMETER_J, REALIZATION, RUN_COLUMNS,
                           SENSITIVITY_DIM, SOLVER_RUNS, SOLVER_WALL_TIME, STATISTIC, STATUS,
                           STATUS_FAILED, UNITS, gradient_variable, hessian_variable,
                           is_diagnostic)
from uqflow.methods.base import (MethodOptions, PropagationMethod, get_method,
                                 method_registry)
from uqflow.realization import run_batch, takes_seed
from uqflow.report import MethodReport, ResultView
from uqflow.solver import Solver, register_solver
from uqflow.store import open_result
from uqflow.study import load_study

__all__ = ["ConformanceError", "ConformanceWarning", "NotApplicable", "TinyModel",
           "check_method", "check_solver", "checks", "method_checks", "run_in_memory",
           "solver_checks"]


class ConformanceError(AssertionError):
    """A solver or method breaks the contract: the message names the check and the fix."""

    def __init__(self, message: str, failures: Mapping[str, str] | None = None):
        super().__init__(message)
        self.failures = dict(failures or {})


class ConformanceWarning(UserWarning):
    """Not wrong, but a reader of the results would miss something (a label, a coordinate)."""


class NotApplicable(unittest.SkipTest):
    """The check does not apply to this solver or method (the message says why)."""


def _fail(check: str, what: str, fix: str) -> ConformanceError:
    return ConformanceError(f"{check}: {what} ({fix})")


_DOTTED = re.compile(r"^[\w\-]+(\.[\w\-]+)*$")
#: dims and variable names the result layout gives a meaning of its own
_RESERVED_DIMS = (REALIZATION, STATISTIC, PARAMETER, PARAMETER_J, SENSITIVITY_DIM)
_RESERVED_NAMES = frozenset({INPUTS, *RUN_COLUMNS})


def _quantities(ds: xr.Dataset) -> list[str]:
    """The variables of a solver's dataset that must be reproducible (not its timings)."""
    return [str(v) for v in ds.data_vars if not is_diagnostic(ds[v])]


def _first_difference(a: xr.Dataset, b: xr.Dataset, names) -> str | None:
    """'output 'y' differs at index (2,): 1.0 vs 1.5' for the first differing output."""
    for name in names:
        x, y = np.asarray(a[name].values, dtype=float), np.asarray(b[name].values, dtype=float)
        if x.shape != y.shape:
            return f"output '{name}' has shape {x.shape} in one run and {y.shape} in the other"
        if not np.array_equal(x, y, equal_nan=True):
            where = np.argwhere(~((x == y) | (np.isnan(x) & np.isnan(y))))[0]
            return (f"output '{name}' differs at index {tuple(int(i) for i in where)}: "
                    f"{x[tuple(where)]!r} vs {y[tuple(where)]!r}")
    return None


# ======================================================================================= solvers

class _SolverCase:
    """What the solver checks share: the class, the scene, one instance, the run parameters."""

    def __init__(self, solver_or_class, scene, params, failing_params, bad_scenes, seed,
                 fields):
        if isinstance(solver_or_class, type):
            self.cls, self._solver = solver_or_class, None
            self.scene = {} if scene is None else scene
        else:
            self.cls, self._solver, self.scene = type(solver_or_class), solver_or_class, scene
        self.params, self.failing_params = params, failing_params
        self.bad_scenes, self.seed, self.fields = dict(bad_scenes or {}), seed, fields

    @property
    def solver(self) -> Solver:
        if self._solver is None:
            try:
                self._solver = self.cls.from_scene(copy.deepcopy(self.scene))
            except Exception as exc:
                raise _fail("from_scene", f"{self.cls.__name__}.from_scene(scene) raised "
                            f"{type(exc).__name__}: {exc}",
                            "pass a scene the solver accepts: check_solver(cls, scene=...)") \
                    from exc
        return self._solver

    def run_params(self) -> dict[str, float]:
        """The parameters of the checks' runs: the caller's, or each nominal value moved by
        1 % (so that a run depends on what it is given, not only on the scene)."""
        if self.params is not None:
            return dict(self.params)
        return {k: float(v) * 1.01 if v else 0.01 for k, v in self.solver.nominal().items()}

    def run(self, solver=None, params=None, **kwargs) -> xr.Dataset:
        solver = solver or self.solver
        extra = {"seed": self.seed} if takes_seed(solver) else {}
        args = (self.fields,) if self.fields is not None else ()
        return solver.run(self.run_params() if params is None else params, *args,
                          **extra, **kwargs)


def check_solver_contract(case: _SolverCase) -> None:
    """The class is a Solver with every abstract method implemented; from_scene builds it."""
    name = "contract"
    if not (isinstance(case.cls, type) and issubclass(case.cls, Solver)):
        raise _fail(name, f"{case.cls!r} is not a subclass of uqflow.solver.Solver",
                    "derive it from Solver, or make it with uqflow.solver_from_function")
    if inspect.isabstract(case.cls):
        missing = ", ".join(sorted(case.cls.__abstractmethods__))
        raise _fail(name, f"{case.cls.__name__} leaves abstract: {missing}",
                    "implement from_scene, nominal, outputs and run")
    if not isinstance(case.solver, case.cls):
        raise _fail(name, "from_scene returned no instance of the class",
                    "return cls(...) from from_scene")


def check_solver_nominal(case: _SolverCase) -> None:
    """nominal(): dotted parameter names with finite float values; parameter_units() names
    only those."""
    name = "nominal"
    nominal = case.solver.nominal()
    if not isinstance(nominal, Mapping) or not nominal:
        raise _fail(name, f"nominal() returned {nominal!r}",
                    "return a dict {dotted name: nominal value} of every parameter a study "
                    "may make uncertain")
    for key, value in nominal.items():
        if not isinstance(key, str) or not _DOTTED.match(key):
            raise _fail(name, f"parameter name {key!r} is not a dotted name",
                        "use names like 'steel.E' or 'load': no spaces, no empty parts")
        if isinstance(value, (bool, np.bool_)) or not isinstance(
                value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
            raise _fail(name, f"nominal value of '{key}' is {value!r}",
                        "give a finite number (SI units)")
    unknown = [k for k in case.solver.parameter_units() if k not in nominal]
    if unknown:
        raise _fail(name, f"parameter_units() names '{unknown[0]}', which nominal() lacks",
                    "give units for the parameters of nominal() only")


def check_solver_outputs_template(case: _SolverCase) -> None:
    """outputs(): a Dataset whose variables have units (and long_name), named dims, no
    dim or name the result layout reserves."""
    name = "outputs_template"
    template = case.solver.outputs()
    if not isinstance(template, xr.Dataset) or not template.data_vars:
        raise _fail(name, f"outputs() returned {type(template).__name__} with no variables",
                    "return an xr.Dataset template with one variable per output")
    for out, var in template.data_vars.items():
        if not isinstance(out, str) or out in _RESERVED_NAMES or \
                out.endswith((GRADIENT_SUFFIX, HESSIAN_SUFFIX)):
            raise _fail(name, f"output name {out!r} is one the result layout reserves",
                        f"rename it (reserved: {', '.join(sorted(_RESERVED_NAMES))} and "
                        f"the {GRADIENT_SUFFIX}/{HESSIAN_SUFFIX} suffixes)")
        if not isinstance(var.attrs.get(UNITS), str):
            raise _fail(name, f"output '{out}' has no 'units' attribute",
                        f"set attrs['units'] (SI, '1' when dimensionless) on '{out}'")
        for dim in var.dims:
            if not isinstance(dim, str) or not dim:
                raise _fail(name, f"output '{out}' has an unnamed dim {dim!r}",
                            "name every dim")
            if dim in _RESERVED_DIMS:
                raise _fail(name, f"output '{out}' has the dim '{dim}', which uqflow adds "
                                  f"itself", "rename the dim")
    unlabelled = [str(o) for o, v in template.data_vars.items()
                  if not v.attrs.get(LONG_NAME) and not is_diagnostic(v)]
    if unlabelled:
        warnings.warn(f"outputs_template: no 'long_name' on {', '.join(unlabelled)}: the report "
                      f"labels them by their variable names (set attrs['long_name'] to what a "
                      f"reader understands, e.g. 'tip deflection')", ConformanceWarning,
                      stacklevel=2)


def _compare_with_template(check: str, result: xr.Dataset, template: xr.Dataset,
                           when: str) -> None:
    if not isinstance(result, xr.Dataset):
        raise _fail(check, f"run({when}) returned {type(result).__name__}",
                    "return an xr.Dataset laid out as outputs()")
    for out, var in template.data_vars.items():
        if out not in result.data_vars:
            raise _fail(check, f"run({when}) returned no output '{out}'",
                        "return every variable of the outputs() template")
        got = result[out]
        if got.dims != var.dims or got.shape != var.shape:
            raise _fail(check, f"output '{out}' of run({when}) has dims "
                               f"{dict(zip(got.dims, got.shape))}, the outputs() template "
                               f"has {dict(zip(var.dims, var.shape))}",
                        "an output keeps the dims and sizes of its template in every run; "
                        "put what varies on a fixed grid, or make it a scene option")
        if got.attrs.get(UNITS) != var.attrs.get(UNITS):
            raise _fail(check, f"output '{out}' of run({when}) has units "
                               f"{got.attrs.get(UNITS)!r}, the template {var.attrs.get(UNITS)!r}",
                        "give the run's variables the template's attributes")
        for coord, values in template.coords.items():
            if not set(values.dims) <= set(var.dims):
                continue  # a coordinate of other outputs' dims
            if coord not in result.coords or not np.array_equal(
                    np.asarray(result[coord].values), np.asarray(values.values)):
                raise _fail(check, f"coordinate '{coord}' of output '{out}' in run({when}) "
                                   f"{'is missing' if coord not in result.coords else 'differs'}"
                                   f" (the template's: {np.asarray(values.values)[:4]}...)",
                            "give the runs the template's coordinates, e.g. build the result "
                            "from a copy of outputs()")


def check_solver_run_matches_template(case: _SolverCase) -> None:
    """run() returns every output with the template's dims, sizes, coordinates and units, at
    the nominal parameters and at the checks' parameters."""
    template = case.solver.outputs()
    _compare_with_template("run_matches_template", case.run(params={}), template,
                           "nominal parameters")
    _compare_with_template("run_matches_template", case.run(), template,
                           f"{case.run_params()}")


def check_solver_deterministic(case: _SolverCase) -> None:
    """Two runs with the same parameters (and the same seed and fields) give identical
    outputs (timings and counters marked diagnostic excepted)."""
    name = "deterministic"
    first, second = case.run(), case.run()
    diff = _first_difference(first, second, _quantities(case.solver.outputs()))
    if diff:
        seeded = f" and seed={case.seed}" if takes_seed(case.solver) else ""
        raise _fail(name, f"two runs with the same parameters{seeded} differ: {diff}",
                    "a run must depend on its parameters, scene, fields and seed alone: draw "
                    "random numbers from np.random.default_rng(seed), and mark timings "
                    "output_kind='diagnostic'")


def check_solver_failure_capture(case: _SolverCase) -> None:
    """A run that cannot succeed (the caller's ``failing_params``; by default every parameter
    NaN) becomes a failed realization with a one-line message in uqflow's runner."""
    name = "failure_capture"
    solver = case.solver
    params = case.failing_params or {k: math.nan for k in solver.nominal()}
    names = list(params)
    outputs = list(solver.outputs().data_vars)
    seeds = np.array([case.seed]) if takes_seed(solver) else None
    try:
        batch = run_batch(solver, names, np.array([[params[k] for k in names]]), outputs,
                          seeds=seeds)
    except BaseException as exc:  # what the runner lets through ends a study
        raise _fail(name, f"{type(exc).__name__} escaped uqflow's runner", "raise "
                    "SolverError (or any Exception) from run, never BaseException") from exc
    status, message = batch[STATUS][0], batch[MESSAGE][0]
    if status != STATUS_FAILED:
        raise _fail(name, f"a run with {params} ended '{status}' with finite outputs",
                    "raise SolverError on parameters the model cannot take (a NaN, a "
                    "negative modulus), or pass failing_params= that make it fail")
    if not message or "\n" in message:
        raise _fail(name, f"the failed run's message is {message!r}",
                    "say in one line where and why the run failed")


def check_solver_pickle(case: _SolverCase) -> None:
    """The instance round-trips through cloudpickle (dask's serializer) and the copy runs the
    same; one that only cloudpickle can ship gets a warning (the standard library's pickle,
    used by multiprocessing, cannot)."""
    name = "pickle"
    expected = case.run()
    for module in (cloudpickle, pickle):
        try:
            copy_ = module.loads(module.dumps(case.solver))
        except Exception as exc:
            if module is pickle:
                warnings.warn(f"pickle: the standard library cannot pickle the solver "
                              f"({type(exc).__name__}: {exc}); cloudpickle can, so dask ships "
                              f"it", ConformanceWarning, stacklevel=2)
                continue
            raise _fail(name, f"{module.__name__} cannot round-trip the solver "
                              f"({type(exc).__name__}: {exc})",
                        "keep no open file, lock or thread in the instance") from exc
        diff = _first_difference(expected, case.run(solver=copy_),
                                 _quantities(case.solver.outputs()))
        if diff:
            raise _fail(name, f"the {module.__name__} copy runs differently: {diff}",
                        "keep everything a run needs in picklable attributes")


def check_solver_bad_scene(case: _SolverCase) -> None:
    """A bad scene is one ``SceneError`` line naming its key: an unknown key added to the
    scene, and each of the caller's ``bad_scenes`` ({key: scene})."""
    name = "bad_scene"
    if not isinstance(case.scene, Mapping):
        raise NotApplicable("bad_scene: no scene given (check_solver(cls, scene=...))")
    unknown = "no_such_key_for_conformance"
    cases = {f"scene.{unknown}": {**copy.deepcopy(dict(case.scene)), unknown: 1.0},
             **case.bad_scenes}
    for key, scene in cases.items():
        try:
            case.cls.from_scene(scene)
        except SceneError as exc:
            if exc.key != key:
                raise _fail(name, f"the scene error names key {exc.key!r}, not {key!r} "
                                  f"({exc})", "raise SceneError(reason, key='scene.<key>') "
                                              "naming the offending key") from exc
            if "\n" in str(exc):
                raise _fail(name, f"the scene error for {key} spans lines",
                            "say it in one line") from exc
            continue
        except Exception as exc:
            raise _fail(name, f"the scene with a bad {key} raised {type(exc).__name__}: {exc}",
                        "validate the scene in from_scene and raise SceneError(reason, "
                        "key=...)") from exc
        raise _fail(name, f"from_scene accepted the scene with a bad {key}",
                    "validate every scene key and refuse unknown ones with SceneError")


def check_solver_local_sensitivities(case: _SolverCase) -> None:
    """Declared local sensitivities name outputs and parameters the solver has, and
    run_with_sensitivities returns them laid out as the contract says, beside run's outputs."""
    name = "local_sensitivities"
    solver = case.solver
    declared = solver.local_sensitivities()
    if not declared:
        raise NotApplicable("local_sensitivities: the solver declares none")
    template, nominal = solver.outputs(), solver.nominal()
    params = case.run_params()
    plain = solver.run(params)
    for out, wrt in declared.items():
        if out not in template.data_vars:
            raise _fail(name, f"local_sensitivities() names output '{out}', which outputs() "
                              f"lacks", "name outputs of the template")
        unknown = [w for w in wrt if w not in nominal]
        if unknown:
            raise _fail(name, f"local_sensitivities()['{out}'] names parameter "
                              f"'{unknown[0]}', which nominal() lacks",
                        "name parameters of nominal()")
        wrt = list(wrt)
        result = solver.run_with_sensitivities(params, wrt=wrt, outputs=[out])
        diff = _first_difference(plain, result, [out])
        if diff:
            raise _fail(name, f"run_with_sensitivities and run disagree: {diff}",
                        "return run(params)'s dataset plus the derivatives")
        dims = template[out].dims
        for var, extra in ((gradient_variable(out), (PARAMETER,)),
                           (hessian_variable(out), (PARAMETER, PARAMETER_J))):
            if var not in result.data_vars:
                raise _fail(name, f"run_with_sensitivities returned no '{var}'",
                            "add the gradient and Hessian of every output asked for")
            if set(result[var].dims) != {*dims, *extra}:
                raise _fail(name, f"'{var}' has dims {result[var].dims}, not "
                                  f"{(*dims, *extra)}", "lay it out as the Solver contract "
                                                        "says")
            for d in extra:
                if d in result[var].coords and \
                        sorted(map(str, result[var][d].values)) != sorted(wrt):
                    raise _fail(name, f"'{var}' has {d} {list(result[var][d].values)}, "
                                      f"asked for {wrt}", "give the derivatives of wrt")
            if not np.all(np.isfinite(result[var].values)):
                raise _fail(name, f"'{var}' is not finite at {params}",
                            "return finite derivatives where the run is ok")


SOLVER_CHECKS: dict[str, Callable[[_SolverCase], None]] = {
    "contract": check_solver_contract,
    "nominal": check_solver_nominal,
    "outputs_template": check_solver_outputs_template,
    "run_matches_template": check_solver_run_matches_template,
    "deterministic": check_solver_deterministic,
    "failure_capture": check_solver_failure_capture,
    "pickle": check_solver_pickle,
    "bad_scene": check_solver_bad_scene,
    "local_sensitivities": check_solver_local_sensitivities,
}


def solver_checks(solver_or_class, scene: Mapping | None = None, *,
                  params: Mapping[str, float] | None = None,
                  failing_params: Mapping[str, float] | None = None,
                  bad_scenes: Mapping[str, Mapping] | None = None, seed: int = 12345,
                  fields=None) -> Iterator[tuple[str, Callable[[], None]]]:
    """The solver checks as ``(name, callable)``; arguments as ``check_solver``."""
    case = _SolverCase(solver_or_class, scene, params, failing_params, bad_scenes, seed, fields)
    for name, check in SOLVER_CHECKS.items():
        yield name, (lambda check=check: check(case))


def check_solver(solver_or_class, scene: Mapping | None = None, *,
                 params: Mapping[str, float] | None = None,
                 failing_params: Mapping[str, float] | None = None,
                 bad_scenes: Mapping[str, Mapping] | None = None, seed: int = 12345,
                 fields=None) -> dict[str, str]:
    """Run every solver check; raise ``ConformanceError`` listing the failures.

    ``solver_or_class``: a Solver subclass (built from ``scene``, default ``{}``) or an
    instance (the ``bad_scene`` check then needs ``scene``). ``params``: parameters of the
    checks' runs (default: every nominal value moved by 1 %). ``failing_params``: parameters
    that make a run fail (default: every parameter NaN). ``bad_scenes``: ``{key: scene}``,
    scenes ``from_scene`` must refuse with a ``SceneError`` naming ``key``. ``seed``: given to
    a ``run`` that takes one; ``fields``: given to ``run`` as its random fields.
    """
    return _run_all(solver_checks(solver_or_class, scene, params=params,
                                  failing_params=failing_params, bad_scenes=bad_scenes,
                                  seed=seed, fields=fields), "check_solver")


def _run_all(found: Iterator[tuple[str, Callable[[], None]]], suite: str) -> dict[str, str]:
    outcome, failures = {}, {}
    for name, check in found:
        try:
            check()
            outcome[name] = "ok"
        except NotApplicable as exc:
            outcome[name] = f"not applicable: {exc}"
        except ConformanceError as exc:
            failures[name] = str(exc)
        except Exception as exc:  # a check that crashes is a failure of what it checks
            failures[name] = f"{name}: raised {type(exc).__name__}: {' '.join(str(exc).split())}"
    if failures:
        lines = "\n".join(f"  - {m}" for m in failures.values())
        raise ConformanceError(f"{suite}: {len(failures)} check(s) failed:\n{lines}", failures)
    return outcome


# ============================================================================ the tiny model

@register_solver("uqflow-testing-tiny")
class TinyModel(Solver):
    """A tiny smooth model for the method checks: y = x1 (1 + x2) + x2²/2 + x1/resolution
    [m] and a profile p(s) = x1 e^(−x2 s / 4) [Pa] at s = 0, 1, 2 m, with exact local
    derivatives; a random field may drive x1 along s; ``resolution`` (scene) sets a bias
    x1/resolution, a fidelity level's truncation error."""

    S = np.array([0.0, 1.0, 2.0])

    def __init__(self, resolution: int = 64):
        self.resolution = resolution

    @classmethod
    def from_scene(cls, scene):
        if not isinstance(scene, Mapping):
            raise SceneError("must be a table", key="scene")
        for key in scene:
            if key != "resolution":
                raise SceneError("unknown key (takes resolution)", key=f"scene.{key}")
        resolution = scene.get("resolution", 64)
        if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 1:
            raise SceneError(f"must be an integer >= 1, got {resolution!r}",
                             key="scene.resolution")
        return cls(resolution)

    def nominal(self):
        return {"x1": 1.0, "x2": 2.0}

    def parameter_units(self):
        return {"x1": "m", "x2": "1"}

    def outputs(self):
        return xr.Dataset(
            {"y": xr.Variable((), np.nan, {UNITS: "m", LONG_NAME: "tiny response"}),
             "profile": xr.Variable("s", np.full(3, np.nan),
                                    {UNITS: "Pa", LONG_NAME: "tiny profile"})},
            coords={"s": ("s", self.S, {UNITS: "m", LONG_NAME: "position"})})

    def field_points(self, name):
        if name == "x1":
            return self.S[:, None]
        return super().field_points(name)

    def _values(self, params, fields=None):
        p = {**self.nominal(), **params}
        x1 = np.full(3, float(p["x1"]))
        if fields and "x1" in fields:
            x1 = np.asarray(fields.values("x1", self.S[:, None], mean=float(p["x1"])),
                            dtype=float).reshape(3)
        x2 = float(p["x2"])
        if not (np.all(np.isfinite(x1)) and math.isfinite(x2)):
            raise SolverError(f"non-finite parameter: x1 = {x1[0]}, x2 = {x2}")
        mean_x1 = float(x1.mean())
        y = mean_x1 * (1 + x2) + 0.5 * x2**2 + mean_x1 / self.resolution
        return y, x1 * np.exp(-x2 * self.S / 4)

    def run(self, params, fields=None):
        y, profile = self._values(params, fields)
        ds = self.outputs()
        ds["y"].values[...] = y
        ds["profile"].values[...] = profile
        return ds

    def local_sensitivities(self):
        return {"y": ("x1", "x2"), "profile": ("x1", "x2")}

    def run_with_sensitivities(self, params, wrt, outputs):
        ds = self.run(params)
        p = {**self.nominal(), **params}
        x1, x2 = float(p["x1"]), float(p["x2"])
        decay = np.exp(-x2 * self.S / 4)
        grads = {"y": (np.array([1 + x2 + 1 / self.resolution, x1 + x2]),
                       np.array([[0.0, 1.0], [1.0, 1.0]])),
                 "profile": (np.stack([decay, -x1 * self.S / 4 * decay], axis=-1),
                             np.stack([np.stack([0 * decay, -self.S / 4 * decay], -1),
                                       np.stack([-self.S / 4 * decay,
                                                 x1 * (self.S / 4) ** 2 * decay], -1)], -2))}
        index = [["x1", "x2"].index(w) for w in wrt]
        for out in outputs:
            gradient, hessian = grads[out]
            dims = ds[out].dims
            ds[gradient_variable(out)] = xr.Variable((*dims, PARAMETER), gradient[..., index])
            ds[hessian_variable(out)] = xr.Variable((*dims, PARAMETER, PARAMETER_J),
                                                    hessian[..., index, :][..., index])
        return ds.assign_coords({PARAMETER: list(wrt), PARAMETER_J: list(wrt)})


# ======================================================================================= methods

def _toml_value(value) -> str:
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{json.dumps(str(k))} = {_toml_value(v)}"
                                for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    return json.dumps(str(value))


class _MethodCase:
    """What the method checks share: the tiny study, its loaded form, one run's result."""

    def __init__(self, method_class, options, levels, fields, seed, random_plan, folder,
                 limit_states=None):
        self.method_class, self.options = method_class, dict(options or {})
        self.limit_states = list(limit_states or [])
        self.levels, self.fields, self.seed = levels, fields, seed
        self.random_plan = random_plan
        self._folder = None if folder is None else Path(folder)
        self._study = self._result = self._runs = None
        self._study_error: ConformanceError | None = None

    @property
    def folder(self) -> Path:
        """Where the tiny study and its result are written (made on first use)."""
        if self._folder is None:
            self._folder = Path(tempfile.mkdtemp(prefix="uqflow-check-method-"))
        return self._folder

    @property
    def kind(self) -> str:
        cls = self.method_class
        if not cls.name or cls.name not in method_registry.names() or \
                get_method(cls.name) is not cls:
            # an unregistered class is run under a name of its own
            method_registry.register(f"conformance-{cls.__module__}.{cls.__qualname__}")(cls)
        return cls.name

    def study_text(self, extra_options: Mapping | None = None) -> str:
        options = {**self.options, **(extra_options or {})}
        lines = ['name = "conformance"', 'solver = "uqflow-testing-tiny"', "scene = {}", "",
                 "[[inputs]]", 'name = "x1"', 'distribution = "normal"', "mean = 1.0",
                 "std = 0.1", "", "[[inputs]]", 'name = "x2"', 'distribution = "uniform"',
                 "lower = 1.5", "upper = 2.5", ""]
        if self.fields:
            lines += ["[[fields]]", 'name = "x1"', "correlation_length = 1.0", "modes = 2",
                      ""]
        for table in self.limit_states:
            lines += ["[[limit_states]]"] + [f"{k} = {_toml_value(v)}"
                                             for k, v in table.items()] + [""]
        if self.levels:
            lines += ["[levels]", 'key = "resolution"',
                      f"values = {_toml_value(list(self.levels))}", ""]
        lines += ["[method]", f"kind = {json.dumps(self.kind)}"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in options.items()]
        lines += ["", "[execution]", "workers = 0", f"seed = {self.seed}", "", "[output]",
                  'path = "result.nc"', "figures = false", ""]
        return "\n".join(lines)

    def load(self, extra_options: Mapping | None = None, file: str = "study.toml"):
        path = self.folder / file
        path.write_text(self.study_text(extra_options))
        return load_study(path)

    @property
    def study(self):
        if self._study_error is not None:
            raise NotApplicable(f"the tiny study does not load ({self._study_error})")
        if self._study is None:
            try:
                self._study = self.load()
            except StudyError as exc:
                self._study_error = _fail(
                    "study", f"the tiny study with these options does not load: {exc}",
                    "pass options=/levels=/fields= the method needs to check_method")
                raise self._study_error from exc
        return self._study

    def plan(self, seed: int) -> xr.Dataset:
        study = self.study
        return study.method.plan(study.space, study.fields, np.random.SeedSequence(seed))

    @property
    def result(self) -> xr.DataTree:
        """The tiny study's result file, as ``uqflow report`` reads it."""
        if self._result is None:
            outcome = run_study(self.study, show_progress=False, force=True)
            self._runs = outcome.runs
            self._result = open_result(outcome.path).load()
        return self._result

    @property
    def runs(self) -> xr.Dataset:
        """The runs as the executor gave them to ``analyze`` (the design's variables and
        attributes included)."""
        self.result
        return self._runs

    @property
    def outputs(self) -> list[str]:
        return list(self.study.outputs)


def check_method_options(case: _MethodCase) -> None:
    """Options is a MethodOptions; the method builds from the options given."""
    name = "options"
    cls = case.method_class
    if not (isinstance(cls, type) and issubclass(cls, PropagationMethod)):
        raise _fail(name, f"{cls!r} is not a PropagationMethod subclass",
                    "derive it from uqflow.methods.base.PropagationMethod")
    if inspect.isabstract(cls):
        raise _fail(name, f"{cls.__name__} leaves abstract: "
                          f"{', '.join(sorted(cls.__abstractmethods__))}",
                    "implement plan and analyze")
    if not (isinstance(cls.Options, type) and issubclass(cls.Options, MethodOptions)):
        raise _fail(name, f"{cls.__name__}.Options is not a MethodOptions subclass",
                    "derive Options from uqflow.methods.base.MethodOptions (strict validation)")
    cls(**case.options)


def _expect_study_error(check: str, case: _MethodCase, options: dict, key: str) -> None:
    try:
        case.load(options, file="bad_options.toml")
    except StudyError as exc:
        if exc.key != key or "\n" in str(exc):
            raise _fail(check, f"a bad '{key}' gave the error {str(exc)!r} (key {exc.key!r})",
                        f"validate options in Options (a MethodOptions) so that the error "
                        f"is one line naming {key}") from exc
        return
    except Exception as exc:
        raise _fail(check, f"a bad '{key}' raised {type(exc).__name__}: {exc}",
                    "validate options in Options, not in plan") from exc
    raise _fail(check, f"the method accepted the bad option {options}",
                "declare every option in Options (extra keys are refused)")


def check_method_strict_options(case: _MethodCase) -> None:
    """An unknown option, and a string where a number option is, are one-line errors
    naming the key."""
    name = "strict_options"
    _expect_study_error(name, case, {"no_such_option": 1}, "method.no_such_option")
    for field, info in case.method_class.Options.model_fields.items():
        if info.annotation in (int, float):
            _expect_study_error(name, case, {field: "many"}, f"method.{field}")
            break


def check_method_plan_deterministic(case: _MethodCase) -> None:
    """plan() gives the same design for the same SeedSequence, and (``random_plan=True``)
    another for another seed."""
    name = "plan_deterministic"
    first, second = case.plan(case.seed), case.plan(case.seed)
    try:
        xr.testing.assert_identical(first, second)
    except AssertionError as exc:
        differing = [str(v) for v in first.variables if v in second.variables and
                     not first[v].identical(second[v])] or ["the layout"]
        raise _fail(name, f"two plans with the same SeedSequence differ in "
                          f"{', '.join(differing)}",
                    "draw every random number from the seed argument "
                    "(np.random.default_rng(seed)), never from global state or the clock") \
            from exc
    if case.random_plan:
        other = case.plan(case.seed + 1)
        if np.array_equal(first[INPUTS].values, other[INPUTS].values):
            raise _fail(name, "plans with two different seeds give the same inputs",
                        "draw the design from the seed argument")


def check_method_design_layout(case: _MethodCase) -> None:
    """The design has inputs (realization, parameter) with the study's parameter names and
    realizations numbered from 0."""
    name = "design_layout"
    design = case.plan(case.seed)
    if INPUTS not in design.data_vars or design[INPUTS].dims != (REALIZATION, PARAMETER):
        raise _fail(name, f"the design's '{INPUTS}' has dims "
                          f"{design[INPUTS].dims if INPUTS in design else 'none'}",
                    f"build the design with make_design: '{INPUTS}' (realization, parameter)")
    names = [str(p) for p in design[PARAMETER].values]
    if names != case.study.space.names:
        raise _fail(name, f"parameter coordinate {names}, the inputs are "
                          f"{case.study.space.names}", "build the design with make_design")
    n = design.sizes[REALIZATION]
    if n < 1 or not np.array_equal(design[REALIZATION].values, np.arange(n)):
        raise _fail(name, f"realization coordinate {design[REALIZATION].values[:5]}...",
                    "number realizations 0, 1, ..., n-1 (make_design does)")
    if not np.all(np.isfinite(design[INPUTS].values)):
        raise _fail(name, "the design has non-finite inputs", "plan finite parameter values")


def check_method_analyze(case: _MethodCase) -> None:
    """On the tiny model's runs, every output's statistics have the ``statistic`` dim and
    keep the output's dims; the statistics carry the method and cost attributes."""
    name = "analyze"
    stats = case.result["statistics"].to_dataset()
    runs = case.result["runs"].to_dataset()
    for out in case.outputs:
        if out not in stats.data_vars:
            raise _fail(name, f"the statistics have no output '{out}'",
                        "give every output of the runs (output_names(runs)) its statistics")
        dims = stats[out].dims
        if STATISTIC not in dims:
            raise _fail(name, f"the statistics of '{out}' have dims {dims}, no 'statistic'",
                        "put the statistics on a leading 'statistic' dim")
        lost = [d for d in runs[out].dims if d != REALIZATION and d not in dims]
        if lost:
            raise _fail(name, f"analyze dropped the dim(s) {', '.join(map(repr, lost))} of "
                              f"output '{out}' (its statistics have dims {dims})",
                        "keep every dim of an output in its statistics, e.g. reduce over "
                        "'realization' only")
    missing = [a for a in (METHOD, SOLVER_RUNS, FAILED_RUNS, SOLVER_WALL_TIME)
               if a not in stats.attrs]
    if missing:
        raise _fail(name, f"the statistics lack the attributes {', '.join(missing)}",
                    "end analyze with finish_statistics(stats, design, runs, self.name, "
                    "warnings)")


def check_method_handles_failed_runs(case: _MethodCase) -> None:
    """analyze takes runs with a failed realization (NaN outputs, status failed): it gives
    statistics counting the failure, or a one-line StudyError saying it cannot."""
    name = "handles_failed_runs"
    runs = case.runs.copy(deep=True)
    runs[STATUS].values[0] = STATUS_FAILED
    runs[MESSAGE].values[0] = "SolverError: diverged (a failure put in by check_method)"
    for out in case.outputs:
        runs[out].values[0] = np.nan
    design = runs  # the runs hold every variable and attribute of the design
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            stats = case.study.method.analyze(design, runs)
    except UqflowError as exc:
        if "\n" in str(exc):
            raise _fail(name, "the error for a failed run spans lines", "say it in one line") \
                from exc
        return
    except Exception as exc:
        raise _fail(name, f"analyze raised {type(exc).__name__}: {exc} on runs with a failed "
                          f"realization", "use ok_mask(runs) / sample_mask(runs) to leave "
                                          "failed runs out") from exc
    if int(stats.attrs.get(FAILED_RUNS, 0)) < 1:
        raise _fail(name, "the statistics do not count the failed run",
                    "end analyze with finish_statistics (it counts failures)")


def check_method_pickle(case: _MethodCase) -> None:
    """The method round-trips through cloudpickle (dask's serializer) and plans the same; one
    that only cloudpickle can ship gets a warning."""
    name = "pickle"
    method = case.study.method
    expected = case.plan(case.seed)
    for module in (cloudpickle, pickle):
        try:
            copy_ = module.loads(module.dumps(method))
        except Exception as exc:
            if module is pickle:
                warnings.warn(f"pickle: the standard library cannot pickle the method "
                              f"({type(exc).__name__}: {exc}); cloudpickle can",
                              ConformanceWarning, stacklevel=2)
                continue
            raise _fail(name, f"{module.__name__} cannot round-trip the method "
                              f"({type(exc).__name__}: {exc})",
                        "keep no open file, lock or thread in the instance") from exc
        got = copy_.plan(case.study.space, case.study.fields,
                         np.random.SeedSequence(case.seed))
        if not expected.identical(got):
            raise _fail(name, f"the {module.__name__} copy plans another design",
                        "keep the method's state in picklable attributes")


def check_method_report_hook(case: _MethodCase) -> None:
    """report(view) returns None or a MethodReport."""
    name = "report_hook"
    got = case.method_class.report(ResultView(case.result))
    if got is not None and not isinstance(got, MethodReport):
        raise _fail(name, f"report() returned {type(got).__name__}",
                    "return None or a uqflow.report.MethodReport")


METHOD_CHECKS: dict[str, Callable[[_MethodCase], None]] = {
    "options": check_method_options,
    "strict_options": check_method_strict_options,
    "plan_deterministic": check_method_plan_deterministic,
    "design_layout": check_method_design_layout,
    "analyze": check_method_analyze,
    "handles_failed_runs": check_method_handles_failed_runs,
    "pickle": check_method_pickle,
    "report_hook": check_method_report_hook,
}


def method_checks(method_class: type[PropagationMethod], options: Mapping | None = None, *,
                  levels: list | None = None, fields: bool = False, seed: int = 20240501,
                  random_plan: bool | None = None, folder: str | Path | None = None,
                  limit_states: list[dict] | None = None
                  ) -> Iterator[tuple[str, Callable[[], None]]]:
    """The method checks as ``(name, callable)``; arguments as ``check_method``."""
    case = _MethodCase(method_class, options, levels, fields, seed, random_plan, folder,
                       limit_states)
    for name, check in METHOD_CHECKS.items():
        yield name, (lambda check=check: check(case))


def check_method(method_class: type[PropagationMethod], options: Mapping | None = None, *,
                 levels: list | None = None, fields: bool = False, seed: int = 20240501,
                 random_plan: bool | None = None, folder: str | Path | None = None,
                 limit_states: list[dict] | None = None) -> dict[str, str]:
    """Run every method check on a tiny study of ``TinyModel``; raise ``ConformanceError``
    listing the failures.

    ``options``: the ``[method]`` options (keep them small: a few realizations).
    ``levels``: values of the tiny model's ``resolution`` for a method with ``uses_levels``
    (e.g. ``[4, 16]``). ``fields``: add a random field on ``x1`` (a method with
    ``accepts_fields`` that needs one). ``random_plan``: True for a method whose design is
    random (then another seed must give another design), False or None to skip that half.
    ``limit_states``: ``[[limit_states]]`` tables of the tiny study (its outputs are ``y`` [m],
    about 5, and ``profile`` [Pa] over ``s``) for a method that needs one.
    """
    return _run_all(method_checks(method_class, options, levels=levels, fields=fields,
                                  seed=seed, random_plan=random_plan,
                                  limit_states=limit_states), "check_method")


def checks(subject, *args, **kwargs) -> Iterator[tuple[str, Callable[[], None]]]:
    """``method_checks`` for a PropagationMethod subclass, ``solver_checks`` otherwise."""
    if isinstance(subject, type) and issubclass(subject, PropagationMethod):
        return method_checks(subject, *args, **kwargs)
    return solver_checks(subject, *args, **kwargs)


# ====================================================================== a method in memory

def run_in_memory(method: PropagationMethod, space, limit_states, function: Callable,
                  seed: int, *, outputs: xr.Dataset | Mapping[str, str] | None = None
                  ) -> tuple[xr.Dataset, xr.Dataset]:
    """Run ``method`` on ``space`` as ``uqflow.run_study`` runs it, with a vectorized
    function in place of the solver and no result file: ``(runs, statistics)``.

    For repeating a method hundreds of times (its coverage, its spread over seeds) where a
    study through the executor would spend most of its time on checkpoints and
    per-realization bookkeeping. The method is driven through its own contract exactly as
    the executor drives it: ``check(space, None)``, ``check_limit_states``,
    ``plan(space, None, SeedSequence(seed))``, ``enough`` at its ``stop_points`` once a
    prefix has run, ``extend(design, runs)`` on everything so far until it answers None,
    then ``analyze(design, runs)`` (on the prefix it stopped at, if ``enough`` said so).
    The runs have the executor's layout: the design's variables, the outputs,
    ``realization_seed`` spawned from ``seed`` by row (or ``seed_key``), status "ok", an
    empty message, ``wall_time`` and ``compile_time`` 0; an added design joins the runs as
    the executor joins it. A row with a non-finite output is "failed" with the executor's
    message and NaN outputs. So a study with ``[execution] seed = seed`` and a solver giving
    the same numbers row by row has the same design, outputs and statistics bit for bit
    (tests/test_reliability_benchmark_smoke.py checks it).

    ``function(x)`` takes the design's inputs (rows, parameters; physical values, in the
    order of ``space``) and returns the outputs of every row: an array (one output) or a
    dict of arrays. ``limit_states``: the study's ``[[limit_states]]`` tables (a list of
    dicts), a ``uqflow.limit_states.LimitStates``, or None. ``outputs``: the solver's
    outputs template (``solver.outputs()``), or output name -> units; by default the
    outputs the limit-state tables name, each with units "1". No random fields, fidelity
    levels or solver sensitivities (a design that asks for them is refused).
    """
    from uqflow.layout import (COMPILE_TIME, REALIZATION_SEED, SEED_KEY, STATUS_OK,
                               WALL_TIME, WITH_SENSITIVITIES, is_sensitivity_variable)
    from uqflow.limit_states import LimitStates
    from uqflow.realization import empty_runs, realization_prefix

    template = _outputs_template(outputs, limit_states)
    names = list(template.data_vars)
    if limit_states is not None and not isinstance(limit_states, LimitStates):
        limit_states = LimitStates.from_tables(list(limit_states), template)
    if getattr(method, "uses_levels", False):
        raise ValueError(f"run_in_memory runs no fidelity levels (method '{method.name}')")
    method.check(space, None)
    method.check_limit_states(limit_states)

    def evaluated(design: xr.Dataset) -> xr.Dataset:
        if WITH_SENSITIVITIES in design.variables and np.any(design[WITH_SENSITIVITIES]):
            raise ValueError("run_in_memory evaluates no solver sensitivities: the design "
                             f"of '{method.name}' asks for them (gradient = \"solver\"?)")
        runs = empty_runs(design, template)
        keys = runs[SEED_KEY].values if SEED_KEY in runs else runs[REALIZATION].values
        runs[REALIZATION_SEED] = (REALIZATION, np.array(
            [np.random.SeedSequence(seed, spawn_key=(int(i),)).generate_state(1)[0]
             for i in keys], dtype=np.uint32))
        got = function(np.asarray(runs[INPUTS].values, dtype=float))
        if not isinstance(got, Mapping):
            if len(names) != 1:
                raise ValueError(f"function returned one array for {len(names)} outputs "
                                 f"{names}: return a dict of arrays")
            got = {names[0]: got}
        n = runs.sizes[REALIZATION]
        values = {}
        for name in names:
            value = np.asarray(got[name], dtype=float)
            values[name] = value.reshape((n, *template[name].shape))
        finite = np.ones(n, dtype=bool)
        message = np.full(n, "", dtype=object)
        for name in reversed(names):            # the first non-finite output is named
            bad = ~np.all(np.isfinite(values[name].reshape(n, -1)), axis=1)
            message[bad] = f"non-finite output '{name}'"
            finite &= ~bad
        for name in names:
            runs[name].values[finite] = values[name][finite]
        runs[STATUS].values[:] = np.where(finite, STATUS_OK, STATUS_FAILED)
        runs[MESSAGE].values[:] = message
        runs[WALL_TIME].values[:] = 0.0
        runs[COMPILE_TIME].values[:] = 0.0
        return runs

    def design_of(runs: xr.Dataset) -> xr.Dataset:
        written = [*names, *RUN_COLUMNS,
                   *(v for v in runs.data_vars if is_sensitivity_variable(v))]
        return runs.drop_vars(written, errors="ignore")

    def stopped_at(design: xr.Dataset, runs: xr.Dataset, n_planned: int) -> int | None:
        # every row has run: enough at each stop point in turn, as the executor asks once
        # a prefix has finished
        n = runs.sizes[REALIZATION]
        for point in np.asarray(method.stop_points(int(n_planned)), dtype=np.int64):
            if 0 < point <= n and method.enough(realization_prefix(design, int(point)),
                                                realization_prefix(runs, int(point))):
                return int(point)
        return None

    runs = evaluated(method.plan(space, None, np.random.SeedSequence(seed)))
    design, n_planned = design_of(runs), runs.sizes[REALIZATION]
    while (keep := stopped_at(design, runs, n_planned)) is None:
        more = method.extend(design, runs)
        if more is None or more.sizes.get(REALIZATION, 0) == 0:
            break
        n = runs.sizes[REALIZATION]
        new = evaluated(more).assign_coords(
            {REALIZATION: np.arange(n, n + more.sizes[REALIZATION])})
        runs = xr.concat([runs, new], dim=REALIZATION, data_vars="minimal",
                         coords="minimal", compat="override", join="override",
                         combine_attrs="override")
        design, n_planned = design_of(runs), runs.sizes[REALIZATION]
    if keep is not None:
        runs, design = realization_prefix(runs, keep), realization_prefix(design, keep)
    return runs, method.analyze(design, runs)


def _outputs_template(outputs, limit_states) -> xr.Dataset:
    """The solver's outputs template for ``run_in_memory``."""
    if isinstance(outputs, xr.Dataset):
        return outputs
    if outputs is None:
        tables = limit_states if isinstance(limit_states, (list, tuple)) else []
        outputs = {}
        for table in tables:
            if isinstance(table, Mapping) and isinstance(table.get("output"), str):
                outputs.setdefault(table["output"], "1")
        if not outputs:
            raise ValueError("run_in_memory needs outputs (a template or name -> units) "
                             "when no limit-state table names one")
    return xr.Dataset({name: xr.Variable((), np.nan, {UNITS: units})
                       for name, units in outputs.items()})
