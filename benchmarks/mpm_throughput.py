"""Throughput of the explicit MPM solver (docs/mpm.md) against a minimal Taichi MLS-MPM step.

(a) particle-updates per second of the full steel/TNT/water physics (MUSL: P2G, grid solve,
    G2P velocity with the remap scatter, grid solve, and per material the velocity gradient,
    bulk viscosity, material model, state check and CFL speed; quadratic B-splines, f64) at ``--particles`` (default 160,000) on ``--threads``
    (default 2) numba threads; target ≥ 1.0e7. The scene is built programmatically from
    ``studies/scenes/mpm_contact_thin.toml``: the seed's charge and thin plate in a square
    half-domain [−L/2, L/2] × [0, L] of water at the seed's dx = 5 mm and 2 × 2 particles per
    cell, L chosen so the count is exactly 4 (L/dx)² (plate up to y = L, clamped there).
    Timed: the solver's own step (``solver._Run._step``, and the CFL time step from the
    maximum signal speed its material loops found) for ``--steps`` steps from t = 0 (the detonation starting), on a
    fresh ``_Run`` per repetition; not timed: seeding, ``_Run`` set-up (material init),
    probe recording. Median of ``--repeats``, after a warm-up: a first run's set-up and first
    step (every kernel's first call: numba compiles it, or loads it from its on-disk cache)
    are timed apart as the first call, with the seconds numba's compile events report
    (0 when every kernel came from the cache), then two more steps.
    A per-kernel breakdown (one extra repetition, each kernel call timed) is the profile.
    Variants in the same run: 1 thread; and 2 threads while a busy loop holds one core, with
    GNU OpenMP's default spinning and with GOMP_SPINCOUNT=10000.
(b) the same measure, in the same run, for a minimal MLS-MPM step (fluid, 3 × 3 stencil, f64)
    written in Taichi on its CPU backend with ``cpu_max_num_threads`` = the same thread count:
    ``benchmarks/taichi_mlsmpm.py`` in a subprocess (its own thread pool; its banner off our
    stdout). ``null`` when Taichi is not installed (``pip install -e .[bench]``).
    Measured in ``--pairs`` alternated sets (default 3): (a)'s measure again on the same warm
    solver, then Taichi's, then the same minimal step written in numba
    (``benchmarks/numba_mlsmpm.py``, in this process); the ratios are the medians of the sets'
    ratios, each taken from measurements seconds apart, so a slow spell of the shared machine
    falls on both sides of a ratio rather than on one side of the comparison (Taichi's step
    time is bimodal on this machine: docs/mpm.md, "Performance"). Taichi's minimal step in
    numba separates the two differences of the headline ratio: the language and kernel style
    on the same work, and the work of our full MUSL step.
(c) step time and memory against particle count: ``--scaling-counts`` (default 1e4, 4e4,
    1.6e5, 6.4e5, 1e6), each exactly 4 s² for s cells a side of the same scene family (2 × 2
    particles per cell, L = s dx; s = 50, 100, 200, 400, 500; s ≥ 24 so the plate is whole;
    other counts are refused). Each count runs in a fresh subprocess (``--scaling-child``):
    a warm-up on the family's 30 × 30-cell scene (first call timed as in (a)), then the
    memory, then the step time (median of 3 × ``--scaling-steps`` steps, fresh ``_Run``
    each; a count is skipped once one measurement took > 120 s). The log-log slope of step
    time against count is the least-squares line (np.polyfit) through every measured count;
    figure ``docs/figures/mpm_scaling.png`` (step time, particle-updates/s, bytes/particle).
    Memory: the peak resident memory of that process (VmHWM, /proc/self/status) while it
    builds the solver and one ``_Run`` of the count and steps it ``MEMORY_STEPS`` times,
    less its resident memory just before (after the warm-up, its arrays freed; the peak is
    reset there through /proc/self/clear_refs), divided by the count. This is the honest
    figure: it is what the machine must provide, and it counts what tracemalloc cannot see
    (numba's own allocations inside kernels, parallel reductions' temporaries, the OpenMP
    threads' stacks, allocator slack); tracemalloc sees numpy's buffers and Python objects
    only. The bytes of the numpy arrays the solver and the run hold are reported beside it
    (a lower bound of the resident growth: the run writes all of them).
(d) one seed-size run of ``mpm_contact_thin.toml`` and ``mpm_contact_thick.toml`` to 100 µs
    each (320,000 particles, the scene as it is — ``threads`` = 1, its default), each in a
    fresh subprocess (after a small warm-up run that loads numba's cache): wall time of
    ``run``, steps, and the peak resident memory of that process: VmHWM of /proc/self/status
    (``resource.getrusage`` ru_maxrss is reported too, but on Linux a child's ru_maxrss
    starts at its parent's RSS at fork time — the benchmark process's, (a)'s arrays
    included — so it is an upper bound, not the child's own peak). The warm-up run's wall
    time and numba's compile seconds in it are the first call; numba's compile seconds
    inside the timed run are reported too (0 when the warm-up loaded every kernel).

NUMBA_NUM_THREADS is set to ``--threads`` before numba is imported. The machine is shared:
the 1-minute load average is recorded at the start and the end, and the script first waits
(up to ``--wait`` s) for it to drop below ``--max-load``.

    python benchmarks/mpm_throughput.py --particles 160000 --steps 50 --json

prints ONE JSON object on stdout (progress goes to stderr) and writes the section
``mpm-throughput`` of BENCHMARKS.md and the figure (unless ``--no-write`` or a part is
skipped with ``--skip-scaling`` / ``--skip-seed``).
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import statistics
import subprocess
import sys
import time
import tomllib
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks._threads import numba_threads_from_argv  # noqa: E402

THREADS = numba_threads_from_argv(sys.argv[1:])      # before numba is imported

import numpy as np  # noqa: E402

import numba  # noqa: E402

from benchmarks._record import FIGURES, load1, log, wait_for_load, write_section  # noqa: E402
from solvers.mpm import MPMSolver  # noqa: E402
from solvers.mpm.solver import _Run  # noqa: E402
from uqflow.realization import compile_clock  # noqa: E402

SCENES = ROOT / "studies" / "scenes"
TARGET = 1.0e7
COUNTS = (10_000, 40_000, 160_000, 640_000, 1_000_000)
SKIP_AFTER_S = 120.0
#: the fewest cells a side of an exact scaling count: the half-domain [-L/2, L/2] holds the
#: plate (x up to 0.06 m) whole at dx = 5 mm
MIN_SIDE = 24
#: cells a side of the scaling children's warm-up scene (3,600 particles)
WARM_UP_SIDE = 30
#: steps of the run whose peak memory is measured (every buffer is allocated by the first)
MEMORY_STEPS = 3






# -- scene ----------------------------------------------------------------------------------

def seed_scene() -> dict:
    return tomllib.load(open(SCENES / "mpm_contact_thin.toml", "rb"))


def cells_per_side(n: int) -> int:
    """s such that the family's scene of s × s cells holds exactly ``n`` particles
    (ppc² s², ppc particles per cell a side); ValueError for any other count."""
    ppc = seed_scene().get("particles_per_cell", 2)
    side = math.isqrt(n // ppc ** 2)
    if ppc ** 2 * side ** 2 != n or side < MIN_SIDE:
        exact = ", ".join(f"{ppc ** 2 * k * k:,}" for k in (MIN_SIDE, 50, 100, 500))
        raise ValueError(f"{n} particles is not {ppc ** 2} s² for a whole number s ≥ "
                         f"{MIN_SIDE} of cells a side (e.g. {exact})")
    return side


def scene_for(n: int, threads: int) -> dict:
    """The thin-plate seed scene on a square half-domain holding ~n particles (exactly n
    when ``cells_per_side(n)`` accepts it)."""
    scene = seed_scene()
    dx = scene["cell_size"] / scene.get("resolution", 1.0)
    ppc = scene.get("particles_per_cell", 2)
    side = max(20, int(round(math.sqrt(n / ppc ** 2))))     # cells a side (>= the charge)
    L = side * dx
    scene["domain"] = {"x": [-L / 2, L / 2], "y": [0.0, L]}
    for b in scene["bodies"]:
        if b["name"] == "plate":
            b["max"] = [b["max"][0], L]
        elif b["name"] == "water":
            b["min"], b["max"] = [-L / 2, 0.0], [L / 2, L]
    scene["clamps"] = [{"min": [0.04, L - 2 * dx], "max": [0.06, L + 0.1]}]
    scene["threads"] = threads
    scene.pop("extent", None)
    return scene


def new_run(solver: MPMSolver) -> _Run:
    return _Run(solver, solver._parameters({}))


def drive(run: _Run, steps: int, profile: dict | None = None) -> float:
    """``steps`` solver steps (CFL dt from max_speed, as ``_Run._advance`` does, without
    output-time shortening or probe recording). Returns the wall time."""
    before = numba.get_num_threads()
    numba.set_num_threads(run.nthreads)
    try:
        t0 = time.perf_counter()
        for _ in range(steps):
            ts = time.perf_counter()
            vmax = run.max_speed()
            dt = run.cfg.cfl * run.g.dx / vmax
            if profile is None:
                run._step(dt)
            else:
                profile["max_speed"] = profile.get("max_speed", 0.0) + time.perf_counter() - ts
                profiled_step(run, dt, profile)
            run.t += dt
            run.step_no += 1
        return time.perf_counter() - t0
    finally:
        numba.set_num_threads(before)


def profiled_step(r: _Run, dt: float, acc: dict) -> None:
    """``_Run._step`` with each kernel timed (the kernels are synchronous; ``lap`` is called
    after each) — only for the breakdown; the throughput figures time ``_Run._step`` alone."""
    last = [time.perf_counter()]

    def lap(name):
        now = time.perf_counter()
        acc[name] = acc.get(name, 0.0) + now - last[0]
        last[0] = now

    r._step(dt, lap)


def first_call(solver: MPMSolver) -> dict:
    """The warm-up: a fresh run's set-up and first step, timed together (each kernel's first
    call compiles it or loads it from numba's cache; the set-up calls the material init
    kernels), with numba's compile seconds in them; then two more steps, not timed."""
    t0 = time.perf_counter()
    with compile_clock() as compiled:
        run = new_run(solver)
        drive(run, 1)
    out = {"first_call_s": round(time.perf_counter() - t0, 3),
           "numba_compile_s": round(compiled.seconds, 3)}
    drive(run, 2)
    return out


