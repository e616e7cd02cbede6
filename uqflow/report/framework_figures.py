"""The figures every result gets, whatever its method and solver (docs/results.md, "Figures"),
and ``write_figures``, which adds the figures the result's method draws (its ``MethodReport``).

- ``<output>_scatter.png``: an output over time or space: the mean with a 95 % prediction band
  (the runs' 2.5-97.5 % quantiles where the runs are draws, else mean ± 1.96 std), the 95 %
  interval of the mean as a second, lighter band, and the standard deviation below it; one
  panel per label of a second, categorical dim (a probe), at most ``MAX_PANELS``.
- ``<output>_histogram.png``, ``<output>_exceedance.png``: a scalar output's runs, and
  P[Y > y] with a pointwise 95 % Clopper-Pearson band (runs that are draws only).
- ``<output>_sensitivities.png``: where the method gives a ``Sensitivity``.

``exceedance_log_figure`` draws a limit state's exceedance curve on a log probability axis
from arrays (levels, estimate, band, threshold, p_f): for any method's report hook.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr
from scipy import stats as sps

from uqflow.layout import (LONG_NAME, PARAMETER, STATISTIC, STATISTIC_MEAN, STATISTIC_STD,
                           STATISTIC_STDERR, UNITS)
from uqflow.report.figures import (FigureWarning, colors, figure_path, input_label, new_figure,
                                   save_figure)
from uqflow.report.units import display_units, quantity_label
from uqflow.report.view import ResultView

#: small multiples of a field's categorical dim (probes): at most this many panels
MAX_PANELS = 8
#: the probability of the prediction band, the interval of the mean and the exceedance band
LEVEL = 0.95
Z95 = float(sps.norm.ppf(0.5 + LEVEL / 2))  # 1.959964...: the two-sided 95 % normal quantile

BAND_COLOR, MEAN_COLOR, STDERR_COLOR, STD_COLOR = "#9ab7d3", "#1f4e79", "#e08e2b", "#2e7d32"
MEAN_INTERVAL_LABEL = "95 % interval of the mean (± 1.96 standard errors)"


# --------------------------------------------------------------------------- the numbers

@dataclass(frozen=True)
class ScatterBand:
    """The numbers a scatter figure draws, with the output's dims (no ``statistic``)."""

    mean: xr.DataArray
    std: xr.DataArray
    lower: xr.DataArray
    upper: xr.DataArray
    stderr: xr.DataArray | None
    label: str
    from_runs: bool


def scatter_band(view: ResultView, output: str) -> ScatterBand | None:
    """The 95 % prediction band of ``output``: the 2.5 and 97.5 % quantiles of the runs where
    they are draws from the inputs' distribution (``MethodReport.runs_are_draws``), else
    mean ± 1.96 std from the statistics (95 % if the output were normal). None without a
    mean and a std."""
    mean, std = view.statistic(output, STATISTIC_MEAN), view.statistic(output, STATISTIC_STD)
    if mean is None or std is None:
        return None
    stderr = view.statistic(output, STATISTIC_STDERR)
    stderr = None if stderr is None or not np.any(np.isfinite(stderr.values)) else stderr
    runs = view.sample_values(output) if view.method_report.runs_are_draws else None
    if runs is not None and runs.shape[1:] == mean.shape and runs.shape[0] >= 2:
        with warnings.catch_warnings():  # a point where every run is NaN stays NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            low, high = np.nanquantile(runs, [0.5 - LEVEL / 2, 0.5 + LEVEL / 2], axis=0)
        return ScatterBand(mean, std, mean.copy(data=low), mean.copy(data=high), stderr,
                           f"95 % of the runs (2.5-97.5 % quantiles of {runs.shape[0]} runs)",
                           True)
    return ScatterBand(mean, std, mean - Z95 * std, mean + Z95 * std, stderr,
                       "mean ± 1.96 std (95 % of the scatter if it is normal)", False)


@dataclass(frozen=True)
class Exceedance:
    """The empirical exceedance curve P[Y > y] at each distinct run value ``levels`` (the
    curve steps down there) and its pointwise ``confidence`` Clopper-Pearson band."""

    levels: np.ndarray
    probability: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    count: int
    confidence: float = LEVEL


