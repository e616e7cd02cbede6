"""What the report says of a multilevel or multifidelity result (their ``report`` hooks): how
sure each output's estimate is and what it saved, the level (or model) table, a figure of
V_l, |E_l| and C_l against level with the fitted rates beside the cost each level took, and
``uqflow report a.nc b.nc``'s comparison of the error each result bought against its cost."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import xarray as xr

from uqflow.layout import (LEVEL, METHOD, SOLVER, SOLVER_COMPILE_TIME, SOLVER_RUNS,
                           SOLVER_WALL_TIME, STATISTIC, STATISTIC_STD, STATISTIC_STDERR,
                           STATISTIC_VARIANCE, STATISTICS_GROUP, STUDY_NAME, UNITS)
from uqflow.report import (Column, FigureSpec, MethodReport, ResultView, figure_path, grid,
                           new_figure, save_figure)

#: the methods whose results this module reports; the first is the one with levels of a
#: hierarchy (corrections P_l - P_l-1), the second the one with models beside the finest
MULTILEVEL, MULTIFIDELITY = "multilevel", "multifidelity"
#: the Monte Carlo method, whose result in a comparison gives plain MC's cost per run
MONTE_CARLO = "monte-carlo"
#: statistics labels of the multilevel estimate: its bias estimate and root mean square error
BIAS, RMSE = "bias", "rmse"
#: multifidelity's dim of models (0 = high fidelity)
MODEL = "model"


def _g(x) -> str:
    x = float(x)
    return "nan" if not np.isfinite(x) else f"{x:.4g}"


def squared(unit: str) -> str:
    """The unit of a variance: ``unit^2``, or '-' for a dimensionless output."""
    if unit in ("", "-", "1"):
        return "-"
    return f"{unit}^2" if unit.isalpha() else f"({unit})^2"  # m s-1 -> (m s-1)^2


def cost_unit(stats: xr.Dataset, variable: str) -> str:
    """'s' for measured costs, 'stated units' for the study's stated ones."""
    return "s" if stats[variable].attrs.get(UNITS, "") == "s" else "stated units"


def level_report(view: ResultView, description: str) -> MethodReport:
    """A multilevel or multifidelity result's part of its report."""
    stats, method = view.stats, view.method
    column = Column("how sure [u], what it saved",
                    lambda out, focus: how_sure(stats, method, out, focus))
    notes = [""] + level_lines(stats, method, view.outputs, view.focus, view.units)
    figures = [FigureSpec("levels", levels_figure)] if method == MULTILEVEL else []
    return MethodReport(description=description, runs_are_draws=False, columns=[column],
                        notes=notes, figures=figures)


def how_sure(stats: xr.Dataset, method: str, out: str, focus: dict) -> str:
    """The summary table's method column: how sure (in the output's unit u), and what it
    saved."""
    at = stats[out].isel(focus)
    ratio = stats[f"{out}_cost_ratio"].isel(focus) if f"{out}_cost_ratio" in stats else np.nan
    parts = [f"stderr {_g(at.sel({STATISTIC: STATISTIC_STDERR}))}"]
    if method == MULTILEVEL:
        parts += [f"bias ~{_g(at.sel({STATISTIC: BIAS}))}",
                  f"rmse {_g(at.sel({STATISTIC: RMSE}))}"]
    parts.append(f"{_g(ratio)}x cheaper than plain MC at the finest level")
    return ", ".join(parts)


def level_lines(stats: xr.Dataset, method: str, outs: list[str], focus_of,
                units_of=lambda out: "") -> list[str]:
    """The per-level (multilevel) or per-model (multifidelity) table; ``units_of(out)`` gives
    an output's unit for the headers of its columns."""
    if method == MULTILEVEL:
        return _multilevel_lines(stats, outs, focus_of, units_of)
    unit = cost_unit(stats, "model_run_cost")
    lines = [f"models (0 = high fidelity; cost per run in {unit}; rho: correlation with "
             f"model 0 at each output's row point):"]
    head = ["model", "level value", "samples", "cost/run"] + [f"rho {o}" for o in outs] + \
        [f"alpha {o}" for o in outs]
    rows = []
    for m in range(stats.sizes[MODEL]):
        row = [str(m), _g(stats["level_value"].values[m]),
               str(int(stats["model_samples"].values[m])), _g(stats["model_run_cost"].values[m])]
        row += [f"{float(stats[f'{o}_correlation'].isel({MODEL: m, **focus_of(o)})):.6f}"
                for o in outs]
        row += [_g(stats[f"{o}_weight"].isel({MODEL: m, **focus_of(o)})) for o in outs]
        rows.append(row)
    lines += grid(head, rows, right=set(range(len(head))))
    lines.append(f"{stats.attrs.get('rounds', '?')} rounds, total cost "
                 f"{_g(stats.attrs.get('total_cost'))} {unit}, "
                 f"{stats.attrs.get('dropped_samples', 0)} samples dropped for failures")
    return lines


