"""Running realizations of a design on one solver: the unit of work a dask task does.

Kept free of dask so the same code runs in-process (``workers = 0``), on a local cluster
and on a remote one, and so a method's tests can evaluate a design directly.

Sensitivity runs: a design's boolean variable ``with_sensitivities`` (``SENSITIVITY_FLAG``,
dim ``realization``) marks the realizations run with ``solver.run_with_sensitivities`` (local
derivatives with respect to the design's parameters, see ``uqflow.solver``). Their derivatives
live on a dim of their own, ``sensitivity_run`` (the flagged realizations in realization
order, coordinate ``sensitivity_realization``): ``o__gradient`` (sensitivity_run, *dims,
parameter) and ``o__hessian`` (sensitivity_run, *dims, parameter, parameter_j) for every
output ``o``, NaN until that realization has run ok. Lacking the ``realization`` dim, they are
never taken for outputs.
"""

from __future__ import annotations

import importlib.util
import inspect
import threading
import time
import traceback
from contextlib import contextmanager

import numpy as np
import xarray as xr

from uqflow.errors import SolverError, SolverUnavailable
from uqflow.fields import FieldSample, field_value_variable, germ_variable
from uqflow.layout import (CLIPPED_POINTS, COMPILE_TIME, GERM_PREFIX, INPUTS, LONG_NAME,
                           MESSAGE, NO_VALUE_REASON, PARAMETER, PARAMETER_J, REALIZATION,
                           REALIZATION_SEED, SENSITIVITY_COORD, SENSITIVITY_DIM, STATUS,
                           STATUS_FAILED, STATUS_OK, STATUS_PENDING, UNITS, WALL_TIME,
                           WITH_SENSITIVITIES, gradient_variable, hessian_variable, is_diagnostic,
                           is_sensitivity_variable)

#: the design's flag of sensitivity runs, by the name methods and benchmarks know it
#: (docs/taylor_local.md); ``uqflow.layout.WITH_SENSITIVITIES`` is its home
SENSITIVITY_FLAG = WITH_SENSITIVITIES


def sensitivity_flags(design: xr.Dataset) -> np.ndarray:
    """Which realizations of ``design`` run with sensitivities (all False without the flag)."""
    if WITH_SENSITIVITIES not in design.variables:
        return np.zeros(design.sizes[REALIZATION], dtype=bool)
    return np.asarray(design[WITH_SENSITIVITIES].values).astype(bool)


def sensitivity_arrays(runs: xr.Dataset, output: str):
    """(realization indices, gradient, hessian) of ``output``'s sensitivity runs, arrays of
    shapes (m,), (m, *dims, n) and (m, *dims, n, n); NaN where a realization did not run ok."""
    if SENSITIVITY_COORD not in runs.coords:
        raise KeyError(f"the runs hold no sensitivity runs (no '{WITH_SENSITIVITIES}' in the "
                       f"design)")
    return (np.asarray(runs[SENSITIVITY_COORD].values, dtype=np.int64),
            np.asarray(runs[gradient_variable(output)].values, dtype=float),
            np.asarray(runs[hessian_variable(output)].values, dtype=float))


def realization_prefix(runs: xr.Dataset, n: int) -> xr.Dataset:
    """The first ``n`` realizations of ``runs`` (or of a design), with their sensitivity
    runs only."""
    prefix = runs.isel({REALIZATION: slice(0, n)})
    if SENSITIVITY_COORD in runs.coords:
        keep = np.flatnonzero(runs[SENSITIVITY_COORD].values < n)
        prefix = prefix.isel({SENSITIVITY_DIM: keep})
    return prefix


def _per_parameter(units: str, power: int) -> str:
    per = "parameter unit" if power == 1 else "parameter unit^2"
    return f"{units or 1} per {per}"


def _add_sensitivity_variables(runs: xr.Dataset, template: xr.Dataset) -> xr.Dataset:
    if WITH_SENSITIVITIES not in runs.variables:
        return runs
    flagged = np.flatnonzero(sensitivity_flags(runs))
    parameters = [str(p) for p in runs[PARAMETER].values]
    n, m = len(parameters), flagged.size
    runs = runs.assign_coords({SENSITIVITY_COORD: (SENSITIVITY_DIM, flagged.astype(np.int64), {
        LONG_NAME: "realization run with local sensitivities"})})
    if PARAMETER_J not in runs.coords:
        runs = runs.assign_coords({PARAMETER_J: (PARAMETER_J, parameters)})
    for name, var in template.data_vars.items():
        if is_diagnostic(var):  # a timing or a counter has no derivative
            continue
        units = var.attrs.get(UNITS, "")
        runs[gradient_variable(name)] = xr.Variable(
            (SENSITIVITY_DIM, *var.dims, PARAMETER), np.full((m, *var.shape, n), np.nan),
            {LONG_NAME: f"local derivative d{name}/dx_k at the realization's parameters "
                          f"(frozen state)", UNITS: _per_parameter(units, 1)})
        runs[hessian_variable(name)] = xr.Variable(
            (SENSITIVITY_DIM, *var.dims, PARAMETER, PARAMETER_J),
            np.full((m, *var.shape, n, n), np.nan),
            {LONG_NAME: f"local second derivative d2{name}/dx_k dx_j at the realization's "
                          f"parameters (frozen state)", UNITS: _per_parameter(units, 2)})
    return runs


