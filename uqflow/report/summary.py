"""Tables and figures from a result file (see docs/results.md).

``summary_table(tree)`` is the text ``uqflow run`` and ``uqflow report`` print: one row per
output, the cost of the study and the inputs' summary. ``write_figures(tree, folder)`` draws
the PNG figures that apply to the result's method and outputs and returns their paths.

A field output (one with dimensions besides ``realization``, e.g. ``y(t)``) gets one table row,
taken at its point of largest std; the row says where, and a note gives the range of the mean
over the field.

Figures are drawn on ``matplotlib.figure.Figure`` objects with the Agg canvas: no pyplot, so
nothing is ever shown, no figure stays registered after saving, and the backend of a user's
interactive session (a notebook calling ``write_figures``) is left alone.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import xarray as xr
from scipy import stats as sps

from uqflow.errors import StudyError
from uqflow.methods.base import sample_mask
from uqflow.report.figures import FigureWarning, figure_folder, figure_path, safe_file_name
from uqflow.report.figures import axis_label as _label
from uqflow.report.figures import colors as _colors
from uqflow.report.figures import coordinate as _coordinate
from uqflow.report.figures import input_label as _input_label
from uqflow.report.figures import new_figure as _figure
from uqflow.report.figures import save_figure as _save
from uqflow.report.figures import scientific_ticks as _sci
from uqflow.report.tables import focus_point as _focus
from uqflow.report.tables import grid as _grid
from uqflow.report.tables import number as _num
from uqflow.report.tables import seconds as _seconds
from uqflow.report.tables import statistic as _stat
from uqflow.report.tables import units_of
from uqflow.report.tables import where as _where
from uqflow.report_levels import LEVEL_METHODS, level_lines, levels_figure, method_cell
from uqflow.store import open_result

#: Individual Monte Carlo runs drawn faintly behind the mean ± 2 std band of a field output.
FAINT_RUNS = 12

__all__ = ["open_result", "summary_table", "write_figures", "figure_folder", "figure_path",
           "safe_file_name", "FigureWarning"]

# --------------------------------------------------------------------------- reading a tree

def _parts(tree: xr.DataTree) -> tuple[dict, xr.Dataset | None, xr.Dataset | None]:
    """Root attributes, runs and statistics (None when absent)."""
    runs = tree["runs"].to_dataset() if "runs" in tree.children else None
    stats = tree["statistics"].to_dataset() if "statistics" in tree.children else None
    if runs is None and stats is None:
        raise StudyError("has neither a 'runs' nor a 'statistics' group: not a uqflow "
                         "result file")
    return dict(tree.attrs), runs, stats


def _outputs(stats: xr.Dataset) -> list[str]:
    """The outputs analysed: every statistics variable with a ``statistic`` dimension."""
    return [str(v) for v in stats.data_vars if "statistic" in stats[v].dims]


def _units(stats: xr.Dataset | None, runs: xr.Dataset | None, out: str) -> str:
    return units_of(out, stats, runs)


def _cell(stats: xr.Dataset, out: str, label: str, focus: dict[str, int]) -> str:
    value = _stat(stats, out, label)
    return "-" if value is None else _num(value.isel(focus))


def _control_lines(stats: xr.Dataset, outs: list[str]) -> list[str]:
    """What a control variate bought, per output at its row's point (docs/control_variates.md)."""
    if not stats.attrs.get("control"):
        return []
    if not int(stats.attrs.get("control_used", 0)):
        return [f"control variate {stats.attrs['control']}: not used (its control runs "
                f"failed), plain Monte Carlo"]
    lines = [f"control variate {stats.attrs['control']} ({stats.attrs['control_runs']} "
             f"control run(s)): correlation rho with the surrogate, variance reduction "
             f"1/(1 - rho^2), equivalent plain samples n/(1 - rho^2)"]
    for out in outs:
        if f"{out}_correlation" in stats:
            focus = _focus(stats, out)
            rho, gain, count = (float(stats[f"{out}_{v}"].isel(focus)) for v in
                                ("correlation", "variance_reduction", "equivalent_samples"))
            where = f" at {_where(stats, focus)}" if focus else ""
            if math.isfinite(gain):
                lines.append(f"  {out}{where}: rho {rho:.6g}, reduction {gain:.3g}x, "
                             f"equivalent to {count:.3g} plain samples")
            else:
                lines.append(f"  {out}{where}: rho 1, the surrogate reproduces it to rounding "
                             f"(no error left to reduce)")
    return lines


