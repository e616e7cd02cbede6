"""Compiling a solver's code before a study's first run, once, on every core at hand.

A solver that compiles (numba) pays for it in the first run of every process: a cold
quickstart spent most of its time compiling, and two dask workers each compiled the same
kernels side by side (issue 19). A solver may split what it compiles into shares
(``Solver.compile_shares``, ``Solver.warm_up``); processes sharing numba's cache folder each
compile one share at once and load the others' machine code from the cache afterwards.

* In this process (``workers = 0``): when the solver says its code is not cached, shares
  1, 2, ... compile in subprocesses (``python -m uqflow.warm_up``) while this process compiles
  share 0; the runs start when all are done. A warm cache costs one check, no process.
* On dask: one warm-up task per worker, each its own share, all finished before the first
  realization is submitted; a worker whose cache is warm returns at once. Workers on other
  machines share the cache only through a shared file system (``NUMBA_CACHE_DIR``); without
  one each still compiles its own share first and the rest on first use, as before.

A solver without these methods, or whose ``compile_shares`` is 0, is left alone.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import time

from uqflow.realization import compile_clock


def shares_to_compile(solver) -> int:
    """How many shares ``solver`` would split its compilation into now (0: nothing to do)."""
    counting = getattr(solver, "compile_shares", None)
    return int(counting()) if counting is not None else 0


def warm_up_in_process(solver, solver_class, scene) -> dict:
    """Compile ``solver``'s code before its first run here, its shares spread over this
    process and ``min(shares, cores) - 1`` subprocesses. Returns what it cost (``seconds``
    wall, ``compile_seconds`` of numba here, ``processes``)."""
    start = time.perf_counter()
    shares = shares_to_compile(solver)
    if shares == 0:
        return {"seconds": 0.0, "compile_seconds": 0.0, "processes": 0}
    parts = max(1, min(shares, os.cpu_count() or 1))
    try:
        task = pickle.dumps((solver_class, scene, parts))
    except (pickle.PicklingError, TypeError, AttributeError):
        task, parts = None, 1       # not picklable: everything compiles here
    helpers = [_start_share(task, part) for part in range(1, parts)]
    try:
        compiled = [warm_solver(solver, 0, parts)]
    finally:
        # a share that failed elsewhere compiles here at its first call: later, same code
        compiled += [_share_result(p) for p in helpers]
    done = [seconds for seconds in compiled if seconds is not None]
    return {"seconds": time.perf_counter() - start, "compile_seconds": float(sum(done)),
            "processes": len(done)}


def _start_share(task: bytes, part: int) -> subprocess.Popen:
    process = subprocess.Popen([sys.executable, "-m", "uqflow.warm_up", str(part)],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               stderr=subprocess.DEVNULL)
    process.stdin.write(task)
    process.stdin.close()
    return process


def _share_result(process: subprocess.Popen) -> float | None:
    """The compile seconds a share's subprocess printed, None when it failed."""
    printed = process.stdout.read()
    if process.wait() != 0:
        return None
    try:
        return float(printed.split()[-1])     # the last word: a solver may print too
    except (IndexError, ValueError):
        return None


def warm_solver(solver, part: int, parts: int) -> float | None:
    """Compile share ``part`` of ``parts`` of ``solver``'s code unless all of it is cached;
    returns numba's compile seconds, or None when the warm-up failed. A failure is not the
    study's: what failed here fails again in the runs, where it is recorded with the
    realization (or stops a dask study with its message), and what compiled is kept."""
    try:
        if shares_to_compile(solver) == 0:
            return 0.0
        with compile_clock() as compiled:
            solver.warm_up(part, parts)
    except Exception:  # noqa: BLE001 - see the docstring
        return None
    return compiled.seconds


def _warm_task(build, solver_class, scene, part: int, parts: int) -> float | None:
    try:
        solver = build(solver_class, scene)
    except Exception:  # noqa: BLE001 - the realizations' tasks report it
        return None
    return warm_solver(solver, part, parts)


def warm_up_on_dask(client, build, solver_class, scene) -> dict:
    """One warm-up task per worker of ``client``'s cluster, worker k compiling share k of
    as many shares as workers, all finished before the caller submits realizations.
    ``build(solver_class, scene)`` makes the solver on the worker (the worker's own cache of
    solvers, so its realizations reuse what the warm-up built)."""
    start = time.perf_counter()
    workers = sorted(client.scheduler_info()["workers"])
    futures = [client.submit(_warm_task, build, solver_class, scene, k, len(workers),
                             workers=[address], allow_other_workers=False, pure=False)
               for k, address in enumerate(workers)]
    seconds = [s for s in client.gather(futures) if s is not None]
    return {"seconds": time.perf_counter() - start, "compile_seconds": float(sum(seconds)),
            "processes": len(seconds)}


def _main() -> int:
    solver_class, scene, parts = pickle.loads(sys.stdin.buffer.read())
    seconds = warm_solver(solver_class.from_scene(scene), int(sys.argv[1]), parts)
    if seconds is None:
        return 1
    print(seconds)
    return 0


if __name__ == "__main__":
    sys.exit(_main())