def _multilevel_lines(stats, outs, focus_of, units_of) -> list[str]:
    unit = cost_unit(stats, "level_run_cost")
    # A sample of level l > 0 is a pair of runs (levels l and l - 1): its cost C_l is
    # c_l + c_l-1, and the level's share of the study is N_l C_l.
    lines = [f"levels (cost per run in {unit}; E_l, V_l: mean and variance of the "
             f"correction P_l - P_l-1 at each output's row point; a sample of level "
             f"l > 0 is the pair of runs at l and l - 1):"]
    head = ["level", "value", "N_l", "failed pairs", f"run cost c_l [{unit}]",
            f"sample cost C_l [{unit}]", f"level cost N_l C_l [{unit}]"]
    for out in outs:
        out_unit = units_of(out) or "-"
        head += [f"E_l {out} [{out_unit}]", f"V_l {out} [{squared(out_unit)}]"]
    rows = []
    for l in range(stats.sizes[LEVEL]):
        n = int(stats["level_samples"].values[l])
        row = [str(l), _g(stats["level_value"].values[l]), str(n),
               str(int(stats["level_failed_pairs"].values[l])),
               _g(stats["level_run_cost"].values[l]), _g(stats["level_sample_cost"].values[l]),
               _g(n * stats["level_sample_cost"].values[l])]
        for out in outs:
            at = {LEVEL: l, **focus_of(out)}
            row += [_g(stats[f"{out}_level_mean"].isel(at)),
                    _g(stats[f"{out}_level_variance"].isel(at))]
        rows.append(row)
    lines += grid(head, rows, right=set(range(len(head))))
    rates = ", ".join(f"{out}: alpha {_g(stats[f'{out}_rates'].values[0])}, beta "
                      f"{_g(stats[f'{out}_rates'].values[1])}" for out in outs)
    lines.append(f"rates per level: {rates}; gamma {_g(stats.attrs.get('gamma'))}; "
                 f"{stats.attrs.get('rounds', '?')} rounds, total cost "
                 f"{_g(stats.attrs.get('total_cost'))} {unit}")
    return lines


def levels_figure(view: ResultView, out: str):
    """V_l (unit^2) and |E_l| (unit) at the output's row point against level, each on its own
    log2 axis with its fitted rate; the cost per run c_l with gamma; the cost each level took.
    None for a result without level corrections."""
    stats = view.stats
    if f"{out}_level_variance" not in stats:
        return None
    focus = view.focus(out)
    unit = view.units(out) or "-"
    c_unit = cost_unit(stats, "level_run_cost")
    l = np.arange(stats.sizes[LEVEL])
    V = np.asarray(stats[f"{out}_level_variance"].isel(focus).values, dtype=float)
    E = np.abs(np.asarray(stats[f"{out}_level_mean"].isel(focus).values, dtype=float))
    c = np.asarray(stats["level_run_cost"].values, dtype=float)
    spent = np.asarray(stats["level_samples"].values) * stats["level_sample_cost"].values
    fig, ((vx, ex), (cx, bx)) = new_figure(width=9.0, height=6.6, rows=2, columns=2,
                                           sharex=False)
    alpha, beta = (float(v) for v in stats[f"{out}_rates"].values)
    for ax, values, label, rate, name, style, axis_unit in (
            (vx, V, "V_l", beta, "beta", "o-", squared(unit)),
            (ex, E, "|E_l|", alpha, "alpha", "s-", unit)):
        ok = values > 0
        ax.plot(l[ok], np.log2(values[ok]), style, label=f"{label}, {name} = {_g(rate)}")
        if np.isfinite(rate) and ok[-1]:
            ax.plot(l[1:], np.log2(values[-1]) - rate * (l[1:] - l[-1]), ":", color="0.5",
                    label=f"slope -{name}")
        ax.set(xlabel="level", ylabel=f"log2 {label} [{axis_unit}]",
               title=f"{label}: {'variance' if label == 'V_l' else 'mean'} of the correction")
        ax.legend(fontsize=8)
    cx.plot(l, np.log2(c), "^-", label=f"c_l, gamma = {_g(stats.attrs.get('gamma'))}")
    cx.set(xlabel="level", ylabel=f"log2 c_l [{c_unit}]", title="cost of one run")
    cx.legend(fontsize=8)
    bx.bar(l, spent, color="tab:blue")
    bx.set(xlabel="level", ylabel=f"N_l C_l [{c_unit}]",
           title="cost each level took (C_l: a pair of runs)")
    for a in (vx, ex, cx, bx):
        a.set_xticks(l)
    where = f" at {view.where(focus)}" if focus else ""
    # ~95 characters fit across 9 inches at the suptitle's size: wrap rather than clip.
    fig.suptitle("\n".join(textwrap.wrap(f"{view.study}: {out}{where}, multilevel levels",
                                          width=90)))
    return fig


