"""How long the README's first command takes on this machine: `uqflow run
studies/quickstart.toml`, from a cold numba cache (what a newcomer meets) and a warm one.

Each repeat runs the CLI in a fresh process with ``NUMBA_CACHE_DIR`` pointing at a new empty
folder (cold: every kernel compiles) or at one folder reused
(warm), writing the result into a temporary folder. Medians of ``--repeats`` runs; the warm
runs follow the cold ones, so the two are measured under the same load.

    python benchmarks/quickstart_time.py [--repeats 3]
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import ROOT, write_section  # noqa: E402

STUDY = ROOT / "studies" / "quickstart.toml"


def one_run(cache: Path, out: Path) -> float:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "uqflow.cli", "run", str(STUDY), "--quiet", "--force",
                    "-o", str(out)], env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    cold, warm = [], []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for k in range(args.repeats):
            cold.append(one_run(tmp / f"cold{k}", tmp / f"cold{k}.nc"))
            print(f"cold {k}: {cold[-1]:.1f} s", flush=True)
        for k in range(args.repeats):
            warm.append(one_run(tmp / "cold0", tmp / f"warm{k}.nc"))
            print(f"warm {k}: {warm[-1]:.1f} s", flush=True)
    body = (f"`uqflow run studies/quickstart.toml` (9 MPM runs of 8,400 particles in-process "
            f"as the study says, figures and the comparison report included), wall time of the whole "
            f"command in a fresh process, median of {args.repeats}:\n\n"
            f"| numba cache | median | runs |\n|---|---|---|\n"
            f"| cold (empty `NUMBA_CACHE_DIR`) | {statistics.median(cold):.1f} s | "
            f"{', '.join(f'{t:.1f}' for t in cold)} s |\n"
            f"| warm | {statistics.median(warm):.1f} s | "
            f"{', '.join(f'{t:.1f}' for t in warm)} s |\n")
    write_section("quickstart-time", "Quickstart", body)
    print(body)


if __name__ == "__main__":
    main()
