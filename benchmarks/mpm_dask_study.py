"""One study of seed-size MPM runs, in this process and on a local dask cluster of 2 workers:
what the framework adds to each realization (issue 19, point 3).

The study: Monte Carlo (``--realizations`` N, default 4, independent normal draws, seed 0) on
the Johnson-Cook yield stress A of the steel (normal, mean 792 MPa, C.V. 0.10), the scene
``studies/scenes/mpm_contact_thin.toml`` as it is (seed size: 400 x 200 cells, 320,000
particles, 100 µs, ``threads`` = 1, its default), outputs flow stress and plastic strain at
the probes, no figures. It is written to a scratch folder and run twice through
``uqflow.run_study``: (a) ``workers = 0`` (in this process, one realization at a time) and
(b) ``workers = --workers`` (default 2: a ``LocalCluster`` of single-threaded worker
processes, each with NUMBA_NUM_THREADS = cores / workers as uqflow sets it). Each result goes
to its own file; the two runs datasets must be identical (uqflow's results do not depend on
the workers).

Both start from a warm numba cache: a subprocess first runs one tiny realization of the scene
(resolution 0.25, 2 µs), which compiles the kernels into numba's on-disk cache or finds them
there; its wall time and numba's compile seconds are reported as the first-call figure. Every
process (this one for (a), each worker for (b)) still loads the cached kernels at its first
realization: that time is inside that realization's ``wall_time`` (its ``compile_time`` is
numba's compile seconds, 0 when everything came from the cache).

Reported per variant: the study's wall time (``load_study`` and ``run_study``, as ``uqflow
run`` does: the solver built, the cluster started and closed, each worker's own solver
built, batches, checkpoints, analysis, the result file), the sum over realizations of
the runs dataset's ``wall_time`` and of ``compile_time`` (a part of ``wall_time``), the
concurrency c (1 in-process, min(workers, N) on dask), and the per-realization overhead

    (study wall - sum(wall_time) / c) / N,

the time per realization not spent inside a realization, assuming the c workers were kept
equally busy. On dask it includes the cluster's start-up, measured also on its own (a
``LocalCluster`` of the same workers started and closed, median of 3, after the studies).

    python benchmarks/mpm_dask_study.py [--realizations 4] [--workers 2] [--json]

writes the section ``mpm-dask-study`` of BENCHMARKS.md (not with ``--no-write`` or
``--quick``). ``--quick``: the scene at resolution 0.25 (20,000 particles) to 20 µs, a smoke
test of the whole path in seconds. The machine is shared: the 1-minute load average is
recorded at the start and the end, after waiting (up to ``--wait`` s) for it to drop below
``--max-load``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import ROOT, load1, log, wait_for_load, write_section  # noqa: E402
from _studies import toml_value, write_scene_variant  # noqa: E402

from uqflow.execute import run_study  # noqa: E402
from uqflow.layout import COMPILE_TIME, REALIZATION, STATUS, STATUS_OK, WALL_TIME  # noqa: E402
from uqflow.study import load_study  # noqa: E402

SCENE = "mpm_contact_thin.toml"
INPUT, MEAN, CV = "steel.jc.A", 792.0e6, 0.10
OUTPUTS = ("flow_stress", "plastic_strain")
QUICK_SCENE = {"resolution": 0.25, "end_time": 20e-6}
WARM_UP_SCENE = {"resolution": 0.25, "end_time": 2e-6}

STUDY = """\
name = "mpm-dask-study"
solver = "mpm"
scene = {scene}
outputs = {outputs}

[[inputs]]
name = "{input}"
distribution = "normal"
mean = {mean!r}
cv = {cv!r}

[method]
kind = "monte-carlo"
samples = {samples}

[execution]
workers = 0

[output]
path = "in_process.nc"
figures = false
"""

WARM_UP = """
import json, sys, time, tomllib
sys.path.insert(0, {root!r})
from solvers.mpm import MPMSolver
from uqflow.realization import compile_clock
scene = tomllib.load(open({scene!r}, "rb"))
t0 = time.perf_counter()
with compile_clock() as compiled:
    MPMSolver.from_scene(scene).run({{}})
