"""Run a study: plan, execute realizations (in this process or on dask), checkpoint, analyze,
store.

Realization values and seeds come from the method's design, fixed before anything runs, and a
method may stop early only at realization counts fixed by the design (``stop_points``), so the
result does not depend on the number of workers, the batch size, the order in which tasks
finish or a resume. One solver instance per worker process is built from the scene on first
use and cached. Finished realizations reach the result file within ``checkpoint_interval``
seconds plus the run time of one realization, whatever the batch size: a task runs its
realizations until a time budget is spent and hands back what it finished; the rest goes back
to the queue.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from uqflow import progress as progress_mod
from uqflow.errors import ResultFileError, StudyError, UqflowError
from uqflow.layout import (COMPLETE, CONVENTIONS, CREATED, ELAPSED_TIME, FAILED_RUNS,
                           FIELD_PREFIX, FINISHED, MESSAGE, METHOD, METHOD_OPTIONS, PARAMETER,
                           PLANNED_REALIZATIONS, REALIZATION, REALIZATION_SEED, RESUMED,
                           RUN_COLUMNS, SEED, SEED_KEY, SENSITIVITY_COORD, SENSITIVITY_DIM,
                           SOLVER, SOLVER_DESCRIPTION, SOLVER_RUNS, STATUS, STATUS_FAILED,
                           STATUS_PENDING, STOPPED_EARLY, STUDY_FILE, STUDY_HASH, STUDY_NAME,
                           STUDY_OVERRIDES, STUDY_READ_FILES, STUDY_TEXT, STUDY_TEXT_HASH,
                           STUDY_TEXT_OMITTED, TITLE, WARM_UP_COMPILE_TIME, WARM_UP_PROCESSES,
                           WARM_UP_TIME, WARNINGS, WORKERS, is_sensitivity_variable)
from uqflow.levels import AlignedSolver, level_array, same_level_runs
from uqflow.realization import (UNAVAILABLE, add_field_value_variables, batch_arguments,
                                empty_runs, realization_prefix, run_batch, store_batch)
from uqflow.store import (check_unlocked, check_writable, now, read_runs, result_lock, versions,
                          write_result)
from uqflow.study import SET_OPTION, Study, scheduler_address_problem
from uqflow.warm_up import warm_up_in_process, warm_up_on_dask

#: how long a client waits for a dask scheduler before saying it cannot reach it
CONNECT_TIMEOUT_S = 30.0


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


def _work(solver_class, scene, names, outputs, arguments, budget, align=None):
    solver = _worker_solver(solver_class, scene)
    if align:
        solver = AlignedSolver(solver, align)
    return run_batch(solver, names, outputs=outputs, budget=budget, **arguments)


# --- on the client --------------------------------------------------------------------------

def _batch_size(study: Study, n_pending: int, workers: int) -> int:
    if study.spec.execution.batch:
        return study.spec.execution.batch
    # Enough batches to keep every worker busy and the progress bar moving, few enough that
    # dask's per-task cost (~1 ms) is amortised over many realizations.
    return int(np.clip(n_pending // (8 * max(workers, 1)), 1, 128))


def _text_sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


#: the largest study text stored in the result (bytes of UTF-8); a larger one is stored by its
#: hash alone, so that it is not rewritten at every checkpoint
MAX_STORED_STUDY_BYTES = 1 << 20


def _study_text_attrs(text: str) -> dict:
    size = len(text.encode())
    if size <= MAX_STORED_STUDY_BYTES:
        return {STUDY_TEXT: text}
    return {STUDY_TEXT_OMITTED: f"the study text ({size} bytes) is larger than "
                                  f"{MAX_STORED_STUDY_BYTES} bytes and is not stored; "
                                  f"{STUDY_TEXT_HASH} identifies it"}


def _root_attrs(study: Study, n_planned: int) -> dict:
    spec = study.spec
    return {
        TITLE: f"uqflow study '{study.name}'",
        STUDY_NAME: study.name,
        STUDY_FILE: str(study.path),
        **_study_text_attrs(study.text),
        STUDY_HASH: study.sha256,
        STUDY_TEXT_HASH: _text_sha256(study.text),
        STUDY_READ_FILES: json.dumps(study.read_files, sort_keys=True),
        SOLVER: spec.solver,
        SOLVER_DESCRIPTION: study.solver.describe(),
        METHOD: spec.method.kind,
        METHOD_OPTIONS: json.dumps(study.method.options.model_dump(), default=str),
        SEED: spec.execution.seed,
        PLANNED_REALIZATIONS: n_planned,
        CREATED: now(),
        COMPLETE: 0,
        CONVENTIONS: "CF-1.10",
        **({STUDY_OVERRIDES: study.overrides_text} if study.overrides else {}),
        **versions(),
    }


class _Checkpoint:
    """Writes the runs to the result file at most every ``spacing`` seconds, when new ones
    have finished since the last write."""

    def __init__(self, path: Path, attrs: dict, spacing: float):
        self.path, self.attrs, self.spacing = path, attrs, spacing
        self.last = time.monotonic()
        self.dirty = False

    def seconds_until_due(self) -> float:
        return max(self.last + self.spacing - time.monotonic(), 0.0)

    def maybe(self, runs: xr.Dataset) -> None:
        if self.dirty and self.seconds_until_due() == 0.0:
            self.write(runs)

    def write(self, runs: xr.Dataset) -> None:
        with _ctrl_c_deferred():
            write_result(self.path, runs, None, self.attrs)
        self.last = time.monotonic()
        self.dirty = False


def _check_provenance(study: Study, attrs: dict, path: Path) -> None:
    """Refuse to resume a result made by another study, by this study with a changed
    scene file (naming the file that changed) or with other ``--set`` overrides."""
    if attrs.get(STUDY_HASH) == study.sha256:
        return
    stored_overrides = str(attrs.get(STUDY_OVERRIDES, ""))
    if attrs.get(STUDY_TEXT_HASH) == _text_sha256(study.text) and \
            stored_overrides != study.overrides_text:
        def shown(text):
            return "; ".join(text.splitlines()) or "none"
        raise StudyError(f"{path} was made with other {SET_OPTION} overrides "
                         f"({shown(stored_overrides)}) than these "
                         f"({shown(study.overrides_text)}); resume with the same ones, or use "
                         f"--force to start again", file=str(study.path),
                         key=SET_OPTION)
    if attrs.get(STUDY_TEXT_HASH) == _text_sha256(study.text):
        try:
            stored = json.loads(str(attrs.get(STUDY_READ_FILES, "{}")))
        except ValueError:
            stored = {}
        for key, (file, sha) in sorted(study.read_files.items()):
            old = stored.get(key)
            if not isinstance(old, list) or len(old) != 2 or old[1] != sha:
                raise StudyError(f"the {key} file {file} changed since {path} was written; "
                                 f"resuming would mix two {key}s: use --force to start again",
                                 file=str(study.path), key=key)
    raise StudyError(f"{path} was made by a different version of this study; "
                     f"use --force to start again", file=str(study.path), key="output.path")


def _prepare(study: Study, resume: bool, path: Path):
    """The runs to complete: fresh from the plan, or read back from the partial result at
    ``path``."""
    fresh = _planned_runs(study)
    if resume and path.exists():
        runs, attrs = read_runs(path, verify=True)
        _check_provenance(study, attrs, path)
        _check_stored_design(runs, fresh, study, path)
        attrs[RESUMED] = now()
        attrs.setdefault(PLANNED_REALIZATIONS, runs.sizes[REALIZATION])
        return runs, attrs
    return fresh, _root_attrs(study, fresh.sizes[REALIZATION])


def _planned_runs(study: Study) -> xr.Dataset:
    seed = np.random.SeedSequence(study.spec.execution.seed)
    design = study.method.plan(study.space, study.fields or None, seed)
    if _empty(design):
        # Checked here, before anything is written: an empty design would otherwise fail in
        # the netCDF writer with a message about string types.
        raise StudyError(f"the '{study.spec.method.kind}' method's design has no "
                         f"realizations with these options; nothing to run",
                         file=str(study.path), key="method")
    return _runs_of(design, study)


def _empty(design) -> bool:
    return isinstance(design, xr.Dataset) and design.sizes.get(REALIZATION, 0) == 0


def _runs_of(design: xr.Dataset, study: Study) -> xr.Dataset:
    """Pending runs of ``design``, with their realization seeds."""
    runs = add_field_value_variables(empty_runs(design, study.solver.outputs()[study.outputs]),
                                     study.fields, study.solver)
    # A seed per realization, spawned by index (by seed_key where a design couples rows: the
    # same sample at two levels draws the same layout): reproducible without the rest of the
    # design.
    keys = runs[SEED_KEY].values if SEED_KEY in runs else \
        runs[REALIZATION].values
    runs[REALIZATION_SEED] = (REALIZATION, np.array(
        [np.random.SeedSequence(study.spec.execution.seed, spawn_key=(int(i),))
         .generate_state(1)[0] for i in keys], dtype=np.uint32))
    return runs


def _check_stored_design(stored: xr.Dataset, fresh: xr.Dataset, study: Study,
                         path: Path) -> None:
    """The partial result must hold this study's design (a prefix of it, if it stopped
    early) and every variable a run writes: another uqflow version may plan differently."""
    n = stored.sizes.get(REALIZATION, 0)
    if study.method.extends and n > fresh.sizes[REALIZATION]:
        # rows the method added after its plan: the plan must open the stored design
        n = fresh.sizes[REALIZATION]
        stored = realization_prefix(stored, n)
    prefix = realization_prefix(fresh, n)
    problem = None
    if not 0 < n <= fresh.sizes[REALIZATION]:
        problem = f"{n} realizations where this study plans {fresh.sizes[REALIZATION]}"
    else:
        for name, var in prefix.variables.items():
            if name not in stored.variables:
                problem = f"it has no variable '{name}'"
                break
            mine = stored.variables[name]
            if mine.dims != var.dims or mine.shape != var.shape:
                problem = f"'{name}' has dims {mine.dims} {mine.shape}, not {var.dims} {var.shape}"
                break
            designed = name not in (*study.outputs, *RUN_COLUMNS) and \
                not str(name).startswith(FIELD_PREFIX) and not is_sensitivity_variable(name)
            if designed and not _same_values(mine.values, var.values):
                problem = f"its '{name}' differ from this study's plan"
                break
    if problem:
        raise StudyError(f"{path} does not hold this study's design ({problem}; another "
                         f"uqflow version?); use --force to start again",
                         file=str(study.path), key="output.path")


def _sensitivity_runs(runs: xr.Dataset) -> xr.Dataset | None:
    """The variables on the sensitivity-run dim (derivatives and the realization each run
    is), or None without any."""
    if SENSITIVITY_DIM not in runs.dims:
        return None
    return runs[[v for v in runs.data_vars if SENSITIVITY_DIM in runs[v].dims]]


def _design_of(runs: xr.Dataset, study: Study) -> xr.Dataset:
    """The design inside ``runs``: everything but what a run writes (outputs, their
    derivatives, the run columns)."""
    written = [*study.outputs, *RUN_COLUMNS,
               *(name for name in runs.data_vars if is_sensitivity_variable(name))]
    return runs.drop_vars(written, errors="ignore")


def _same_values(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind in "fc" and b.dtype.kind in "fc":
        return np.array_equal(a, b, equal_nan=True)
    return a.shape == b.shape and bool(np.all(a.astype(str) == b.astype(str)))


class _Stopper:
    """Asks the method whether it has enough at its ``stop_points`` only, on the prefix
    ``[0, n)`` once every realization in it has finished, in increasing order: the stopping
    count depends on the design alone."""

    def __init__(self, method, design: xr.Dataset, runs: xr.Dataset, n_planned: int):
        self.method, self.design, self.runs = method, design, runs
        n = runs.sizes[REALIZATION]
        points = np.asarray(method.stop_points(int(n_planned)), dtype=np.int64)
        self.points = [int(p) for p in points if 0 < p <= n]
        self.next = 0
        self.keep: int | None = None

    def horizon(self) -> int | None:
        """The next count at which ``enough`` will be asked (None: no more)."""
        return self.points[self.next] if self.next < len(self.points) else None

    def advance(self) -> bool:
        """Ask at every count whose prefix is now finished; True once one says enough."""
        status = self.runs[STATUS].values
        pending = np.flatnonzero(status == STATUS_PENDING)
        first_pending = int(pending[0]) if pending.size else status.size
        while self.keep is None and self.next < len(self.points):
            n = self.points[self.next]
            if n > first_pending:
                return False
            self.next += 1
            if self.method.enough(realization_prefix(self.design, n),
                                  realization_prefix(self.runs, n)):
                self.keep = n
        return self.keep is not None


class _Execution:
    """The client's bookkeeping: store finished realizations, count failures, checkpoint,
    ask the stopper."""

    def __init__(self, study: Study, runs: xr.Dataset, design: xr.Dataset, attrs: dict,
                 checkpoint: _Checkpoint, bar):
        self.study, self.runs, self.design = study, runs, design
        self.checkpoint, self.bar = checkpoint, bar
        self.n_total = runs.sizes[REALIZATION]
        self.stopper = _Stopper(study.method, design, runs,
                                int(attrs.get(PLANNED_REALIZATIONS, self.n_total)))
        self.names = [str(p) for p in runs[PARAMETER].values]
        self.levels = level_array(runs)

    def add(self, more: xr.Dataset) -> np.ndarray:
        """Append the method's new rows ``more`` (a design) as pending runs; their indices."""
        n = self.runs.sizes[REALIZATION]
        new = _runs_of(more, self.study)
        # the sensitivity runs of added rows flagged with_sensitivities (FORM's search points)
        # join the first rows' on their own dim, renumbered to the rows' places
        added = _sensitivity_runs(new).assign_coords(
            {SENSITIVITY_COORD: lambda d: d[SENSITIVITY_COORD] + n}) \
            if new.sizes.get(SENSITIVITY_DIM, 0) else None
        new = new.drop_dims(SENSITIVITY_DIM, errors="ignore") \
            .assign_coords({REALIZATION: np.arange(n, n + more.sizes[REALIZATION])})
        runs = xr.concat([self.runs, new], dim=REALIZATION, data_vars="minimal",
                         coords="minimal", compat="override", join="override",
                         combine_attrs="override")
        if added is not None:
            before = _sensitivity_runs(self.runs)
            joined = added if before is None else xr.concat(
                [before, added], dim=SENSITIVITY_DIM, data_vars="minimal", coords="minimal",
                compat="override", combine_attrs="override")
            runs = runs.drop_dims(SENSITIVITY_DIM, errors="ignore").merge(
                joined, combine_attrs="override")
        self.runs = runs
        self.design = _design_of(self.runs, self.study)
        self.n_total = self.runs.sizes[REALIZATION]
        self.levels = level_array(self.runs)
        self.stopper = _Stopper(self.study.method, self.design, self.runs, self.n_total)
        self.bar.total = self.n_total
        return np.arange(n, self.n_total)

    def record(self, indices: np.ndarray, result: dict) -> str | None:
        """Store a task's results; the reason to stop, if any."""
        done = indices[:len(result[STATUS])]
        store_batch(self.runs, done, result)
        self.bar.update(len(done), result[STATUS].count(STATUS_FAILED))
        self.checkpoint.dirty = True
        if result.get(UNAVAILABLE):
            stopped_at = int(indices[len(done)])
            # it stays pending, for --resume to run; its message says why it has not run
            self.runs[MESSAGE].values[stopped_at] = f"not run: {result[UNAVAILABLE]}"
            return (f"failed:the solver could not run realization {stopped_at} "
                    f"({result[UNAVAILABLE]}); it and the rest are pending: finish with "
                    f"--resume once the solver is back")
        ex = self.study.spec.execution
        failed = int((self.runs[STATUS].values == STATUS_FAILED).sum())
        if failed > ex.max_failure_fraction * self.n_total:
            return _failure_stop(self.runs, failed, self.n_total, ex.max_failure_fraction)
        return "enough" if self.stopper.advance() else None