def exceedance_curve(values, confidence: float = LEVEL) -> Exceedance | None:
    """P[Y > y] from the finite ``values`` (runs that are draws): k of n runs above y give
    k/n, and the exact binomial (Clopper-Pearson) interval beta(a/2; k, n-k+1) ..
    beta(1-a/2; k+1, n-k), a = 1 - confidence, with 0 and 1 at k = 0 and k = n. None with
    fewer than two finite values."""
    y = np.sort(np.asarray(values, dtype=float).ravel())
    y = y[np.isfinite(y)]
    n = y.size
    if n < 2:
        return None
    levels = np.unique(y)
    above = n - np.searchsorted(y, levels, side="right")
    alpha = 1.0 - confidence
    with np.errstate(invalid="ignore"):
        lower = np.where(above == 0, 0.0, sps.beta.ppf(alpha / 2, above, n - above + 1))
        upper = np.where(above == n, 1.0, sps.beta.ppf(1 - alpha / 2, above + 1, n - above))
    return Exceedance(levels, above / n, lower, upper, n, confidence)


# --------------------------------------------------------------------------- drawing helpers

def _title(view: ResultView, output: str, what: str, at: str = "") -> str:
    where = f" at {at}" if at else ""
    return f"{view.study}: {view.long_name(output)}{where}\n{what} ({view.description})"


def _axis(view: ResultView, dim: str) -> tuple[np.ndarray, str, bool]:
    """The values of ``dim`` in display units, the axis label, and whether it is numeric."""
    ds = view.stats
    if dim in ds.coords and np.issubdtype(ds[dim].dtype, np.number):
        values = np.asarray(ds[dim].values, dtype=float)
        scale, units = display_units(values, ds[dim].attrs.get(UNITS, ""))
        name = str(ds[dim].attrs.get(LONG_NAME, dim))
        return values * scale, quantity_label(name, units), True
    return np.arange(ds.sizes[dim], dtype=float), \
        (dim if dim in ds.coords else f"{dim} (index)"), False


def _field_layout(var: xr.DataArray) -> tuple[str, str | None] | None:
    """(x dim, panel dim or None) of an output with one or two field dims: x is the first
    numeric dim (else the only dim), panels the other one. None where that does not fit."""
    dims = [d for d in var.dims if d != STATISTIC]
    if not dims or len(dims) > 2:
        return None
    numeric = [d for d in dims if d in var.coords and np.issubdtype(var[d].dtype, np.number)]
    if len(dims) == 1:
        return dims[0], None
    if not numeric:
        return None
    x = numeric[0]
    return x, next(d for d in dims if d != x)


def _panels(size: int) -> list[int]:
    """Which labels of a panel dim get a panel: all, or ``MAX_PANELS`` spread evenly."""
    if size <= MAX_PANELS:
        return list(range(size))
    return sorted({int(round(i)) for i in np.linspace(0, size - 1, MAX_PANELS)})


# --------------------------------------------------------------------------- the figures

