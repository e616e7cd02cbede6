"""Run a study: plan, execute realizations on dask in batches, checkpoint, analyze, store.

One solver instance per worker process is built from the scene on first use and cached.
Realization values come from the method's design, fixed before anything runs, so results do
not depend on the number of workers or on the order in which batches finish.
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from uqflow import progress as progress_mod
from uqflow.errors import StudyError, UqflowError
from uqflow.realization import (STATUS_FAILED, STATUS_PENDING, add_field_value_variables,
                                batch_arguments, empty_runs, run_batch, store_batch)
from uqflow.store import now, read_runs, versions, write_result
from uqflow.study import Study

_RUN_COLUMNS = {"status", "message", "wall_time", "clipped_points"}


class StudyFailed(UqflowError):
    """The study stopped because too many realizations failed (the runs are on disk)."""


@dataclass
class Outcome:
    path: Path
    runs: xr.Dataset
    statistics: xr.Dataset | None
    attrs: dict
    resumed: int = 0
    warnings: list[str] = field(default_factory=list)


# --- on the workers -------------------------------------------------------------------------

_SOLVERS: dict = {}


def _worker_solver(solver_class, scene: dict):
    key = (f"{solver_class.__module__}.{solver_class.__qualname__}",
           json.dumps(scene, sort_keys=True, default=str))
    if key not in _SOLVERS:
        _SOLVERS[key] = solver_class.from_scene(scene)
    return _SOLVERS[key]


def _work(solver_class, scene, names, outputs, arguments):
    return run_batch(_worker_solver(solver_class, scene), names, outputs=outputs, **arguments)


# --- on the client --------------------------------------------------------------------------

def _batch_size(study: Study, n_pending: int, workers: int) -> int:
    if study.spec.execution.batch:
        return study.spec.execution.batch
    # Enough batches to keep every worker busy and the progress bar moving, few enough that
    # dask's per-task cost (~1 ms) is amortised over many realizations.
    return int(np.clip(n_pending // (8 * max(workers, 1)), 1, 128))


def _root_attrs(study: Study) -> dict:
    spec = study.spec
    return {
        "title": f"uqflow study '{study.name}'",
        "study_name": study.name,
        "study_file": str(study.path),
        "study": study.text,
        "study_sha256": study.sha256,
        "solver": spec.solver,
        "solver_description": study.solver.describe(),
        "method": spec.method.kind,
        "method_options": json.dumps(study.method.options.model_dump(), default=str),
        "seed": spec.execution.seed,
        "created": now(),
        "complete": 0,
        "Conventions": "CF-1.10",
        **versions(),
    }


class _Checkpoint:
    def __init__(self, path: Path, attrs: dict, interval: float):
        self.path, self.attrs, self.interval = path, attrs, interval
        self.last = time.monotonic()

    def maybe(self, runs: xr.Dataset, force: bool = False) -> None:
        if force or time.monotonic() - self.last >= self.interval:
            write_result(self.path, runs, None, self.attrs)
            self.last = time.monotonic()


def _prepare(study: Study, resume: bool, force: bool):
    """The runs to complete: fresh from the plan, or read back from a partial result."""
    path = study.output_path
    if path.exists() and not (resume or force):
        raise StudyError(f"{path} exists: add --resume to finish it or --force to overwrite it",
                         file=str(study.path), key="output.path")
    if resume and path.exists():
        runs, attrs = read_runs(path)
        if attrs.get("study_sha256") != study.sha256:
            raise StudyError(f"{path} was made by a different version of this study; "
                             f"use --force to start again", file=str(study.path),
                             key="output.path")
        attrs["resumed"] = now()
        return runs, attrs
    seed = np.random.SeedSequence(study.spec.execution.seed)
    design = study.method.plan(study.space, study.fields or None, seed)
    runs = add_field_value_variables(empty_runs(design, study.solver.outputs()[study.outputs]),
                                     study.fields, study.solver)
    # A seed per realization, spawned by index: reproducible without the rest of the design.
    runs["realization_seed"] = ("realization", np.array(
        [np.random.SeedSequence(study.spec.execution.seed, spawn_key=(int(i),))
         .generate_state(1)[0] for i in runs["realization"].values], dtype=np.uint32))
    return runs, _root_attrs(study)


def run_study(study: Study, *, workers: int | None = None, scheduler: str | None = None,
              resume: bool = False, force: bool = False, show_progress: bool = True) -> Outcome:
    """Run (or finish, with ``resume``) ``study`` and write its result file."""
    started = time.perf_counter()
    ex = study.spec.execution
    workers = ex.workers if workers is None else workers
    scheduler = scheduler if scheduler is not None else ex.scheduler
    runs, attrs = _prepare(study, resume, force)
    pending = np.flatnonzero(runs["status"].values == STATUS_PENDING)
    resumed = int(runs.sizes["realization"] - pending.size)
    checkpoint = _Checkpoint(study.output_path, attrs, ex.checkpoint_interval)
    checkpoint.maybe(runs, force=True)

    design = runs.drop_vars([*study.outputs, *_RUN_COLUMNS], errors="ignore")
    names = [str(p) for p in runs["parameter"].values]
    n_total = runs.sizes["realization"]
    size = _batch_size(study, pending.size, workers if scheduler is None else 2)
    batches = [pending[i:i + size] for i in range(0, pending.size, size)]
    bar = progress_mod.Progress(n_total, resumed, enabled=show_progress)
    stopper = _Stopper(study, design, runs, batches)

    def record(k, result):
        store_batch(runs, batches[k], result)
        bar.update(len(batches[k]), result["status"].count(STATUS_FAILED))
        checkpoint.maybe(runs)
        failed = int((runs["status"].values == STATUS_FAILED).sum())
        if failed > ex.max_failure_fraction * n_total:
            return _failure_stop(runs, failed, n_total, ex.max_failure_fraction)
        return stopper.after(k)

    stop_reason = None
    if workers == 0 and scheduler is None:
        for k, idx in enumerate(batches):
            stop_reason = record(k, run_batch(study.solver, names, outputs=study.outputs,
                                              **batch_arguments(runs, idx, study.fields)))
            if stop_reason:
                break
    else:
        stop_reason = _run_on_dask(study, workers, scheduler, names, runs, batches, record)
    bar.close()

    if stop_reason and stop_reason.startswith("failed:"):
        checkpoint.maybe(runs, force=True)
        raise StudyFailed(f"{study.path}: stopped: {stop_reason[7:]}; the runs so far are in "
                          f"{study.output_path}")
    if stopper.keep is not None:
        runs = runs.isel(realization=slice(0, stopper.keep))
        design = design.isel(realization=slice(0, stopper.keep))
        attrs["stopped_early"] = f"target reached after {stopper.keep} realizations"
    statistics = study.method.analyze(design, runs)
    attrs.update(complete=1, finished=now(),
                 elapsed_time=float(attrs.get("elapsed_time", 0.0))
                 + time.perf_counter() - started,
                 solver_runs=statistics.attrs.get("solver_runs", 0),
                 failed_runs=statistics.attrs.get("failed_runs", 0),
                 workers=workers if scheduler is None else f"scheduler {scheduler}")
    write_result(study.output_path, runs, statistics, attrs)
    warnings = [w for w in statistics.attrs.get("warnings", "").split("\n") if w]
    return Outcome(study.output_path, runs, statistics, attrs, resumed, warnings)


def _failure_stop(runs, failed, n_total, fraction):
    status = runs["status"].values
    first = int(np.flatnonzero(status == STATUS_FAILED)[0])
    return (f"failed:{failed} of {n_total} realizations failed (more than "
            f"max_failure_fraction {fraction:g}); first, realization {first}: "
            f"{runs['message'].values[first]}")


class _Stopper:
    """Asks the method whether it has enough, on prefixes of whole batches in order only, so
    the stopping point is the same whatever order the batches finish in."""

    def __init__(self, study, design, runs, batches):
        self.study, self.design, self.runs, self.batches = study, design, runs, batches
        self.done = np.zeros(len(batches), bool)
        self.checked = 0
        self.keep = None
        self.active = type(study.method).enough is not _base_enough()

    def after(self, k):
        self.done[k] = True
        if not self.active:
            return None
        while self.checked < len(self.batches) and self.done[self.checked]:
            end = int(self.batches[self.checked][-1]) + 1
            self.checked += 1
            if np.any(self.runs["status"].values[:end] == STATUS_PENDING):
                continue  # resumed file with holes before this point; decide later
            if self.study.method.enough(self.design.isel(realization=slice(0, end)),
                                        self.runs.isel(realization=slice(0, end))):
                self.keep = end
                return "enough"
        return None


def _base_enough():
    from uqflow.methods.base import PropagationMethod
    return PropagationMethod.enough


def _run_on_dask(study, workers, scheduler, names, runs, batches, record):
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        threads = str(max(1, (os.cpu_count() or 1) // max(workers, 1)))
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR,
                               env={"NUMBA_NUM_THREADS": threads, "OMP_NUM_THREADS": threads,
                                    "OPENBLAS_NUM_THREADS": threads, "MKL_NUM_THREADS": threads})
    try:
        client = Client(cluster if cluster is not None else scheduler, timeout="30s")
    except OSError as exc:
        if cluster is not None:
            cluster.close()
        raise StudyError(f"cannot reach dask scheduler {scheduler}: {exc}",
                         key="execution.scheduler") from None
    stop_reason = None
    try:
        # Fields (their KL bases) travel to each worker once, not with every batch.
        fields = client.scatter(study.fields, broadcast=True) if study.fields else None
        futures = {}
        for k, idx in enumerate(batches):
            arguments = batch_arguments(runs, idx, study.fields)
            if fields is not None:
                arguments["fields"] = fields
            futures[client.submit(_work, study.solver_class, study.scene, names, study.outputs,
                                  arguments, pure=False)] = k
        for future in as_completed(futures):
            stop_reason = record(futures[future], future.result())
            if stop_reason:
                client.cancel(list(futures))
                break
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return stop_reason