def empty_runs(design: xr.Dataset, template: xr.Dataset) -> xr.Dataset:
    """The runs dataset before anything ran: NaN outputs, every realization pending."""
    n = design.sizes[REALIZATION]
    runs = design.copy()
    for name, var in template.data_vars.items():
        runs[name] = xr.Variable((REALIZATION, *var.dims),
                                 np.full((n, *var.shape), np.nan), dict(var.attrs))
    runs = runs.assign_coords({c: template.coords[c] for c in template.coords})
    runs[STATUS] = (REALIZATION, np.full(n, STATUS_PENDING, dtype=object))
    runs[MESSAGE] = (REALIZATION, np.full(n, "", dtype=object))
    runs[WALL_TIME] = (REALIZATION, np.full(n, np.nan), {UNITS: "s"})
    runs[COMPILE_TIME] = (REALIZATION, np.full(n, np.nan), {
        UNITS: "s", LONG_NAME: "part of wall_time numba spent compiling (0 when every "
                                   "kernel was compiled or loaded from the cache before)"})
    if any(str(v).startswith(GERM_PREFIX) for v in design.data_vars):
        runs[CLIPPED_POINTS] = (REALIZATION, np.zeros(n, dtype=np.int64), {
            LONG_NAME: "field values clipped into the parameter's physical range"})
    return _add_sensitivity_variables(runs, template)


def add_field_value_variables(runs: xr.Dataset, fields: list | None, solver) -> xr.Dataset:
    """NaN-filled variables for the fields whose ``store_values`` is set, sized from the
    solver's nominal points (a realization with more points keeps the first ones)."""
    for field in fields or []:
        if not field.spec.store_values:
            continue
        for parameter in field.targets:
            name = field_value_variable(parameter)
            n = len(np.asarray(solver.field_points(parameter)))
            runs[name] = ((REALIZATION, f"{name}_point"),
                          np.full((runs.sizes[REALIZATION], n), np.nan),
                          {LONG_NAME: f"random-field values of {parameter}"})
    return runs


def takes_seed(solver, method: str = "run") -> bool:
    try:
        return "seed" in inspect.signature(getattr(solver, method)).parameters
    except (TypeError, ValueError, AttributeError):
        return False


def _derivatives(result: xr.Dataset, output: str, wrt: list[str], dims: tuple) -> dict:
    """``output``'s gradient and Hessian from a solver's dataset, as arrays with the
    parameter dims last, in ``wrt`` order (whatever order the solver used)."""
    got = {}
    for name, extra in ((gradient_variable(output), (PARAMETER,)),
                        (hessian_variable(output), (PARAMETER, PARAMETER_J))):
        if name not in result.variables:
            raise SolverError(f"run_with_sensitivities returned no '{name}'")
        var = result[name]
        if set(var.dims) != {*dims, *extra}:
            raise SolverError(f"'{name}' has dims {var.dims}, not {(*dims, *extra)}")
        for d in extra:
            if d in var.coords and [str(c) for c in var[d].values] != list(wrt):
                var = var.sel({d: list(wrt)})
        got[name] = np.asarray(var.transpose(*dims, *extra).values, dtype=float)
    return got


