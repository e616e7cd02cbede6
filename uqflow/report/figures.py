"""Figure plumbing shared by the framework's, the methods' and the solvers' figures.

Figures are drawn on ``matplotlib.figure.Figure`` objects with the Agg canvas: no pyplot, so
nothing is ever shown, no figure stays registered after saving, and the backend of a user's
interactive session (a notebook calling ``write_figures``) is left alone. Every figure a
result writes is saved through ``figure_path``, which keeps names from solvers and study files
(an output called '../x') inside the figures folder.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import xarray as xr

from uqflow.errors import StudyError
from uqflow.layout import PARAMETER, PARAMETER_UNITS, UNITS


class FigureWarning(UserWarning):
    """A figure could not be drawn; the others are still written."""


def safe_file_name(text: str) -> str:
    """``text`` as one file name: characters other than [A-Za-z0-9._-] become '_' (no path
    separator, no drive, nothing a shell or another OS reads specially), and no leading '.'
    (no hidden file, no '..')."""
    name = re.sub(r"[^A-Za-z0-9._-]", "_", str(text))
    return "_" + name[1:] if not name or name.startswith(".") else name


def figure_path(folder: Path, *parts: str, suffix: str = ".png") -> Path:
    """The path of a figure named from ``parts`` (output names, kinds) inside ``folder``."""
    folder = Path(folder)
    path = folder / (safe_file_name("_".join(map(str, parts))) + suffix)
    if path.resolve().parent != folder.resolve():
        raise StudyError(f"figure name {path.name!r} leaves the figures folder {folder}")
    return path


def figure_folder(result_path: Path) -> Path:
    """The folder for a result's figures: ``<stem>_figures`` beside the result file."""
    result_path = Path(result_path)
    return result_path.with_name(result_path.stem + "_figures")


def new_figure(width: float = 6.4, height: float = 4.2, rows: int = 1, columns: int = 1,
               **subplots):
    """A figure and its axes, on the Agg canvas (no pyplot)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    if rows == 1 and columns == 1 and not subplots:
        return fig, fig.subplots()
    subplots.setdefault("sharex", rows > 1 and columns == 1)
    return fig, fig.subplots(rows, columns, **subplots)


def save_figure(fig, path: Path, dpi: int = 110) -> Path:
    """Save ``fig`` as PNG and free it (it is not registered with pyplot)."""
    fig.savefig(path, dpi=dpi, format="png")
    fig.clear()
    return Path(path)


def axis_label(name: str, units: str) -> str:
    """An axis label: the name, with the units in brackets when there are any."""
    return f"{name} [{units}]" if units else name


def scientific_ticks(ax, axis: str) -> None:
    """Powers of ten outside 1e-3 .. 1e4 go into the axis' offset text, not every tick."""
    try:
        ax.ticklabel_format(axis=axis, style="sci", scilimits=(-3, 4))
    except AttributeError:  # not a ScalarFormatter (log axis)
        pass


def colors(n: int) -> list:
    """``n`` distinguishable colours (tab10, tab20 beyond ten)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def coordinate(ds: xr.Dataset, dim: str) -> tuple[np.ndarray, str]:
    """The values of ``dim`` to plot against, and the axis label (index where not numeric)."""
    if dim in ds.coords and np.issubdtype(ds[dim].dtype, np.number):
        return np.asarray(ds[dim].values), axis_label(dim, ds[dim].attrs.get(UNITS, ""))
    return np.arange(ds.sizes[dim]), f"{dim} (index)"


def input_label(ds: xr.Dataset, k: int) -> str:
    """The name of input ``k`` with its units on a second line (for a bar chart's ticks)."""
    p = str(ds[PARAMETER].values[k])
    if PARAMETER_UNITS in ds.coords and str(ds[PARAMETER_UNITS].values[k]):
        return f"{p}\n[{ds[PARAMETER_UNITS].values[k]}]"
    return p