def _failure_stop(runs, failed, n_total, fraction):
    status = runs[STATUS].values
    first = int(np.flatnonzero(status == STATUS_FAILED)[0])
    return (f"failed:{failed} of {n_total} realizations failed (more than "
            f"max_failure_fraction {fraction:g}); first, realization {first}: "
            f"{runs[MESSAGE].values[first]}")


def run_study(study: Study, *, workers: int | None = None, scheduler: str | None = None,
              resume: bool = False, force: bool = False, show_progress: bool = True,
              output: str | Path | None = None) -> Outcome:
    """Run (or finish, with ``resume``) ``study`` and write its result file (``output``,
    when given, instead of the study's ``[output] path``; ``resume``/``force`` apply to it).

    Everything that can be checked before a realization runs is: the result path (a probe
    file is written in its folder), a partial result and its checksum and provenance on
    ``resume``, the dask scheduler. Those problems raise ``StudyError`` and leave any
    existing file as it was; a write failing mid-run raises ``ResultFileError`` and keeps the
    last checkpoint.
    """
    started = time.perf_counter()
    ex = study.spec.execution
    workers = ex.workers if workers is None else workers
    source = {"key": "--scheduler"} if scheduler is not None else \
        {"file": str(study.path), "key": "execution.scheduler"}
    if scheduler is not None and (problem := scheduler_address_problem(scheduler)):
        raise StudyError(problem, **source)
    scheduler = scheduler if scheduler is not None else ex.scheduler
    if output is not None:
        path, where = Path(output).resolve(), {"key": "--output"}
        if path.suffix != ".nc":
            raise StudyError(f"a result file ends in .nc, got '{output}'", **where)
    else:
        path, where = study.output_path, {"file": str(study.path), "key": "output.path"}
    check_unlocked(path, **where)  # before "exists": another run may be writing it now
    check_writable(path, replace=resume or force, **where)
    runs, attrs = _prepare(study, resume, path)
    pending = np.flatnonzero(runs[STATUS].values == STATUS_PENDING)
    resumed = int(runs.sizes[REALIZATION] - pending.size)
    design = _design_of(runs, study)
    in_process = workers == 0 and scheduler is None

    with contextlib.ExitStack() as held:  # the result's lock, once taken
        with contextlib.ExitStack() as stack:
            client = None if in_process else \
                stack.enter_context(_dask_client(workers, scheduler, source))
            # In this process a chunk runs until the next write is due; on dask a task spends
            # at most half the interval and the client writes at most every half interval, so
            # in both cases a realization is on disk within checkpoint_interval (plus one run).
            spacing = ex.checkpoint_interval if in_process else ex.checkpoint_interval / 2
            # From the first write to the last, this run alone writes the result.
            held.enter_context(result_lock(path, **where))
            checkpoint = _Checkpoint(path, attrs, spacing)
            try:
                checkpoint.write(runs)
            except ResultFileError as exc:
                raise StudyError(str(exc)) from None
            bar = progress_mod.Progress(runs.sizes[REALIZATION], resumed,
                                        enabled=show_progress)
            execution = _Execution(study, runs, design, attrs, checkpoint, bar)
            stop_reason = "enough" if execution.stopper.advance() else None
            if stop_reason is None and pending.size:
                attrs.update(_warm_up(study, client))
            try:
                while stop_reason is None:
                    if pending.size:
                        if in_process:
                            stop_reason = _run_in_process(execution, pending)
                        else:
                            stop_reason = _run_on_dask(execution, client, pending,
                                                       workers if scheduler is None else 2,
                                                       ex.checkpoint_interval / 2)
                    if stop_reason is not None or execution.stopper.keep is not None:
                        break
                    # Every row so far has finished: a method that re-plans may add rows.
                    more = study.method.extend(execution.design, execution.runs)
                    if more is None or _empty(more):  # no new rows: the method is done
                        break
                    pending = execution.add(more)
                    checkpoint.write(execution.runs)
            except KeyboardInterrupt:
                if checkpoint.dirty:
                    checkpoint.write(execution.runs)  # Ctrl-C keeps everything finished
                raise
            runs, design = execution.runs, execution.design
            if checkpoint.dirty and not in_process:
                checkpoint.write(runs)  # closing a cluster takes seconds: save first
            bar.close()

        if stop_reason and stop_reason.startswith("failed:"):
            checkpoint.write(runs)
            raise StudyFailed(f"{study.path}: stopped: {stop_reason[7:]}; the runs so far are "
                              f"in {path}")
        keep = execution.stopper.keep
        if keep is not None:
            runs = realization_prefix(runs, keep)
            design = realization_prefix(design, keep)
            attrs[STOPPED_EARLY] = f"target reached after {keep} realizations"
        statistics = study.method.analyze(design, runs)
        attrs.update({COMPLETE: 1, FINISHED: now(),
                      ELAPSED_TIME: float(attrs.get(ELAPSED_TIME, 0.0))
                      + time.perf_counter() - started,
                      SOLVER_RUNS: statistics.attrs.get(SOLVER_RUNS, 0),
                      FAILED_RUNS: statistics.attrs.get(FAILED_RUNS, 0),
                      WORKERS: workers if scheduler is None else f"scheduler {scheduler}"})
        with _ctrl_c_deferred():
            write_result(path, runs, statistics, attrs)
        warnings = [w for w in statistics.attrs.get(WARNINGS, "").split("\n") if w]
        return Outcome(path, runs, statistics, attrs, resumed, warnings)


