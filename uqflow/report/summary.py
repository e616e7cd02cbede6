"""The summary table of a result (docs/results.md): the text ``uqflow run`` and ``uqflow report``
print: one row per output, the columns and notes the result's method adds (its
``MethodReport``), the sensitivity indices it computed, the cost of the study and the inputs.

A field output (one with dimensions besides ``realization``, e.g. ``y(t)``) gets one table row,
taken at its point of largest std (``uqflow.report.focus_point``: without a std, where its
statistics differ most); the row says where, and a note gives the range of the mean
over the field.
"""

from __future__ import annotations

import json
import math

import numpy as np
import xarray as xr

from uqflow.layout import (COMPILE_TIME, COMPLETE, ELAPSED_TIME, FAILED_RUNS, FIELD_PREFIX,
                           GERM_PREFIX, INPUT_CV, INPUT_MEAN, INPUT_SKEWNESS, INPUT_STD, MESSAGE,
                           PARAMETER, PARAMETER_UNITS, REALIZATION, SOLVER_COMPILE_TIME,
                           SOLVER_RUNS, SOLVER_WALL_TIME, STATISTIC_MEAN, STATISTIC_STD,
                           STATISTIC_VARIANCE, STATUS, STATUS_FAILED, STATUS_OK, STATUS_PENDING,
                           STOPPED_EARLY, STUDY_NAME, WALL_TIME, WARM_UP_COMPILE_TIME,
                           WARM_UP_PROCESSES, WARM_UP_TIME, WARNINGS)
from uqflow.report.contributions import MethodReport, Sensitivity
from uqflow.report.tables import focus_point as _focus
from uqflow.report.tables import Table
from uqflow.report.tables import number as _num
from uqflow.report.tables import seconds as _seconds
from uqflow.report.tables import statistic as _stat
from uqflow.report.tables import units_of
from uqflow.report.tables import where as _where
from uqflow.report.view import ResultView

__all__ = ["summary_table", "summary_blocks", "sensitivity_tables"]

# --------------------------------------------------------------------------- reading a tree

def _units(stats: xr.Dataset | None, runs: xr.Dataset | None, out: str) -> str:
    return units_of(out, stats, runs)


def _cell(stats: xr.Dataset, out: str, label: str, focus: dict[str, int]) -> str:
    value = _stat(stats, out, label)
    return "-" if value is None else _num(value.isel(focus))


# --------------------------------------------------------------------------- the table

def summary_table(tree: xr.DataTree) -> str:
    """A readable summary of a result: outputs, cost, inputs (or, unfinished, its runs)."""
    lines = []
    for block in summary_blocks(tree):
        lines += block.lines() if isinstance(block, Table) else [block]
    return "\n".join(lines).rstrip()


