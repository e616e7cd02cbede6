"""What ``uqflow report`` says of a multilevel or multifidelity result: the level (or model)
table, and a figure of V_l, |E_l| and C_l against level with the fitted rates beside the cost
each level took."""

from __future__ import annotations

import numpy as np
import xarray as xr

LEVEL_METHODS = ("multilevel", "multifidelity")


def _g(x) -> str:
    x = float(x)
    return "nan" if not np.isfinite(x) else f"{x:.4g}"


def squared(unit: str) -> str:
    """The unit of a variance: ``unit^2``, or '-' for a dimensionless output."""
    if unit in ("", "-", "1"):
        return "-"
    return f"{unit}^2" if unit.isalpha() else f"({unit})^2"  # m s-1 -> (m s-1)^2


def method_cell(stats: xr.Dataset, method: str, out: str, focus: dict) -> str:
    """The summary table's method column: how sure (in the output's unit u), and what it
    saved."""
    at = stats[out].isel(focus)
    ratio = stats[f"{out}_cost_ratio"].isel(focus) if f"{out}_cost_ratio" in stats else np.nan
    parts = [f"stderr {_g(at.sel(statistic='stderr'))}"]
    if method == "multilevel":
        parts += [f"bias ~{_g(at.sel(statistic='bias'))}", f"rmse {_g(at.sel(statistic='rmse'))}"]
    parts.append(f"{_g(ratio)}x cheaper than plain MC at the finest level")
    return ", ".join(parts)


def level_lines(stats: xr.Dataset, method: str, outs: list[str], focus_of,
                units_of=lambda out: "") -> list[str]:
    """The per-level (multilevel) or per-model (multifidelity) table; ``units_of(out)`` gives
    an output's unit for the headers of its columns."""
    units = stats["level_run_cost" if method == "multilevel" else "model_run_cost"].attrs.get(
        "units", "")
    cost_unit = "s" if units == "s" else "stated units"
    if method == "multilevel":
        # A sample of level l > 0 is a pair of runs (levels l and l - 1): its cost C_l is
        # c_l + c_l-1, and the level's share of the study is N_l C_l.
        lines = [f"levels (cost per run in {cost_unit}; E_l, V_l: mean and variance of the "
                 f"correction P_l - P_l-1 at each output's row point; a sample of level "
                 f"l > 0 is the pair of runs at l and l - 1):"]
        head = ["level", "value", "N_l", "failed pairs", f"run cost c_l [{cost_unit}]",
                f"sample cost C_l [{cost_unit}]", f"level cost N_l C_l [{cost_unit}]"]
        for out in outs:
            unit = units_of(out) or "-"
            head += [f"E_l {out} [{unit}]", f"V_l {out} [{squared(unit)}]"]
        rows = []
        for l in range(stats.sizes["level"]):
            n = int(stats["level_samples"].values[l])
            row = [str(l), _g(stats["level_value"].values[l]), str(n),
                   str(int(stats["level_failed_pairs"].values[l])),
                   _g(stats["level_run_cost"].values[l]),
                   _g(stats["level_sample_cost"].values[l]),
                   _g(n * stats["level_sample_cost"].values[l])]
            for out in outs:
                sel = {"level": l, **focus_of(out)}
                row += [_g(stats[f"{out}_level_mean"].isel(sel)),
                        _g(stats[f"{out}_level_variance"].isel(sel))]
            rows.append(row)
        lines += _table(head, rows)
        rates = ", ".join(f"{out}: alpha {_g(stats[f'{out}_rates'].values[0])}, beta "
                          f"{_g(stats[f'{out}_rates'].values[1])}" for out in outs)
        lines.append(f"rates per level: {rates}; gamma {_g(stats.attrs.get('gamma'))}; "
                     f"{stats.attrs.get('rounds', '?')} rounds, total cost "
                     f"{_g(stats.attrs.get('total_cost'))} {cost_unit}")
        return lines
    lines = [f"models (0 = high fidelity; cost per run in {cost_unit}; rho: correlation with "
             f"model 0 at each output's row point):"]
    head = ["model", "level value", "samples", "cost/run"] + [f"rho {o}" for o in outs] + \
        [f"alpha {o}" for o in outs]
    rows = []
    for m in range(stats.sizes["model"]):
        row = [str(m), _g(stats["level_value"].values[m]), str(int(stats["model_samples"]
                                                                     .values[m])),
               _g(stats["model_run_cost"].values[m])]
        row += [f"{float(stats[f'{o}_correlation'].isel({'model': m, **focus_of(o)})):.6f}"
                for o in outs]
        row += [_g(stats[f"{o}_weight"].isel({"model": m, **focus_of(o)})) for o in outs]
        rows.append(row)
    lines += _table(head, rows)
    lines.append(f"{stats.attrs.get('rounds', '?')} rounds, total cost "
                 f"{_g(stats.attrs.get('total_cost'))} {cost_unit}, "
                 f"{stats.attrs.get('dropped_samples', 0)} samples dropped for failures")
    return lines


def _table(head, rows) -> list[str]:
    from uqflow.report.tables import grid as _grid

    return _grid(head, rows, right=set(range(len(head))))