def cost_comparison(trees: list, folder, figures: bool = True) -> tuple[str, list[Path]]:
    """For results of one solver and output, at least one of them multilevel or
    multifidelity: each result's standard error against its solver time, beside plain Monte
    Carlo at the finest level (from a plain Monte Carlo result among them, or else from the
    first multilevel result's own estimate of Var[P_L] and c_L). Empty otherwise."""
    views = [ResultView(t) for t in trees if STATISTICS_GROUP in t.children]
    if len(views) < 2 or not any(v.method in (MULTILEVEL, MULTIFIDELITY) for v in views):
        return "", []
    if len({str(v.attrs.get(SOLVER)) for v in views}) != 1:
        return "", []
    common = [o for o in views[0].outputs if all(o in v.stats for v in views)]
    if not common:
        return "", []
    out = common[0]
    focus = views[0].focus(out)
    rows, plain = [], None
    for view in views:
        stats, method = view.stats, str(view.stats.attrs.get(METHOD))
        at = stats[out].isel(focus)
        if STATISTIC_STDERR not in at[STATISTIC].values:
            continue
        se = float(at.sel({STATISTIC: STATISTIC_STDERR}))
        # numba's compile time is paid once per process, not per run: a cost that scales
        # with the samples leaves it out (results written before it was measured have none)
        cost = float(stats.attrs.get(SOLVER_WALL_TIME, np.nan)) - float(
            stats.attrs.get(SOLVER_COMPILE_TIME, 0.0))
        runs = int(stats.attrs.get(SOLVER_RUNS, 0))
        rows.append((str(view.attrs.get(STUDY_NAME, "?")), method, runs, cost, se))
        if method == MONTE_CARLO and plain is None:
            plain = (float(at.sel({STATISTIC: STATISTIC_STD})), cost / max(runs, 1))
        elif method == MULTILEVEL and plain is None and "level_run_cost" in stats:
            if stats["level_run_cost"].attrs.get(UNITS) == "s":
                plain = (float(np.sqrt(max(float(at.sel({STATISTIC: STATISTIC_VARIANCE})),
                                           0.0))),
                         float(stats["level_run_cost"].values[-1]))
    if not rows:
        return "", []
    lines = [f"error against cost, {out} at its row point of the first result "
             f"(plain MC at the finest level: "
             + ("s / sqrt(n) with its measured std and cost per run)" if plain else
                "no plain Monte Carlo result or measured costs among them)")]
    unit = str(views[0].stats[out].attrs.get(UNITS, "")) or "-"
    head = ["study", "method", "runs", "solver time without compile (s)", f"stderr [{unit}]",
            "plain MC time (s)"]
    table = []
    for name, method, runs, cost, se in rows:
        need = plain[0] ** 2 / se**2 * plain[1] if plain and se > 0 else np.nan
        table.append([name, method, str(runs), _g(cost), _g(se), _g(need)])
    lines += grid(head, table, right=set(range(len(head))))
    written = []
    if figures:
        written.append(_cost_figure(rows, plain, out, unit, Path(folder)))
    return "\n".join(lines), written


def compare(method_class, trees: list, folder, figures: bool = True):
    """``PropagationMethod.compare`` of the multilevel and multifidelity methods."""
    return cost_comparison(trees, folder, figures)


def _cost_figure(rows, plain, out, unit, folder: Path) -> Path:
    fig, ax = new_figure(height=4.4)
    costs = [r[3] for r in rows if np.isfinite(r[3]) and r[3] > 0]
    if plain and costs:
        c = np.geomspace(min(costs) / 10, max(costs) * 100, 50)
        ax.loglog(c, plain[0] * np.sqrt(plain[1] / c), "k-", label="plain MC, finest level")
    for (name, method, _, cost, se), marker in zip(rows, "os^vD<>p*h"):
        if np.isfinite(cost) and cost > 0 and se > 0:
            ax.loglog(cost, se, marker, ms=8, label=f"{name} ({method})")
    ax.set(xlabel="solver time without numba's compile time (s)",
           ylabel=f"standard error of {out} [{unit}]", title="error against cost")
    ax.legend(fontsize=8)
    folder.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, figure_path(folder, out, "error_vs_cost"))
