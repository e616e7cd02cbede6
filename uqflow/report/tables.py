"""Text tables and the numbers in them, for the framework's summary and for every solver's and
method's report: fixed-width grids, numbers to six significant digits, durations, and the
point of a field output a table row is taken at."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import xarray as xr

from uqflow.layout import STATISTIC, STATISTIC_STD, UNITS
from uqflow.report.units import display_units, format_value, long_name, units_attr


def grid(header: list[str], rows: list[list[str]], right: set[int] = frozenset()) -> list[str]:
    """A fixed-width table as lines; columns whose index is in ``right`` are right-aligned."""
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def line(cells):
        return "  ".join(c.rjust(w) if i in right else c.ljust(w)
                         for i, (c, w) in enumerate(zip(cells, widths))).rstrip()

    return [line(header), "  ".join("-" * w for w in widths), *map(line, rows)]


@dataclass(frozen=True)
class Table:
    """A table of text cells: drawn as a fixed-width ``grid`` in the text summary and as an
    HTML table in the HTML report; ``right`` holds the indices of right-aligned columns."""

    header: list[str]
    rows: list[list[str]]
    right: frozenset[int] = frozenset()

    def lines(self) -> list[str]:
        return grid(self.header, self.rows, set(self.right))


def number(x) -> str:
    """A number for a table: 6 significant digits, 'nan' for missing."""
    try:
        x = float(x)
    except (TypeError, ValueError):
        return str(x)
    if math.isnan(x):
        return "nan"
    return f"{x:.6g}"


def seconds(t) -> str:
    """A duration in s, min or h; '?' when unknown."""
    try:
        t = float(t)
    except (TypeError, ValueError):
        return "?"
    if not math.isfinite(t):
        return "?"
    if t < 120:
        return f"{t:.3g} s"
    if t < 7200:
        return f"{t / 60:.3g} min"
    return f"{t / 3600:.3g} h"


def statistic(stats: xr.Dataset, output: str, label: str) -> xr.DataArray | None:
    """Statistic ``label`` ("mean", "std", …) of ``output``, None where the method gives none."""
    if STATISTIC not in stats.coords or label not in stats[STATISTIC].values:
        return None
    return stats[output].sel({STATISTIC: label})


def units_of(output: str, *datasets: xr.Dataset | None) -> str:
    """The ``units`` attribute of ``output`` in the first dataset that gives one ('' if none)."""
    for ds in datasets:
        if ds is not None and output in ds and ds[output].attrs.get(UNITS):
            return str(ds[output].attrs[UNITS])
    return ""


def focus_point(stats: xr.Dataset, output: str) -> dict[str, int]:
    """Index of a field output's point of largest std ({} for a scalar output): where a table
    row of a field is taken. Statistics without a std (an output's values at two points of
    the inputs, a weighted mean alone) give the point where they differ most, or with one
    statistic the point of largest magnitude: a table cell must be one number."""
    spread = statistic(stats, output, STATISTIC_STD)
    if spread is None and output in stats and STATISTIC in stats[output].dims:
        values = stats[output]
        spread = abs(values).isel({STATISTIC: 0}) if values.sizes[STATISTIC] == 1 else \
            values.max(STATISTIC) - values.min(STATISTIC)
    if spread is None or spread.ndim == 0:
        return {}
    values = np.asarray(spread.values, dtype=float)
    flat = np.where(np.isfinite(values), values, -np.inf).ravel()
    at = np.unravel_index(int(np.argmax(flat)), values.shape)
    return {d: int(i) for d, i in zip(spread.dims, at)}


def where(ds: xr.Dataset, focus: dict[str, int]) -> str:
    """'t = 0.001 s, probe H (x = 120, y = 10 mm)' for a focus point: by coordinate value
    where there is one; a label dim's non-dim coordinates (a probe's position) in brackets."""
    parts = []
    for dim, i in focus.items():
        if dim in ds.coords:
            coord = ds[dim]
            units = coord.attrs.get(UNITS, "")
            value = coord.values[i]
            position = "" if isinstance(value, (float, np.floating, int, np.integer)) \
                else _position(ds, dim, i)
            if position:  # a label placed somewhere: 'probe H (x = 120, y = 10 mm)'
                parts.append(f"{dim} {value}{position}")
                continue
            text = f"{value:.4g}" if isinstance(value, (float, np.floating)) else str(value)
            parts.append(f"{dim} = {text}{' ' + units if units else ''}")
        else:
            parts.append(f"{dim}[{i}]")
    return ", ".join(parts)


def label_coordinates(ds: xr.Dataset, dim: str) -> list[str]:
    """The non-dim numeric coordinates along ``dim`` alone (a probe's x and y)."""
    return [str(c) for c in ds.coords if c != dim and ds[c].dims == (dim,)
            and np.issubdtype(ds[c].dtype, np.number)]


def _position(ds: xr.Dataset, dim: str, i: int) -> str:
    """' (x = 120, y = 10 mm)': the label's coordinates, in one display unit where they
    share their units (the unit picked from all the labels' values, so labels compare)."""
    names = label_coordinates(ds, dim)
    if not names:
        return ""
    shared = {units_attr(ds[c]) for c in names}
    common = shared.pop() if len(shared) == 1 else None
    if common is not None:
        scale, label = display_units(np.concatenate([np.ravel(ds[c].values) for c in names]),
                                     common)
        text = ", ".join(f"{long_name(ds[c], c)} = {format_value(ds[c].values[i], scale)}"
                         for c in names)
        return f" ({text}{' ' + label if label else ''})"
    pieces = []
    for c in names:
        scale, label = display_units(ds[c].values, units_attr(ds[c]))
        pieces.append(f"{long_name(ds[c], c)} = {format_value(ds[c].values[i], scale)}"
                      + (f" {label}" if label else ""))
    return f" ({', '.join(pieces)})"
