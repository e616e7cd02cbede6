"""The result file: one netCDF4 file per study, read back as an ``xarray.DataTree``.

Groups ``runs`` (one row per realization) and ``statistics`` (the method's analysis), root
attributes for provenance. Every write goes to a temporary file in the same folder that is
then renamed over the result, so a killed study leaves the last complete checkpoint behind.
"""

from __future__ import annotations

import os
from datetime import datetime, timezone
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
import xarray as xr

from uqflow.errors import StudyError

ENGINE = "netcdf4"


def versions() -> dict[str, str]:
    out = {}
    for pkg in ("uqflow", "numpy", "numba", "dask", "distributed", "xarray", "chaospy", "SALib",
                "scipy"):
        try:
            out[f"version_{pkg}"] = version(pkg)
        except PackageNotFoundError:
            out[f"version_{pkg}"] = "not installed"
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


def write_result(path: Path, runs: xr.Dataset, statistics: xr.Dataset | None,
                 attrs: dict) -> None:
    """Write the result file atomically (temporary file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    groups = {"/": xr.Dataset(attrs=_netcdf_attrs(attrs)), "runs": _clean(runs)}
    if statistics is not None:
        groups["statistics"] = _clean(statistics)
    tree = xr.DataTree.from_dict(groups)
    tmp = path.with_name(path.name + ".tmp")
    tree.to_netcdf(tmp, engine=ENGINE)
    os.replace(tmp, path)


def open_result(path: str | Path) -> xr.DataTree:
    """Open a result file: groups ``runs`` and ``statistics`` (loaded, file closed)."""
    path = Path(path)
    if not path.exists():
        raise StudyError("no such result file", file=str(path))
    try:
        with xr.open_datatree(path, engine=ENGINE) as tree:
            return tree.load()
    except (OSError, ValueError) as exc:
        raise StudyError(f"not a uqflow result file ({exc})", file=str(path)) from None


def read_runs(path: Path) -> tuple[xr.Dataset, dict]:
    """The ``runs`` group and root attributes of a (possibly partial) result file."""
    tree = open_result(path)
    if "runs" not in tree.children:
        raise StudyError("has no 'runs' group: not a uqflow result file", file=str(path))
    runs = tree["runs"].to_dataset()
    for name in ("status", "message"):
        runs[name] = runs[name].astype(object)
    return runs, dict(tree.attrs)