def run_one(solver, params: dict, fields, outputs: list[str], seed: int | None = None,
            wrt: list[str] | None = None, derived: list[str] | None = None):
    """One realization: (status, message, {output: array}, wall time).

    With ``wrt`` (parameter names) the realization runs ``solver.run_with_sensitivities``
    and the dict also holds the gradient and Hessian with respect to ``wrt``
    (``gradient_variable(o)``, ``hessian_variable(o)``) of each output in ``derived``
    (default: every output; a solver's diagnostics, a timing or a counter, have none).

    A ``SolverError`` or any other exception, and any non-finite output or derivative, make
    the realization failed with a one-line message; nothing propagates. ``seed`` goes to
    the solver when given: callers give it only to solvers that take one (``takes_seed``).
    """
    start = time.perf_counter()
    try:
        kwargs = {"seed": seed} if seed is not None else {}
        if wrt is not None:
            if fields:
                raise SolverError("a realization with sensitivities takes no random fields "
                                  "(run_with_sensitivities has no fields argument)")
            derived = list(outputs) if derived is None else list(derived)
            result = solver.run_with_sensitivities(params, wrt=list(wrt), outputs=derived,
                                                   **kwargs)
        elif fields:
            result = solver.run(params, fields, **kwargs)
        else:
            result = solver.run(params, **kwargs)
        values = {name: np.asarray(result[name].values, dtype=float) for name in outputs}
        if wrt is not None:
            for name in derived:
                values.update(_derivatives(result, name, wrt, result[name].dims))
        bad = [name for name, v in values.items() if not np.all(np.isfinite(v))]
        if bad:
            what = "derivative" if is_sensitivity_variable(bad[0]) else "output"
            status, message = STATUS_FAILED, f"non-finite {what} '{bad[0]}'"
            # the solver may say why (a bar broken before its loops): keep it in the message
            if result.attrs.get(NO_VALUE_REASON):
                message += f": {result.attrs[NO_VALUE_REASON]}"
        else:
            status, message = STATUS_OK, ""
    except SolverUnavailable:
        raise                      # not this realization's failure: the caller stops
    except SolverError as exc:
        values, status, message = {}, STATUS_FAILED, f"SolverError: {exc}"
    except Exception as exc:  # a solver bug must not end the study; keep where it happened
        where = traceback.extract_tb(exc.__traceback__)[-1]
        values, status = {}, STATUS_FAILED
        message = (f"{type(exc).__name__}: {exc} "
                   f"(at {where.filename.rsplit('/', 1)[-1]}:{where.lineno})")
    return status, " ".join(message.split()), values, time.perf_counter() - start


class _CompileTime:
    """Seconds numba spent compiling on the installing thread: the outermost START..END
    intervals of its "numba:compile" events (a kernel calling another nests them; a dask
    worker's other threads compile for their own runs)."""

    def __init__(self):
        self.seconds = 0.0
        self._thread = threading.get_ident()
        self._depth = 0
        self._started = 0.0

    def on_start(self, event):
        if threading.get_ident() != self._thread:
            return
        if self._depth == 0:
            self._started = time.perf_counter()
        self._depth += 1

    def on_end(self, event):
        if threading.get_ident() != self._thread or self._depth == 0:
            return
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._started


_NUMBA_LISTENER = []  # [(numba.core.event, listener class) or None], looked up once


def _numba_listener():
    if not _NUMBA_LISTENER:
        found = None
        if importlib.util.find_spec("numba") is not None:
            from numba.core import event
            found = (event, type("CompileListener", (_CompileTime, event.Listener), {}))
        _NUMBA_LISTENER.append(found)
    return _NUMBA_LISTENER[0]


@contextmanager
def compile_clock():
    """Measure numba's compile time inside the block: yields an object whose ``seconds`` holds
    it at the end (always 0 without numba). A solver's first run in a process compiles its
    kernels; counted in its wall time alone, that would make one run look like many."""
    numba = _numba_listener()
    if numba is None:
        yield _CompileTime()
        return
    event, listener_class = numba
    listener = listener_class()
    with event.install_listener("numba:compile", listener):
        yield listener


#: the key of ``run_batch``'s result saying why the solver could not run the next row (a
#: ``SolverUnavailable``'s message; None when every row ran or the budget stopped the batch)
UNAVAILABLE = "unavailable"


