"""Figures and validation numbers of the deformation-gamut bar (docs/gamut_bar.md).

Writes docs/figures/gamut_bar_monotonic.png (deterministic M1/M2 curves against
Ramberg–Osgood, with stochastic grids) and docs/figures/gamut_bar_cyclic.png (M1 hysteresis
loops and the log–log fit of n′, K′), prints the benchmark figures quoted in the docs
(stochastic grids, timings), and writes the deterministic validation tables of
docs/gamut_bar.md between its "gamut-bar-validation" markers (``validation_markdown``; the
test tests/solvers/gamut_bar/test_doc_numbers.py recomputes them and compares).

    python benchmarks/gamut_bar_figures.py [--stochastic 5] [--no-docs]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from solvers.gamut_bar import GamutBarSolver  # noqa: E402
from solvers.gamut_bar.materials import MATERIALS, ro_stress  # noqa: E402

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
DOC = FIGURES.parent / "gamut_bar.md"
BEGIN, END = "<!-- begin gamut-bar-validation -->", "<!-- end gamut-bar-validation -->"
SEED_TABLE1 = {"M1": (0.06244, 791.6e6), "M2": (0.04762, 1105.4e6)}   # deterministic column
CASES = [("M1", {}), ("M2", {}), ("M2", {"n_ro": 21.0})]


def label(name, over):
    return name + ("" if not over else " (n_ro = %g)" % over["n_ro"])


def ro_curve(m, strain):
    return np.array([ro_stress(e, m["E"], m["sigma_y"], m["n_ro"], m["K_ro"]) for e in strain])


def _run_scene(scene):
    return GamutBarSolver.from_scene(scene).run({})


def deterministic_numbers(name, over, run=_run_scene):
    """Validation numbers of the homogeneous bar on the uniform grid, monotonic and cyclic
    (no timings: they are what the docs state and the tests recompute). ``run(scene)`` runs a
    scene (the tests pass their cached runner)."""
    m = dict(MATERIALS[name], **over)
    mono = run({"material": name, **over})
    e, s = mono["strain"].values, mono["stress"].values
    sel = e >= 0.002
    cyc = run({"material": name, "loading": "cyclic", **over})
    ro_n = 1.0 / m["n_ro"]
    ro_K = m["sigma_y"] / m["K_ro"] ** ro_n
    seed = SEED_TABLE1[name] if not over else SEED_TABLE1["M2"]
    return {"case": label(name, over),
            "ro_deviation": float(np.abs(s[sel] / ro_curve(m, e[sel]) - 1).max()),
            "failure_strain": mono["failure_strain"].item(),
            "failure_stress": mono["failure_stress"].item(),
            "steps": int(mono.attrs["steps"]),
            "n_prime": cyc["n_prime"].item(), "K_prime": cyc["K_prime"].item(),
            "ro_n": ro_n, "ro_K": ro_K, "seed_n": seed[0], "seed_K": seed[1],
            "cyclic_steps": int(cyc.attrs["steps"]), "cyclic_points": cyc.sizes["step"]}


def validation_markdown(rows) -> str:
    """The two tables of docs/gamut_bar.md's validation section, from deterministic_numbers."""
    out = [BEGIN,
           "Written by `python benchmarks/gamut_bar_figures.py` (uniform grid, 500 local bonds, "
           "default loading); `tests/solvers/gamut_bar/test_doc_numbers.py` recomputes every "
           "number here and compares it to the last digit shown.",
           "",
           r"| case | max \|σ/σ_RO − 1\| (ε ≥ 0.002) | ε at failure | σ at failure [MPa] "
           "| load steps to failure |",
           "|---|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['case']} | {100 * r['ro_deviation']:.2f} % | "
                   f"{r['failure_strain']:.4f} | {r['failure_stress'] / 1e6:.1f} | "
                   f"{r['steps']} |")
    out += ["",
            "| case | n′ | K′ [MPa] | RO 1/n_ro | RO σ_y/K_ro^(1/n_ro) [MPa] | n′/RO − 1 "
            "| K′/RO − 1 | seed deterministic n′, K′ [MPa] | n′/seed − 1 | K′/seed − 1 "
            "| load steps | recorded states |",
            "|---|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['case']} | {r['n_prime']:.5f} | {r['K_prime'] / 1e6:.1f} | "
                   f"{r['ro_n']:.5f} | {r['ro_K'] / 1e6:.1f} | "
                   f"{100 * (r['n_prime'] / r['ro_n'] - 1):+.2f} % | "
                   f"{100 * (r['K_prime'] / r['ro_K'] - 1):+.2f} % | "
                   f"{r['seed_n']}, {r['seed_K'] / 1e6:.1f} | "
                   f"{100 * (r['n_prime'] / r['seed_n'] - 1):+.1f} % | "
                   f"{100 * (r['K_prime'] / r['seed_K'] - 1):+.1f} % | "
                   f"{r['cyclic_steps']} | {r['cyclic_points']} |")
    out.append(END)
    return "\n".join(out)


