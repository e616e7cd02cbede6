"""`uqflow report` on sph results (docs/sph.md § 10): per realization, the apparent modulus
against its own Voigt–Reuss bounds; the ensemble's mean modulus, with its Monte Carlo standard
error, against the Hashin–Shtrikman bounds; the macroscopic stress–strain envelope; and the
proportion of realizations with a fully debonded inclusion by each strain, with its exact
(Clopper–Pearson) interval. A multilevel or multifidelity result is reported level by level:
its levels are different discretisations, not one sample."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import stats

from uqflow.methods.base import sample_mask
from uqflow.report import figure_path

#: confidence of the interval of a proportion
CONFIDENCE = 0.95
#: the runs' variable naming the level of a multilevel/multifidelity result (uqflow.levels)
LEVEL = "level"
#: |mean - bound| within this many standard errors counts as consistent with the bound
HS_STANDARD_ERRORS = 2.0


def _runs(tree):
    try:
        runs = tree["runs"].to_dataset()
    except KeyError:
        return None
    if "effective_modulus" not in runs or "status" not in runs:
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
    lines = [f"  effective modulus  mean {E.mean():.6g} Pa, std {sd:.4g} Pa, "
             f"stderr of the mean {se:.3g} Pa"]
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
            lines.append(f"  ensemble mean {verdict} the Hashin-Shtrikman bounds [{lo:.6g}, "
                         f"{hi:.6g}] Pa of the volume fraction (mean/lower "
                         f"{E.mean() / lo:.4f} ± {se / lo:.4f}); HS bounds the effective "
                         f"modulus, not each window")
    return lines


def _debond_line(runs) -> str:
    k, n = detach_counts(runs)
    lo, hi = clopper_pearson(k[-1], n)
    return (f"  P(an inclusion fully debonded by strain {runs.strain.values[0, -1]:.4g}): "
            f"{int(k[-1])} of {n}, {CONFIDENCE:.0%} CI [{lo:.3g}, {hi:.3g}] (Clopper-Pearson)")


def report(trees, folder, figures: bool = True) -> tuple[str, list[Path]]:
    parts, pngs = [], []
    for k, tree in enumerate(trees):
        runs = _runs(tree)
        if runs is None or runs.sizes.get("realization", 0) == 0:
            continue
        name = tree.attrs.get("study_name", f"result {k}")
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
                pngs += _figures(group, Path(folder), stem)
    return "\n\n".join(parts), pngs


def _figures(runs, folder, stem):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    strain = runs.strain.values[0]
    stress = runs.macro_stress.values / 1e3
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    q = np.quantile(stress, [0.05, 0.5, 0.95], axis=0)
    axes[0].fill_between(strain, q[0], q[2], alpha=0.3, label="5-95 %")
    axes[0].plot(strain, stress.mean(axis=0), label="mean")
    axes[0].plot(strain, q[1], "--", label="median")
    axes[0].set(xlabel="applied strain", ylabel="mean σ_yy (kPa)", title="stress–strain")
    axes[0].legend()
    vf = runs.volume_fraction.values
    if "modulus_reuss_bound" in runs:
        axes[1].vlines(vf, runs.modulus_reuss_bound.values / 1e6,
                       runs.modulus_voigt_bound.values / 1e6, color="0.7",
                       label="Voigt–Reuss (each window)")
    if "modulus_hs_lower" in runs:
        # each window's own: its volume fraction and (with random moduli) its phases
        for var in ("modulus_hs_lower", "modulus_hs_upper"):
            axes[1].plot(vf, runs[var].values / 1e6, "_", color="C1", ms=12,
                         label="Hashin–Shtrikman (effective)" if var.endswith("lower")
                         else None)
    axes[1].plot(vf, runs.effective_modulus.values / 1e6, "o", label="apparent modulus")
    axes[1].set(xlabel="volume fraction", ylabel="modulus (MPa)", yscale="log",
                title="apparent modulus")
    axes[1].xaxis.set_major_locator(plt.MaxNLocator(4))
    axes[1].legend(fontsize=8)
    k, n = detach_counts(runs)
    lo, hi = clopper_pearson(k, n)
    p = k / n
    axes[2].errorbar(strain, p, yerr=[p - lo, hi - p], fmt="-o", ms=3)
    axes[2].set(xlabel="applied strain", ylabel="P(an inclusion fully debonded)",
                ylim=(-0.05, 1.05), title=f"full debonding ({CONFIDENCE:.0%} Clopper–Pearson)")
    fig.tight_layout()
    path = figure_path(folder, stem, "composite")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
