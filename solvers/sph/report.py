"""What SPH results add to their report (``SPHSolver.report``; docs/sph.md § 10): a map of the
scene (``scene_map.png``) with every result; and for a tension result, per realization, the
apparent modulus against its own Voigt–Reuss bounds; the ensemble's mean modulus, with its
Monte Carlo standard error, against the Hashin–Shtrikman bounds; the macroscopic stress–strain
envelope; and the proportion of realizations with a fully debonded inclusion by each strain,
with its exact (Clopper–Pearson) interval. A multilevel or multifidelity result is reported
level by level: its levels are different discretisations, not one sample."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from scipy import stats

from solvers.sph.scene import parse
from solvers.sph.scene_layout import scene_layout
from solvers.sph.scene_map import FILE_NAME, pairs_visible, write_scene_map
from uqflow.errors import StudyError
from uqflow.layout import LEVEL, STATUS, STUDY_NAME, sample_mask
from uqflow.report import (FigureWarning, axis_label, display_units, figure_path, new_figure,
                           save_figure, scene_ran)

#: confidence of the interval of a proportion; the stress–strain band holds this share of
#: the realizations (the 2.5 % and 97.5 % quantiles)
CONFIDENCE = 0.95
#: |mean - bound| within this many standard errors counts as consistent with the bound
HS_STANDARD_ERRORS = 2.0


def _runs(tree):
    try:
        runs = tree["runs"].to_dataset()
    except KeyError:
        return None
    if "effective_modulus" not in runs or STATUS not in runs:
        return None
    return runs.isel(realization=np.flatnonzero(sample_mask(runs)))


def clopper_pearson(k, n, confidence: float = CONFIDENCE):
    """Exact two-sided interval of a binomial proportion with ``k`` successes in ``n`` trials
    (arrays broadcast): the beta quantiles; 0 below at k = 0 and 1 above at k = n."""
    k, n = np.asarray(k), np.asarray(n)
    alpha = 1.0 - confidence
    with np.errstate(invalid="ignore"):
        lo = np.where(k > 0, stats.beta.ppf(alpha / 2, k, n - k + 1), 0.0)
        hi = np.where(k < n, stats.beta.ppf(1 - alpha / 2, k + 1, n - k), 1.0)
    return lo, hi


def detach_counts(runs):
    """Per step: realizations with at least one inclusion detached, and the realizations."""
    detached = runs.detached_inclusions.values > 0            # (realization, step)
    return detached.sum(axis=0), detached.shape[0]


def _level_groups(runs):
    """(label, runs) per level of a multilevel/multifidelity result, else one group."""
    if LEVEL not in runs:
        return [("", runs)]
    levels = np.asarray(runs[LEVEL].values)
    return [(f"level {int(lv)}", runs.isel(realization=np.flatnonzero(levels == lv)))
            for lv in np.unique(levels)]


def _modulus_lines(runs) -> list[str]:
    E = runs.effective_modulus.values
    n = E.size
    sd = E.std(ddof=1) if n > 1 else np.nan
    se = sd / np.sqrt(n)
    scale, units = display_units(E, "Pa")
    lines = [f"  apparent Young's modulus: mean {E.mean() * scale:.6g} {units}, standard "
             f"deviation {sd * scale:.4g} {units}, standard error of the mean "
             f"{se * scale:.3g} {units}"]
    if "modulus_reuss_bound" in runs:
        reuss, voigt = runs.modulus_reuss_bound.values, runs.modulus_voigt_bound.values
        inside = np.count_nonzero((E >= reuss) & (E <= voigt))
        lines.append(f"  within its own Voigt-Reuss bounds (each window, its phase areas): "
                     f"{inside} of {n}")
    if "modulus_hs_lower" in runs:
        lo, hi = runs.modulus_hs_lower.values.mean(), runs.modulus_hs_upper.values.mean()
        if n > 1:
            margin = min(E.mean() - lo, hi - E.mean())
            gap = margin / se if se > 0 else np.copysign(np.inf, margin)
            verdict = ("within" if gap >= 0 else
                       "consistent with (within 2 standard errors of)"
                       if gap >= -HS_STANDARD_ERRORS else "outside")
            lines.append(f"  ensemble mean {verdict} the Hashin-Shtrikman bounds "
                         f"[{lo * scale:.6g}, {hi * scale:.6g}] {units} of the volume fraction "
                         f"(mean/lower {E.mean() / lo:.4f} ± {se / lo:.4f}); HS bounds the "
                         f"effective modulus, not each window")
    return lines


def _debond_line(runs) -> str:
    k, n = detach_counts(runs)
    lo, hi = clopper_pearson(k[-1], n)
    return (f"  P(an inclusion fully debonded by {100 * runs.strain.values[0, -1]:.4g} % "
            f"strain): {int(k[-1])} of {n}, {CONFIDENCE:.0%} CI [{lo:.3g}, {hi:.3g}] "
            f"(Clopper-Pearson)")


def report(trees, folder, figures: bool = True) -> tuple[str, list[Path]]:
    """The text and the figures SPH results add: a scene map of each, and for tension
    results their moduli, bounds, stress–strain envelope and debonding."""
    parts, pngs = [], []
    folder = Path(folder)
    for k, tree in enumerate(trees):
        name = tree.attrs.get(STUDY_NAME, f"result {k}")
        if figures:
            path, note = scene_map(tree, folder, FILE_NAME if len(trees) == 1
                                   else f"{FILE_NAME}_{k}")
            pngs += [path] if path is not None else []
            parts.append(f"{name}: {note}")
        runs = _runs(tree)
        if runs is None or runs.sizes.get("realization", 0) == 0:
            continue
        groups = _level_groups(runs)
        if len(groups) > 1 or groups[0][0]:
            parts.append(f"{name}: {runs.sizes['realization']} runs over {len(groups)} levels, "
                         f"reported per level (each level a discretisation of its own)")
        for label, group in groups:
            head = f"{name}, {label}" if label else name
            parts.append("\n".join([f"{head}: {group.sizes['realization']} realizations",
                                    *_modulus_lines(group), _debond_line(group)]))
            if figures:
                stem = f"sph_{k}" + (f"_{label.replace(' ', '')}" if label else "")
                pngs += _figures(group, folder, stem)
    return "\n\n".join(parts), pngs


def scene_map(tree, folder: Path, name: str = FILE_NAME) -> tuple[Path | None, str]:
    """The map of the scene ``tree`` ran (``scene_map.png``) and a line saying what it shows;
    (None, why not) when the scene cannot be had or drawn: the rest of the report goes on."""
    scene, where = scene_ran(tree.attrs)
    if scene is None:
        return None, f"no scene map: {where}"
    try:
        cfg = parse(scene)
        layout = scene_layout(cfg)
    except StudyError as exc:
        return None, f"no scene map: {where}: {exc}"
    drawn = f"the ellipses of layout_seed = {cfg.random.layout_seed}; each realization " \
            f"draws its own" if cfg.layout == "random" else ""
    try:
        path = write_scene_map(cfg, layout, folder, title="; ".join(filter(None, (where, drawn))),
                               name=name)
    except (ValueError, RuntimeError) as exc:   # a map that cannot be drawn costs no report
        warnings.warn(f"figure {name}.png not written: {exc}", FigureWarning, stacklevel=2)
        return None, f"no scene map: {exc}"
    pairs = "" if pairs_visible(layout) else " (the interface pairs are too dense to show)"
    return path, f"scene map of {where}{' (' + drawn + ')' if drawn else ''}{pairs}"


def _figures(runs, folder, stem):
    folder.mkdir(parents=True, exist_ok=True)
    return [save_figure(composite_figure(runs), figure_path(folder, stem, "composite"))]


def composite_figure(runs):
    """Three panels: the stress–strain envelope, each window's apparent modulus against its
    bounds, and the probability of full debonding by each strain."""
    strain = 100.0 * runs.strain.values[0]                   # %
    stress = runs.macro_stress.values
    scale, stress_units = display_units(stress, "Pa")
    fig, axes = new_figure(14.0, 4.4, 1, 3)
    q = np.quantile(stress * scale, [(1 - CONFIDENCE) / 2, 0.5, (1 + CONFIDENCE) / 2], axis=0)
    axes[0].fill_between(strain, q[0], q[2], alpha=0.3,
                         label=f"{CONFIDENCE:.0%} of the realizations (2.5–97.5 % quantiles)")
    axes[0].plot(strain, (stress * scale).mean(axis=0), label="mean")
    axes[0].plot(strain, q[1], "--", label="median")
    axes[0].set(xlabel=axis_label("applied strain", "%"),
                ylabel=axis_label("mean tensile stress σ_yy of the plate", stress_units),
                title="stress–strain curve")
    axes[0].legend(fontsize="small")
    vf = runs.volume_fraction.values
    E = runs.effective_modulus.values
    E_scale, E_units = display_units(E, "Pa")
    if "modulus_reuss_bound" in runs:
        axes[1].vlines(vf, runs.modulus_reuss_bound.values * E_scale,
                       runs.modulus_voigt_bound.values * E_scale, color="0.7",
                       label="Voigt–Reuss bounds of each window")
    if "modulus_hs_lower" in runs:
        # each window's own: its volume fraction and (with random moduli) its phases
        for var in ("modulus_hs_lower", "modulus_hs_upper"):
            axes[1].plot(vf, runs[var].values * E_scale, "_", color="C1", ms=12,
                         label="Hashin–Shtrikman bounds (of the effective modulus)"
                         if var.endswith("lower") else None)
    axes[1].plot(vf, E * E_scale, "o", label="apparent Young's modulus of each window")
    axes[1].set(xlabel=axis_label("inclusion volume fraction", "-"),
                ylabel=axis_label("apparent Young's modulus", E_units), yscale="log",
                title="apparent Young's modulus")
    axes[1].xaxis.set_major_locator(_few_ticks())
    axes[1].legend(fontsize="small")
    k, n = detach_counts(runs)
    lo, hi = clopper_pearson(k, n)
    p = k / n
    axes[2].errorbar(strain, p, yerr=[p - lo, hi - p], fmt="-o", ms=3,
                     label=f"share of realizations, {CONFIDENCE:.0%} Clopper–Pearson interval")
    axes[2].set(xlabel=axis_label("applied strain", "%"),
                ylabel=axis_label("probability that an inclusion has fully debonded", "-"),
                ylim=(-0.05, 1.05), title="full debonding")
    axes[2].legend(fontsize="small")
    return fig


def _few_ticks():
    from matplotlib.ticker import MaxNLocator

    return MaxNLocator(4)