# --------------------------------------------------------------------------- the table

def summary_table(tree: xr.DataTree) -> str:
    """A readable summary of a result: outputs, cost, inputs (or, unfinished, its runs)."""
    attrs, runs, stats = _parts(tree)
    name = attrs.get("study_name", "?")
    method = str(stats.attrs.get("method") if stats is not None else
                 attrs.get("method", "?"))
    if stats is None:
        return "\n".join(_unfinished(name, method, attrs, runs))

    state = "complete" if int(attrs.get("complete", 1)) else "incomplete"
    if attrs.get("stopped_early"):
        state += f", {attrs['stopped_early']}"
    lines = [f"study '{name}' ({method}, {state})", ""]

    outs = _outputs(stats)
    extra_header, extra = _method_column(stats, method)
    variance_header, variance_cell = _variance_column(stats, outs)
    rows, notes = [], []
    for out in outs:
        focus = _focus(stats, out)
        at = stats[out].isel(focus)
        unit = _units(stats, runs, out)
        row = [out, unit or "-", _where(stats, focus) or "-",
               _cell(stats, out, "mean", focus), _cell(stats, out, "std", focus)]
        if variance_header:
            row.append(variance_cell(out, focus))
        if extra_header:
            row.append(extra(out, focus, at))
        rows.append(row)
        if focus and _stat(stats, out, "mean") is not None:
            mean = np.asarray(_stat(stats, out, "mean").values, dtype=float)
            finite = mean[np.isfinite(mean)]
            span = f"{_num(finite.min())} .. {_num(finite.max())}" if finite.size else "nan"
            notes.append(f"{out} is a field of {mean.size} points "
                         f"({', '.join(stats[out].dims[1:])}): its row is at the point of "
                         f"largest std; the mean ranges over {span}{_unit_suffix(unit)}")
    # Rows differ in units: the column 'unit u' gives each row's, the headers say in what
    # power of it a column is.
    header = ["output", "unit u", "at", "mean [u]", "std [u]"] + \
        ([variance_header] if variance_header else []) + ([extra_header] if extra_header else [])
    if not any(r[2] != "-" for r in rows):  # scalar outputs only: no 'at' column
        header.pop(2)
        for r in rows:
            r.pop(2)
    right = set(range(header.index("mean [u]"), header.index("std [u]") + 1))
    if variance_header:
        right.add(header.index(variance_header))
    lines += _grid(header, rows, right) if rows else ["(no outputs)"]
    lines += notes
    if stats.attrs.get("stderr_note"):
        # Which error the interval rests on decides how far it can be trusted: say it.
        lines.append(f"standard error and interval of the mean: {stats.attrs['stderr_note']}")
    lines += _control_lines(stats, outs)
    if method in LEVEL_METHODS:
        lines += [""] + level_lines(stats, method, outs, lambda o: _focus(stats, o),
                                    lambda o: _units(stats, runs, o))
    lines.append("")
    lines.append(_cost_line(stats, attrs, method))
    lines += _compile_lines(stats, runs)
    failure = _first_failure(runs)
    if failure:
        lines.append(failure)
    lines += [""] + _inputs_table(stats, runs)
    recorded = [w for w in str(stats.attrs.get("warnings", "")).split("\n") if w]
    if recorded:
        n_warn = len(recorded)
        lines += ["", f"{n_warn} warning{'s' if n_warn > 1 else ''} recorded with the "
                      f"statistics (attribute 'warnings'):"]
        lines += [f"  - {w}" for w in recorded]
    return "\n".join(lines).rstrip()


VARIANCE_HEADER = "variance [u^2]"
VARIANCE_STDERR_HEADER = "variance ± stderr [u^2]"


