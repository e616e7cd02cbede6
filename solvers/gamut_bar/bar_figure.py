""""The bar with its field realizations": the figure every gamut-bar result gets.

The bar is drawn along x (mm), fixed at x = 0 and loaded at x = L (a pull to failure, or
tension–compression cycles then a pull); below it, one panel per parameter a random field
drives (Young's modulus, density, modulus of softness, bond weights): a few realizations, their
mean and the band holding 95 % of them (2.5–97.5 % quantiles at each point), in the
parameter's units. A result without random fields shows the bar with its nominal properties.

Field values come from the runs: the stored values (``runs.field_<parameter>``, a field with
``store_values = true``) where there are any, else they are rebuilt from the stored germs
(``runs.germ_<field>``) and the field's KL modes on the nominal grid, exactly as the study
built them (the [[fields]] tables of the stored study text). Either way they are plotted at
the points of the nominal (uniform) grid: on a stochastic grid a realization's own points
differ from those by at most its grid perturbation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from uqflow.fields import FieldSample, FieldSpec, RandomField, field_value_variable
from uqflow.layout import FIELD_PREFIX, GERM_PREFIX, INPUTS, PARAMETER
from uqflow.report import axis_label, new_figure

#: how a field's parameter is labelled and shown: (words, display unit, SI per display unit)
FIELD_LABELS = {
    "bar.E": ("Young's modulus E", "GPa", 1e9),
    "bar.rho": ("density ρ", "kg/m³", 1.0),
    "bar.R": ("modulus of softness R", "-", 1.0),
    "bar.w": ("nonlocal bond weight multiplier w", "-", 1.0),
}
#: the quantiles bounding the band of the realizations
BAND = (0.025, 0.975)
#: realizations drawn one by one (the others are in the mean and the band)
SHOWN = 5

_BAR = "#b8c7d6"
_LINE = "#1f4e79"


@dataclass
class FieldRealizations:
    """The values of one field-driven parameter over the realizations, along the bar."""

    parameter: str
    x: np.ndarray            # points (m), nominal grid
    values: np.ndarray       # (realization, point), SI
    nominal: float           # the parameter's nominal value, SI
    source: str              # "stored values" or "rebuilt from the germs"

    def band(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = np.quantile(self.values, BAND, axis=0)
        return lo, hi

    def mean(self) -> np.ndarray:
        return self.values.mean(axis=0)


def field_realizations(bar, field_tables: list, runs: xr.Dataset) -> list[FieldRealizations]:
    """Every field-driven parameter of a result, its values along the bar per realization.

    ``bar``: the result's solver (``GamutBarSolver`` of its scene); ``field_tables``: the
    study's [[fields]] tables; ``runs``: the result's runs. A realization without finite values
    (a stored value never written) is left out.
    """
    stored = {str(v) for v in runs.data_vars if str(v).startswith(FIELD_PREFIX)}
    fields = _fields(bar, field_tables) if any(
        str(v).startswith(GERM_PREFIX) for v in runs.data_vars) else []
    nominal = bar.nominal()
    out = []
    for field in fields:
        for parameter in field.targets:
            x = np.asarray(bar.field_points(parameter), dtype=float)[:, 0]
            name = field_value_variable(parameter)
            if name in stored:
                values = np.asarray(runs[name].values, dtype=float)[:, :x.size]
                source = "stored values"
            else:
                values = _rebuilt(bar, fields, runs, parameter, x)
                source = "rebuilt from the germs"
            values = values[np.isfinite(values).all(axis=1)]
            if values.shape[0]:
                out.append(FieldRealizations(parameter, x, values, float(nominal[parameter]),
                                             source))
    return out


def _fields(bar, field_tables) -> list[RandomField]:
    """The study's random fields, their KL bases built on the points of each field's first
    parameter (as the study does)."""
    fields = []
    for table in field_tables:
        spec = FieldSpec.model_validate(table)
        fields.append(RandomField(spec, np.asarray(bar.field_points(spec.targets[0]),
                                                   dtype=float)))
    return fields


def _rebuilt(bar, fields, runs, parameter, x) -> np.ndarray:
    """Each realization's values of ``parameter`` at ``x`` from its germs: around the run's
    value of the parameter (an input of the study) or its nominal value, in its range."""
    n = runs.sizes["realization"]
    means = np.full(n, float(bar.nominal()[parameter]))
    if INPUTS in runs and parameter in runs[PARAMETER].values:
        means = np.asarray(runs[INPUTS].sel({PARAMETER: parameter}).values, dtype=float)
    lower, upper = bar.field_range(parameter)
    points = x[:, None]
    values = np.empty((n, x.size))
    for r in range(n):
        sample = FieldSample.from_design(fields, runs, r)
        values[r] = sample.values(parameter, points, means[r], lower, upper)
    return values


def draw(bar, realizations: list[FieldRealizations], title: str, note: str = ""):
    """The figure: the bar and its loading on top, one panel per field-driven parameter."""
    rows = 1 + len(realizations)
    fig, axes = new_figure(7.5, 3.0 + 2.3 * len(realizations), rows, 1, squeeze=False,
                           sharex=True, height_ratios=[1.0] + [1.6] * len(realizations))
    axes = axes[:, 0]
    _draw_bar(axes[0], bar, note)
    where = ", at the nominal grid's points" if bar.cfg["grid"] == "stochastic" else ""
    for ax, field in zip(axes[1:], realizations):
        _draw_field(ax, field, where)
    axes[-1].set_xlabel("position along the bar x [mm]")
    fig.suptitle(title, fontsize="medium")
    return fig


def _draw_bar(ax, bar, note):
    length = bar.props["length"] * 1e3
    ax.add_patch(_rectangle(length))
    # the fixed end: a wall with hatching
    ax.plot([0, 0], [-0.9, 0.9], color="k", lw=2, gid="support")
    for y in np.linspace(-0.9, 0.7, 6):
        ax.plot([-0.025 * length, 0], [y, y + 0.2], color="k", lw=0.8)
    c = bar.cfg
    if c["loading"] == "cyclic":
        lo, hi = c["amplitude_range"]
        sy = bar.props["sigma_y"]
        ax.annotate("", xy=(1.1 * length, 0), xytext=(1.0 * length, 0), gid="load",
                    arrowprops=dict(arrowstyle="<->", color="#c0392b", lw=2))
        load = (f"end force cycled in tension and compression: {c['cycles']} amplitudes "
                f"{lo * sy / 1e6:.0f}–{hi * sy / 1e6:.0f} MPa ({lo:g}–{hi:g} × yield stress), "
                f"{c['cycle_repeats']} cycles each, then pulled to failure")
    else:
        ax.annotate("", xy=(1.1 * length, 0), xytext=(1.0 * length, 0), gid="load",
                    arrowprops=dict(arrowstyle="->", color="#c0392b", lw=2))
        load = (f"end force raised by {100 * (c['force_growth'] - 1):g} % per step until the "
                f"bar fails (monotonic tension)")
    p = bar.props
    props = (f"{bar.n} local bonds, {c['grid']} grid, cross-section {p['area'] * 1e6:g} mm²; "
             f"nominal: E = {p['E'] / 1e9:.4g} GPa, yield stress {p['sigma_y'] / 1e6:.4g} MPa, "
             f"failure stress {p['sigma_f'] / 1e6:.4g} MPa, failure strain "
             f"{100 * p['eps_f']:.3g} %, ρ = {p['rho']:.4g} kg/m³, R = {p['R']:.4g}")
    ax.text(0.5 * length, 1.15, load, ha="center", va="bottom", fontsize="small", wrap=True)
    ax.text(0.5 * length, -1.15, props + (f"\n{note}" if note else ""), ha="center", va="top",
            fontsize="small", wrap=True)
    ax.set_xlim(-0.05 * length, 1.14 * length)
    ax.set_ylim(-2.6, 2.4)
    ax.set_yticks([])
    for side in ("left", "right", "top"):
        ax.spines[side].set_visible(False)


def _rectangle(length):
    from matplotlib.patches import Rectangle

    return Rectangle((0.0, -0.5), length, 1.0, facecolor=_BAR, edgecolor="k", lw=1.0,
                     gid="bar")


def _draw_field(ax, field: FieldRealizations, where: str):
    words, unit, scale = FIELD_LABELS.get(field.parameter, (field.parameter, "", 1.0))
    x = field.x * 1e3
    lo, hi = field.band()
    n = field.values.shape[0]
    ax.fill_between(x, lo / scale, hi / scale, color=_LINE, alpha=0.18, lw=0, gid="band",
                    label=f"95 % of the {n} realizations (2.5–97.5 % quantiles)")
    for k in range(min(SHOWN, n)):
        ax.plot(x, field.values[k] / scale, color="0.45", lw=0.6, gid="realization",
                label=f"{min(SHOWN, n)} of the realizations" if k == 0 else None)
    ax.plot(x, field.mean() / scale, color=_LINE, lw=1.8, gid="mean",
            label="mean of the realizations")
    ax.axhline(field.nominal / scale, color="k", lw=0.8, ls="--", gid="nominal",
               label="nominal value")
    ax.set_ylabel(axis_label(words, unit))
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize="x-small", ncols=2)
    ax.set_title(f"{words} along the bar ({field.source}{where})", fontsize="small")