def summary_blocks(tree: xr.DataTree) -> list:
    """The summary as lines of text and ``Table`` objects, in the order they are printed
    (the text summary draws the tables as grids, the HTML report as HTML tables)."""
    view = ResultView(tree)
    attrs, runs, stats = view.attrs, view.runs, view.stats
    name, method = attrs.get(STUDY_NAME, "?"), view.method
    if stats is None:
        return _unfinished(name, method, attrs, runs)

    state = "complete" if int(attrs.get(COMPLETE, 1)) else "incomplete"
    if attrs.get(STOPPED_EARLY):
        state += f", {attrs[STOPPED_EARLY]}"
    contribution = view.method_report
    lines = [f"study '{name}' ({method}, {state})"]
    if contribution.description:
        lines.append(f"method: {contribution.description}")
    lines.append("")

    outs = view.outputs
    variance_header, variance_cell = _variance_column(stats, outs)
    rows, notes = [], []
    for out in outs:
        focus = _focus(stats, out)
        unit = _units(stats, runs, out)
        row = [out, unit or "-", _where(stats, focus) or "-",
               _cell(stats, out, STATISTIC_MEAN, focus), _cell(stats, out, STATISTIC_STD, focus)]
        if variance_header:
            row.append(variance_cell(out, focus))
        row += [column.cell(out, focus) for column in contribution.columns]
        rows.append(row)
        if focus and _stat(stats, out, STATISTIC_MEAN) is not None:
            mean = np.asarray(_stat(stats, out, STATISTIC_MEAN).values, dtype=float)
            finite = mean[np.isfinite(mean)]
            span = f"{_num(finite.min())} .. {_num(finite.max())}" if finite.size else "nan"
            chosen = "largest std" if _stat(stats, out, STATISTIC_STD) is not None else \
                "largest magnitude of the mean"
            notes.append(f"{out} is a field of {mean.size} points "
                         f"({', '.join(stats[out].dims[1:])}): its row is at the point of "
                         f"{chosen}; the mean ranges over {span}{_unit_suffix(unit)}")
    # Rows differ in units: the column 'unit u' gives each row's, the headers say in what
    # power of it a column is.
    header = ["output", "unit u", "at", "mean [u]", "std [u]"] + \
        ([variance_header] if variance_header else []) + \
        [column.header for column in contribution.columns]
    if not any(r[2] != "-" for r in rows):  # scalar outputs only: no 'at' column
        header.pop(2)
        for r in rows:
            r.pop(2)
    first_method_column = len(header) - len(contribution.columns)
    right = set(range(header.index("mean [u]"), header.index("std [u]") + 1))
    if variance_header:
        right.add(header.index(variance_header))
    right |= {first_method_column + k for k, column in enumerate(contribution.columns)
              if column.right_aligned}
    lines.append(Table(header, rows, frozenset(right)) if rows else "(no outputs)")
    lines += notes
    lines += contribution.notes
    lines += sensitivity_tables(view)
    lines.append("")
    lines.append(_cost_line(stats, attrs, method, contribution))
    lines += _compile_lines(stats, runs, attrs)
    failure = _first_failure(runs)
    if failure:
        lines.append(failure)
    lines += [""] + _inputs_table(stats, runs)
    recorded = [w for w in str(stats.attrs.get(WARNINGS, "")).split("\n") if w]
    if recorded:
        n_warn = len(recorded)
        lines += ["", f"{n_warn} warning{'s' if n_warn > 1 else ''} recorded with the "
                      f"statistics (attribute 'warnings'):"]
        lines += [f"  - {w}" for w in recorded]
    return lines


def sensitivity_tables(view: ResultView) -> list[str]:
    """One table per output the method gives sensitivity indices of: inputs by kind of index,
    at the output's row point, 'value ± error' where the method gives errors."""
    found = view.method_report.sensitivities
    if found is None:
        return []
    lines = []
    for out in view.outputs:
        sens = found(out)
        if sens is not None:
            lines += [""] + _sensitivity_table(view, out, sens)
    return lines


def _sensitivity_table(view: ResultView, out: str, sens: Sensitivity) -> list[str]:
    focus = {d: i for d, i in view.focus(out).items() if d in sens.values.dims}
    values = sens.values.isel(focus)
    errors = sens.errors.isel(focus) if sens.errors is not None else None
    kinds = [str(k) for k in values["index"].values]
    rows = []
    for p in values[PARAMETER].values:
        row = [str(p)]
        for kind in kinds:
            cell = _num(values.sel({PARAMETER: p, "index": kind}))
            if errors is not None:
                error = float(errors.sel({PARAMETER: p, "index": kind}))
                cell += f" ± {_num(abs(error))}" if math.isfinite(error) else ""
            row.append(cell)
        rows.append(row)
    where = f" at {view.where(focus)}" if focus else ""
    error = f"; ± {sens.error_label}" if errors is not None and sens.error_label else ""
    lines = [f"{sens.title}: {out}{where} ({sens.quantity}{error})"]
    lines.append(Table(["input", *kinds], rows, frozenset(range(1, len(kinds) + 1))))
    return lines + ([sens.note] if sens.note else [])


def _cost_line(stats: xr.Dataset, attrs: dict, method: str, contribution: MethodReport) -> str:
    runs_ = stats.attrs.get(SOLVER_RUNS, attrs.get(SOLVER_RUNS, "?"))
    failed = stats.attrs.get(FAILED_RUNS, attrs.get(FAILED_RUNS, "?"))
    detail = contribution.cost_details
    return (f"cost: {runs_} solver runs, {failed} failed, solver wall time "
            f"{_seconds(stats.attrs.get(SOLVER_WALL_TIME))}, elapsed "
            f"{_seconds(attrs.get(ELAPSED_TIME))}, method {method}"
            + (f" ({', '.join(detail)})" if detail else ""))


