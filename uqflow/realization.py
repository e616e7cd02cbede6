"""Running realizations of a design on one solver: the unit of work a dask task does.

Kept free of dask so the same code runs in-process (``workers = 0``), on a local cluster
and on a remote one, and so a method's tests can evaluate a design directly.
"""

from __future__ import annotations

import inspect
import time
import traceback

import numpy as np
import xarray as xr

from uqflow.errors import SolverError
from uqflow.fields import FieldSample, field_value_variable, germ_variable

STATUS_OK, STATUS_FAILED, STATUS_PENDING = "ok", "failed", "pending"


def empty_runs(design: xr.Dataset, template: xr.Dataset) -> xr.Dataset:
    """The runs dataset before anything ran: NaN outputs, every realization pending."""
    n = design.sizes["realization"]
    runs = design.copy()
    for name, var in template.data_vars.items():
        runs[name] = xr.Variable(("realization", *var.dims),
                                 np.full((n, *var.shape), np.nan), dict(var.attrs))
    runs = runs.assign_coords({c: template.coords[c] for c in template.coords})
    runs["status"] = ("realization", np.full(n, STATUS_PENDING, dtype=object))
    runs["message"] = ("realization", np.full(n, "", dtype=object))
    runs["wall_time"] = ("realization", np.full(n, np.nan), {"units": "s"})
    if any(str(v).startswith("germ_") for v in design.data_vars):
        runs["clipped_points"] = ("realization", np.zeros(n, dtype=np.int64), {
            "long_name": "field values clipped into the parameter's physical range"})
    return runs


def add_field_value_variables(runs: xr.Dataset, fields: list | None, solver) -> xr.Dataset:
    """NaN-filled variables for the fields whose ``store_values`` is set, sized from the
    solver's nominal points (a realization with more points keeps the first ones)."""
    for field in fields or []:
        if not field.spec.store_values:
            continue
        for parameter in field.targets:
            name = field_value_variable(parameter)
            n = len(np.asarray(solver.field_points(parameter)))
            runs[name] = (("realization", f"{name}_point"),
                          np.full((runs.sizes["realization"], n), np.nan),
                          {"long_name": f"random-field values of {parameter}"})
    return runs


def takes_seed(solver) -> bool:
    try:
        return "seed" in inspect.signature(solver.run).parameters
    except (TypeError, ValueError):
        return False


def run_one(solver, params: dict, fields, outputs: list[str], seed: int | None = None):
    """One realization: (status, message, {output: array}, wall time).

    A ``SolverError`` or any other exception, and any non-finite output, make the
    realization failed with a one-line message; nothing propagates. ``seed`` goes to
    ``solver.run`` when given: callers give it only to solvers that take one (``takes_seed``).
    """
    start = time.perf_counter()
    try:
        kwargs = {"seed": seed} if seed is not None else {}
        result = solver.run(params, fields, **kwargs) if fields else solver.run(params, **kwargs)
        values = {name: np.asarray(result[name].values, dtype=float) for name in outputs}
        bad = [name for name, v in values.items() if not np.all(np.isfinite(v))]
        if bad:
            status, message = STATUS_FAILED, f"non-finite output '{bad[0]}'"
        else:
            status, message = STATUS_OK, ""
    except SolverError as exc:
        values, status, message = {}, STATUS_FAILED, f"SolverError: {exc}"
    except Exception as exc:  # a solver bug must not end the study; keep where it happened
        where = traceback.extract_tb(exc.__traceback__)[-1]
        values, status = {}, STATUS_FAILED
        message = (f"{type(exc).__name__}: {exc} "
                   f"(at {where.filename.rsplit('/', 1)[-1]}:{where.lineno})")
    return status, " ".join(message.split()), values, time.perf_counter() - start