def _unit_suffix(unit: str) -> str:
    return f" {unit}" if unit and unit != "-" else ""


def _variance_stderr(stats: xr.Dataset, out: str) -> xr.DataArray | None:
    """The standard error of an output's variance, where its method gives one: a statistic
    ``variance_stderr`` (multilevel) or a variable ``{out}_variance_stderr`` (a control
    variate); None where it is absent or not a number anywhere."""
    found = _stat(stats, out, "variance_stderr")
    if found is None and f"{out}_variance_stderr" in stats:
        found = stats[f"{out}_variance_stderr"]
    if found is None or not np.any(np.isfinite(np.asarray(found.values, dtype=float))):
        return None
    return found


def _variance_column(stats: xr.Dataset, outs: list[str]):
    """Header and cell function of the variance column (None: no output has a variance).
    The '±' appears only with a method that gives the variance's standard error."""
    if not any(_stat(stats, out, "variance") is not None for out in outs):
        return None, None
    errors = {out: _variance_stderr(stats, out) for out in outs}

    def cell(out, focus):
        value = _cell(stats, out, "variance", focus)
        error = np.nan if errors[out] is None else float(errors[out].isel(focus))
        return f"{value} ± {_num(error)}" if math.isfinite(error) else value

    has_error = any(e is not None for e in errors.values())
    return (VARIANCE_STDERR_HEADER if has_error else VARIANCE_HEADER), cell


def _method_column(stats: xr.Dataset, method: str):
    """Header and cell function of the method-specific column (None: no column)."""
    if method == "monte-carlo" and "ci_low" in stats["statistic"].values:
        level = float(stats.attrs.get("confidence", 0.95))

        def ci(out, focus, at):
            return f"{_num(at.sel(statistic='ci_low'))} .. {_num(at.sel(statistic='ci_high'))}"

        return f"{100 * level:g} % CI of the mean [u]", ci
    if method == "taylor":
        order = stats.attrs.get("order", "?")
        variance = stats.attrs.get("variance", "")
        text = f"Taylor order {order}" + (f", {variance} variance" if variance else "")
        return "expansion", lambda out, focus, at: text
    if method == "sobol":
        def top(out, focus, at):
            var = f"{out}_sobol"
            if var not in stats:
                return "-"
            si = stats[var].isel(focus)
            params = [str(p) for p in si["parameter"].values]
            s1 = si.sel(sobol_index="S1").values
            st = si.sel(sobol_index="ST").values
            order = sorted(range(len(params)),
                           key=lambda k: -st[k] if np.isfinite(st[k]) else math.inf)
            shown = [f"{params[k]} {s1[k]:.2f}/{st[k]:.2f}" for k in order[:4]]
            if len(params) > 4:
                shown.append(f"+{len(params) - 4} more")
            return ", ".join(shown)

        return "S1/ST per input (largest ST first)", top
    if method in LEVEL_METHODS:
        return "how sure [u], what it saved", lambda out, focus, at: method_cell(
            stats, method, out, focus)
    if method == "pce":
        def fit(out, focus, at):
            if f"{out}_loo_error" not in stats or f"{out}_order" not in stats:
                return "-"
            loo = float(stats[f"{out}_loo_error"].isel(focus))
            return (f"order {int(stats[f'{out}_order'])}, {int(stats[f'{out}_terms'])} terms, "
                    f"LOO error {loo:.2g}")

        return "expansion (LOO error: relative to the variance)", fit
    return None, None


def _cost_line(stats: xr.Dataset, attrs: dict, method: str) -> str:
    runs_ = stats.attrs.get("solver_runs", attrs.get("solver_runs", "?"))
    failed = stats.attrs.get("failed_runs", attrs.get("failed_runs", "?"))
    detail = []
    if method == "monte-carlo" and stats.attrs.get("rule"):
        detail.append(f"rule {stats.attrs['rule']}")
    if method == "sobol" and "samples" in stats.attrs:
        kept = stats.attrs.get("samples_kept", "?")
        detail.append(f"{stats.attrs['samples']} base samples, {kept} kept")
    return (f"cost: {runs_} solver runs, {failed} failed, solver wall time "
            f"{_seconds(stats.attrs.get('solver_wall_time'))}, elapsed "
            f"{_seconds(attrs.get('elapsed_time'))}, method {method}"
            + (f" ({', '.join(detail)})" if detail else ""))