def _warm_up(study: Study, client) -> dict:
    """Compile the solver's code before the first run, its shares side by side
    (uqflow/warm_up.py); the root attributes recording what that cost."""
    if client is None:
        cost = warm_up_in_process(study.solver, study.solver_class, study.scene)
    else:
        cost = warm_up_on_dask(client, _worker_solver, study.solver_class, study.scene)
    if not cost["processes"]:
        return {}
    return {WARM_UP_TIME: cost["seconds"], WARM_UP_COMPILE_TIME: cost["compile_seconds"],
            WARM_UP_PROCESSES: cost["processes"]}


def _run_in_process(execution: _Execution, pending: np.ndarray) -> str | None:
    study, runs = execution.study, execution.runs
    cap = study.spec.execution.batch or pending.size
    start = 0
    while start < pending.size:
        # Stop at the next stop point: the question is asked before running past it.
        horizon = execution.stopper.horizon()
        end = pending.size if horizon is None else \
            max(int(np.searchsorted(pending, horizon)), start + 1)
        chunk = same_level_runs(pending[start:min(end, start + cap)], execution.levels)[0]
        solver = study.solver if execution.levels is None else \
            study.levels.aligned_solver(int(execution.levels[chunk[0]]))
        result = run_batch(solver, execution.names, outputs=study.outputs,
                           budget=execution.checkpoint.seconds_until_due(),
                           **batch_arguments(runs, chunk, study.fields))
        start += len(result[STATUS])
        reason = execution.record(chunk, result)
        if reason:
            return reason
        execution.checkpoint.maybe(runs)
    return None


