"""Numba's on-disk cache of the MPM kernels, made to see a change of any module they use.

Numba (``cache=True``) stamps a function's cache index with the hash of the function's own
source file only: a kernel in ``step.py`` that inlines ``johnson_cook.advance`` keeps the old
machine code after ``johnson_cook.py`` (or ``state.N_STATE``) changes. ``DependencyLocator``
fixes that for the files of a registered package: it wraps the locator numba would have used
(same cache folder, so ``NUMBA_CACHE_DIR`` still applies) and adds to the source stamp a
SHA-256 of the source of every module of the package that the file imports, directly or
through the modules it imports (read from their ``import`` statements). A changed dependency
changes the stamp, numba finds the index stale and compiles afresh (docs/mpm.md, "Kernel
cache").

``register`` must run before the kernel modules are imported: the locator is chosen when
``@njit(cache=True)`` decorates. Importing this module registers ``solvers/mpm`` (done first
by ``solvers/mpm/__init__.py``).
"""

from __future__ import annotations

import ast
import functools
import hashlib
from pathlib import Path

from numba.core import caching

_PACKAGES: dict[Path, str] = {}      # registered package folder → its dotted name


def register(folder, package: str) -> None:
    """Stamp the cache of every cached function defined under ``folder`` (the package
    ``package``) with the source of the package modules it depends on."""
    _PACKAGES[Path(folder).resolve()] = package
    if DependencyLocator not in caching.CacheImpl._locator_classes:
        caching.CacheImpl._locator_classes.insert(0, DependencyLocator)


def _package_of(path: Path):
    """(folder, dotted name) of the registered package holding ``path``, or None."""
    for folder, package in _PACKAGES.items():
        if path.is_relative_to(folder):
            return folder, package
    return None


def _module_file(folder: Path, package: str, name: str) -> Path | None:
    """The source file of module ``name`` when it lies in the package, else None."""
    if name != package and not name.startswith(package + "."):
        return None
    base = folder.joinpath(*name.split(".")[len(package.split(".")):])
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imported_files(path: Path, folder: Path, package: str) -> set[Path]:
    """Package modules ``path`` names in its import statements (``from p import m`` names
    the module p.m when it exists, else p)."""
    module = [package, *path.relative_to(folder).with_suffix("").parts]
    own_package = module[:-1]       # a module's package; for __init__.py, the package itself
    found = set()
    for node in ast.walk(ast.parse(path.read_bytes(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module.split(".") if node.module else []
            if node.level:
                base = own_package[:len(own_package) - node.level + 1] + base
            names = [".".join(base + [alias.name]) for alias in node.names]
            names = [n if _module_file(folder, package, n) else ".".join(base) for n in names]
        else:
            continue
        found.update(f for n in names if (f := _module_file(folder, package, n)) is not None)
    return found


def dependencies(path) -> list[Path]:
    """``path`` and every module of its registered package it imports, transitively, sorted."""
    path = Path(path).resolve()
    folder, package = _package_of(path)
    seen, pending = {path}, [path]
    while pending:
        for f in _imported_files(pending.pop(), folder, package) - seen:
            seen.add(f)
            pending.append(f)
    return sorted(seen)


@functools.lru_cache(maxsize=None)
def dependency_digest(path) -> str:
    """SHA-256 over the relative names and bytes of ``dependencies(path)`` (once per file
    and process, as numba reads a stamp once per function)."""
    folder, _ = _package_of(Path(path).resolve())
    digest = hashlib.sha256()
    for f in dependencies(path):
        digest.update(str(f.relative_to(folder)).encode() + b"\0" + f.read_bytes() + b"\0")
    return digest.hexdigest()


class DependencyLocator(caching._CacheLocator):
    """The locator numba would choose for a file of a registered package, with the digest
    of the file's package dependencies added to its source stamp."""

    def __init__(self, inner, py_file):
        self._inner = inner
        self._digest = dependency_digest(py_file)

    def ensure_cache_path(self):
        self._inner.ensure_cache_path()

    def get_cache_path(self):
        return self._inner.get_cache_path()

    def get_source_stamp(self):
        return self._inner.get_source_stamp(), self._digest

    def get_disambiguator(self):
        return self._inner.get_disambiguator()

    @classmethod
    def from_function(cls, py_func, py_file):
        if _package_of(Path(py_file).resolve()) is None:
            return None
        for other in caching.CacheImpl._locator_classes:
            if other is not cls and (inner := other.from_function(py_func, py_file)):
                return cls(inner, py_file)
        return None


def is_cached(dispatcher) -> bool:
    """Whether numba's on-disk cache holds fresh machine code of ``dispatcher`` for this CPU
    (any signature): the index is read as numba reads it (stale stamp: empty), and a key
    names the CPU it was compiled for. An unreadable cache counts as cached: the check only
    decides whether to compile ahead of the first run, never what runs."""
    try:
        overloads = dispatcher._cache._cache_file._load_index()
        magic = dispatcher.targetctx.codegen().magic_tuple()
        return any(key[1] == magic for key in overloads)
    except Exception:   # noqa: BLE001 - numba's private cache API changed: assume cached
        return True


register(Path(__file__).resolve().parent, "solvers.mpm")