def _compile_lines(stats: xr.Dataset, runs: xr.Dataset | None) -> list[str]:
    """numba's compile time apart from the runs' own: the first runs in each process compile
    the solver's kernels, so the summed wall time over-states what one more run costs."""
    if "solver_compile_time" not in stats.attrs and (runs is None or "compile_time" not in runs):
        return []
    compiling = stats.attrs.get("solver_compile_time")
    line = (f"compile time (numba, part of the solver wall time above): "
            f"{_seconds(compiling)}")
    if runs is not None and "compile_time" in runs and "status" in runs:
        ok = _status(runs) == "ok"
        own = (np.asarray(runs["wall_time"].values, float)
               - np.asarray(runs["compile_time"].values, float))[ok]
        own = own[np.isfinite(own)]
        if own.size:
            line += (f"; per run without it: median {_seconds(np.median(own))} over "
                     f"{own.size} ok run{'s' if own.size > 1 else ''}")
    return [line]


def _field_rows(stats: xr.Dataset, runs: xr.Dataset | None) -> list[list[str]]:
    """One row per random field of the study: what it drives, its kernel and KL modes, from
    the statistics' ``field_<name>_*`` attributes (kl-weibull), else from the germs in the
    runs ('?' where a detail was not recorded)."""
    try:
        germs = dict(json.loads(stats.attrs.get("fields", "{}")))  # field -> germ variable
    except (TypeError, ValueError):
        germs = {}
    if runs is not None:
        for var in map(str, runs.data_vars):
            if var.startswith("germ_") and var not in germs.values():
                germs[str(runs[var].attrs.get("field", var[len("germ_"):]))] = var
    rows = []
    for name, var in germs.items():
        prefix = f"field_{str(var)[len('germ_'):]}_"
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
        lines += _grid(["field", "parameters", "kernel", "correlation length", "KL modes",
                        "germs xi_j", "amplitude"], fields, {3})
    if "parameter" not in stats.coords or stats.sizes.get("parameter", 0) == 0:
        return lines or ["inputs: none uncertain"]
    params = [str(p) for p in stats["parameter"].values]
    units = [str(u) for u in stats["parameter_units"].values] \
        if "parameter_units" in stats.coords else [""] * len(params)

    def col(name):
        return stats[name].values if name in stats else np.full(len(params), np.nan)

    mean, std, cv, skew = col("input_mean"), col("input_std"), col("input_cv"), \
        col("input_skewness")
    rows = []
    for k, p in enumerate(params):
        # A zero-mean input has no C.V. (the store keeps inf); say so rather than print inf.
        cv_text = "n/a (mean 0)" if mean[k] == 0 else f"{cv[k]:.3g}"
        rows.append([p, units[k] or "-", _num(mean[k]), _num(std[k]), cv_text,
                     f"{skew[k]:.3g}"])
    table = _grid(["input", "units", "mean", "std", "C.V.", "skewness"], rows, {2, 3, 4, 5})
    return table + ([""] + lines if lines else [])


def _status(runs: xr.Dataset) -> np.ndarray:
    return np.asarray(runs["status"].values).astype(str)


def _first_failure(runs: xr.Dataset | None) -> str | None:
    if runs is None or "status" not in runs:
        return None
    failed = np.flatnonzero(_status(runs) == "failed")
    if failed.size == 0:
        return None
    r = int(failed[0])
    message = str(runs["message"].values[r]) if "message" in runs else ""
    index = runs["realization"].values[r] if "realization" in runs.coords else r
    return f"first failure, realization {index}: {message or '(no message)'}"


