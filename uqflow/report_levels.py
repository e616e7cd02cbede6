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


def method_cell(stats: xr.Dataset, method: str, out: str, focus: dict) -> str:
    """The summary table's method column: how sure, and what it saved."""
    at = stats[out].isel(focus)
    ratio = stats[f"{out}_cost_ratio"].isel(focus) if f"{out}_cost_ratio" in stats else np.nan
    parts = [f"stderr {_g(at.sel(statistic='stderr'))}"]
    if method == "multilevel":
        parts += [f"bias ~{_g(at.sel(statistic='bias'))}", f"rmse {_g(at.sel(statistic='rmse'))}"]
    parts.append(f"{_g(ratio)}x cheaper than plain MC at the finest level")
    return ", ".join(parts)


def level_lines(stats: xr.Dataset, method: str, outs: list[str], focus_of) -> list[str]:
    """The per-level (multilevel) or per-model (multifidelity) table."""
    units = stats["level_run_cost" if method == "multilevel" else "model_run_cost"].attrs.get(
        "units", "")
    cost_unit = "s" if units == "s" else "stated units"
    if method == "multilevel":
        lines = [f"levels (cost per run in {cost_unit}; E_l, V_l: mean and variance of the "
                 f"correction P_l - P_l-1 at each output's row point):"]
        head = ["level", "value", "N_l", "failed pairs", "C_l run", "N_l C_l"]
        for out in outs:
            head += [f"E_l {out}", f"V_l {out}"]
        rows = []
        for l in range(stats.sizes["level"]):
            n = int(stats["level_samples"].values[l])
            row = [str(l), _g(stats["level_value"].values[l]), str(n),
                   str(int(stats["level_failed_pairs"].values[l])),
                   _g(stats["level_run_cost"].values[l]),
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
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    fmt = (lambda r: "  ".join(str(c).rjust(w) for c, w in zip(r, widths)))
    return [fmt(head), fmt(["-" * w for w in widths]), *map(fmt, rows)]


def levels_figure(ctx, out: str):
    """V_l and |E_l| (at the output's row point) against level, log2 scale, with the fitted
    rates; C_l with gamma; the cost each level took. None for other methods."""
    if ctx.method != "multilevel" or f"{out}_level_variance" not in ctx.stats:
        return None
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from uqflow.report import _focus

    stats = ctx.stats
    focus = _focus(stats, out)
    l = np.arange(stats.sizes["level"])
    V = np.asarray(stats[f"{out}_level_variance"].isel(focus).values, dtype=float)
    E = np.abs(np.asarray(stats[f"{out}_level_mean"].isel(focus).values, dtype=float))
    c = np.asarray(stats["level_run_cost"].values, dtype=float)
    spent = np.asarray(stats["level_samples"].values) * stats["level_sample_cost"].values
    fig = Figure(figsize=(12.0, 3.8), layout="constrained")
    FigureCanvasAgg(fig)
    ax, cx, bx = fig.subplots(1, 3)
    alpha, beta = (float(v) for v in stats[f"{out}_rates"].values)
    for values, label, rate, style in ((V, "V_l", beta, "o-"), (E, "|E_l|", alpha, "s-")):
        ok = values > 0
        ax.plot(l[ok], np.log2(values[ok]), style, label=f"{label}, rate {_g(rate)}")
        if np.isfinite(rate):
            ax.plot(l[1:], np.log2(values[-1]) - rate * (l[1:] - l[-1]), ":", color="0.5")
    ax.set(xlabel="level", ylabel="log2", title=ctx.title(out, "corrections", focus))
    ax.legend(fontsize=8)
    cx.plot(l, np.log2(c), "^-", label=f"C_l, rate {_g(stats.attrs.get('gamma'))}")
    cx.set(xlabel="level", ylabel="log2 cost per run", title="cost per run")
    cx.legend(fontsize=8)
    bx.bar(l, spent, color="tab:blue")
    bx.set(xlabel="level", ylabel="N_l C_l", title="cost each level took")
    for a in (ax, cx, bx):
        a.set_xticks(l)
    return fig
