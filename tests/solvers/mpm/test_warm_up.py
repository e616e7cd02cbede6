"""The MPM solver's warm-up (``MPMSolver.warm_up``, ``compile_shares``; uqflow/warm_up.py):
its shares together hold every kernel a run calls, and it reads numba's cache to know whether
anything needs compiling (issue 19)."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

from solvers.mpm import MPMSolver

ROOT = Path(__file__).resolve().parents[3]
SCENE = ROOT / "studies" / "scenes" / "mpm_contact_thin_small.toml"

# In a fresh process: warm both shares, then run, and count the machine code numba adds
# (compiled or loaded from its cache) during the run: none if the shares held every kernel.
SHARES_THEN_RUN = f"""
import gc, tomllib
from numba.core.dispatcher import Dispatcher
from solvers.mpm import MPMSolver

scene = tomllib.loads(open({str(SCENE)!r}).read())
scene.update(end_time=2e-6, resolution=0.5)
solver = MPMSolver.from_scene(scene)
solver.warm_up(0, 2)
solver.warm_up(1, 2)

def overloads():
    return {{id(d): len(d.overloads) for d in gc.get_objects() if isinstance(d, Dispatcher)}}

before = overloads()
solver.run({{}})
after = overloads()
print(sum(n - before.get(k, 0) for k, n in after.items()))
"""


def _python(code, **env):
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         timeout=600, env=dict(os.environ, **env))
    assert out.returncode == 0, out.stderr
    return out.stdout.strip().splitlines()[-1]


def test_the_shares_hold_every_kernel_a_run_calls():
    assert _python(SHARES_THEN_RUN) == "0"


def test_compile_shares_reads_numbas_cache(tmp_path):
    scene = tomllib.loads(SCENE.read_text())
    scene.update(end_time=2e-6, resolution=0.5)
    solver = MPMSolver.from_scene(scene)
    solver.run({})                         # compiled or loaded, and on disk
    assert solver.compile_shares() == 0
    # an empty cache folder: the grid kernels and the loops of TNT, steel and water
    count = ("import tomllib; from solvers.mpm import MPMSolver; "
             f"s = tomllib.loads(open({str(SCENE)!r}).read()); s.update(resolution=0.5); "
             "print(MPMSolver.from_scene(s).compile_shares())")
    assert _python(count, NUMBA_CACHE_DIR=str(tmp_path)) == "4"