def _unfinished(name: str, method: str, attrs: dict, runs: xr.Dataset | None) -> list[str]:
    lines = [f"study '{name}' ({method}): no statistics: the study did not finish",
             "(it was stopped by failing realizations, interrupted, or is still running)", ""]
    if runs is None or "status" not in runs:
        return lines + ["no runs recorded"]
    status = _status(runs)
    counts = {s: int((status == s).sum()) for s in ("ok", "failed", "pending")}
    others = sorted(set(status) - set(counts))
    counts.update({s: int((status == s).sum()) for s in others})
    lines.append(f"runs: {status.size} planned: "
                 + ", ".join(f"{n} {s}" for s, n in counts.items()))
    wall = runs["wall_time"].values if "wall_time" in runs else np.array([np.nan])
    compiling = (f" (numba compiling {_seconds(np.nansum(runs['compile_time'].values))} of it)"
                 if "compile_time" in runs else "")
    lines.append(f"solver wall time so far {_seconds(np.nansum(wall))}{compiling}")
    failure = _first_failure(runs)
    if failure:
        lines.append(failure)
    return lines


# --------------------------------------------------------------------------- figures

def write_figures(tree: xr.DataTree, folder: Path) -> list[Path]:
    """Draw the figures that apply to this result into ``folder``; return the paths written.

    ``<output>_histogram.png`` (Monte Carlo, scalar output), ``<output>_band.png`` (output
    with one dimension: mean ± 2 std over it), ``<output>_convergence.png`` (Monte Carlo),
    ``<output>_sobol.png`` (sobol) and ``<output>_contributions.png`` (taylor). A result
    without statistics gets none. A figure that fails is skipped with a ``FigureWarning``.
    """
    attrs, runs, stats = _parts(tree)
    if stats is None:
        return []
    folder = Path(folder)
    method = str(stats.attrs.get("method", attrs.get("method", "")))
    study = str(attrs.get("study_name", "study"))
    ctx = _Context(study, method, runs, stats)
    written = []
    for out in _outputs(stats):
        for kind, draw in _FIGURES:
            try:
                fig = draw(ctx, out)
            except Exception as exc:  # one broken figure must not cost the others
                warnings.warn(f"figure {out}_{kind}.png not written: {type(exc).__name__}: "
                              f"{exc}", FigureWarning, stacklevel=2)
                continue
            if fig is None:
                continue
            folder.mkdir(parents=True, exist_ok=True)
            path = figure_path(folder, out, kind)
            if path in written:  # two names that differ only in characters made '_'
                path = figure_path(folder, out, kind, len(written))
            _save(fig, path)
            written.append(path)
    return written


class _Context:
    def __init__(self, study, method, runs, stats):
        self.study, self.method, self.runs, self.stats = study, method, runs, stats

    def units(self, out):
        return _units(self.stats, self.runs, out)

    def ok_values(self, out) -> np.ndarray | None:
        """The outputs of the ok runs (realization first), None without runs; a control
        variate's control realizations (stencil points at the means) are not samples."""
        if self.runs is None or out not in self.runs or "status" not in self.runs:
            return None
        return np.asarray(self.runs[out].values, dtype=float)[sample_mask(self.runs)]

    def title(self, out, what, focus=None):
        where = f" at {_where(self.stats, focus)}" if focus else ""
        return f"{self.study}: {out}{where}\n{what}"


def _histogram(ctx: _Context, out: str):
    if ctx.method != "monte-carlo" or ctx.stats[out].ndim != 1:
        return None
    y = ctx.ok_values(out)
    if y is None:
        return None
    y = y[np.isfinite(y)]
    if y.size < 2:
        return None
    units = ctx.units(out)
    fig, ax = _figure()
    edges = np.histogram_bin_edges(y, bins="auto")
    bins = edges if len(edges) <= 61 else 60
    ax.hist(y, bins=bins, color="#9ab7d3", edgecolor="white", linewidth=0.4)
    lo, hi = np.quantile(y, [0.025, 0.975])
    ax.axvspan(lo, hi, color="#f2c14e", alpha=0.25, zorder=0,
               label=f"central 95 % of runs: {lo:.4g} .. {hi:.4g}")
    mean = float(_stat(ctx.stats, out, "mean"))
    ax.axvline(mean, color="#c0392b", linewidth=2, label=f"mean {mean:.4g}")
    for q in (lo, hi):
        ax.axvline(q, color="#b8860b", linewidth=1, linestyle="--")
    ax.set_xlabel(_label(out, units))
    _sci(ax, "x")
    ax.set_ylabel("realizations per bin")
    ax.set_title(ctx.title(out, f"Monte Carlo: distribution of {y.size} ok runs"))
    ax.legend(loc="best", fontsize="small")
    return fig


