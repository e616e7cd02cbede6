"""Digests of the statistics every shipped study gives at CI size, to show a redesign keeps them
bit for bit (issue 17).

    PYTHONPATH=<checkout> python tools/shipped_statistics.py OUT.json [--checkout DIR]

runs each study of ``<checkout>/studies`` shrunk exactly as ``tests/test_shipped_studies.py``
shrinks it (its ``shrunk``), through the CLI in this process, and writes per study the SHA-256
of every statistics variable's bytes (values, dims, dtype) with the machine and library versions
it was recorded on. Run it at the revision before a change (in a ``git worktree``) and compare
with what the current code gives: ``tests/test_shipped_studies.py`` does, against
``tests/data/shipped_statistics.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np


def variable_digest(values: np.ndarray, dims: tuple) -> str:
    values = np.ascontiguousarray(values)
    h = hashlib.sha256()
    h.update(repr((tuple(dims), values.shape, values.dtype.str)).encode())
    if values.dtype.kind in "OUS":
        h.update("\x00".join(map(str, values.ravel())).encode())
    else:
        h.update(values.tobytes())
    return h.hexdigest()


def statistics_digests(path: Path) -> dict[str, str]:
    import xarray as xr

    with xr.open_datatree(path) as tree:
        stats = tree["statistics"].to_dataset().load()
    return {str(name): variable_digest(stats[name].values, stats[name].dims)
            for name in sorted(map(str, stats.variables))}


def machine() -> dict[str, str]:
    import importlib.metadata as md

    cpu = platform.processor()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in
                   Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    versions = {p: md.version(p) for p in ("numpy", "scipy", "numba", "chaospy", "SALib",
                                            "xarray")}
    # the SIMD loops numpy dispatches to here: another set rounds some results differently
    from numpy._core._multiarray_umath import __cpu_features__ as features
    simd = " ".join(sorted(k for k, on in features.items() if on))
    return {"cpu": cpu, "python": platform.python_version(), "numpy_simd": simd, **versions}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--checkout", type=Path, default=Path(__file__).resolve().parent.parent)
    args = parser.parse_args(argv)
    checkout = args.checkout.resolve()
    sys.path.insert(0, str(checkout))
    from tests.test_shipped_studies import FILES, IDS, expected_exit, shrunk
    from uqflow.cli import main as cli

    studies = {}
    for path, name in zip(FILES, IDS):
        if expected_exit(path) != 0:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            code = cli(["run", str(shrunk(path, Path(tmp))), "--quiet", "--no-figures"])
            if code != 0:
                raise SystemExit(f"{name}: exit {code}")
            studies[name] = statistics_digests(Path(tmp) / f"{path.stem}.nc")
        print(name, len(studies[name]), "variables", flush=True)
    args.out.write_text(json.dumps({"machine": machine(), "studies": studies}, indent=1,
                                   sort_keys=True) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