@contextlib.contextmanager
def _ctrl_c_ignored():
    """SIGINT ignored in this process for the ``with`` block (main thread only).

    Around the start of a local cluster: Ctrl-C reaches every process of the terminal's
    foreground group, local dask workers included, and each would print its own
    KeyboardInterrupt traceback; only the client should react (it saves the runs and closes
    the cluster, which ends the workers). An ignored signal stays ignored across fork and
    exec, and Python then installs no handler of its own, so workers started here never see
    it. Around the close of a cluster: the runs are saved by then, and a close cut short
    leaves workers that log their lost scheduler and an exit that waits for them.
    A Ctrl-C in these seconds is ignored; the next one interrupts.
    """
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread may change signal handlers
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _ctrl_c_deferred():
    """A Ctrl-C during the ``with`` block (a result write) takes effect when it ends.

    Raised inside the netCDF writer, a KeyboardInterrupt would abandon the write halfway, in
    library code not written to be interrupted (and the first checkpoint, the file --resume
    needs, would not exist); deferred, the write completes and the interrupt follows.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pressed = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: pressed.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if pressed:
        if callable(previous):
            previous(signal.SIGINT, None)  # Python's own handler raises KeyboardInterrupt
        else:
            os.kill(os.getpid(), signal.SIGINT)  # as the signal would have done


@contextlib.contextmanager
def _dask_client(workers: int, scheduler: str | None, source: dict):
    """A client of a new local cluster (``workers`` processes) or of ``scheduler``; a
    malformed or unreachable address is a one-line ``StudyError`` naming ``source`` (the
    file and key the address came from)."""
    from dask.distributed import Client, LocalCluster

    cluster = None
    try:
        if scheduler is None:
            threads = str(max(1, (os.cpu_count() or 1) // max(workers, 1)))
            with _ctrl_c_ignored():
                cluster = LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True,
                    dashboard_address=":0", silence_logs=logging.ERROR,
                    env={"NUMBA_NUM_THREADS": threads, "OMP_NUM_THREADS": threads,
                         "OPENBLAS_NUM_THREADS": threads, "MKL_NUM_THREADS": threads})
        client = Client(cluster if cluster is not None else scheduler,
                        timeout=CONNECT_TIMEOUT_S)
    except (OSError, ValueError, TypeError, TimeoutError) as exc:
        if cluster is not None:
            with _ctrl_c_ignored():
                cluster.close()
        if scheduler is None:
            raise StudyError(f"cannot start a local dask cluster of {workers} workers: "
                             f"{exc}", key="execution.workers") from None
        raise StudyError(f"cannot reach dask scheduler '{scheduler}': {exc}", **source) \
            from None
    try:
        yield client
    finally:
        with _ctrl_c_ignored():
            client.close()
            if cluster is not None:
                cluster.close()


def _run_on_dask(execution: _Execution, client, pending: np.ndarray, workers: int,
                 budget: float) -> str | None:
    from dask.distributed import wait

    study, runs = execution.study, execution.runs
    # Fields (their KL bases) travel to each worker once, not with every batch.
    fields = client.scatter(study.fields, broadcast=True) if study.fields else None
    active: dict = {}

    def submit(indices):
        for part in same_level_runs(indices, execution.levels):
            arguments = batch_arguments(runs, part, study.fields)
            if fields is not None:
                arguments["fields"] = fields
            scene, align = study.scene, None
            if execution.levels is not None:
                level = int(execution.levels[part[0]])
                scene, align = study.levels.scenes[level], study.levels.alignments[level]
            # Lower realizations first: the stop points are prefixes of the design.
            future = client.submit(_work, study.solver_class, scene, execution.names,
                                   study.outputs, arguments, budget, align, pure=False,
                                   priority=-int(part[0]))
            active[future] = part

    size = _batch_size(study, pending.size, workers)
    for i in range(0, pending.size, size):
        submit(pending[i:i + size])
    reason = None
    try:
        while active and reason is None:
            timeout = execution.checkpoint.seconds_until_due() \
                if execution.checkpoint.dirty else None
            try:
                done = wait(list(active), timeout=timeout, return_when="FIRST_COMPLETED").done
            except TimeoutError:
                done = ()
            for future in sorted(done, key=lambda f: int(active[f][0])):
                indices = active.pop(future)
                try:
                    result = future.result()
                except Exception as exc:  # the task itself, not a realization, failed
                    execution.checkpoint.write(runs)
                    why = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
                    raise UqflowError(f"{study.path}: a dask task failed ({why}); the runs "
                                      f"so far are in {execution.checkpoint.path}") from None
                reason = execution.record(indices, result)
                if reason:
                    break
                if len(result[STATUS]) < len(indices):
                    submit(indices[len(result[STATUS]):])
            execution.checkpoint.maybe(runs)
    finally:
        if active:
            client.cancel(list(active))
    return reason