def _band(ctx: _Context, out: str):
    var = ctx.stats[out]
    if var.ndim != 2:
        return None
    dim = var.dims[1]
    mean, std = _stat(ctx.stats, out, "mean"), _stat(ctx.stats, out, "std")
    if mean is None or std is None:
        return None
    x, xlabel = _coordinate(ctx.stats, dim)
    m, s = np.asarray(mean.values, float), np.asarray(std.values, float)
    units = ctx.units(out)
    fig, ax = _figure()
    if ctx.method == "monte-carlo":
        y = ctx.ok_values(out)
        if y is not None and y.shape[0]:
            pick = np.linspace(0, y.shape[0] - 1, min(FAINT_RUNS, y.shape[0])).astype(int)
            for i, r in enumerate(pick):
                ax.plot(x, y[r], color="0.45", linewidth=0.7, alpha=0.35,
                        label=f"{len(pick)} of the runs" if i == 0 else None)
    ax.fill_between(x, m - 2 * s, m + 2 * s, color="#9ab7d3", alpha=0.5,
                    label="mean ± 2 std", linewidth=0)
    ax.plot(x, m, color="#1f4e79", linewidth=2, label="mean")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(_label(out, units))
    _sci(ax, "y")
    ax.set_title(ctx.title(out, f"{_method_name(ctx.method)}: mean ± 2 std over {dim}"))
    ax.legend(loc="best", fontsize="small")
    return fig


def _convergence(ctx: _Context, out: str):
    trace_name = f"{out}_trace"
    if ctx.method != "monte-carlo" or trace_name not in ctx.stats:
        return None
    trace = ctx.stats[trace_name]
    counts = np.asarray(ctx.stats["trace_samples"].values, float)
    if counts.size < 2:
        return None
    focus = _focus(ctx.stats, out)
    trace = trace.isel(focus)
    mean = np.asarray(trace.sel(trace_statistic="mean").values, float)
    stderr = np.asarray(trace.sel(trace_statistic="stderr").values, float)
    std = np.asarray(trace.sel(trace_statistic="std").values, float)
    units = ctx.units(out)
    fig, (ax, ax2) = _figure(height=5.2, rows=2)
    level = float(ctx.stats.attrs.get("confidence", 0.95))
    replicates = ctx.stats.attrs.get("replicates")
    if ctx.stats.attrs.get("stderr_kind") == "rqmc" and replicates:
        # The band is the interval the table reports: t with R - 1 degrees of freedom.
        half = sps.t.ppf(0.5 + level / 2, int(replicates) - 1) * stderr
        label = (f"{100 * level:g} % interval, randomized QMC ({int(replicates)} replicates, "
                 f"t with {int(replicates) - 1} dof)")
    else:
        half, label = 1.96 * stderr, "± 1.96 stderr"
    ax.fill_between(counts, mean - half, mean + half, color="#9ab7d3",
                    alpha=0.6, linewidth=0, label=label)
    ax.plot(counts, mean, color="#1f4e79", marker="o", markersize=3, label="running mean")
    ax.axhline(mean[-1], color="#c0392b", linestyle="--", linewidth=1,
               label=f"final mean {mean[-1]:.4g}")
    ax.set_ylabel(_label(f"mean of {out}", units))
    _sci(ax, "y")
    ax.legend(loc="best", fontsize="small")
    ax2.plot(counts, std, color="#2e7d32", marker="o", markersize=3, label="running std")
    ax2.set_ylabel(_label(f"std of {out}", units))
    _sci(ax2, "y")
    ax2.set_xlabel("number of samples")
    ax2.set_xscale("log")
    ax.set_title(ctx.title(out, "Monte Carlo convergence", focus))
    return fig


