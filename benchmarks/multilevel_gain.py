"""Multilevel and multifidelity Monte Carlo against plain Monte Carlo at the finest level:
what each saves on the MPM thin plate, the gamut bar and the SPH composite (issue 11).

For each case three studies run in this process (measured costs: the pilot's median wall
time per level): plain Monte Carlo at the finest level (its per-run cost and the variance
of each quantity), ``multilevel`` and ``multifidelity`` with the same relative target. For a
quantity q, plain MC reaches the stderr se of a method with s_L^2 / se^2 runs of cost c_L
(the same finest level, so the same bias): the cost ratio is that over the method's measured
solver wall time. Quantities may be aggregates of an output (the MPM's time mean at H): the
estimators are linear, so they are re-applied to the aggregate's level samples.

    python benchmarks/multilevel_gain.py                # all cases; BENCHMARKS.md
                                                        # "multilevel-gain-<case>" each
    python benchmarks/multilevel_gain.py --cases sph    # one case
    python benchmarks/multilevel_gain.py --quick        # the analytic Euler model only (smoke test)
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import FIGURES, ROOT, write_section  # noqa: E402

import uqflow  # noqa: E402
from uqflow.methods.multilevel_estimators import (level_rate, mfmc_estimate,  # noqa: E402
                                                  mlmc_bias, mlmc_level_terms)

METHODS = ("multilevel", "multifidelity", "multifidelity+taylor-local")
JC = {"steel.jc.A": 792.0e6, "steel.jc.B": 510.0e6, "steel.jc.C": 0.014,
      "steel.jc.n": 0.26, "steel.jc.m": 1.03}


def _mpm_scene(folder: Path) -> str:
    # the shipped scene of studies/multilevel/thin_plate_*.toml: probes averaged over 15 mm,
    # comparable across resolutions
    return str(ROOT / "studies" / "scenes" / "thin_plate_levels.toml")


def _nearest(coord, at):
    return int(np.argmin(np.abs(np.asarray(coord) - at)))


MPM = dict(
    solver="mpm", scene=_mpm_scene, key="resolution", values=[0.25, 0.5, 1.0],
    outputs=["flow_stress"], inputs={k: ("normal", v, 0.10) for k, v in JC.items()},
    target=0.01, pilot=8, plain=12, surrogate=True,
    quantities={
        "σy at H, 9 µs": lambda runs: runs["flow_stress"].sel(probe="H").isel(
            time=_nearest(runs["time"].values, 9e-6)).values,
        "σy at H, time mean": lambda runs: runs["flow_stress"].sel(probe="H").mean(
            "time").values})

CASES = {
    # the allocation on the seed's quantity: sigma_y at H at the seed-matched 9 us
    "mpm": dict(MPM, allocate_at='{ time = [9e-6], probe = ["H"] }'),
    # every point of the four probes' series must meet the target
    "mpm_all_points": MPM,
    "gamut_bar": dict(
        solver="gamut_bar",
        scene={"material": "M1", "grid": "stochastic", "loading": "monotonic"},
        key="local_bonds", values=[125, 250, 500], outputs=["failure_stress"],
        inputs={"bar.E": ("normal", 71.6e9, 0.05), "bar.sigma_y": ("normal", 538.6e6, 0.05),
                "bar.sigma_f": ("normal", 665.8e6, 0.05)},
        target=0.002, pilot=16, plain=48,
        quantities={"failure stress": lambda runs: runs["failure_stress"].values}),
    "sph": dict(
        solver="sph", scene=None, key="resolution", values=[0.5, 0.75, 1.0],
        outputs=["effective_modulus"],
        inputs={"matrix.E": ("lognormal", 1e6, 0.10), "inclusion.E": ("lognormal", 150e6, 0.10)},
        target=0.003, pilot=8, plain=24,
        quantities={"effective modulus": lambda runs: runs["effective_modulus"].values}),
    "euler": dict(
        solver="analytic", scene={"model": "euler_decay"}, key="steps", values=[4, 16, 64],
        outputs=["y"], inputs={"k": ("normal", 1.0, 0.2)}, target=0.01, pilot=8, plain=32,
        surrogate=True,
        quantities={"y(T)": lambda runs: runs["y"].values}),
}


def _sph_scene(folder: Path) -> str:
    # Example 3's materials on a 150 µm plate with 3 ellipses kept 23 µm apart (a gap in
    # metres: the same ellipses at every resolution, docs/sph.md § 6); one load step gives the
    # effective modulus
    text = (ROOT / "studies" / "scenes" / "sph_example3.toml").read_text()
    text = text.replace("steps = 40", "steps = 1")
    text = text.replace("width = 100e-6", "width = 150e-6").replace("height = 100e-6",
                                                                      "height = 150e-6")
    text = text.replace("random = { count = 9, semi_axes_min = [6e-6, 3e-6], semi_axes_max = "
                        "[10e-6, 6e-6], layout_seed = 3 }",
                        "random = { count = 3, semi_axes_min = [8e-6, 6e-6], semi_axes_max = "
                        "[12e-6, 9e-6], layout_seed = 3, min_gap = 23e-6 }")
    path = folder / "sph_levels_scene.toml"
    path.write_text(text)
    return str(path)


def _scene_line(case, folder) -> str:
    scene = case["scene"]
    if callable(scene):
        scene = scene(folder)
    if scene is None:
        scene = _sph_scene(folder)
    if isinstance(scene, str):
        return f'scene = "{scene}"'
    return "scene = { " + ", ".join(f"{k} = {v!r}".replace("'", '"')
                                     for k, v in scene.items()) + " }"


def _study(folder: Path, name: str, case: dict, method: str, finest_only=False,
           extra: str = "") -> Path:
    lines = [f'name = "{name}"', f'solver = "{case["solver"]}"', _scene_line(case, folder),
             "outputs = [" + ", ".join(f'"{o}"' for o in case["outputs"]) + "]", ""]
    for k, (dist, mean, cv) in case["inputs"].items():
        lines += ["[[inputs]]", f'name = "{k}"', f'distribution = "{dist}"',
                  f"mean = {mean!r}", f"cv = {cv!r}", ""]
    if finest_only:
        lines += ["[method]", 'kind = "monte-carlo"', f"samples = {case['plain']}", ""]
    else:
        lines += ["[levels]", f'key = "{case["key"]}"', f"values = {case['values']!r}", "",
                  "[method]", f'kind = "{method}"', f"target_rel_rmse = {case['target']!r}",
                  f"pilot = {case['pilot']}", extra,
                  f"allocate_at = {case['allocate_at']}" if case.get("allocate_at") else "", ""]
    lines += ["[execution]", "workers = 0", "seed = 7", "", "[output]",
              f'path = "{name}.nc"', "figures = false", ""]
    path = folder / f"{name}.toml"
    path.write_text("\n".join(lines))
    if finest_only:
        study = uqflow.load_study(path)
        scene = dict(study.scene)
        scene[case["key"]] = case["values"][-1]
        text = path.read_text().replace(lines[2], "scene = " + _inline(scene))
        path.write_text(text)
    return path


def _inline(value) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_inline(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_inline(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def _mlmc_quantity(study, runs, q):
    method = study.method
    pairs = method.pairs(runs)
    values = q(runs)
    terms = [mlmc_level_terms(values[fine][:, None], None if coarse is None else
                              values[coarse][:, None]) for fine, coarse, _, _ in pairs]
    E = np.array([t["mean"][0] for t in terms])
    V = np.array([t["V"][0] for t in terms])
    n = np.array([fine.size for fine, _, _, _ in pairs])
    alpha = level_rate(E)
    return dict(mean=E.sum(), se=math.sqrt(np.sum(V / n)),
                bias=float(mlmc_bias(E[:, None], alpha)[0]), E=E, V=V, n=n,
                alpha=alpha, beta=level_rate(V))


def _mfmc_quantity(study, runs, q):
    method = study.method
    rows, _, _ = method.samples(runs)
    values = q(runs)
    parts = [values[r][:, None] for r in rows]
    counts = [r.size for r in rows]
    shared = min(r.size for r in rows)   # samples every model ran (the finest need not be fewest)
    rho = [float(np.corrcoef(values[rows[0][:shared]], values[r[:shared]])[0, 1]) for r in rows]
    surrogates = method.surrogates(runs.drop_vars(study.outputs), runs)
    if surrogates:
        # the quantities are linear in the output (a value, a time mean): the surrogate of
        # the quantity is the quantity of the surrogate, and so is its exact mean
        name = study.outputs[0]
        widest = rows[int(np.argmax(counts))]
        template = runs[name].isel(realization=widest)
        g = q(xr.Dataset({name: template.copy(data=surrogates[name](
            runs["inputs"].values[widest]).reshape(template.shape))}))
        mean = q(xr.Dataset({name: template.isel(realization=[0]).copy(
            data=surrogates[name].mean.reshape((1, *template.shape[1:])))}))
        parts.append(g[:, None])
        counts.append(math.inf)
        rho.append(float(np.corrcoef(values[rows[0][:shared]], g[:shared])[0, 1]))
        got = mfmc_estimate(parts, counts, exact_mean=np.asarray(mean, dtype=float))
    else:
        got = mfmc_estimate(parts, counts)
    return dict(mean=float(got["mean"][0]), se=float(math.sqrt(got["variance"][0])),
                rho=rho, m=[r.size for r in rows] + (["∞"] if surrogates else []))


def run_case(name, case, folder):
    t0 = time.perf_counter()
    plain = uqflow.run_study(uqflow.load_study(_study(folder, f"{name}_plain", case, None,
                                                      finest_only=True)),
                             show_progress=False, force=True)
    ok = plain.runs["status"].values == "ok"
    c_L = float(np.median(plain.runs["wall_time"].values[ok]))
    out = {"plain": plain, "c_L": c_L}
    for method in METHODS if case.get("surrogate") else METHODS[:2]:
        kind, extra = method.split("+")[0], ""
        if "+" in method:
            extra = 'surrogate = "taylor-local"'
        study = uqflow.load_study(_study(folder, f"{name}_{kind}{'_s' if extra else ''}",
                                         case, kind, extra=extra))
        outcome = uqflow.run_study(study, show_progress=False, force=True)
        out[method] = (study, outcome)
    out["wall"] = time.perf_counter() - t0
    rows = []
    for label, q in case["quantities"].items():
        p = q(plain.runs)[ok]
        s2 = float(np.var(p, ddof=1))
        plain_se = math.sqrt(s2 / p.size)
        row = {"quantity": label, "plain_mean": float(p.mean()), "plain_se": plain_se,
               "s_L": math.sqrt(s2)}
        for method in (m for m in METHODS if m in out):
            estimate = _mlmc_quantity if method == "multilevel" else _mfmc_quantity
            study, outcome = out[method]
            got = estimate(study, outcome.runs, q)
            cost = float(np.nansum(outcome.runs["wall_time"].values))
            needed = s2 / got["se"] ** 2 * c_L
            got.update(cost=cost, plain_cost=needed, ratio=needed / cost,
                       z=(got["mean"] - p.mean()) / math.hypot(got["se"], plain_se))
            row[method] = got
        rows.append(row)
    out["rows"] = rows
    return out


def _level_costs(outcome):
    return outcome.statistics[("level_run_cost" if outcome.statistics.attrs["method"] ==
                               "multilevel" else "model_run_cost")].values


def report(results) -> str:
    body = ("Each case: plain MC at the finest level (its runs give s_L and the cost per run "
            "c_L), then `multilevel` and `multifidelity` with the same `target_rel_rmse`, all "
            "in one process, costs measured (the pilot's median wall time per level). "
            "'plain cost' is s_L^2 / se^2 runs of c_L for the method's stderr se (same finest "
            "level, so the same bias); 'ratio' is plain cost over the method's measured "
            "solver time; z compares the method's mean with plain MC's (combined s.e.). "
            f"1-minute load average at the end: {os.getloadavg()[0]:.2f}.\n")
    for name, res in results.items():
        case = CASES[name]
        ml_study, ml = res["multilevel"]
        where = f", allocate_at = {case['allocate_at']}" if case.get("allocate_at") else \
            ", every point of the output allocating"
        body += (f"\n### {name}: {case['key']} = {case['values']}{where}\n\n"
                 f"Plain MC: {case['plain']} runs at {case['key']} = {case['values'][-1]}, "
                 f"c_L = {res['c_L']:.3g} s per run. Run costs per level (pilot medians, s): "
                 f"{', '.join(f'{c:.3g}' for c in _level_costs(ml))}. Whole case "
                 f"{res['wall']:.0f} s.\n\n")
        body += ("| quantity | method | mean | se | bias est. | runs per level | V_l or ρ | "
                 "cost (s) | plain cost (s) | ratio | z vs plain |\n"
                 "|---|---|---|---|---|---|---|---|---|---|---|\n")
        for row in res["rows"]:
            body += (f"| {row['quantity']} | plain | {row['plain_mean']:.5g} | "
                     f"{row['plain_se']:.3g} | | {case['plain']} | s_L {row['s_L']:.3g} | "
                     f"{case['plain'] * res['c_L']:.3g} | | | |\n")
            g = row["multilevel"]
            body += (f"| | multilevel | {g['mean']:.5g} | {g['se']:.3g} | {g['bias']:.2g} | "
                     f"{'/'.join(map(str, g['n']))} | "
                     f"{'/'.join(f'{v:.2g}' for v in g['V'])} (β {g['beta']:.2g}) | "
                     f"{g['cost']:.3g} | {g['plain_cost']:.3g} | **{g['ratio']:.2g}** | "
                     f"{g['z']:.2f} |\n")
            for method in (m for m in METHODS[1:] if m in row):
                g = row[method]
                body += (f"| | {method} | {g['mean']:.5g} | {g['se']:.3g} | | "
                         f"{'/'.join(map(str, g['m']))} | "
                         f"ρ {'/'.join(f'{v:.4f}' for v in g['rho'])} | {g['cost']:.3g} | "
                         f"{g['plain_cost']:.3g} | **{g['ratio']:.2g}** | {g['z']:.2f} |\n")
        warnings = [w for m in METHODS if m in res for w in res[m][1].warnings]
        if warnings:
            body += "\nWarnings: " + " / ".join(warnings) + "\n"
    return body


def figure(results, name) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.6), squeeze=False)
    for ax, name in zip(axes[0], names):
        res = results[name]
        row = res["rows"][0]
        cost = np.geomspace(res["c_L"], 1e3 * res["c_L"] * CASES[name]["plain"], 50)
        ax.loglog(cost, row["s_L"] * np.sqrt(res["c_L"] / cost), "k-", label="plain MC")
        ax.loglog(CASES[name]["plain"] * res["c_L"], row["plain_se"], "ko")
        for method, marker in zip(METHODS, "s^v"):
            if method not in row:
                continue
            g = row[method]
            ax.loglog(g["cost"], g["se"], marker, ms=8, label=f"{method} ({g['ratio']:.2g}x)")
        ax.set(xlabel="solver time (s)", ylabel="standard error",
               title=f"{name}: {row['quantity']}")
        ax.legend(fontsize=8, loc="upper right")   # the methods' points sit low and left
    fig.tight_layout()
    fig.savefig(FIGURES / f"multilevel_gain_{name}.png", dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=["mpm", "gamut_bar", "sph"])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    cases = ["euler"] if args.quick else args.cases
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in cases:
            results[name] = run_case(name, CASES[name], Path(tmp))
            print(report({name: results[name]}), flush=True)
    if args.quick:
        return results
    for name, result in results.items():
        write_section(f"multilevel-gain-{name}", f"Multilevel and multifidelity Monte Carlo "
                      f"against plain Monte Carlo: {name}", report({name: result}))
        figure({name: result}, name)
    return results


if __name__ == "__main__":
    main()