def write_doc(rows) -> None:
    text = DOC.read_text(encoding="utf-8")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    DOC.write_text(head + validation_markdown(rows) + tail, encoding="utf-8")


def timed(solver, *args, **kwargs):
    t = time.perf_counter()
    ds = solver.run(*args, **kwargs)
    return ds, time.perf_counter() - t


def monotonic(n_stochastic):
    fig, grid = plt.subplots(2, 2, figsize=(11, 7), sharex="col",
                             gridspec_kw={"height_ratios": [2, 1]})
    rows = []
    for name, over in CASES:
        m = dict(MATERIALS[name], **over)
        col = 0 if name == "M1" else 1
        ax, dax = grid[0, col], grid[1, col]
        sol = GamutBarSolver.from_scene({"material": name, **over})
        sol.run({})                                            # compiled
        ds, wall = timed(sol, {})
        e, s = ds["strain"].values, ds["stress"].values
        sel = e >= 0.002
        dev = np.abs(s[sel] / ro_curve(m, e[sel]) - 1).max()
        slope = s[1] / e[1] / m["E"] - 1
        ref = np.linspace(0, m["eps_f"], 400)
        color = {"": "C0", "n_ro": "C2"}["n_ro" if over else ""]
        ax.plot(ref, ro_curve(m, ref) / 1e6, "k--", lw=1)
        ax.plot(e, s / 1e6, color=color, lw=1.8, label=f"{label(name, over)}: network")
        dax.plot(e[sel], 100 * (s[sel] / ro_curve(m, e[sel]) - 1), color=color, lw=1.5)
        stoch = GamutBarSolver.from_scene({"material": name, "grid": "stochastic", **over})
        fails, slopes, devs = [], [], []
        for seed in range(n_stochastic):
            d = stoch.run({}, seed=seed)
            es, ss = d["strain"].values, d["stress"].values
            ax.plot(es, ss / 1e6, color=color, lw=0.6, alpha=0.5)
            fails.append(d["failure_strain"].item())
            slopes.append(abs(ss[1] / es[1] / m["E"] - 1))
            k = es >= 0.002
            rel = ss[k] / ro_curve(m, es[k]) - 1
            dax.plot(es[k], 100 * rel, color=color, lw=0.6, alpha=0.5, ls=":")
            devs.append(np.abs(rel).max())
        rows.append((label(name, over), slope, dev, ds["failure_strain"].item(),
                     ds["failure_stress"].item(), wall, max(slopes), max(devs),
                     min(fails), max(fails)))
    for col, title in enumerate(("Material 1", "Material 2")):
        ax, dax = grid[0, col], grid[1, col]
        ax.plot([], [], "k--", lw=1, label="Ramberg–Osgood")
        ax.plot([], [], color="0.5", lw=0.6, label="stochastic grids (thin)")
        ax.set_ylabel("stress [MPa]")
        ax.set_title(f"{title}: deterministic bar, 500 local bonds")
        ax.legend(loc="lower right", fontsize=8)
        ax.grid(alpha=0.3)
        dax.axhline(0.0, color="k", lw=0.8)
        dax.set_xlabel("strain")
        dax.set_ylabel("network / RO − 1 [%]")
        dax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(FIGURES / "gamut_bar_monotonic.png", dpi=130)
    plt.close(fig)
    return rows