def timed_steps(solver: MPMSolver, steps: int, repeats: int) -> tuple[list[float], int]:
    """Wall times of ``repeats`` runs of ``steps`` steps, each on a fresh run (stopping after
    one that took longer than SKIP_AFTER_S), and the runs' thread count."""
    times = []
    for _ in range(repeats):
        run = new_run(solver)
        times.append(drive(run, steps))
        threads = int(run.nthreads)
        del run
        if times[-1] > SKIP_AFTER_S:
            break
    return times, threads


def throughput(n: int, steps: int, repeats: int, threads: int, profile: bool,
               solver: MPMSolver | None = None, warm_up: dict | None = None) -> dict:
    """Step time of the family's scene of ~n particles (or of ``solver``, already warm when
    ``warm_up`` gives its first call)."""
    solver = MPMSolver.from_scene(scene_for(n, threads)) if solver is None else solver
    np_ = int(solver.parts.x.size)
    warm_up = first_call(solver) if warm_up is None else warm_up
    times, threads_used = timed_steps(solver, steps, repeats)
    med = statistics.median(times)
    out = {"particles": np_, "steps": steps, "threads": threads_used,
           "cells": int(solver.cfg.grid.cells), "times_s": [round(t, 4) for t in times],
           "median_s": med, "step_s": med / steps, "particle_updates_per_s": np_ * steps / med,
           "first_call": warm_up,
           "materials": {lab: int(idx.size) for lab, idx in zip(solver.labels,
                                                                solver.mat_index)}}
    if profile:
        acc: dict = {}
        run = new_run(solver)
        total = drive(run, steps, acc)
        out["profile_ms_per_step"] = {k: round(1e3 * v / steps, 3) for k, v in
                                      sorted(acc.items(), key=lambda kv: -kv[1])}
        out["profile_total_ms_per_step"] = round(1e3 * total / steps, 3)
    return out


