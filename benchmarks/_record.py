"""Write a benchmark's figures into its own section of BENCHMARKS.md.

Each benchmark owns the text between ``<!-- begin NAME -->`` and ``<!-- end NAME -->``, so
benchmarks can be rerun one at a time without touching the others' figures.
"""

from __future__ import annotations

import os
import platform
import re
import shlex
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS_MD = ROOT / "BENCHMARKS.md"
FIGURES = ROOT / "docs" / "figures"


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores, {cpu}, Python {platform.python_version()}"


def command() -> str:
    return "python " + " ".join(shlex.quote(a) for a in [os.path.relpath(sys.argv[0], ROOT),
                                                          *sys.argv[1:]])


def write_section(name: str, title: str, body: str) -> None:
    """Replace (or append) the section ``name`` of BENCHMARKS.md."""
    text = BENCHMARKS_MD.read_text() if BENCHMARKS_MD.exists() else "# Benchmarks\n\n" \
        "Figures measured by the scripts in `benchmarks/`; each section says how to redo it.\n"
    block = (f"<!-- begin {name} -->\n## {title}\n\n"
             f"Command: `{command()}`  \nMachine: {machine()}\n\n{body.strip()}\n"
             f"<!-- end {name} -->")
    pattern = re.compile(rf"<!-- begin {re.escape(name)} -->.*?<!-- end {re.escape(name)} -->",
                         re.S)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else \
        text.rstrip() + "\n\n" + block + "\n"
    BENCHMARKS_MD.write_text(text)


def log(*parts) -> None:
    """Progress on stderr (stdout carries a benchmark's JSON)."""
    print(*parts, file=sys.stderr, flush=True)


def load1() -> float:
    """The 1-minute load average, as recorded beside a benchmark's figures."""
    return round(os.getloadavg()[0], 2)


def wait_for_load(max_load: float, wait_s: float) -> float:
    """Wait (up to ``wait_s``) for the load average to drop below ``max_load``: the machine
    is shared. Returns the seconds waited."""
    t0 = time.time()
    while load1() >= max_load and time.time() - t0 < wait_s:
        log(f"load {load1():.2f} >= {max_load}: waiting ...")
        time.sleep(15)
    return time.time() - t0
