"""`uqflow report` on sph results: the effective modulus against its Hashin–Shtrikman bounds,
the macroscopic stress–strain envelope, and the probability that an inclusion has fully
debonded by each strain, with its binomial standard error (docs/sph.md § 10)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _runs(tree):
    try:
        runs = tree["runs"].to_dataset()
    except KeyError:
        return None
    if "effective_modulus" not in runs or "status" not in runs:
        return None
    return runs.isel(realization=np.flatnonzero(runs.status.values == "ok"))


def detach_probability(runs):
    """P(at least one inclusion detached by step k) and its binomial standard error."""
    detached = runs.detached_inclusions.values > 0            # (realization, step)
    p = detached.mean(axis=0)
    return p, np.sqrt(p * (1.0 - p) / max(detached.shape[0], 1))


def report(trees, folder, figures: bool = True) -> tuple[str, list[Path]]:
    parts, pngs = [], []
    for k, tree in enumerate(trees):
        runs = _runs(tree)
        if runs is None or runs.sizes.get("realization", 0) == 0:
            continue
        E = runs.effective_modulus.values
        lo, hi = runs.modulus_lower_bound.values, runs.modulus_upper_bound.values
        n = E.size
        p, se = detach_probability(runs)
        name = tree.attrs.get("study_name", f"result {k}")
        parts.append(
            f"{name}: {n} realizations\n"
            f"  effective modulus  mean {E.mean():.6g} Pa, std {E.std(ddof=1) if n > 1 else 0:.4g} "
            f"Pa, stderr of the mean {(E.std(ddof=1) / np.sqrt(n)) if n > 1 else 0:.3g} Pa\n"
            f"  within the Hashin-Shtrikman bounds of its volume fraction: "
            f"{np.count_nonzero((E > lo) & (E < hi))} of {n}\n"
            f"  P(an inclusion fully debonded by strain {runs.strain.values[0, -1]:.4g}) = "
            f"{p[-1]:.3f} ± {se[-1]:.3f}")
        if figures:
            pngs += _figures(runs, Path(folder), f"sph_{k}")
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
    axes[1].vlines(vf, runs.modulus_lower_bound.values / 1e6,
                   runs.modulus_upper_bound.values / 1e6, color="0.7", label="HS bounds")
    axes[1].plot(vf, runs.effective_modulus.values / 1e6, "o", label="effective modulus")
    axes[1].set(xlabel="volume fraction", ylabel="MPa", yscale="log",
                title="effective modulus")
    axes[1].legend()
    p, se = detach_probability(runs)
    axes[2].errorbar(strain, p, yerr=se, fmt="-o", ms=3)
    axes[2].set(xlabel="applied strain", ylabel="P(an inclusion fully debonded)",
                ylim=(-0.05, 1.05), title="full debonding")
    fig.tight_layout()
    path = folder / f"{stem}_composite.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