def _sobol(ctx: _Context, out: str):
    name = f"{out}_sobol"
    if ctx.method != "sobol" or name not in ctx.stats:
        return None
    si = ctx.stats[name]
    params = [str(p) for p in si["parameter"].values]
    fields = si.dims[2:]
    if len(fields) == 1:
        return _sobol_lines(ctx, out, si, params, fields[0])
    focus = _focus(ctx.stats, out)
    si = si.isel(focus)
    fig, ax = _figure(width=max(5.0, 1.1 * len(params) + 2.5))
    x = np.arange(len(params))
    w = 0.38
    for offset, idx, color in ((-w / 2, "S1", "#1f4e79"), (w / 2, "ST", "#e08e2b")):
        val = np.asarray(si.sel(sobol_index=idx).values, float)
        conf = np.abs(np.asarray(si.sel(sobol_index=f"{idx}_conf").values, float))
        ax.bar(x + offset, val, w, yerr=conf, capsize=3, color=color,
               label={"S1": "first order S1", "ST": "total ST"}[idx],
               error_kw={"elinewidth": 1, "ecolor": "0.2"})
    ax.axhline(0, color="0.3", linewidth=0.8)
    ax.set_xticks(x, [_input_label(ctx.stats, k) for k in range(len(params))])
    ax.set_xlabel("input")
    ax.set_ylabel("Sobol' index (fraction of the variance)")
    level = ctx.stats.attrs.get("confidence", 0.95)
    ax.set_title(ctx.title(out, f"Sobol' indices, error bars: {100 * float(level):g} % "
                                f"bootstrap half-widths", focus))
    ax.legend(loc="best", fontsize="small")
    return fig


