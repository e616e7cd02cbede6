"""The result file: one netCDF4 file per study, read back as an ``xarray.DataTree``.

Groups ``runs`` (one row per realization) and ``statistics`` (the method's analysis), root
attributes for provenance. Every write goes to a temporary file in the same folder that is
then renamed over the result, so a killed study leaves the last complete checkpoint behind;
a write that fails removes its temporary file and leaves that checkpoint alone. The root
attribute ``runs_sha256`` is a checksum of the stored runs, verified before a resume trusts
them.

One run at a time writes a result: from its first write to its last it holds a lock file
beside it (``<result>.lock``, created exclusively, holding the writer's pid and host). Another
run of the same result is refused with a one-line error naming the holder; a lock left by a
process that is gone (killed) on this host is taken over with a note.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import socket
import sys
import tempfile
import time
from datetime import datetime, timezone
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
import xarray as xr

from uqflow.errors import ResultFileError, StudyError
from uqflow.layout import (MESSAGE, RUNS_GROUP, RUNS_HASH, STATISTICS_GROUP, STATUS,
                           VERSION_PREFIX)

ENGINE = "netcdf4"


def versions() -> dict[str, str]:
    out = {}
    for pkg in ("uqflow", "numpy", "numba", "dask", "distributed", "xarray", "chaospy", "SALib",
                "scipy"):
        try:
            out[VERSION_PREFIX + pkg] = version(pkg)
        except PackageNotFoundError:
            out[VERSION_PREFIX + pkg] = "not installed"
    return out


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _netcdf_attrs(attrs: dict) -> dict:
    """netCDF attributes take numbers, strings and arrays of them; map the rest."""
    out = {}
    for k, v in attrs.items():
        if v is None:
            continue
        if isinstance(v, (bool, np.bool_)):
            v = int(v)
        elif isinstance(v, (list, tuple)):
            v = np.asarray(v) if v and not isinstance(v[0], str) else ", ".join(map(str, v))
        elif not isinstance(v, (int, float, str, np.number, np.ndarray)):
            v = str(v)
        out[k] = v
    return out


def _clean(ds: xr.Dataset) -> xr.Dataset:
    ds = ds.copy()
    ds.attrs = _netcdf_attrs(ds.attrs)
    for name in ds.variables:
        ds[name].attrs = _netcdf_attrs(ds[name].attrs)
        if ds[name].dtype == object:
            ds[name].encoding["dtype"] = str
    return ds


def runs_checksum(runs: xr.Dataset) -> str:
    """SHA-256 over every variable of ``runs`` (design, seeds, status, outputs), by name.

    Values are hashed in a canonical form (float64 with one NaN, int64, UTF-8 text) so the
    checksum of the dataset written equals that of the dataset read back.
    """
    digest = hashlib.sha256()
    for name in sorted(map(str, runs.variables)):
        var = runs.variables[name]
        digest.update(f"\0{name}\0{var.dims}\0{var.shape}\0".encode())
        values = np.asarray(var.values)
        if values.dtype.kind in "fc":
            values = values.astype(np.complex128 if values.dtype.kind == "c" else np.float64)
            digest.update(np.where(np.isnan(values), np.nan, values).tobytes())
        elif values.dtype.kind in "iub":
            digest.update(values.astype(np.int64).tobytes())
        else:
            digest.update("\x1f".join(map(str, values.ravel())).encode())
    return digest.hexdigest()


def check_writable(path: Path, *, replace: bool, file: str | None = None,
                   key: str | None = None) -> None:
    """Raise a one-line ``StudyError`` (naming ``file`` and ``key``, where the path came from)
    unless a result can be written at ``path``.

    Checked before anything runs: a folder in the way (never replaced, even by ``--force``),
    a file where a folder should be, a folder that cannot be written in (a probe file is
    created and removed, which tests what permissions, quotas and read-only mounts actually
    allow, even for root), and an existing result without ``replace``.
    """
    path = Path(path)

    def refuse(reason):
        return StudyError(f"{path}: {reason}", file=file, key=key)

    if path.is_dir():
        raise refuse("is a folder, not a result file; choose another path (--force replaces "
                      "only a result file)")
    existing = next(parent for parent in path.parents if parent.exists())
    if not existing.is_dir():
        raise refuse(f"{existing} is a file, not a folder")
    if path.exists() and not replace:
        raise refuse("exists: add --resume to finish it or --force to overwrite it")
    # The probe goes into the deepest folder that exists: folders still missing are created
    # at the first write, so a study refused later (say, by its scheduler) leaves nothing.
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=f".{path.name}.", suffix=".probe")
    except OSError as exc:
        raise refuse(f"cannot write in {existing}: {exc.strerror or exc}") from None
    try:
        os.close(fd)
    finally:
        with contextlib.suppress(OSError):
            os.remove(probe)


def lock_path(path: Path) -> Path:
    """The lock file of the result at ``path``."""
    path = Path(path)
    return path.with_name(path.name + ".lock")


def _lock_holder(lock: Path) -> tuple[int, str] | None:
    """(pid, host) written in ``lock``; None when it cannot be read (gone, or unreadable)."""
    for _ in range(10):  # a lock just created is empty until its writer's next line
        try:
            pid, host = lock.read_text(encoding="utf-8").split(maxsplit=1)
            return int(pid), host.strip()
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            time.sleep(0.02)
    return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except (OSError, OverflowError):  # not a pid this system can have
        return False
    return True


def _refuse_held(path: Path, holder: tuple[int, str] | None, file, key) -> StudyError:
    lock = lock_path(path)
    who = "another uqflow run" if holder is None else \
        f"another uqflow run (pid {holder[0]} on {holder[1]})"
    return StudyError(f"{path}: {who} is writing this result; wait for it to end (if no run "
                      f"is going on, delete {lock})", file=file, key=key)


def _stale(holder: tuple[int, str] | None) -> bool:
    """A lock whose writer is known to be gone: on this host, its pid no longer runs."""
    return holder is not None and holder[1] == socket.gethostname() and not _alive(holder[0])


def check_unlocked(path: Path, *, file: str | None = None, key: str | None = None) -> None:
    """Raise a one-line ``StudyError`` if another live run holds the lock of ``path``."""
    lock = lock_path(path)
    if lock.exists() and not _stale(_lock_holder(lock)):
        raise _refuse_held(Path(path), _lock_holder(lock), file, key)


@contextlib.contextmanager
def result_lock(path: Path, *, file: str | None = None, key: str | None = None):
    """Hold the lock of the result at ``path`` (creating its folder) for the ``with`` block;
    it is removed however the block ends."""
    path = Path(path)
    lock = lock_path(path)
    me = f"{os.getpid()} {socket.gethostname()}\n"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StudyError(f"{path}: cannot create its folder: {exc.strerror or exc}",
                         file=file, key=key) from None
    for attempt in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            holder = _lock_holder(lock)
            if attempt == 0 and _stale(holder):
                lock.unlink(missing_ok=True)
                print(f"uqflow: note: {lock}: took over the lock of pid {holder[0]}, which is "
                      f"no longer running (a run that was killed)", file=sys.stderr)
                continue
            raise _refuse_held(path, holder, file, key) from None
        except OSError as exc:
            raise StudyError(f"{path}: cannot create its lock file {lock}: "
                             f"{exc.strerror or exc}", file=file, key=key) from None
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(me)
        break
    try:
        yield lock
    finally:
        with contextlib.suppress(OSError):
            if lock.read_text(encoding="utf-8") == me:  # never remove a lock taken over
                lock.unlink()


def write_result(path: Path, runs: xr.Dataset, statistics: xr.Dataset | None,
                 attrs: dict) -> None:
    """Write the result file atomically (temporary file, then rename).

    On failure the temporary file is removed, the previous file stays as it was and a
    one-line ``ResultFileError`` names the file and the reason.
    """
    import dask  # imported with the first write, not with the CLI

    path = Path(path)
    groups = {"/": xr.Dataset(attrs=_netcdf_attrs({**attrs, RUNS_HASH: runs_checksum(runs)})),
              RUNS_GROUP: _clean(runs)}
    if statistics is not None:
        groups[STATISTICS_GROUP] = _clean(statistics)
    tree = xr.DataTree.from_dict(groups)
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # with a dask client open (a study on dask), xarray would guard the file's every
        # variable write with a distributed lock, a round trip to the scheduler each: 3 x
        # the write's time at every checkpoint. This process alone writes the file
        # (``result_lock``); the synchronous scheduler's lock is a thread lock
        with dask.config.set(scheduler="synchronous"):
            tree.to_netcdf(tmp, engine=ENGINE)
        os.replace(tmp, path)
    except BaseException as exc:
        # Whatever stopped the write (a full disk, a value netCDF cannot hold, Ctrl-C), the
        # temporary file goes; only the last complete checkpoint stays.
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        if not isinstance(exc, (OSError, RuntimeError)):  # HDF5 failures may be RuntimeError
            raise
        reason = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        raise ResultFileError(f"{path}: cannot write the result: {reason}; the last complete "
                              f"checkpoint (if any) is unchanged") from None


def open_result(path: str | Path) -> xr.DataTree:
    """Open a result file: groups ``runs`` and ``statistics`` (loaded, file closed)."""
    path = Path(path)
    if not path.exists():
        raise StudyError("no such result file", file=str(path))
    try:
        with xr.open_datatree(path, engine=ENGINE) as tree:
            tree = tree.load()
    except (OSError, ValueError) as exc:
        raise StudyError(f"not a uqflow result file ({exc})", file=str(path)) from None
    if not {RUNS_GROUP, STATISTICS_GROUP} & set(tree.children):
        raise StudyError("has neither a 'runs' nor a 'statistics' group: not a uqflow result "
                         "file", file=str(path))
    return tree


def read_runs(path: Path, verify: bool = False) -> tuple[xr.Dataset, dict]:
    """The ``runs`` group and root attributes of a (possibly partial) result file.

    With ``verify`` the runs must match their stored checksum (``runs_sha256``): a damaged or
    edited file is refused rather than resumed into wrong statistics.
    """
    tree = open_result(path)
    if RUNS_GROUP not in tree.children:
        raise StudyError(f"has no '{RUNS_GROUP}' group: not a uqflow result file",
                         file=str(path))
    runs = tree[RUNS_GROUP].to_dataset()
    for name in (STATUS, MESSAGE):
        if name not in runs:
            raise StudyError(f"runs has no '{name}' variable: not a uqflow result file",
                             file=str(path))
        runs[name] = runs[name].astype(object)
    attrs = dict(tree.attrs)
    if verify:
        stored = attrs.get(RUNS_HASH)
        if stored is None:
            raise StudyError("has no checksum of its runs (runs_sha256), so a resume cannot "
                             "trust them; use --force to start again", file=str(path))
        if stored != runs_checksum(runs):
            raise StudyError("the stored runs do not match their checksum (runs_sha256): the "
                             "file is damaged or was edited; use --force to start again",
                             file=str(path))
    return runs, attrs