VARIANCE_HEADER = "variance [u^2]"
VARIANCE_STDERR_HEADER = "variance ± stderr [u^2]"


def _unit_suffix(unit: str) -> str:
    return f" {unit}" if unit and unit != "-" else ""


def _variance_stderr(stats: xr.Dataset, out: str) -> xr.DataArray | None:
    """The standard error of an output's variance, where its method gives one: a statistic
    ``variance_stderr`` or a variable ``{out}_variance_stderr``; None where it is absent or
    not a number anywhere."""
    found = _stat(stats, out, "variance_stderr")
    if found is None and f"{out}_variance_stderr" in stats:
        found = stats[f"{out}_variance_stderr"]
    if found is None or not np.any(np.isfinite(np.asarray(found.values, dtype=float))):
        return None
    return found


def _variance_column(stats: xr.Dataset, outs: list[str]):
    """Header and cell function of the variance column (None: no output has a variance).
    The '±' appears only with a method that gives the variance's standard error."""
    if not any(_stat(stats, out, STATISTIC_VARIANCE) is not None for out in outs):
        return None, None
    errors = {out: _variance_stderr(stats, out) for out in outs}

    def cell(out, focus):
        value = _cell(stats, out, STATISTIC_VARIANCE, focus)
        error = np.nan if errors[out] is None else float(errors[out].isel(focus))
        return f"{value} ± {_num(error)}" if math.isfinite(error) else value

    has_error = any(e is not None for e in errors.values())
    return (VARIANCE_STDERR_HEADER if has_error else VARIANCE_HEADER), cell


def _compile_lines(stats: xr.Dataset, runs: xr.Dataset | None, attrs: dict) -> list[str]:
    """numba's compile time apart from the runs' own: the first runs in each process compile
    the solver's kernels, so the summed wall time over-states what one more run costs; a
    warm-up before the runs (uqflow/warm_up.py) compiled them instead."""
    warm = []
    if attrs.get(WARM_UP_PROCESSES):
        count = int(attrs[WARM_UP_PROCESSES])
        warm = [f"warm-up before the runs: {_seconds(attrs.get(WARM_UP_TIME))} on {count} "
                f"process{'es' if count > 1 else ''} (numba compile "
                f"{_seconds(attrs.get(WARM_UP_COMPILE_TIME))} in all)"]
    if SOLVER_COMPILE_TIME not in stats.attrs and (runs is None or COMPILE_TIME not in runs):
        return warm
    compiling = stats.attrs.get(SOLVER_COMPILE_TIME)
    line = (f"compile time (numba, part of the solver wall time above): "
            f"{_seconds(compiling)}")
    if runs is not None and COMPILE_TIME in runs and STATUS in runs:
        ok = _status(runs) == STATUS_OK
        own = (np.asarray(runs[WALL_TIME].values, float)
               - np.asarray(runs[COMPILE_TIME].values, float))[ok]
        own = own[np.isfinite(own)]
        if own.size:
            line += (f"; per run without it: median {_seconds(np.median(own))} over "
                     f"{own.size} ok run{'s' if own.size > 1 else ''}")
    return [line] + warm


def _field_rows(stats: xr.Dataset, runs: xr.Dataset | None) -> list[list[str]]:
    """One row per random field of the study: what it drives, its kernel and KL modes, from
    the statistics' ``field_<name>_*`` attributes, else from the germs in the
    runs ('?' where a detail was not recorded)."""
    try:
        germs = dict(json.loads(stats.attrs.get("fields", "{}")))  # field -> germ variable
    except (TypeError, ValueError):
        germs = {}
    if runs is not None:
        for var in map(str, runs.data_vars):
            if var.startswith(GERM_PREFIX) and var not in germs.values():
                germs[str(runs[var].attrs.get("field", var[len(GERM_PREFIX):]))] = var
    rows = []
    for name, var in germs.items():
        prefix = f"{FIELD_PREFIX}{str(var)[len(GERM_PREFIX):]}_"
        info = {k[len(prefix):]: v for k, v in stats.attrs.items() if k.startswith(prefix)}
        modes = str(info.get("modes", runs[var].shape[-1] if runs is not None and var in runs
                             else "?"))
        if "captured_fraction" in info:
            modes += f" ({100 * float(info['captured_fraction']):.3g} % of the variance)"
        rows.append([name, str(info.get("parameters", "?")), str(info.get("kernel", "?")),
                     _num(info.get("correlation_length", "?")), modes,
                     str(info.get("germ", "?")), _num(info.get("amplitude", "?"))])
    return rows