def cyclic():
    rows = []
    loops_m1 = None
    for name, over in CASES + [("M1", {"grid": "stochastic"})]:
        sol = GamutBarSolver.from_scene({"material": name, "loading": "cyclic", **over})
        ds, wall = timed(sol, {})
        rows.append((label(name, {k: v for k, v in over.items() if k == "n_ro"})
                     + (" stochastic grid" if "grid" in over else ""),
                     ds["n_prime"].item(), ds["K_prime"].item(), wall, ds.sizes["step"],
                     ds.attrs["factorisations"]))
        if name == "M1" and not over:
            loops_m1 = (sol, ds)
    sol, ds = loops_m1
    plan = sol.plan
    peaks = sol._amplitudes(sol.props) * sol.props["area"]
    _, starts = plan.forces(peaks)
    span = 2 * plan.per_half
    e, s = ds["strain"].values, ds["stress"].values
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for lvl, row in enumerate(starts):
        i = row[-1]
        a1.plot(e[i:i + span + 1], s[i:i + span + 1] / 1e6, lw=1,
                color=plt.cm.viridis(lvl / max(len(starts) - 1, 1)))
    a1.set_xlabel("strain")
    a1.set_ylabel("stress [MPa]")
    a1.set_title("Material 1: stable loops (last repeat of each level)")
    a1.grid(alpha=0.3)
    sa, ep = ds["stress_amplitude"].values, ds["plastic_strain_amplitude"].values
    n_p, K_p = ds["n_prime"].item(), ds["K_prime"].item()
    a2.loglog(ep, sa / 1e6, "o", label="loops")
    xx = np.geomspace(ep.min() * 0.8, ep.max() * 1.25, 50)
    a2.loglog(xx, K_p * xx**n_p / 1e6, "-", label=f"fit: n′ = {n_p:.4f}, K′ = {K_p / 1e6:.1f} MPa")
    n_s, K_s = SEED_TABLE1["M1"]
    a2.loglog(xx, K_s * xx**n_s / 1e6, "k--", lw=1,
              label=f"seed (deterministic): n′ = {n_s}, K′ = {K_s / 1e6:.1f} MPa")
    for axis in (a2.xaxis, a2.yaxis):
        axis.set_major_formatter(matplotlib.ticker.LogFormatter(labelOnlyBase=False,
                                                               minor_thresholds=(2, 0.4)))
        axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    a2.set_yticks([540, 560, 580, 600, 620, 640, 660])
    a2.set_xticks([0.002, 0.005, 0.01, 0.02, 0.05])
    for axis in (a2.xaxis, a2.yaxis):
        axis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    a2.set_xlabel("plastic strain amplitude")
    a2.set_ylabel("stress amplitude [MPa]")
    a2.set_title("Material 1: σ_a = K′ ε_pa^n′")
    a2.legend(fontsize=8)
    a2.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(FIGURES / "gamut_bar_cyclic.png", dpi=130)
    plt.close(fig)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stochastic", type=int, default=5, help="stochastic grids per material")
    ap.add_argument("--no-docs", action="store_true", help="do not rewrite docs/gamut_bar.md")
    args = ap.parse_args(argv)
    FIGURES.mkdir(parents=True, exist_ok=True)
    if not args.no_docs:
        write_doc([deterministic_numbers(name, over) for name, over in CASES])
        print(f"validation tables written into {DOC}")
    print("monotonic (uniform grid, deterministic; stochastic grids: seeds 0..%d)"
          % (args.stochastic - 1))
    print("| case | slope/E − 1 | max dev. from RO | ε at failure | σ at failure [MPa] | "
          "wall [s] | stoch.: max slope err | max dev. | ε at failure |")
    for r in monotonic(args.stochastic):
        print(f"| {r[0]} | {r[1]:.1e} | {100 * r[2]:.2f} % | {r[3]:.4f} | {r[4] / 1e6:.1f} | "
              f"{r[5]:.2f} | {r[6]:.1e} | {100 * r[7]:.2f} % | {r[8]:.3f}–{r[9]:.3f} |")
    print("\ncyclic (10 levels × 2 repeats)")
    print("| case | n′ | K′ [MPa] | wall [s] | steps | factorisations |")
    for r in cyclic():
        print(f"| {r[0]} | {r[1]:.5f} | {r[2] / 1e6:.1f} | {r[3]:.2f} | {r[4]} | {r[5]} |")
    sol = GamutBarSolver.from_scene({"local_bonds": 5000})
    _, wall = timed(sol, {})
    print(f"\nmonotonic M1, 5000 local bonds: {wall:.2f} s")
    print(f"figures: {FIGURES / 'gamut_bar_monotonic.png'}, {FIGURES / 'gamut_bar_cyclic.png'}")


if __name__ == "__main__":
    main()