def levels_figure(ctx, out: str):
    """V_l (unit^2) and |E_l| (unit) at the output's row point against level, each on its own
    log2 axis with its fitted rate; the cost per run c_l with gamma; the cost each level took.
    None for other methods."""
    if ctx.method != "multilevel" or f"{out}_level_variance" not in ctx.stats:
        return None
    import textwrap

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from uqflow.report.tables import focus_point as _focus, where as _where

    stats = ctx.stats
    focus = _focus(stats, out)
    unit = ctx.units(out) or "-"
    cost_unit = "s" if stats["level_run_cost"].attrs.get("units") == "s" else "stated units"
    l = np.arange(stats.sizes["level"])
    V = np.asarray(stats[f"{out}_level_variance"].isel(focus).values, dtype=float)
    E = np.abs(np.asarray(stats[f"{out}_level_mean"].isel(focus).values, dtype=float))
    c = np.asarray(stats["level_run_cost"].values, dtype=float)
    spent = np.asarray(stats["level_samples"].values) * stats["level_sample_cost"].values
    fig = Figure(figsize=(9.0, 6.6), layout="constrained")
    FigureCanvasAgg(fig)
    (vx, ex), (cx, bx) = fig.subplots(2, 2)
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
    cx.set(xlabel="level", ylabel=f"log2 c_l [{cost_unit}]", title="cost of one run")
    cx.legend(fontsize=8)
    bx.bar(l, spent, color="tab:blue")
    bx.set(xlabel="level", ylabel=f"N_l C_l [{cost_unit}]",
           title="cost each level took (C_l: a pair of runs)")
    for a in (vx, ex, cx, bx):
        a.set_xticks(l)
    where = f" at {_where(stats, focus)}" if focus else ""
    # ~95 characters fit across 9 inches at the suptitle's size: wrap rather than clip.
    fig.suptitle("\n".join(textwrap.wrap(f"{ctx.study}: {out}{where}, multilevel levels",
                                          width=90)))
    return fig


def cost_comparison(trees: list, folder, figures: bool = True) -> tuple[str, list]:
    """For results of one solver and output, at least one of them multilevel or
    multifidelity: each result's standard error against its solver time, beside plain Monte
    Carlo at the finest level (from a plain Monte Carlo result among them, or else from the
    first multilevel result's own estimate of Var[P_L] and c_L). Empty otherwise."""
    from pathlib import Path

    from uqflow.report.summary import _focus, _outputs

    parts = [(t.attrs, t["statistics"].to_dataset()) for t in trees if "statistics" in t.children]
    if len(parts) < 2 or not any(s.attrs.get("method") in LEVEL_METHODS for _, s in parts):
        return "", []
    if len({str(a.get("solver")) for a, _ in parts}) != 1:
        return "", []
    common = [o for o in _outputs(parts[0][1]) if all(o in s for _, s in parts)]
    if not common:
        return "", []
    out = common[0]
    focus = _focus(parts[0][1], out)
    rows, plain = [], None
    for attrs, stats in parts:
        method = str(stats.attrs.get("method"))
        at = stats[out].isel(focus)
        if "stderr" not in at["statistic"].values:
            continue
        se = float(at.sel(statistic="stderr"))
        # numba's compile time is paid once per process, not per run: a cost that scales
        # with the samples leaves it out (results written before it was measured have none)
        cost = float(stats.attrs.get("solver_wall_time", np.nan)) - float(
            stats.attrs.get("solver_compile_time", 0.0))
        rows.append((str(attrs.get("study_name", "?")), method, int(stats.attrs.get(
            "solver_runs", 0)), cost, se))
        if method == "monte-carlo" and plain is None:
            runs = int(stats.attrs.get("solver_runs", 0))
            plain = (float(at.sel(statistic="std")), cost / max(runs, 1))
        elif method == "multilevel" and plain is None and "level_run_cost" in stats:
            units = stats["level_run_cost"].attrs.get("units")
            if units == "s":
                plain = (float(np.sqrt(max(float(at.sel(statistic="variance")), 0.0))),
                         float(stats["level_run_cost"].values[-1]))
    if not rows:
        return "", []
    lines = [f"error against cost, {out} at its row point of the first result "
             f"(plain MC at the finest level: "
             + ("s / sqrt(n) with its measured std and cost per run)" if plain else
                "no plain Monte Carlo result or measured costs among them)")]
    unit = str(parts[0][1][out].attrs.get("units", "")) or "-"
    head = ["study", "method", "runs", "solver time without compile (s)", f"stderr [{unit}]",
            "plain MC time (s)"]
    table = []
    for name, method, runs, cost, se in rows:
        need = plain[0] ** 2 / se**2 * plain[1] if plain and se > 0 else np.nan
        table.append([name, method, str(runs), _g(cost), _g(se), _g(need)])
    lines += _table(head, table)
    written = []
    if figures:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.4, 4.4), layout="constrained")
        FigureCanvasAgg(fig)
        ax = fig.subplots()
        costs = [r[3] for r in rows if np.isfinite(r[3]) and r[3] > 0]
        if plain and costs:
            c = np.geomspace(min(costs) / 10, max(costs) * 100, 50)
            ax.loglog(c, plain[0] * np.sqrt(plain[1] / c), "k-", label="plain MC, finest level")
        for (name, method, _, cost, se), marker in zip(rows, "os^vD<>p*h"):
            if np.isfinite(cost) and cost > 0 and se > 0:
                ax.loglog(cost, se, marker, ms=8, label=f"{name} ({method})")
        ax.set(xlabel="solver time without numba's compile time (s)",
               ylabel=f"standard error of {out} [{unit}]",
               title="error against cost")
        ax.legend(fontsize=8)
        from uqflow.report import figure_path

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        path = figure_path(folder, out, "error_vs_cost")
        fig.savefig(path, dpi=110)
        written.append(path)
    return "\n".join(lines), written