print(json.dumps({{"wall_s": time.perf_counter() - t0, "numba_compile_s": compiled.seconds}}))
"""








def warm_cache(folder: Path) -> dict:
    """One tiny realization in a fresh process: numba's on-disk cache holds every kernel
    afterwards (compiled now, or already there)."""
    scene = write_scene_variant(SCENE, folder / "warm_up_scene.toml", **WARM_UP_SCENE)
    p = subprocess.run([sys.executable, "-c", WARM_UP.format(root=str(ROOT), scene=str(scene))],
                       capture_output=True, text=True, cwd=ROOT)
    if p.returncode:
        raise SystemExit(f"warm-up run failed: {p.stderr.strip()[-600:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def write_study(folder: Path, realizations: int, quick: bool) -> Path:
    scene = write_scene_variant(SCENE, folder / "scene.toml", **QUICK_SCENE) if quick \
        else ROOT / "studies" / "scenes" / SCENE
    path = folder / "study.toml"
    path.write_text(STUDY.format(scene=toml_value(str(scene)), outputs=toml_value(list(OUTPUTS)),
                                 input=INPUT, mean=MEAN, cv=CV, samples=realizations))
    return path


def timed_study(path: Path, workers: int, output: Path) -> tuple[dict, object]:
    """The study loaded (its solver built: seeding the particles) and run, as ``uqflow run``
    does; on dask each worker builds the solver again, inside the study's wall time."""
    t0 = time.perf_counter()
    study = load_study(path)
    load = time.perf_counter() - t0
    outcome = run_study(study, workers=workers, force=True, show_progress=False, output=output)
    wall = time.perf_counter() - t0
    runs = outcome.runs
    n = int(runs.sizes[REALIZATION])
    wall_times = np.asarray(runs[WALL_TIME].values, float)
    compile_times = np.asarray(runs[COMPILE_TIME].values, float)
    concurrency = 1 if workers == 0 else min(workers, n)
    summary = {
        "workers": workers, "realizations": n, "concurrency": concurrency,
        "ok": int(np.sum(runs[STATUS].values == STATUS_OK)),
        "study_wall_s": wall, "study_load_s": load,
        "run_wall_times_s": [round(float(t), 3) for t in wall_times],
        "run_compile_times_s": [round(float(t), 3) for t in compile_times],
        "sum_run_wall_s": float(wall_times.sum()),
        "sum_run_compile_s": float(compile_times.sum()),
        "overhead_per_realization_s": (wall - wall_times.sum() / concurrency) / n,
        "particles": int(study.solver.parts.x.size),
    }
    return summary, runs


