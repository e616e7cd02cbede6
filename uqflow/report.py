"""Tables and figures from a result file."""

from __future__ import annotations

from pathlib import Path

import xarray as xr

from uqflow.store import open_result

__all__ = ["open_result", "summary_table", "write_figures", "figure_folder"]


def figure_folder(result_path: Path) -> Path:
    result_path = Path(result_path)
    return result_path.with_name(result_path.stem + "_figures")


def summary_table(tree: xr.DataTree) -> str:
    stats = tree["statistics"].to_dataset()
    lines = []
    for name, var in stats.data_vars.items():
        if "statistic" in var.dims and var.ndim == 1:
            vals = {str(s): float(v) for s, v in zip(stats["statistic"].values, var.values)}
            lines.append(f"{name}: " + ", ".join(f"{k} {v:.6g}" for k, v in vals.items()))
    return "\n".join(lines)


def write_figures(tree: xr.DataTree, folder: Path) -> list[Path]:
    return []
