"""The MPM kernels' numba cache sees a change of any package module they import
(solvers/mpm/kernel_cache.py, docs/mpm.md "Kernel cache")."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from solvers.mpm import kernel_cache, step
from solvers.mpm.materials import johnson_cook

ROOT = Path(__file__).resolve().parents[3]
MPM = ROOT / "solvers" / "mpm"

KERNEL = """from numba import njit

from cachedemo.dep import VALUE


@njit(cache=True)
def value():
    return VALUE
"""
RUN = ("from solvers.mpm import kernel_cache; import cachedemo; "
       "kernel_cache.register(cachedemo.__path__[0], 'cachedemo'); "
       "from cachedemo.kern import value; print(value())")


def test_step_depends_on_every_material_module_and_nothing_else_of_the_package():
    deps = {str(p.relative_to(MPM)) for p in kernel_cache.dependencies(MPM / "step.py")}
    materials = {"elastic", "johnson_cook", "jwl", "water", "mie_gruneisen", "state",
                 "parameters"}
    assert deps == {"step.py", "shapes.py"} | {f"materials/{m}.py" for m in materials}


def test_the_mpm_kernels_are_stamped_with_their_dependencies():
    for kernel in (step.p2g, step.loop_for(johnson_cook)[0], johnson_cook.advance,
                   step.SERIAL.p2g, step.loop_for(johnson_cook, parallel=False)[0]):
        locator = kernel._cache._impl.locator
        assert isinstance(locator, kernel_cache.DependencyLocator)
        assert locator.get_source_stamp()[1] == kernel_cache.dependency_digest(
            kernel.py_func.__code__.co_filename)


def test_serial_twins_keep_their_own_cache_entries():
    # numba keys a cache index on the function's name, not on `parallel`: a twin sharing
    # its kernel's index would load the parfors machine code (or the kernel the serial one)
    pairs = [(getattr(step.PARALLEL, name), getattr(step.SERIAL, name))
             for name in vars(step.PARALLEL)]
    pairs.append((step.loop_for(johnson_cook)[0], step.loop_for(johnson_cook, False)[0]))
    for parallel, serial in pairs:
        assert parallel.targetoptions.get("parallel") and not serial.targetoptions.get("parallel")
        assert serial._cache._cache_file._index_name != parallel._cache._cache_file._index_name


def _value(folder):
    """(value printed, whether numba loaded it from the cache) of a fresh process."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(folder), str(ROOT)]),
               NUMBA_DEBUG_CACHE="1")
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", RUN], env=env, capture_output=True,
                         text=True, timeout=300, check=True).stdout
    return float(out.strip().splitlines()[-1]), "data loaded" in out


def test_a_changed_dependency_is_not_served_from_the_cache(tmp_path):
    package = tmp_path / "cachedemo"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "kern.py").write_text(KERNEL)
    (package / "dep.py").write_text("VALUE = 1.0\n")
    assert _value(tmp_path) == (1.0, False)       # compiled, saved
    assert _value(tmp_path) == (1.0, True)        # unchanged: the cache is reused
    (package / "dep.py").write_text("VALUE = 2.0\n")
    assert _value(tmp_path) == (2.0, False)       # only the dependency changed: recompiled
    assert _value(tmp_path) == (2.0, True)