def _sobol_lines(ctx, out, si, params, dim):
    x, xlabel = _coordinate(ctx.stats, dim)
    fig, ax = _figure()
    colors = _colors(len(params))
    for k, p in enumerate(params):
        for idx, style in (("S1", "-"), ("ST", "--")):
            val = np.asarray(si.sel(sobol_index=idx).isel(parameter=k).values, float)
            conf = np.abs(np.asarray(si.sel(sobol_index=f"{idx}_conf").isel(parameter=k)
                                     .values, float))
            ax.plot(x, val, style, color=colors[k], label=f"{idx} {p}")
            ax.fill_between(x, val - conf, val + conf, color=colors[k], alpha=0.12,
                            linewidth=0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("Sobol' index (fraction of the variance)")
    level = ctx.stats.attrs.get("confidence", 0.95)
    ax.set_title(ctx.title(out, f"Sobol' indices over {dim} (S1 solid, ST dashed; bands: "
                                f"{100 * float(level):g} % half-widths)"))
    ax.legend(loc="best", fontsize="small", ncol=2)
    return fig


def _contributions(ctx: _Context, out: str):
    name = f"{out}_gradient"
    stats = ctx.stats
    if ctx.method != "taylor" or name not in stats or "input_std" not in stats:
        return None
    g = stats[name]
    s = stats["input_std"]
    contrib = (g * s) ** 2  # (parameter, *dims): g_k^2 s_k^2
    params = [str(p) for p in stats["parameter"].values]
    units = ctx.units(out)
    vunits = f"({units})²" if units else ""
    variance = _stat(stats, out, "variance")
    note = _contribution_note(stats)
    fields = contrib.dims[1:]
    if len(fields) == 1:
        dim = fields[0]
        x, xlabel = _coordinate(stats, dim)
        fig, ax = _figure()
        c = np.nan_to_num(np.asarray(contrib.transpose("parameter", dim).values, float))
        ax.stackplot(x, c, labels=[f"{p}: g² s²" for p in params],
                     colors=_colors(len(params)), alpha=0.8)
        if variance is not None:
            ax.plot(x, np.asarray(variance.values, float), color="k", linewidth=1.5,
                    linestyle="--", label="variance (Taylor estimate)")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(_label(f"variance of {out}", vunits))
        _sci(ax, "y")
        ax.set_title(ctx.title(out, f"Taylor: contributions g_k² s_k² to the variance{note}"))
        ax.legend(loc="best", fontsize="small")
        return fig
    focus = _focus(stats, out)
    c = np.asarray(contrib.isel(focus).values, float)
    labels = [_input_label(stats, k) for k in range(len(params))]
    colors = _colors(len(params))
    v = float(variance.isel(focus)) if variance is not None else float(np.nansum(c))
    rest = v - float(np.nansum(c))
    if note and abs(rest) > 1e-9 * abs(v):
        # What the per-input terms leave out (cross terms, curvature), so the bars add up.
        c = np.append(c, rest)
        labels.append("correlation\ncross terms" if "correlated" in note else "curvature\nterms")
        colors.append("0.6")
    fig, ax = _figure(width=max(6.4, 1.0 * len(c) + 2.5))
    x = np.arange(len(c))
    bars = ax.bar(x, c, 0.6, color=colors)
    for bar, value in zip(bars, c):
        if v > 0 and np.isfinite(value):
            ax.annotate(f"{100 * value / v:.1f} %", (bar.get_x() + bar.get_width() / 2,
                                                     max(bar.get_height(), 0.0)),
                        ha="center", va="bottom", fontsize="small")
    ax.axhline(v, color="k", linestyle="--", linewidth=1,
               label=f"variance (Taylor estimate) {v:.4g} = 100 %")
    ax.axhline(0, color="0.3", linewidth=0.8)
    ax.legend(loc="best", fontsize="small")
    ax.set_xticks(x, labels)
    ax.set_xlabel("input")
    ax.set_ylabel(_label(f"g_k² s_k², variance of {out}", vunits))
    _sci(ax, "y")
    ax.margins(y=0.12)
    ax.set_title(ctx.title(out, f"Taylor: contribution of each input to the variance{note}",
                           focus))
    return fig


def _contribution_note(stats: xr.Dataset) -> str:
    """What the bars leave out of the variance, if anything."""
    rho = stats["input_correlation"].values if "input_correlation" in stats else None
    if rho is not None and np.any(rho[~np.eye(rho.shape[0], dtype=bool)] != 0):
        return "\n(correlated inputs: cross terms 2 g_k g_j s_k s_j rho_kj apart)"
    if stats.attrs.get("variance") == "second-order":
        return "\n(second-order variance: the curvature terms apart)"
    return ""


def _method_name(method: str) -> str:
    return {"monte-carlo": "Monte Carlo", "taylor": "Taylor", "sobol": "Sobol'"}.get(
        method, method)


_FIGURES = [("histogram", _histogram), ("band", _band), ("convergence", _convergence),
            ("sobol", _sobol), ("contributions", _contributions), ("levels", levels_figure)]


def solver_report(trees: list, folder: Path, figures: bool = True,
                  **options) -> tuple[str, list[Path]]:
    """What the results' solver adds: its ``report(trees, folder, figures, **options)``
    static- or classmethod, if any.

    A solver knows the comparisons its users look at (the gamut bar prints the seed's Table 1
    beside ours and draws the seed's figures); results of different solvers are not mixed.
    ``options`` given as None are left out; one the solver's report does not take is a
    ``StudyError`` naming it (``uqflow report --time`` on results of a solver without times).
    """
    import inspect

    from uqflow.solver import get_solver

    options = {k: v for k, v in options.items() if v is not None}
    solvers = {str(t.attrs.get("solver", "")) for t in trees}
    if len(solvers) != 1 or "" in solvers:
        if options:
            raise StudyError(f"--{next(iter(options))} applies to a solver's comparison of "
                             f"results of one solver; these are of {sorted(solvers)}",
                             key=next(iter(options)))
        return "", []
    name = solvers.pop()
    try:
        solver_class = get_solver(name)
    except StudyError:
        return "", []
    hook = getattr(solver_class, "report", None)
    taken = set(inspect.signature(hook).parameters) if hook is not None else set()
    for key in options:
        if key not in taken:
            raise StudyError(f"--{key}: the '{name}' solver's report takes no such option",
                             key=key)
    if hook is None:
        return "", []
    return hook(trees, Path(folder), figures=figures, **options)