def scatter_figure(view: ResultView, output: str):
    """The mean, the 95 % prediction band and the 95 % interval of the mean over a field's
    dim, the standard deviation below; one panel per label of a second dim."""
    var = view.stats[output]
    layout = _field_layout(var)
    band = scatter_band(view, output) if layout else None
    if band is None:
        return None
    xdim, panel_dim = layout
    x, xlabel, numeric = _axis(view, xdim)
    labels = _panels(var.sizes[panel_dim]) if panel_dim else [None]
    scale, units = display_units(np.concatenate([np.ravel(band.lower.values),
                                                 np.ravel(band.upper.values)]),
                                 view.units(output))
    name = view.long_name(output)
    columns = min(len(labels), 4)
    groups = math.ceil(len(labels) / columns)
    fig, axes = new_figure(width=max(6.4, 3.8 * columns), height=4.6 * groups + 0.6,
                           rows=2 * groups, columns=columns, squeeze=False, sharex="col",
                           gridspec_kw={"height_ratios": [2, 1] * groups})
    for k, j in enumerate(labels):
        ax, ax_std = axes[2 * (k // columns), k % columns], axes[2 * (k // columns) + 1,
                                                                k % columns]
        pick = {panel_dim: j} if panel_dim else {}

        def line(a):
            return np.asarray(a.isel(pick).transpose(xdim).values, dtype=float) * scale

        if numeric:
            _draw_band(ax, ax_std, x, band, line)
        else:  # labels (probes, parts): no line between them, a bar at each
            _draw_bars(ax, ax_std, x, band, line)
            ax_std.set_xticks(x, [str(v) for v in view.stats[xdim].values]
                              if xdim in view.stats.coords else x.astype(int))
        if k % columns == 0:  # one y label per row of panels
            ax.set_ylabel(quantity_label(name, units))
            ax_std.set_ylabel(quantity_label("std", units))
        ax_std.set_xlabel(xlabel)
        if panel_dim:
            ax.set_title(view.where({panel_dim: j}), fontsize="medium")
    for k in range(len(labels), groups * columns):  # empty cells of the last row
        axes[2 * (k // columns), k % columns].set_visible(False)
        axes[2 * (k // columns) + 1, k % columns].set_visible(False)
    shown = (f", {len(labels)} of {var.sizes[panel_dim]} {panel_dim} labels"
             if panel_dim and len(labels) < var.sizes[panel_dim] else "")
    fig.suptitle(_title(view, output, f"scatter over {xdim}{shown}"))
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center",
               ncols=3 if columns > 2 else 1, fontsize="small")
    return fig


def _draw_band(ax, ax_std, x, band: ScatterBand, line) -> None:
    """The prediction band, the interval of the mean and the mean over a numeric axis."""
    ax.fill_between(x, line(band.lower), line(band.upper), color=BAND_COLOR, alpha=0.55,
                    linewidth=0, label=band.label)
    if band.stderr is not None:
        m, e = line(band.mean), Z95 * line(band.stderr)
        ax.fill_between(x, m - e, m + e, color=STDERR_COLOR, alpha=0.3, linewidth=0,
                        label=MEAN_INTERVAL_LABEL)
    ax.plot(x, line(band.mean), color=MEAN_COLOR, linewidth=1.8, label="mean")
    ax_std.plot(x, line(band.std), color=STD_COLOR, linewidth=1.5)


def _draw_bars(ax, ax_std, x, band: ScatterBand, line) -> None:
    """The same at each label of a categorical axis: a wide bar for the prediction band, a
    narrower one for the interval of the mean, a dot for the mean."""
    ax.vlines(x, line(band.lower), line(band.upper), color=BAND_COLOR, linewidth=12,
              label=band.label)
    if band.stderr is not None:
        m, e = line(band.mean), Z95 * line(band.stderr)
        ax.vlines(x, m - e, m + e, color=STDERR_COLOR, alpha=0.6, linewidth=5,
                  label=MEAN_INTERVAL_LABEL)
    ax.plot(x, line(band.mean), "o", color=MEAN_COLOR, label="mean")
    ax_std.plot(x, line(band.std), "o", color=STD_COLOR)
    ax.margins(x=0.15)


def _scalar_runs(view: ResultView, output: str) -> np.ndarray | None:
    """A scalar output's finite values in the runs that are draws (None: no such runs)."""
    if not view.method_report.runs_are_draws or view.stats[output].ndim != 1:
        return None
    y = view.sample_values(output)
    if y is None:
        return None
    y = y[np.isfinite(y)]
    return y if y.size >= 2 else None


def histogram_figure(view: ResultView, output: str):
    """The runs of a scalar output, their mean and their central 95 %."""
    y = _scalar_runs(view, output)
    if y is None:
        return None
    scale, units = display_units(y, view.units(output))
    y = y * scale
    fig, ax = new_figure()
    edges = np.histogram_bin_edges(y, bins="auto")
    ax.hist(y, bins=edges if len(edges) <= 61 else 60, color=BAND_COLOR, edgecolor="white",
            linewidth=0.4)
    lo, hi = np.quantile(y, [0.5 - LEVEL / 2, 0.5 + LEVEL / 2])
    ax.axvspan(lo, hi, color="#f2c14e", alpha=0.25, zorder=0,
               label=f"central 95 % of the runs: {lo:.4g} .. {hi:.4g} {units}".rstrip())
    ax.axvline(float(np.mean(y)), color="#c0392b", linewidth=2,
               label=f"mean of the runs {np.mean(y):.4g} {units}".rstrip())
    ax.set_xlabel(quantity_label(view.long_name(output), units))
    ax.set_ylabel("runs per bin")
    ax.set_title(_title(view, output, f"distribution of {y.size} runs"))
    ax.legend(loc="best", fontsize="small")
    return fig


def exceedance_figure(view: ResultView, output: str):
    """P[Y > y] of a scalar output from its runs, with its pointwise 95 % band."""
    y = _scalar_runs(view, output)
    curve = exceedance_curve(y) if y is not None else None
    if curve is None:
        return None
    scale, units = display_units(curve.levels, view.units(output))
    levels = curve.levels * scale
    # Left of the smallest run every run exceeds y: the curve starts at 1.
    start = levels[0] - 0.05 * max(levels[-1] - levels[0], abs(levels[0]), 1e-300)
    xs = np.concatenate([[start], levels])
    fig, ax = new_figure()
    # all n runs above y: P = 1 with the lower bound of k = n, (a/2)^(1/n)
    everything = ((1 - curve.confidence) / 2) ** (1 / curve.count)
    ax.fill_between(xs, np.concatenate([[everything], curve.lower]),
                    np.concatenate([[1.0], curve.upper]), step="post", color=BAND_COLOR,
                    alpha=0.55, linewidth=0,
                    label="95 % band, pointwise (exact binomial, Clopper-Pearson)")
    ax.step(xs, np.concatenate([[1.0], curve.probability]), where="post", color=MEAN_COLOR,
            linewidth=1.8, label=f"fraction of the {curve.count} runs above y")
    ax.set_xlabel(quantity_label(f"y: {view.long_name(output)}", units))
    ax.set_ylabel("P[Y > y]")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(_title(view, output, "exceedance probability"))
    ax.legend(loc="best", fontsize="small")
    return fig


_SIGNS = {">=": "≥", "<=": "≤"}


def exceedance_log_figure(levels, probability, lower, upper, *, threshold: float,
                          failure_probability: float, failure_interval=(math.nan, math.nan),
                          comparison: str = ">", name: str = "y", units: str = "",
                          curve_label: str = "estimate", band_label: str = "band",
                          title: str = "", steps: bool = True):
    """The exceedance curve of a limit state's quantity on a log probability axis, for any
    method that estimates one (sampling, subset levels, weighted samples): arrays, no view.

    ``levels`` (increasing, in ``units``, SI) and at each the estimate ``probability`` of
    P[Y > y] (``comparison`` ">"; ">=", "<", "<=" likewise) with its band ``lower`` .. ``upper``
    (NaN: no band there); ``threshold`` is the limit state's, marked by a vertical line, and
    ``failure_probability`` with its ``failure_interval`` by a horizontal line and an error
    bar at the threshold. ``steps``: an empirical curve (constant between levels: after each
    level for ">" and "<=", before it for ">=" and "<") rather than a line through the
    points. Probabilities
    of 0 have no place on a log axis: the curve leaves them out and the band's lower bound
    is drawn at the axis' floor, a tenth of the smallest positive number shown. None when
    nothing positive is left to draw."""
    levels, probability, lower, upper = (np.asarray(a, dtype=float).ravel()
                                         for a in (levels, probability, lower, upper))
    low_pf, high_pf = (float(b) for b in failure_interval)
    shown = np.concatenate([probability, lower, upper, [failure_probability, low_pf,
                                                        high_pf]])
    positive = shown[np.isfinite(shown) & (shown > 0)]
    if positive.size == 0 or levels.size == 0:
        return None
    floor = 0.1 * float(positive.min())
    scale, shown_units = display_units(np.append(levels, threshold), units)
    x = levels * scale
    # P[Y > y] and P[Y <= y] hold their value after each level, P[Y >= y], P[Y < y] before
    where = "post" if comparison in (">", "<=") else "pre"
    if steps:
        # the outer step on the side the curve holds its value gets a width too
        width = 0.05 * max(float(np.ptp(x)), abs(float(x[0])), 1e-300)
        if where == "post":
            x, probability, lower, upper = (np.append(a, a[-1]) for a in
                                            (x, probability, lower, upper))
            x[-1] += width
        else:
            x, probability, lower, upper = (np.insert(a, 0, a[0]) for a in
                                            (x, probability, lower, upper))
            x[0] -= width
    drawstyle = {"step": where} if steps else {}
    fig, ax = new_figure()
    finite_band = np.isfinite(lower) & np.isfinite(upper)
    if finite_band.any():
        ax.fill_between(x, np.where(finite_band, np.maximum(lower, floor), np.nan),
                        np.where(finite_band, upper, np.nan), color=BAND_COLOR, alpha=0.55,
                        linewidth=0, label=band_label, **drawstyle)
    with np.errstate(invalid="ignore"):
        curve = np.where(probability > 0, probability, np.nan)
    if steps:
        ax.step(x, curve, where=where, color=MEAN_COLOR, linewidth=1.8, label=curve_label)
    else:
        ax.plot(x, curve, color=MEAN_COLOR, linewidth=1.8, marker="o", markersize=3,
                label=curve_label)
    ax.axvline(threshold * scale, color="#c0392b", linestyle="--", linewidth=1.2,
               label=f"threshold {threshold * scale:.4g} {shown_units}".rstrip())
    if np.isfinite(failure_probability) and failure_probability > 0:
        ax.axhline(failure_probability, color="#7b2d26", linestyle=":", linewidth=1.2)
        errors = None
        if np.isfinite(low_pf) and np.isfinite(high_pf):
            errors = [[failure_probability - max(low_pf, floor)],
                      [high_pf - failure_probability]]
        ax.errorbar([threshold * scale], [failure_probability], yerr=errors, fmt="o",
                    color="#7b2d26", capsize=4, zorder=5,
                    label=f"p_f = {failure_probability:.3g}" + (
                        f" ({low_pf:.3g} .. {high_pf:.3g})" if errors is not None else ""))
    elif failure_probability == 0 and np.isfinite(high_pf) and high_pf > 0:
        # no failure seen: the estimate has no place on the log axis, its upper bound has
        ax.plot([threshold * scale], [high_pf], "v", color="#7b2d26", zorder=5,
                label=f"p_f = 0, no failure seen (upper bound {high_pf:.3g})")
    ax.set_yscale("log")
    ax.set_ylim(floor, min(1.5, 2.0 * float(positive.max())))
    ax.set_xlabel(quantity_label(f"y: {name}", shown_units))
    ax.set_ylabel(f"P[Y {_SIGNS.get(comparison, comparison)} y]")
    ax.grid(True, which="major", axis="y", linewidth=0.4, alpha=0.5)
    if title:
        ax.set_title(title)
    ax.legend(loc="best", fontsize="small")
    return fig


def sensitivity_figure(view: ResultView, output: str):
    """The method's sensitivity indices of ``output``: bars (inputs x kinds of index) at the
    output's row point, or lines over a field's one dim."""
    found = view.method_report.sensitivities
    sens = found(output) if found is not None else None
    if sens is None:
        return None
    values = sens.values
    field = [d for d in values.dims if d not in (PARAMETER, "index")]
    kinds = [str(k) for k in values["index"].values]
    params = [str(p) for p in values[PARAMETER].values]
    errors = sens.errors
    if len(field) == 1:
        return _sensitivity_lines(view, output, sens, field[0], kinds, params)
    focus = {d: i for d, i in view.focus(output).items() if d in field}
    at = values.isel(focus)
    err = errors.isel(focus) if errors is not None else None
    fig, ax = new_figure(width=max(6.4, 1.0 * len(params) * max(len(kinds), 1) ** 0.5 + 3))
    x = np.arange(len(params))
    width = 0.8 / max(len(kinds), 1)
    for j, (kind, color) in enumerate(zip(kinds, colors(len(kinds)))):
        bar = np.asarray(at.sel(index=kind).transpose(PARAMETER).values, dtype=float)
        yerr = (np.abs(np.asarray(err.sel(index=kind).transpose(PARAMETER).values, float))
                if err is not None else None)
        ax.bar(x + (j - (len(kinds) - 1) / 2) * width, bar, width, yerr=yerr, capsize=3,
               color=color, label=kind, error_kw={"elinewidth": 1, "ecolor": "0.2"})
    ax.axhline(0, color="0.3", linewidth=0.8)
    if PARAMETER in view.stats.coords and view.stats.sizes.get(PARAMETER) == len(params):
        ax.set_xticks(x, [input_label(view.stats, k) for k in range(len(params))])
    else:
        ax.set_xticks(x, params)
    ax.set_xlabel("input")
    ax.set_ylabel(sens.quantity)
    ax.legend(loc="best", fontsize="small")
    bars = f"; error bars: {sens.error_label}" if err is not None and sens.error_label else ""
    ax.set_title(_title(view, output, f"{sens.title}{bars}", view.where(view.focus(output))))
    return fig


def _sensitivity_lines(view, output, sens, dim, kinds, params):
    x, xlabel, _ = _axis(view, dim)
    fig, ax = new_figure()
    styles = ["-", "--", ":", "-."]
    for k, (p, color) in enumerate(zip(params, colors(len(params)))):
        for j, kind in enumerate(kinds):
            val = np.asarray(sens.values.sel(index=kind).isel({PARAMETER: k})
                             .transpose(dim).values, dtype=float)
            ax.plot(x, val, styles[j % len(styles)], color=color, label=f"{kind}: {p}")
            if sens.errors is not None:
                err = np.abs(np.asarray(sens.errors.sel(index=kind).isel({PARAMETER: k})
                                        .transpose(dim).values, dtype=float))
                ax.fill_between(x, val - err, val + err, color=color, alpha=0.12, linewidth=0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(sens.quantity)
    ax.legend(loc="best", fontsize="small", ncol=2)
    bands = f"; bands: {sens.error_label}" if sens.errors is not None and sens.error_label \
        else ""
    kinds_text = ", ".join(f"{k} {styles[j % len(styles)]}" for j, k in enumerate(kinds))
    ax.set_title(_title(view, output, f"{sens.title} over {dim} ({kinds_text}){bands}"))
    return fig


#: the framework's figures of every output, in the order they are written
FRAMEWORK_FIGURES = [("scatter", scatter_figure), ("histogram", histogram_figure),
                     ("exceedance", exceedance_figure), ("sensitivities", sensitivity_figure)]


# --------------------------------------------------------------------------- writing them

def write_figures(tree: xr.DataTree, folder: Path) -> list[Path]:
    """Draw the figures that apply to this result into ``folder``; return the paths written:
    the framework's figures of each output, then the method's (``MethodReport.figures``:
    ``<output>_<kind>.png`` per output, ``<kind>.png`` for the whole result). A result without
    statistics gets none. A figure that fails is skipped with a ``FigureWarning``."""
    view = ResultView(tree)
    if view.stats is None:
        return []
    folder = Path(folder)
    jobs = [((out, kind), draw, out) for out in view.outputs for kind, draw in FRAMEWORK_FIGURES]
    for spec in view.method_report.figures:
        if spec.per_output:
            jobs += [((out, spec.kind), spec.draw, out) for out in view.outputs]
        else:
            jobs.append(((spec.kind,), spec.draw, None))
    written: list[Path] = []
    for parts, draw, out in jobs:
        name = "_".join(parts)
        try:
            fig = draw(view, out)
        except Exception as exc:  # one broken figure must not cost the others
            warnings.warn(f"figure {name}.png not written: {type(exc).__name__}: {exc}",
                          FigureWarning, stacklevel=2)
            continue
        if fig is None:
            continue
        folder.mkdir(parents=True, exist_ok=True)
        path = figure_path(folder, *parts)
        if path in written:  # two names that differ only in characters made '_'
            path = figure_path(folder, *parts, len(written))
        save_figure(fig, path)
        written.append(path)
    return written