# -- scaling: one count per fresh process ---------------------------------------------------

def status_kib(key: str) -> int:
    """A /proc/self/status entry in KiB (VmRSS: resident now; VmHWM: its peak)."""
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def reset_peak_rss() -> bool:
    """Set this process's VmHWM to its current VmRSS (Linux ≥ 4.0); False where refused."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def release_free_heap() -> None:
    """Give the C heap's free pages back to the system (glibc's malloc_trim), so that the
    run's allocations after it fault in new pages rather than reuse, unseen, pages that the
    warm-up (numba's compiler above all) freed but the process still holds resident."""
    import ctypes
    import ctypes.util
    try:
        ctypes.CDLL(ctypes.util.find_library("c")).malloc_trim(0)
    except (OSError, AttributeError):
        pass                                    # not glibc: the growth may read low


def held_array_bytes(*objects) -> int:
    """Bytes of the distinct numpy arrays the objects hold as attributes (one level down,
    lists and tuples of arrays included; views counted by their base)."""
    seen, total = set(), 0
    for obj in objects:
        for value in vars(obj).values():
            for a in value if isinstance(value, (list, tuple)) else (value,):
                if isinstance(a, np.ndarray):
                    base = a if a.base is None else a.base
                    if isinstance(base, np.ndarray) and id(base) not in seen:
                        seen.add(id(base))
                        total += base.nbytes
    return total


def scaling_point(n: int, steps: int, threads: int) -> dict:
    """(c) for one count, in this (fresh) process: warm-up on the small scene, then the
    peak resident memory of building and stepping the count's solver and one run, then
    its step time (median of 3)."""
    side = cells_per_side(n)
    small = MPMSolver.from_scene(scene_for(4 * WARM_UP_SIDE ** 2, threads))
    warm_up = first_call(small)
    del small
    gc.collect()
    release_free_heap()
    before_kib = status_kib("VmRSS")
    reset = reset_peak_rss()
    solver = MPMSolver.from_scene(scene_for(n, threads))
    run = new_run(solver)
    drive(run, MEMORY_STEPS)
    peak_kib = status_kib("VmHWM")
    held = held_array_bytes(solver, solver.parts, run)
    del run
    out = throughput(n, steps, 3, threads, False, solver=solver, warm_up=warm_up)
    growth = 1024 * (peak_kib - before_kib) if reset else None
    out.update({"cells_per_side": side, "rss_before_mib": before_kib / 1024,
                "peak_rss_mib": peak_kib / 1024, "peak_reset": reset,
                "peak_growth_bytes": growth,
                "bytes_per_particle": None if growth is None else growth / n,
                "held_array_bytes_per_particle": held / n})
    return out


def scaling_in_child(n: int, steps: int, threads: int) -> dict:
    cmd = [sys.executable, __file__, "--scaling-child", str(n), "--scaling-steps", str(steps),
           "--threads", str(threads)]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if p.returncode:
        return {"particles": n, "error": f"exit {p.returncode}: {p.stderr.strip()[-400:]}"}
    return json.loads(p.stdout.strip().splitlines()[-1])


# -- Taichi ----------------------------------------------------------------------------------

def taichi(n: int, steps: int, threads: int) -> dict | None:
    import importlib.util
    if importlib.util.find_spec("taichi") is None:       # (importing it prints a banner)
        log("taichi not installed: taichi figures are null")
        return {"error": "taichi not installed (pip install -e .[bench])"}
    cmd = [sys.executable, str(ROOT / "benchmarks" / "taichi_mlsmpm.py"), "--particles",
           str(n), "--steps", str(steps), "--threads", str(threads), "--json"]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode or not lines:
        return {"error": f"exit {p.returncode}: {p.stderr.strip()[-400:]}"}
    return json.loads(lines[-1])


def taichi_pairs(solver: MPMSolver, args) -> list[dict]:
    """``args.pairs`` alternated sets: (a)'s again on the warm ``solver`` (median of
    ``args.repeats``), then Taichi's in a subprocess, then Taichi's minimal step written in
    numba (``minimal_in_numba``); each set's ratios from its own measurements."""
    pairs = []
    n = int(solver.parts.x.size)
    for k in range(args.pairs):
        times, _ = timed_steps(solver, args.steps, args.repeats)
        ours = n * args.steps / statistics.median(times)
        log(f"pair {k + 1}: uqflow {ours:.3g} /s; taichi ...")
        tai = taichi(n, args.steps, args.threads)
        theirs = tai.get("particle_updates_per_s")
        if not theirs:          # not installed, or failed: the next pair would fail alike
            pairs.append({"uqflow_particle_updates_per_s": ours, "taichi": tai, "ratio": None})
            break
        same = minimal_in_numba(n, args.steps, args.repeats, args.threads)
        pairs.append({"uqflow_particle_updates_per_s": ours,
                      "uqflow_times_s": [round(t, 4) for t in times], "taichi": tai,
                      "ratio": ours / theirs, "numba_minimal": same,
                      "numba_minimal_ratio": same["particle_updates_per_s"] / theirs})
        log(f"  taichi {theirs:.3g} /s; the same step in numba "
            f"{same['particle_updates_per_s']:.3g} /s")
    return pairs


def minimal_in_numba(n: int, steps: int, repeats: int, threads: int) -> dict:
    """Taichi's minimal step in numba (``benchmarks/numba_mlsmpm.py``), in this process."""
    from benchmarks.numba_mlsmpm import measure
    return measure(n, steps, repeats, threads)


def median_pair(pairs: list[dict]) -> dict:
    """The set whose Taichi figure is the median (the lower middle one of an even count)."""
    ranked = sorted(pairs, key=lambda q: q["taichi"]["particle_updates_per_s"])
    return ranked[(len(ranked) - 1) // 2]


# -- seed-size runs --------------------------------------------------------------------------

SEED_CHILD = """
import json, resource, sys, time, tomllib
sys.path.insert(0, {root!r})
from solvers.mpm import MPMSolver
from uqflow.realization import compile_clock
small = tomllib.load(open({small!r}, "rb"))
small["resolution"] = 0.25
small["end_time"] = 2e-6
t0 = time.perf_counter()
with compile_clock() as compiled:
    MPMSolver.from_scene(small).run({{}})       # loads numba's cache (every kernel)
first_call = {{"first_call_s": time.perf_counter() - t0, "numba_compile_s": compiled.seconds}}
rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
scene = tomllib.load(open({path!r}, "rb"))
t0 = time.perf_counter()
solver = MPMSolver.from_scene(scene)
setup = time.perf_counter() - t0
t0 = time.perf_counter()
with compile_clock() as compiled:
    ds = solver.run({{}})
wall = time.perf_counter() - t0
def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024          # MiB
    return float("nan")
print(json.dumps({{"first_call": first_call, "run_numba_compile_s": compiled.seconds,
                   "setup_s": setup, "run_s": wall, "solver_wall_time_s": ds.attrs["wall_time"],
                   "steps": ds.attrs["steps"], "particles": ds.attrs["particles"],
                   "threads": ds.attrs["threads"], "end_time_s": float(ds.time[-1]),
                   "particle_updates_per_s": ds.attrs["particle_updates_per_second"],
                   "ru_maxrss_before_mib": rss_before / 1024,
                   "ru_maxrss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                   "peak_rss_mib": status("VmHWM"), "rss_end_mib": status("VmRSS")}}))
"""


def seed_run(name: str) -> dict:
    path = SCENES / f"{name}.toml"
    small = SCENES / f"{name}_small.toml"
    code = SEED_CHILD.format(root=str(ROOT), path=str(path), small=str(small))
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                       env={**os.environ, "NUMBA_NUM_THREADS": str(THREADS)})
    if p.returncode:
        return {"scene": name, "error": p.stderr.strip()[-600:]}
    r = json.loads(p.stdout.strip().splitlines()[-1])
    r["scene"] = name
    r["process_s"] = time.perf_counter() - t0
    return r


# -- figure ----------------------------------------------------------------------------------

def scaling_figure(sc: list[dict], tai: dict | None, path: Path) -> Path:
    """Step time (log-log, with a line of slope 1), particle-updates/s and bytes per
    particle against the count."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.array([s["particles"] for s in sc], float)
    t = np.array([s["step_s"] for s in sc]) * 1e3
    fig, (a, b, c) = plt.subplots(1, 3, figsize=(14, 4))
    a.loglog(n, t, "o-", label=f"uqflow mpm, full physics, {sc[0].get('threads', THREADS)} threads")
    a.loglog(n, t[-1] * n / n[-1], "k:", lw=1, label="linear in n")
    a.set_ylabel("wall time per step [ms]")
    b.semilogx(n, [s["particle_updates_per_s"] for s in sc], "o-", label="uqflow mpm")
    b.axhline(TARGET, color="r", ls="--", lw=1, label="target 1e7")
    if tai and "particle_updates_per_s" in tai:
        a.loglog([tai["particles"]], [tai["step_s"] * 1e3], "s", color="C2",
                 label="Taichi MLS-MPM fluid (CPU, f64)")
        b.semilogx([tai["particles"]], [tai["particle_updates_per_s"]], "s", color="C2",
                   label="Taichi MLS-MPM fluid")
    b.set_ylabel("particle-updates / s")
    with_memory = [s for s in sc if s.get("bytes_per_particle") is not None]
    c.semilogx([s["particles"] for s in with_memory],
               [s["bytes_per_particle"] for s in with_memory], "o-",
               label="peak resident growth / particle")
    c.semilogx([s["particles"] for s in with_memory],
               [s["held_array_bytes_per_particle"] for s in with_memory], "^--",
               label="numpy arrays of solver + run / particle")
    c.set_ylabel("bytes per particle")
    c.set_ylim(bottom=0)
    for ax in (a, b, c):
        ax.set_xlabel("particles")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# -- main ------------------------------------------------------------------------------------

SPIN_LIMIT = {"GOMP_SPINCOUNT": "10000"}


def contended(args, env: dict) -> dict:
    """(a) again in a subprocess while a busy loop holds one of the cores (the situation of a
    shared machine), with the extra environment ``env``. numba's threading layer here is GNU
    OpenMP, whose idle threads spin at every barrier (up to GOMP_SPINCOUNT iterations) before
    they sleep: with a core taken, a spinning thread can hold the core the other one needs."""
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        cmd = [sys.executable, __file__, "--particles", str(args.particles), "--steps",
               str(args.steps), "--repeats", "3", "--threads", str(args.threads),
               "--skip-scaling", "--skip-seed", "--no-taichi", "--no-variants", "--no-write",
               "--json", "--wait", "0", "--max-load", "1e9"]
        p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT,
                           env={**os.environ, **env})
    finally:
        hog.kill()
        hog.wait()
    if p.returncode:
        return {"error": p.stderr.strip()[-400:]}
    r = json.loads(p.stdout.strip().splitlines()[-1])
    return {"env": env, "particle_updates_per_s": r["particle_updates_per_s"],
            "step_ms": r["step_ms"], "repeat_times_s": r["repeat_times_s"],
            "first_call": r["first_call"]}


def loglog_slope(counts, step_times) -> float | None:
    """Least-squares slope of log(step time) against log(count); None below two counts."""
    if len(counts) < 2:
        return None
    return float(np.polyfit(np.log(counts), np.log(step_times), 1)[0])




def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--particles", type=int, default=160_000)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--pairs", type=int, default=3,
                   help="alternated sets of (b): uqflow, Taichi, the same in numba")
    p.add_argument("--scaling-counts", "--counts", dest="counts", type=int, nargs="+",
                   default=list(COUNTS), help="particle counts of (c), each 4 s² (s ≥ 24)")
    p.add_argument("--scaling-steps", type=int, default=20)
    p.add_argument("--scaling-child", type=int, help=argparse.SUPPRESS)
    p.add_argument("--max-load", type=float, default=1.5)
    p.add_argument("--wait", type=float, default=300.0, help="s to wait for the load to drop")
    p.add_argument("--skip-scaling", action="store_true")
    p.add_argument("--skip-seed", action="store_true")
    p.add_argument("--no-taichi", action="store_true")
    p.add_argument("--no-variants", action="store_true",
                   help="skip the 1-thread, spin-limited and contended variants of (a)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--no-write", action="store_true", help="do not touch BENCHMARKS.md")
    args = p.parse_args(argv)
    for n in args.counts + ([args.scaling_child] if args.scaling_child else []):
        try:
            cells_per_side(n)
        except ValueError as exc:
            p.error(f"--scaling-counts: {exc}")
    if args.scaling_child:
        print(json.dumps(scaling_point(args.scaling_child, args.scaling_steps, args.threads)))
        return 0

    waited = wait_for_load(args.max_load, args.wait)
    load_start = load1()
    log(f"load {load_start} (waited {waited:.0f} s); throughput at {args.particles} ...")
    solver = MPMSolver.from_scene(scene_for(args.particles, args.threads))
    main_r = throughput(args.particles, args.steps, args.repeats, args.threads, True, solver)
    log(f"  {main_r['step_s'] * 1e3:.2f} ms/step, {main_r['particle_updates_per_s']:.3g} /s; "
        f"profile {main_r['profile_ms_per_step']}")
    one = busy = busy_spin = None
    if not args.no_variants and args.threads != 1:
        one = throughput(args.particles, args.steps, 3, 1, False)
        log(f"  1 thread: {one['step_s'] * 1e3:.2f} ms/step, "
            f"{one['particle_updates_per_s']:.3g} /s")
        busy = contended(args, {})
        busy_spin = contended(args, SPIN_LIMIT)
        log(f"  one core taken: {busy}; with {SPIN_LIMIT}: {busy_spin}")
    load_mid = load1()
    pairs = [] if args.no_taichi else taichi_pairs(solver, args)
    measured_pairs = [q for q in pairs if q["ratio"] is not None]
    tai = pairs[0]["taichi"] if pairs else None
    tai_ups = ratio = None
    if measured_pairs:
        tai = median_pair(measured_pairs)["taichi"]
        tai_ups = statistics.median(q["taichi"]["particle_updates_per_s"] for q in measured_pairs)
        ratio = statistics.median(q["ratio"] for q in measured_pairs)
    log(f"  taichi: {tai_ups}, ratio {ratio}")
    sc = []
    if not args.skip_scaling:
        for n in sorted(set(args.counts)):
            if sc and ("error" in sc[-1] or max(sc[-1]["times_s"]) > SKIP_AFTER_S):
                log(f"  skip {n} and above: the last count failed or took > {SKIP_AFTER_S} s")
                break
            log(f"scaling {n:,} (fresh process) ...")
            r = scaling_in_child(n, args.scaling_steps, args.threads)
            r["load"] = load1()
            sc.append(r)
            log(f"  {r['error']}" if "error" in r else
                f"  {r['step_s'] * 1e3:.2f} ms/step ({r['particle_updates_per_s']:.3g} /s), "
                f"{r['bytes_per_particle']} B/particle, first call {r['first_call']}, "
                f"load {r['load']}")
    seeds = []
    if not args.skip_seed:
        for name in ("mpm_contact_thin", "mpm_contact_thick"):
            log(f"seed-size run {name} ...")
            seeds.append(seed_run(name))
            log(f"  {json.dumps(seeds[-1])[:300]}")
    load_end = load1()
    measured = [s for s in sc if "error" not in s]
    slope = loglog_slope([s["particles"] for s in measured], [s["step_s"] for s in measured])
    ups = main_r["particle_updates_per_s"]
    result = {
        "particle_updates_per_s": ups,
        "taichi_particle_updates_per_s": tai_ups,
        "ratio_to_taichi": ratio,
        "taichi_pairs": pairs,
        "target": TARGET, "meets_target": ups >= TARGET,
        "particles": main_r["particles"], "steps": args.steps, "threads": main_r["threads"],
        "step_ms": main_r["step_s"] * 1e3, "repeat_times_s": main_r["times_s"],
        "one_thread": None if one is None else {
            "particle_updates_per_s": one["particle_updates_per_s"],
            "step_ms": one["step_s"] * 1e3, "repeat_times_s": one["times_s"],
            "first_call": one["first_call"]},
        "one_core_taken": busy, "one_core_taken_spin_limited": busy_spin,
        "threading_layer": numba.threading_layer(),
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
        "gomp_spincount": os.environ.get("GOMP_SPINCOUNT"),
        "profile_ms_per_step": main_r["profile_ms_per_step"],
        "profile_total_ms_per_step": main_r["profile_total_ms_per_step"],
        "materials": main_r["materials"],
        "method": "solver._Run._step driven directly (CFL dt from max_speed), programmatic "
                  "thin-plate scene on a square half-domain, median of repeats after warm-up",
        "taichi": tai,
        "first_call": main_r["first_call"],
        "scaling": sc,
        "scaling_loglog_slope": slope,
        "scaling_slope_counts": [s["particles"] for s in measured] if slope is not None else [],
        "scaling_steps": args.scaling_steps,
        "seed_runs": seeds,
        "load_1min": {"start": load_start, "after_throughput": load_mid, "end": load_end},
        "numba_num_threads": numba.config.NUMBA_NUM_THREADS,
        "numba": numba.__version__,
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(json.dumps(result, indent=1))
    if args.no_write or args.skip_scaling or args.skip_seed:
        return 0
    fig = scaling_figure(measured, tai if tai_ups else None, FIGURES / "mpm_scaling.png")
    write_section("mpm-throughput", "MPM solver: throughput", section(result, fig))
    log("written: BENCHMARKS.md (mpm-throughput),", fig)
    return 0


def first_call_text(f: dict | None) -> str:
    return "n/a" if not f else f"{f['first_call_s']:.1f} ({f['numba_compile_s']:.1f})"


def scaling_row(s: dict) -> str:
    if "error" in s:
        return f"| {s['particles']:,} | failed: {s['error'][:200]} | | | | | | | |"
    growth = s["peak_growth_bytes"]
    memory = "n/a (peak not resettable) | n/a" if growth is None else \
        f"{growth / 2 ** 20:.1f} | {s['bytes_per_particle']:.0f}"
    return (f"| {s['particles']:,} | {s['cells_per_side']} | {1e3 * s['step_s']:.2f} | "
            f"{s['particle_updates_per_s']:.3g} | {first_call_text(s['first_call'])} | "
            f"{memory} | {s['held_array_bytes_per_particle']:.0f} | {s['load']:.2f} |")


def section(r: dict, fig: Path) -> str:
    tai = r["taichi"] or {}
    tai_ups = r["taichi_particle_updates_per_s"]
    prof = "\n".join(f"| {k} | {v:.2f} | {100 * v / r['profile_total_ms_per_step']:.0f} % |"
                     for k, v in r["profile_ms_per_step"].items())
    scal = "\n".join(scaling_row(s) for s in r["scaling"])
    seeds = "\n".join(
        f"| `{s['scene']}.toml` | {s.get('particles', '')} | {s.get('threads', '')} | "
        f"{s.get('steps', '')} | {s.get('run_s', float('nan')):.1f} | "
        f"{s.get('run_numba_compile_s', float('nan')):.1f} | "
        f"{s.get('particle_updates_per_s', float('nan')):.3g} | "
        f"{first_call_text(s['first_call'])} | "
        f"{s.get('peak_rss_mib', float('nan')):.0f} ({s.get('ru_maxrss_mib', float('nan')):.0f}) |"
        if "error" not in s else
        f"| `{s['scene']}.toml` | failed: {s['error'][:200]} | | | | | | | |"
        for s in r["seed_runs"])
    slope = r["scaling_loglog_slope"]
    slope_text = "not fitted (fewer than two counts measured)" if slope is None else \
        f"**{slope:.2f}** (counts {', '.join(f'{n:,}' for n in r['scaling_slope_counts'])})"
    if tai_ups:
        pairs = [q for q in r["taichi_pairs"] if q["ratio"] is not None]
        listed = "; ".join(f"{q['uqflow_particle_updates_per_s']:.3g} / "
                           f"{q['taichi']['particle_updates_per_s']:.3g} = {q['ratio']:.2f}"
                           for q in pairs)
        same = "; ".join(f"{q['numba_minimal']['particle_updates_per_s']:.3g} / "
                         f"{q['taichi']['particle_updates_per_s']:.3g} = "
                         f"{q['numba_minimal_ratio']:.2f}" for q in pairs)
        same_ratio = statistics.median(q["numba_minimal_ratio"] for q in pairs)
        tai_text = (f"**{tai_ups:.3g}** particle-updates/s, the median of {len(pairs)} "
                    f"alternated sets, each (a)'s measure again on the same warm solver, "
                    f"Taichi's in a subprocess, then the same minimal step written in numba "
                    f"(`benchmarks/numba_mlsmpm.py`: the same operations in the solver's "
                    f"kernel style; uqflow / Taichi per set: {listed}). "
                    f"Ratio uqflow / Taichi, the median of the sets' ratios: "
                    f"**{r['ratio_to_taichi']:.2f}**; the minimal step in numba / in Taichi: "
                    f"{same} — median **{same_ratio:.2f}**: what the language and the kernel "
                    f"style give on the same work. The median set's Taichi run: "
                    f"{1e3 * tai['step_s']:.2f} ms/step, {tai['particles']:,} particles, "
                    f"{tai['threads']} threads, Taichi {tai['taichi_version']}, compile "
                    f"{tai['compile_s']:.1f} s; repetitions "
                    f"{', '.join(f'{t:.3f}' for t in tai['times_s'])} s for "
                    f"{tai['steps']} steps.")
    else:
        tai_text = f"not measured (null): {tai.get('error', 'Taichi unavailable')}."
    verdict = "meets" if r["meets_target"] else "is **below**"
    o = r.get("one_thread")
    one_text = "" if not o else (
        f"The same on 1 thread (same run, median of 3): {o['particle_updates_per_s']:.3g} "
        f"particle-updates/s ({o['step_ms']:.2f} ms/step; first call "
        f"{first_call_text(o['first_call'])}); 2 threads / 1 thread = "
        f"{r['particle_updates_per_s'] / o['particle_updates_per_s']:.2f}.")
    busy, spin = r.get("one_core_taken") or {}, r.get("one_core_taken_spin_limited") or {}
    reading = ""
    if o and "particle_updates_per_s" in busy and "particle_updates_per_s" in spin:
        reading = f"""
**Shared cores.** The same configuration while a busy loop holds one of the 2 cores (the
situation of a shared machine; subprocesses, median of 3): {busy['step_ms']:.1f} ms/step
({busy['particle_updates_per_s']:.3g} particle-updates/s) with GNU OpenMP's default spinning,
{spin['step_ms']:.1f} ms/step ({spin['particle_updates_per_s']:.3g}) with
`GOMP_SPINCOUNT=10000`, against {o['step_ms']:.1f} ms/step on 1 thread of a free machine
(first calls in those subprocesses, apart: {first_call_text(busy.get('first_call'))} and
{first_call_text(spin.get('first_call'))} s).
numba's threading layer here is GNU OpenMP, whose idle threads spin at every barrier before
they sleep; with a core taken a spinning thread holds the core its partner needs. On a machine
shared with other jobs, run 2-thread scenes with `GOMP_SPINCOUNT=10000` in the environment
(or `threads = 1`, the scenes' default, and one realization per core).
"""
    return f"""{reading}
Load average (1 min) at the start {r['load_1min']['start']:.2f}, after (a)
{r['load_1min']['after_throughput']:.2f}, at the end {r['load_1min']['end']:.2f} (2 shared
cores; anything above ≈ 0.1 is other jobs competing with the 2 benchmark threads). numba
{r['numba']}, NUMBA_NUM_THREADS = {r['numba_num_threads']}, threading layer
`{r['threading_layer']}`, OMP_WAIT_POLICY {r['omp_wait_policy'] or 'unset'}, GOMP_SPINCOUNT
{r['gomp_spincount'] or 'unset'}.

**(a) Full physics, {r['particles']:,} particles, {r['threads']} threads:
{r['particle_updates_per_s']:.3g} particle-updates/s** ({r['step_ms']:.2f} ms/step; median
of the repetitions {', '.join(f'{t:.3f}' for t in r['repeat_times_s'])} s for {r['steps']}
steps) — {verdict} the target of {r['target']:.1e}. {one_text} Scene: the thin-plate seed scene
(charge, 0.02 m steel plate, water) on a square half-domain, dx = 5 mm, 2 × 2 particles per
cell, quadratic B-splines, MUSL, f64; particles per material {r['materials']}. Timed: the
solver's own step `_Run._step` with the CFL reduction, driven directly for {r['steps']} steps
from t = 0 on a fresh state per repetition (no probe recording), after a warm-up. Compile
(first call: the first run's set-up and first step, every kernel compiled by numba or loaded
from its cache; numba's compile seconds in brackets, 0 = all from the cache):
{first_call_text(r['first_call'])}, apart from the run times above.

**(b) Taichi MLS-MPM reference** (`benchmarks/taichi_mlsmpm.py`: weakly compressible fluid,
APIC, quadratic B-splines, 3 × 3 stencil, f64, CPU backend, `cpu_max_num_threads` =
{r['threads']}; one P2G, one grid update, one G2P): {tai_text} The Taichi step is one
atomic scatter and one gather with a one-line equation of state; ours is two scatters, two
grid solves, two gathers (MUSL), the CFL reduction, bulk viscosity, the material models (JWL
programmed burn, Johnson–Cook plasticity, Mie–Grüneisen water), the state check and the
guards — so the ratio is a side-by-side figure, not a like-for-like one.

Per-kernel time of one extra repetition of (a) ({r['profile_total_ms_per_step']:.2f} ms/step
including the timers):

| kernel | ms/step | share |
|---|---:|---:|
{prof}

**(c) Scaling** (same scene family: s × s cells, exactly 4 s² particles; {r['threads']}
threads; each count in a fresh process; median of 3 × {r['scaling_steps']} steps; a count
is skipped once one measurement took more than {SKIP_AFTER_S:.0f} s). First call: the
process's warm-up on the 30 × 30-cell scene (numba compiling, or loading its cache; numba's
compile seconds in brackets), apart from the step times. Memory: the peak resident memory
(VmHWM) of the process while it builds the count's solver and one run and takes
{MEMORY_STEPS} steps, less its resident memory just before (the warm-up's arrays freed, the
C heap's free pages returned with malloc_trim, the peak reset), per particle; beside it the
bytes of the numpy arrays the solver and the run hold (the rest: Python objects, numba's
and OpenMP's own allocations, allocator slack):

| particles | cells a side | ms/step | particle-updates/s | first call [s] | peak growth [MiB] | bytes/particle | arrays [B/particle] | load (1 min) |
|---:|---:|---:|---:|---:|---:|---:|---:|---:|
{scal}

Least-squares slope of log(step time) against log(particles): {slope_text}.

![mpm scaling](docs/figures/{fig.name})

**(d) Seed-size runs to 100 µs** (the scenes as they are: 400 × 200 cells, 320,000 particles,
`threads` = 1, their default; one run each in a fresh subprocess after a small warm-up run;
peak RSS = VmHWM of that process, /proc/self/status; `resource.getrusage` ru_maxrss in
brackets — on Linux it starts at the parent's RSS at fork, so it only bounds the peak from
above). Compile is apart: each process's warm-up run (first call [s], numba's compile
seconds in brackets) comes before the timed run, whose own numba compile seconds are listed.
The seed's authors' code took about 130 s per run on a 3.3 GHz PC (as the design notes report):

| scene | particles | threads | steps | run wall [s] | compile in run [s] | particle-updates/s | first call [s] | peak RSS [MiB] |
|---|---:|---:|---:|---:|---:|---:|---:|---:|
{seeds}
"""


if __name__ == "__main__":
    sys.exit(main())
