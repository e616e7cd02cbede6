"""UM-Bridge: what serving costs. Seconds per evaluation over HTTP (``uqflow serve`` in a
subprocess, called by the umbridge package's client) against the same solver's ``run`` in this
process, for a trivial model (the analytic Ishigami function) and for an MPM run (the
quickstart's scene); and evaluations per second with 1, 2 and 4 clients calling at once a
server of 2 workers, for the trivial model and for the same with a 20 ms sleep per run (the
analytic solver's ``delay``: a model whose runs, not the server, take the time).

    python benchmarks/umbridge_overhead.py            # writes BENCHMARKS.md section "umbridge"
    python benchmarks/umbridge_overhead.py --quick    (tests/test_benchmarks_smoke.py)
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import ROOT, load1, log, write_section  # noqa: E402

from uqflow.study import load_study  # noqa: E402

TRIVIAL = ROOT / "studies" / "ishigami_mc.toml"
MPM = ROOT / "studies" / "quickstart.toml"
CLIENTS = (1, 2, 4)
SLOW_DELAY = 0.02            # s a run: the model, not the server, takes the time


class Served:
    """``uqflow serve STUDY --port 0 --workers N`` in a subprocess and a client of it."""

    def __init__(self, study: Path, workers: int, *options: str):
        import umbridge

        self.process = subprocess.Popen(
            [sys.executable, "-c", "import sys; from uqflow.cli import main; "
             "sys.exit(main(sys.argv[1:]))", "serve", str(study), "--port", "0",
             "--workers", str(workers), *options], stdout=subprocess.PIPE, text=True)
        line = self.process.stdout.readline()
        self.url = line.split(" on ")[1].split()[0]
        self.name = load_study(study).name
        self.client = lambda: umbridge.HTTPModel(self.url, self.name)

    def close(self):
        self.process.terminate()
        self.process.wait()


def per_evaluation(f, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return times


def overhead(study_path: Path, repeats: int, warm: int, served: Served | None = None) -> dict:
    """Median seconds per evaluation in process and over HTTP, the same point each time (on
    ``served``, else on a server of 1 worker of its own)."""
    study = load_study(study_path)
    nominal = study.solver.nominal()
    point = [nominal[name] for name in study.space.names]
    params = dict(zip(study.space.names, point))
    for _ in range(warm):                                  # numba's kernels, caches
        study.solver.run(params)
    local = per_evaluation(lambda: study.solver.run(params), repeats)
    own = served is None
    served = Served(study_path, 1) if own else served
    try:
        model = served.client()
        for _ in range(warm):                              # the worker's first run
            model([point])
        remote = per_evaluation(lambda: model([point]), repeats)
    finally:
        if own:
            served.close()
    return {"in_process": statistics.median(local), "http": statistics.median(remote),
            "repeats": repeats}


def throughput(evaluations: int, repeats: int, delay: float = 0.0,
               served: Served | None = None) -> dict:
    """Evaluations per second of the Ishigami model sleeping ``delay`` s a run, k clients at
    once on 2 workers (median of ``repeats``; on ``served`` if given)."""
    own = served is None
    served = Served(TRIVIAL, 2, "--set", f"scene.delay={delay!r}") if own else served
    out = {}
    try:
        model = served.client()
        model([[0.1, 0.2, 0.3]])
        for k in CLIENTS:
            rates = []
            for _ in range(repeats):
                clients = [served.client() for _ in range(k)]

                def call(m):
                    for i in range(evaluations):
                        m([[0.1, 0.2, 0.001 * i]])

                threads = [threading.Thread(target=call, args=(m,)) for m in clients]
                t0 = time.perf_counter()
                for t in threads:
                    t.start()
                for t in threads:
                    t.join()
                rates.append(k * evaluations / (time.perf_counter() - t0))
            out[k] = statistics.median(rates)
            log(f"delay {delay}: {k} clients: {out[k]:.1f} evaluations/s")
    finally:
        if own:
            served.close()
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=200, help="trivial evaluations timed")
    ap.add_argument("--mpm-repeats", type=int, default=5)
    ap.add_argument("--throughput-evaluations", type=int, default=200)
    ap.add_argument("--slow-evaluations", type=int, default=40)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:                  # one server for both parts: the code paths, not figures
        served = Served(TRIVIAL, 2)
        try:
            return {"trivial": overhead(TRIVIAL, 5, 1, served),
                    "throughput": throughput(5, 1, served=served)}
        finally:
            served.close()
    trivial = overhead(TRIVIAL, args.repeats, warm=3)
    log("trivial", trivial)
    mpm = overhead(MPM, args.mpm_repeats, warm=1)
    log("mpm", mpm)
    rates = throughput(args.throughput_evaluations, 3)
    slow = throughput(args.slow_evaluations, 3, delay=SLOW_DELAY)
    body = (f"Seconds per evaluation, median of the repeats; the server `uqflow serve STUDY "
            f"--workers 1` in a subprocess on 127.0.0.1, the umbridge package's HTTPModel "
            f"calling it; in process: the study's solver's `run` at the same point. 1-minute "
            f"load average {load1():.2f} at the end.\n\n"
            "| model | in process | over HTTP | overhead per evaluation | HTTP / in process |\n"
            "|---|---|---|---|---|\n")
    for label, m in (("Ishigami (`studies/ishigami_mc.toml`), "
                      f"{trivial['repeats']} evaluations", trivial),
                     (f"MPM quickstart scene (`studies/quickstart.toml`), {mpm['repeats']} "
                      "runs", mpm)):
        body += (f"| {label} | {m['in_process'] * 1e3:.3f} ms | {m['http'] * 1e3:.3f} ms | "
                 f"{(m['http'] - m['in_process']) * 1e3:.3f} ms | "
                 f"{m['http'] / m['in_process']:.3g} |\n")
    body += ("\nEvaluations per second on a server of 2 workers (`--workers 2`), k clients "
             "calling at once, median of 3:\n\n"
             "| model | " + " | ".join(f"{k} client{'s' if k > 1 else ''}" for k in CLIENTS)
             + " |\n|---|" + "---|" * len(CLIENTS) + "\n"
             f"| Ishigami, {args.throughput_evaluations} evaluations per client | "
             + " | ".join(f"{rates[k]:.0f}" for k in CLIENTS) + " |\n"
             f"| Ishigami sleeping {SLOW_DELAY * 1e3:.0f} ms a run (`--set scene.delay="
             f"{SLOW_DELAY}`), {args.slow_evaluations} per client | "
             + " | ".join(f"{slow[k]:.1f}" for k in CLIENTS) + " |\n")
    write_section("umbridge", "UM-Bridge: serving overhead and throughput", body)
    return {"trivial": trivial, "mpm": mpm, "throughput": rates, "slow": slow}


if __name__ == "__main__":
    main()