def run_batch(solver, names: list[str], values: np.ndarray, outputs: list[str],
              fields: list | None = None, germs: dict | None = None,
              seeds: np.ndarray | None = None, budget: float | None = None,
              sensitivities: np.ndarray | None = None) -> dict:
    """Run realizations given as rows of ``values``; returns plain arrays (cheap to ship).

    ``fields`` are the study's RandomFields and ``germs`` their germs for these rows
    (``germ_variable(name)`` -> (rows, modes)); ``seeds`` the per-realization seeds, passed
    to solvers whose ``run`` takes ``seed`` (e.g. for a random grid); ``sensitivities`` the
    rows' ``with_sensitivities`` flags (those rows also return their derivatives with
    respect to ``names``, under "sensitivities"). With ``budget`` (seconds) the batch
    returns after the first realization that ends past it, so finished realizations reach
    the caller (and its checkpoint) in bounded time: the result then covers the first
    ``len(result[STATUS])`` rows, at least one — or none, if the solver could not run the
    first (``SolverUnavailable``: its message is ``result[UNAVAILABLE]``).
    """
    start = time.perf_counter()
    # once per batch: inspect is slow next to a run
    seeded = {False: takes_seed(solver), True: takes_seed(solver, "run_with_sensitivities")}
    statuses, messages, times, compiling, clipped, evaluated = [], [], [], [], [], []
    unavailable = None
    results = {name: [] for name in outputs}
    derivatives = []
    derived = None
    if sensitivities is not None and np.any(sensitivities) and hasattr(solver, "outputs"):
        template = solver.outputs()
        derived = [o for o in outputs if o not in template or not is_diagnostic(template[o])]
    for i, row in enumerate(values):
        params = dict(zip(names, (float(v) for v in row)))
        sample = None
        if fields:
            sample = FieldSample(fields, {f.name: germs[germ_variable(f.name)][i]
                                          for f in fields})
        flagged = sensitivities is not None and bool(sensitivities[i])
        seed = int(seeds[i]) if seeds is not None and seeded[flagged] else None
        try:
            with compile_clock() as compiled:
                status, message, got, wall = run_one(solver, params, sample, outputs, seed,
                                                     wrt=list(names) if flagged else None,
                                                     derived=derived)
        except SolverUnavailable as exc:
            # the rows before it are returned; this one stays pending
            unavailable = " ".join(str(exc).split())
            break
        compiling.append(min(compiled.seconds, wall))
        clipped.append(sum(sample.clipped.values()) if sample is not None else 0)
        evaluated.append(sample.evaluated if sample is not None else {})
        statuses.append(status)
        messages.append(message)
        times.append(wall)
        for name in outputs:
            results[name].append(got.get(name))
        derivatives.append({k: v for k, v in got.items() if is_sensitivity_variable(k)}
                           if flagged else None)
        if budget is not None and time.perf_counter() - start >= budget:
            break
    return {STATUS: statuses, MESSAGE: messages, WALL_TIME: times,
            COMPILE_TIME: compiling, "outputs": results,
            CLIPPED_POINTS: clipped, "field_values": evaluated,
            "sensitivities": derivatives, UNAVAILABLE: unavailable}


def batch_arguments(runs: xr.Dataset, indices: np.ndarray, fields: list | None) -> dict:
    """The per-row inputs of ``run_batch`` for realizations ``indices`` of ``runs``."""
    args = {"values": runs[INPUTS].values[indices]}
    if fields:
        args["fields"] = fields
        args["germs"] = {germ_variable(f.name): runs[germ_variable(f.name)].values[indices]
                         for f in fields}
    if REALIZATION_SEED in runs:
        args["seeds"] = runs[REALIZATION_SEED].values[indices]
    if WITH_SENSITIVITIES in runs.variables:
        args["sensitivities"] = sensitivity_flags(runs)[indices]
    return args


def store_batch(runs: xr.Dataset, indices: np.ndarray, batch: dict) -> None:
    """Write a finished batch into ``runs`` in place (``indices`` may be longer than the
    batch's results when it stopped at its time budget: only the first ones are written)."""
    indices = indices[:len(batch[STATUS])]
    position = {}
    if SENSITIVITY_COORD in runs.coords:
        position = {int(r): j for j, r in enumerate(runs[SENSITIVITY_COORD].values)}
    for k, idx in enumerate(indices):
        runs[STATUS].values[idx] = batch[STATUS][k]
        runs[MESSAGE].values[idx] = batch[MESSAGE][k]
        runs[WALL_TIME].values[idx] = batch[WALL_TIME][k]
        if COMPILE_TIME in runs and COMPILE_TIME in batch:
            runs[COMPILE_TIME].values[idx] = batch[COMPILE_TIME][k]
        if CLIPPED_POINTS in runs:
            runs[CLIPPED_POINTS].values[idx] = batch[CLIPPED_POINTS][k]
        for parameter, values in batch.get("field_values", [{}] * len(indices))[k].items():
            stored = runs[field_value_variable(parameter)].values[idx]
            n = min(stored.size, values.size)  # random grids may move the point count
            stored[:] = np.nan
            stored[:n] = values[:n]
        ok = batch[STATUS][k] == STATUS_OK
        for name, vals in batch["outputs"].items():
            if vals[k] is not None and ok:
                runs[name].values[idx] = vals[k]
        derivatives = batch.get("sensitivities", [None] * len(indices))[k]
        if derivatives and ok and int(idx) in position:
            for name, value in derivatives.items():
                if name in runs.variables:
                    runs[name].values[position[int(idx)]] = value


def evaluate_design(solver, design: xr.Dataset, outputs: list[str] | None = None,
                    fields: list | None = None) -> xr.Dataset:
    """Run every realization of ``design`` in this process and return the runs dataset."""
    template = solver.outputs()
    outputs = list(template.data_vars) if outputs is None else list(outputs)
    runs = add_field_value_variables(empty_runs(design, template[outputs]), fields, solver)
    names = [str(p) for p in design[PARAMETER].values]
    every = np.arange(design.sizes[REALIZATION])
    batch = run_batch(solver, names, outputs=outputs, **batch_arguments(runs, every, fields))
    store_batch(runs, every, batch)
    return runs