def cluster_startup(workers: int, repeats: int = 3) -> float:
    """Median seconds to start and close a LocalCluster of ``workers`` single-threaded worker
    processes with a client (what run_study does around the realizations)."""
    import logging

    from dask.distributed import Client, LocalCluster

    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                          dashboard_address=":0", silence_logs=logging.ERROR) as cluster, \
                Client(cluster):
            pass
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def same_outputs(a, b) -> bool:
    """The two runs datasets hold the same outputs, bit for bit (NaN where either has NaN)."""
    return all(np.array_equal(a[name].values, b[name].values, equal_nan=True) for name in OUTPUTS)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--realizations", type=int, default=4)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--quick", action="store_true", help="coarse scene, seconds; writes nothing")
    p.add_argument("--max-load", type=float, default=1.5)
    p.add_argument("--wait", type=float, default=300.0, help="s to wait for the load to drop")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--no-write", action="store_true", help="do not touch BENCHMARKS.md")
    args = p.parse_args(argv)
    if args.realizations < 1 or args.workers < 1:
        p.error("--realizations and --workers must be at least 1")

    waited = 0.0 if args.quick else wait_for_load(args.max_load, args.wait)
    load_start = load1()
    with tempfile.TemporaryDirectory(prefix="mpm_dask_study_") as tmp:
        folder = Path(tmp)
        log(f"load {load_start} (waited {waited:.0f} s); warming numba's cache ...")
        warm = warm_cache(folder)
        log(f"  first call {warm['wall_s']:.1f} s "
            f"(numba compiling {warm['numba_compile_s']:.1f} s)")
        path = write_study(folder, args.realizations, args.quick)
        log(f"{args.realizations} realizations in-process ...")
        in_process, runs_in = timed_study(path, 0, folder / "in_process.nc")
        log(f"  {json.dumps(in_process)}")
        log(f"{args.realizations} realizations on {args.workers} dask workers ...")
        on_dask, runs_dask = timed_study(path, args.workers, folder / "dask.nc")
        log(f"  {json.dumps(on_dask)}")
        identical = same_outputs(runs_in, runs_dask)
    startup = None if args.quick else cluster_startup(args.workers)
    if startup is not None:
        on_dask["overhead_per_realization_without_startup_s"] = \
            on_dask["overhead_per_realization_s"] - startup / on_dask["realizations"]
    import numba
    result = {
        "scene": SCENE, "scene_changes": QUICK_SCENE if args.quick else {},
        "particles": in_process["particles"], "input": INPUT, "mean": MEAN, "cv": CV,
        "outputs": list(OUTPUTS),
        "realizations": args.realizations, "workers": args.workers,
        "warm_up_first_call": warm, "in_process": in_process, "dask": on_dask,
        "cluster_startup_s": startup, "identical_outputs": identical,
        "speedup": in_process["study_wall_s"] / on_dask["study_wall_s"],
        "load_1min": {"start": load_start, "end": load1()},
        "cores": os.cpu_count(), "numba": numba.__version__,
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(json.dumps(result, indent=1))
    if not (args.quick or args.no_write):
        write_section("mpm-dask-study", "MPM solver: a seed-size study on dask", section(result))
        log("written: BENCHMARKS.md (mpm-dask-study)")
    return result


def section(r: dict) -> str:
    def row(label, v):
        return (f"| {label} | {v['concurrency']} | {v['ok']} of {v['realizations']} | "
                f"{v['study_wall_s']:.1f} | {v['sum_run_wall_s']:.1f} | "
                f"{v['sum_run_compile_s']:.2f} | {v['overhead_per_realization_s']:.2f} |")

    d, w = r["dask"], r["warm_up_first_call"]
    changes = ", ".join(f"{k} = {v:g}" for k, v in r["scene_changes"].items())
    scene = (f"with {changes} ({r['particles']:,} particles" if changes else
             f"as it is (seed size, {r['particles']:,} particles, 100 µs") + ", `threads` = 1)"
    startup = "" if r["cluster_startup_s"] is None else (
        f"A local cluster of {r['workers']} workers alone (started and closed with a client, "
        f"median of 3) takes {r['cluster_startup_s']:.1f} s; without it the overhead on dask is "
        f"{d['overhead_per_realization_without_startup_s']:.2f} s per realization.")
    return f"""
{r['realizations']} realizations of `studies/scenes/{r['scene']}` {scene}, Monte Carlo on `{r['input']}`
(normal, mean {r['mean'] / 1e6:.0f} MPa, C.V. {r['cv']}), outputs {', '.join(r['outputs'])},
no figures; through `uqflow.run_study` in-process (`workers = 0`) and on a local dask cluster
of {r['workers']} single-threaded workers (NUMBA_NUM_THREADS =
{max(1, r['cores'] // r['workers'])} each).
Both from a warm numba cache: a tiny realization in a subprocess first took {w['wall_s']:.1f} s
(numba compiling {w['numba_compile_s']:.1f} s of it; 0 = every kernel loaded from the cache).
Each process still loads the cached kernels at its first realization, inside that
realization's wall time. Load average (1 min) {r['load_1min']['start']:.2f} at the start,
{r['load_1min']['end']:.2f} at the end (2 shared cores).

| variant | concurrency c | ok | study wall [s] | Σ run wall_time [s] | Σ run compile_time [s] | overhead per realization [s] |
|---|---:|---:|---:|---:|---:|---:|
{row('in-process', r['in_process'])}
{row(f"dask, {r['workers']} workers", d)}

Study wall: `load_study` and `run_study`, as `uqflow run` does (loading, the solver's
particles seeded: {r['in_process']['study_load_s']:.1f} s in-process). Overhead per realization = (study wall − Σ wall_time / c) / N:
the time the study spends outside its realizations (loading, planning, dask's scheduling and
transfers, each worker's imports and solver, checkpoints, analysis, the result file, and on
dask the cluster's start and close), per realization, with the c workers taken as equally
busy. {startup} Study wall in-process / on dask:
**{r['speedup']:.2f}**. Run wall times in-process
{', '.join(f'{t:.1f}' for t in r['in_process']['run_wall_times_s'])} s, on dask
{', '.join(f'{t:.1f}' for t in d['run_wall_times_s'])} s (two realizations at a time share the
2 cores' memory bandwidth). The two runs datasets' outputs are
{'identical' if r['identical_outputs'] else '**not** identical'}.
"""


if __name__ == "__main__":
    main()
