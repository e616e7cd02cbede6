"""How long the README's first command takes on this machine: `uqflow run
studies/quickstart.toml`, from a cold numba cache (what a newcomer meets) and a warm one, with
the compile time apart; and the same study on 1 and 2 dask workers from a cold cache (does a
second worker compile the kernels again, or its share of them?).

Each repeat runs the CLI in a fresh process with ``NUMBA_CACHE_DIR`` pointing at a new empty
folder (cold: every kernel compiles) or at one folder reused (warm), writing the result into
a temporary folder. Reported per run, from the result file: the command's wall time, the
warm-up before the runs (uqflow/warm_up.py: its wall time, numba's compile seconds summed
over its processes, and how many processes shared it), and the runs' own compile time. The
repeats alternate cold and warm, so both meet the same load; medians of ``--repeats``, and
the cold/warm ratio of each pair.

    python benchmarks/quickstart_time.py [--repeats 3] [--skip-workers]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import ROOT, write_section  # noqa: E402

STUDY = ROOT / "studies" / "quickstart.toml"


def one_run(cache: Path, out: Path, workers: int = 0) -> dict:
    """Wall time of ``uqflow run`` and the cost its result records."""
    import uqflow

    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "uqflow.cli", "run", str(STUDY), "--quiet", "--force",
                    "--workers", str(workers), "-o", str(out)], env=env, check=True,
                   stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    tree = uqflow.open_result(out)
    attrs, runs = tree.attrs, tree["runs"].to_dataset()
    return {"wall": wall, "warm_up": float(attrs.get("warm_up_time", 0.0)),
            "warm_up_compile": float(attrs.get("warm_up_compile_time", 0.0)),
            "processes": int(attrs.get("warm_up_processes", 0)),
            "runs_compile": float(np.nansum(runs["compile_time"].values)),
            "runs_wall": float(np.nansum(runs["wall_time"].values))}


def _row(label, results):
    med = {k: statistics.median(r[k] for r in results) for k in results[0]}
    each = ", ".join(f"{r['wall']:.1f}" for r in results)
    return (f"| {label} | {med['wall']:.1f} s | {med['warm_up']:.1f} s on "
            f"{med['processes']:.0f} | {med['warm_up_compile']:.1f} s | "
            f"{med['runs_compile']:.1f} s | {med['runs_wall']:.1f} s | "
            f"{each} s |\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-workers", action="store_true",
                        help="only the in-process cold and warm runs")
    args = parser.parse_args()
    cold, warm, on_workers = [], [], {1: [], 2: []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        warm_cache = tmp / "warm"
        one_run(warm_cache, tmp / "fill.nc")           # fills the warm cache
        for k in range(args.repeats):
            cold.append(one_run(tmp / f"cold{k}", tmp / f"cold{k}.nc"))
            warm.append(one_run(warm_cache, tmp / f"warm{k}.nc"))
            print(f"pair {k}: cold {cold[-1]['wall']:.1f} s, warm {warm[-1]['wall']:.1f} s",
                  flush=True)
            if not args.skip_workers:
                for n in (1, 2):
                    on_workers[n].append(one_run(tmp / f"w{n}-{k}", tmp / f"w{n}-{k}.nc", n))
                    print(f"  {n} worker(s), cold: {on_workers[n][-1]}", flush=True)
    ratios = [c["wall"] / w["wall"] for c, w in zip(cold, warm)]
    cpu = next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo")
                if line.startswith("model name")), "?")
    head = ("| run | wall | warm-up (wall, processes) | its numba compile | runs' compile "
            "| runs' wall (sum) | each |\n|---|---|---|---|---|---|---|\n")
    body = (f"`uqflow run studies/quickstart.toml` (9 MPM runs of 8,400 particles in-process as "
            f"the study says, figures and the comparison report included), wall time of the "
            f"whole command in a fresh process, median of {args.repeats} (cold and warm "
            f"alternated; {os.cpu_count()} cores, {cpu}):\n\n" + head
            + _row("cold (empty `NUMBA_CACHE_DIR`)", cold) + _row("warm", warm)
            + f"\ncold / warm of each pair: {', '.join(f'{r:.2f}' for r in ratios)} "
            f"(median {statistics.median(ratios):.2f}).\n")
    if not args.skip_workers:
        body += ("\nThe same study from a cold cache on dask workers (`--workers N`; cluster "
                 "start included in the wall time):\n\n" + head
                 + _row("1 worker, cold", on_workers[1]) + _row("2 workers, cold", on_workers[2]))
    write_section("quickstart-time", "Quickstart", body)
    print(body)


if __name__ == "__main__":
    main()