def run_batch(solver, names: list[str], values: np.ndarray, outputs: list[str],
              fields: list | None = None, germs: dict | None = None,
              seeds: np.ndarray | None = None, budget: float | None = None) -> dict:
    """Run realizations given as rows of ``values``; returns plain arrays (cheap to ship).

    ``fields`` are the study's RandomFields and ``germs`` their germs for these rows
    (``germ_variable(name)`` -> (rows, modes)); ``seeds`` the per-realization seeds, passed
    to solvers whose ``run`` takes ``seed`` (e.g. for a random grid). With ``budget``
    (seconds) the batch returns after the first realization that ends past it, so finished
    realizations reach the caller (and its checkpoint) in bounded time: the result then
    covers the first ``len(result["status"])`` rows, at least one.
    """
    start = time.perf_counter()
    seeded = takes_seed(solver)          # once per batch: inspect is slow next to a run
    statuses, messages, times, clipped, evaluated = [], [], [], [], []
    results = {name: [] for name in outputs}
    for i, row in enumerate(values):
        params = dict(zip(names, (float(v) for v in row)))
        sample = None
        if fields:
            sample = FieldSample(fields, {f.name: germs[germ_variable(f.name)][i]
                                          for f in fields})
        seed = int(seeds[i]) if seeds is not None and seeded else None
        status, message, got, wall = run_one(solver, params, sample, outputs, seed)
        clipped.append(sum(sample.clipped.values()) if sample is not None else 0)
        evaluated.append(sample.evaluated if sample is not None else {})
        statuses.append(status)
        messages.append(message)
        times.append(wall)
        for name in outputs:
            results[name].append(got.get(name))
        if budget is not None and time.perf_counter() - start >= budget:
            break
    return {"status": statuses, "message": messages, "wall_time": times, "outputs": results,
            "clipped_points": clipped, "field_values": evaluated}


def batch_arguments(runs: xr.Dataset, indices: np.ndarray, fields: list | None) -> dict:
    """The per-row inputs of ``run_batch`` for realizations ``indices`` of ``runs``."""
    args = {"values": runs["inputs"].values[indices]}
    if fields:
        args["fields"] = fields
        args["germs"] = {germ_variable(f.name): runs[germ_variable(f.name)].values[indices]
                         for f in fields}
    if "realization_seed" in runs:
        args["seeds"] = runs["realization_seed"].values[indices]
    return args


def store_batch(runs: xr.Dataset, indices: np.ndarray, batch: dict) -> None:
    """Write a finished batch into ``runs`` in place (``indices`` may be longer than the
    batch's results when it stopped at its time budget: only the first ones are written)."""
    indices = indices[:len(batch["status"])]
    for k, idx in enumerate(indices):
        runs["status"].values[idx] = batch["status"][k]
        runs["message"].values[idx] = batch["message"][k]
        runs["wall_time"].values[idx] = batch["wall_time"][k]
        if "clipped_points" in runs:
            runs["clipped_points"].values[idx] = batch["clipped_points"][k]
        for parameter, values in batch.get("field_values", [{}] * len(indices))[k].items():
            stored = runs[field_value_variable(parameter)].values[idx]
            n = min(stored.size, values.size)  # random grids may move the point count
            stored[:] = np.nan
            stored[:n] = values[:n]
        for name, vals in batch["outputs"].items():
            if vals[k] is not None and batch["status"][k] == STATUS_OK:
                runs[name].values[idx] = vals[k]


def evaluate_design(solver, design: xr.Dataset, outputs: list[str] | None = None,
                    fields: list | None = None) -> xr.Dataset:
    """Run every realization of ``design`` in this process and return the runs dataset."""
    template = solver.outputs()
    outputs = list(template.data_vars) if outputs is None else list(outputs)
    runs = add_field_value_variables(empty_runs(design, template[outputs]), fields, solver)
    names = [str(p) for p in design["parameter"].values]
    every = np.arange(design.sizes["realization"])
    batch = run_batch(solver, names, outputs=outputs, **batch_arguments(runs, every, fields))
    store_batch(runs, every, batch)
    return runs