def _inputs_table(stats: xr.Dataset, runs: xr.Dataset | None = None) -> list[str]:
    """The uncertain inputs: scalar inputs, then random fields (both are uncertain inputs)."""
    lines = []
    fields = _field_rows(stats, runs)
    if fields:
        lines += ["random fields (KL expansion; value = mean (1 + amplitude sum_j "
                  "sqrt(lambda_j) phi_j(x) xi_j)):"]
        lines.append(Table(["field", "parameters", "kernel", "correlation length", "KL modes",
                            "germs xi_j", "amplitude"], fields, frozenset({3})))
    if PARAMETER not in stats.coords or stats.sizes.get(PARAMETER, 0) == 0:
        return lines or ["inputs: none uncertain"]
    params = [str(p) for p in stats[PARAMETER].values]
    units = [str(u) for u in stats[PARAMETER_UNITS].values] \
        if PARAMETER_UNITS in stats.coords else [""] * len(params)

    def col(name):
        return stats[name].values if name in stats else np.full(len(params), np.nan)

    mean, std, cv, skew = col(INPUT_MEAN), col(INPUT_STD), col(INPUT_CV), \
        col(INPUT_SKEWNESS)
    rows = []
    for k, p in enumerate(params):
        # A zero-mean input has no C.V. (the store keeps inf); say so rather than print inf.
        cv_text = "n/a (mean 0)" if mean[k] == 0 else f"{cv[k]:.3g}"
        rows.append([p, units[k] or "-", _num(mean[k]), _num(std[k]), cv_text,
                     f"{skew[k]:.3g}"])
    table = Table(["input", "units", "mean", "std", "C.V.", "skewness"], rows,
                  frozenset({2, 3, 4, 5}))
    return [table] + ([""] + lines if lines else [])


def _status(runs: xr.Dataset) -> np.ndarray:
    return np.asarray(runs[STATUS].values).astype(str)


def _first_failure(runs: xr.Dataset | None) -> str | None:
    if runs is None or STATUS not in runs:
        return None
    failed = np.flatnonzero(_status(runs) == STATUS_FAILED)
    if failed.size == 0:
        return None
    r = int(failed[0])
    message = str(runs[MESSAGE].values[r]) if MESSAGE in runs else ""
    index = runs[REALIZATION].values[r] if REALIZATION in runs.coords else r
    return f"first failure, realization {index}: {message or '(no message)'}"


def _unfinished(name: str, method: str, attrs: dict, runs: xr.Dataset | None) -> list[str]:
    lines = [f"study '{name}' ({method}): no statistics: the study did not finish",
             "(it was stopped by failing realizations, interrupted, or is still running)", ""]
    if runs is None or STATUS not in runs:
        return lines + ["no runs recorded"]
    status = _status(runs)
    counts = {s: int((status == s).sum()) for s in (STATUS_OK, STATUS_FAILED, STATUS_PENDING)}
    others = sorted(set(status) - set(counts))
    counts.update({s: int((status == s).sum()) for s in others})
    lines.append(f"runs: {status.size} planned: "
                 + ", ".join(f"{n} {s}" for s, n in counts.items()))
    wall = runs[WALL_TIME].values if WALL_TIME in runs else np.array([np.nan])
    compiling = (f" (numba compiling {_seconds(np.nansum(runs[COMPILE_TIME].values))} of it)"
                 if COMPILE_TIME in runs else "")
    lines.append(f"solver wall time so far {_seconds(np.nansum(wall))}{compiling}")
    failure = _first_failure(runs)
    if failure:
        lines.append(failure)
    return lines
